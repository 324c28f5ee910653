#!/bin/bash
# What vox and voxd say to bad input: for each kind, the exit status that
# docs/cli.md documents (0 done, 1 failed, 2 bad usage or input, 3 no voxd),
# the words that say what is wrong, at most 3 lines on stderr for the one
# error, and no line of either stream over 240 characters.
. "$(dirname "$0")/lib.sh"
VOXD=${VOXD:-$(dirname "$VOX")/voxd}
# no daemon: the commands that would use one say so (exit 3)
export VOXD_SOCKET=$TMP/none.sock

# msg NAME CODE PATTERN COMMAND...: exit CODE, stderr matching the extended
# regex PATTERN in 1 to 3 lines, no line over 240 characters
msg() {
    local n=$1 code=$2 pat=$3
    shift 3
    "$@" >"$TMP/o" 2>"$TMP/e" </dev/null
    local rc=$? lines long
    lines=$(wc -l <"$TMP/e")
    long=$(awk 'length > 240' "$TMP/o" "$TMP/e" | wc -l)
    if [ "$rc" -eq "$code" ] && [ "$lines" -ge 1 ] && [ "$lines" -le 3 ] && [ "$long" -eq 0 ] &&
        grep -Eq -- "$pat" "$TMP/e"; then
        pass "$n"
    else
        fail "$n" "exit $rc (want $code), $lines lines, $long over 240: $(head -c 600 "$TMP/e")"
    fi
}

"$VOX" voxelize -e 'sqrt(x^2+y^2+z^2)-0.8' -r 8 -w 0 -q -o "$TMP/s.vod" || fail "make s.vod"
printf 'hello\n' >"$TMP/text6"
printf 'a = cuboid size 1,1,1\nresult a\n' >"$TMP/t.csg"
printf 'a = cuboid size 1,1,1\nb = union(a, nope)\nresult b\n' >"$TMP/bad.csg"
printf 'v 0 0 0\nv 1 0 0\nf 1 2 9\n' >"$TMP/bad.obj"

# ---- vox: options and commands
msg "a mistyped option: one line with the nearest" 2 \
    "^vox: voxelize: unknown option '--outptu' \(did you mean '--output'\?\); see 'vox voxelize --help'$" \
    "$VOX" voxelize -e x --outptu "$TMP/a.vod"
msg "an unknown option, nothing near" 2 "^vox: voxelize: unknown option '--zzzzzzzz'; see" \
    "$VOX" voxelize -e x --zzzzzzzz -o "$TMP/a.vod"
msg "an unknown short option" 2 "^vox: voxelize: unknown option '-Q'; see 'vox voxelize --help'$" \
    "$VOX" voxelize -e x -Q -o "$TMP/a.vod"
msg "an ambiguous abbreviation" 2 "ambiguous option '--comp' \(--compress, --compress-level\?\)" \
    "$VOX" voxelize -e x --comp zlib -o "$TMP/a.vod"
msg "an option without its value" 2 "option '-o' needs a value" "$VOX" voxelize -e x -o
msg "a flag given a value" 2 "option '--quiet' takes no value" "$VOX" voxelize --quiet=1 -e x
msg "an argument too many" 2 "unexpected argument 'extra'" "$VOX" voxelize -e x -o "$TMP/a.vod" extra
msg "an unknown command, with the nearest" 2 "unknown command 'voxelise' \(did you mean 'voxelize'\?\)" \
    "$VOX" voxelise
msg "no command" 2 "missing COMMAND" "$VOX"
msg "vox's own option mistyped" 2 "unknown option '--sokcet' \(did you mean '--socket'\?\); see 'vox --help'" \
    "$VOX" --sokcet x status
msg "a long argument is cut in the message" 2 "unknown option '--x{38}\.\.\.'" \
    "$VOX" voxelize "--$(printf 'x%.0s' $(seq 3000))"

# ---- vox voxelize / submit
msg "no job" 2 "missing the job: give one of --expr, --file, --mesh" "$VOX" voxelize -o "$TMP/a.vod"
msg "two jobs" 2 "give only one of --expr, --file, --mesh" "$VOX" voxelize -e x -f f.vx -o "$TMP/a.vod"
msg "no output" 2 "missing -o OUT.vod" "$VOX" voxelize -e x
msg "a bad expression: where, and a caret" 2 "<expr>:1:3: " "$VOX" voxelize -e 'x+' -o "$TMP/a.vod"
msg "a bad --res" 2 "bad --res 'abc'" "$VOX" voxelize -e x -r abc -o "$TMP/a.vod"
msg "--res past the engine's limit" 2 "bad --res '5000': want a whole number from 1 to 4096" \
    "$VOX" voxelize --embedded -e x -r 5000 -o "$TMP/a.vod"
msg "a bad --channel" 2 "bad value 'foo' for --channel" "$VOX" voxelize -e x --channel foo -o "$TMP/a.vod"
msg "mesh options without a mesh" 2 "are for --mesh jobs" "$VOX" voxelize -e x --mode solid -o "$TMP/a.vod"
msg "a mesh that is not there" 2 "nothere.obj" "$VOX" voxelize --embedded --mesh "$TMP/nothere.obj" -o "$TMP/a.vod"
msg "a broken mesh" 2 "bad.obj" "$VOX" voxelize --embedded --mesh "$TMP/bad.obj" -o "$TMP/a.vod"
msg "submit -w: workers belong to the daemon" 2 "submit: -w/--workers belongs to the daemon" \
    "$VOX" submit -w 1 -e x -o "$TMP/a.vod"
msg "submit --embedded" 2 "--embedded is vox voxelize's" "$VOX" submit --embedded -e x -o "$TMP/a.vod"
msg "submit with no daemon" 3 "no voxd answering on .*none.sock" "$VOX" submit -e x -r 8 -o "$TMP/a.vod"
msg "voxelize --daemon with no daemon" 3 "no voxd answering" "$VOX" voxelize --daemon -e x -r 8 -o "$TMP/a.vod"
msg "a job with no voxel: a warning, exit 0" 0 "^vox: warning: .*a.vod has no voxel" \
    "$VOX" voxelize -e 'x+100' -r 8 -w 0 -q -o "$TMP/a.vod"

# ---- status, cancel, ping
msg "status with no daemon" 3 "no voxd answering" "$VOX" status
msg "ping with an argument" 2 "ping: unexpected argument 'now'" "$VOX" ping now
msg "cancel without an id" 2 "cancel: missing JOB_ID" "$VOX" cancel
msg "cancel, a bad id" 2 "bad JOB_ID 'x1'" "$VOX" cancel x1

# ---- info, render, mesh-info
msg "info on a 6-byte text file: not a VOD file" 1 "text6: not a VOD file \(bad signature" "$VOX" info "$TMP/text6"
msg "info on no file" 2 "info: missing FILE.vod" "$VOX" info
msg "info on a missing file" 1 "nothere.vod" "$VOX" info "$TMP/nothere.vod"
msg "render without -o" 2 "render: missing -o OUT.png" "$VOX" render "$TMP/s.vod"
msg "render, a bad value" 2 "render: bad --azimuth 'north'" "$VOX" render "$TMP/s.vod" -o "$TMP/a.png" --azimuth north
msg "mesh-info without a file" 2 "mesh-info: missing the mesh FILE" "$VOX" mesh-info
msg "mesh-info on a broken mesh" 1 "bad.obj" "$VOX" mesh-info "$TMP/bad.obj"

# ---- csg
msg "csg without --res" 2 "^vox: csg: missing --res N \(voxels along the longest axis\); see 'vox csg --help'$" \
    "$VOX" csg "$TMP/t.csg" -o "$TMP/c.vod"
msg "csg without a tree" 2 "csg: missing the tree" "$VOX" csg -o "$TMP/c.vod" -r 8
msg "csg, a bad tree: line, column, node, caret" 2 "bad.csg:2:14: node 'b': unknown node 'nope'" \
    "$VOX" csg "$TMP/bad.csg" -o "$TMP/c.vod" -r 8

# ---- export, mesh
msg "export without input" 2 "export: missing the input FILE.vod" "$VOX" export
msg "export, an unknown format" 2 "no format from its extension" "$VOX" export "$TMP/s.vod" -o "$TMP/x.dat"
msg "export, a mistyped option" 2 "unknown option '--levle' \(did you mean '--level'\?\)" \
    "$VOX" export "$TMP/s.vod" -o "$TMP/x.raw" --levle 1
msg "export --gzip outside NRRD" 2 "gzip is for NRRD only" "$VOX" export "$TMP/s.vod" -o "$TMP/x.vti" --gzip
msg "mesh without -o" 2 "mesh: missing -o OUT" "$VOX" mesh "$TMP/s.vod"
msg "mesh, a mistyped option" 2 "unknown option '--isoo' \(did you mean '--iso'\?\)" \
    "$VOX" mesh "$TMP/s.vod" -o "$TMP/x.ply" --isoo 3

# ---- voxd
msg "voxd: a mistyped option" 2 "^voxd: unknown option '--sokcet' \(did you mean '--socket'\?\); see 'voxd --help'$" \
    "$VOXD" --sokcet "$TMP/v.sock"
msg "voxd: an option without its value" 2 "option '--workers' needs a value" "$VOXD" --workers
msg "voxd: a bad --workers" 2 "bad --workers '0'" "$VOXD" --workers 0
msg "voxd: an argument" 2 "unexpected argument 'now'" "$VOXD" now
msg "voxd: a config that is not there" 1 "nothere.conf" "$VOXD" --config "$TMP/nothere.conf" --socket "$TMP/v.sock"

# ---- what is said on success
refuse "vox --version: version and commit" 0 "^vox [0-9.]+ \(commit ([0-9a-f]{7,}|unknown)\)$" "$VOX" --version
refuse "voxd --version: version and commit" 0 "^voxd [0-9.]+ \(commit ([0-9a-f]{7,}|unknown), protocol 1\)$" \
    "$VOXD" --version
"$VOX" export "$TMP/s.vod" -o "$TMP/x.nrrd" >"$TMP/o" 2>"$TMP/e"
if [ $? -eq 0 ] && [ "$(wc -l <"$TMP/o")" -eq 1 ] && [ ! -s "$TMP/e" ] &&
    grep -Eq "x.nrrd: NRRD, 8x8x8 voxels of level 0 with normals, [0-9]+ bytes$" "$TMP/o"; then
    pass "export says one line: what it wrote"
else
    fail "export says one line: what it wrote" "$(cat "$TMP/o" "$TMP/e")"
fi
refuse "plurals: 1 brick task, 1 worker" 0 "\(1 brick task, 1 worker\)" "$VOX" mesh "$TMP/s.vod" -o "$TMP/x.ply" -w 1

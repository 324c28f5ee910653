#!/bin/bash
# vox end to end: real processes, real files.
. "$(dirname "$0")/lib.sh"
# The embedded engine, always: `vox voxelize` would use a voxd that happens
# to answer on the default socket (these tests are about the engine in vox).
export VOXD_SOCKET=/nonexistent/voxd.sock

check "vox --help" "$VOX" --help
refuse "unknown command" 2 "unknown command 'frobnicate'" "$VOX" frobnicate
check "voxelize --help" "$VOX" voxelize --help

# The same job, serial and with 1 and 2 workers, both schedules: same bytes.
S='sqrt(x^2+y^2+z^2) - 0.8'
check "serial sphere" "$VOX" voxelize -e "$S" -r 64 -w 0 -o "$TMP/s0.vod"
check "1 worker" "$VOX" voxelize -e "$S" -r 64 -w 1 -o "$TMP/s1.vod"
check "2 workers" "$VOX" voxelize -e "$S" -r 64 -w 2 --cpus 0,1 -o "$TMP/s2.vod"
check "2 workers, paper schedule" "$VOX" voxelize -e "$S" -r 64 -w 2 --schedule paper -o "$TMP/sp.vod"
check "serial = 1 worker (bytes)" cmp "$TMP/s0.vod" "$TMP/s1.vod"
check "serial = 2 workers (bytes)" cmp "$TMP/s0.vod" "$TMP/s2.vod"
check "serial = paper schedule (bytes)" cmp "$TMP/s0.vod" "$TMP/sp.vod"

refuse "info validates" 0 "valid VOD.*CRC-32 checked" "$VOX" info "$TMP/s1.vod"
refuse "info shows the volume" 0 "volume +64 x 64 x 64" "$VOX" info "$TMP/s1.vod"

# Any resolution and a box domain: the longest axis gets res voxels.
check "box domain, res 100" "$VOX" voxelize -e "$S" -d -1,1,-0.5,0.5,-0.25,0.25 -r 100 -o "$TMP/box.vod"
refuse "box volume" 0 "volume +100 x 50 x 25" "$VOX" info "$TMP/box.vod"
check "res 1" "$VOX" voxelize -e "x" -r 1 -o "$TMP/one.vod"
refuse "res 1 volume" 0 "volume +1 x 1 x 1" "$VOX" info "$TMP/one.vod"

check "scene file with directives" "$VOX" voxelize -f examples/scene2.vx -r 48 -o "$TMP/scene2.vod"
refuse "directive domain used" 0 "domain=-1.05,1.05" "$VOX" info "$TMP/scene2.vod"
check "occupancy channel" "$VOX" voxelize -e "$S" -r 32 --channel occupancy --compress runl --hash xx32 --brick 8 -o "$TMP/occ.vod"
refuse "occupancy is 1 bit" 0 "1 bits" "$VOX" info "$TMP/occ.vod"
# vox info's content checksum: the voxels, whatever the compression or hash.
for c in "zlib sfhs" "none xx32" "runl sfhs"; do
    set -- $c
    check "sphere, $1 $2" "$VOX" voxelize -e "$S" -r 48 --compress "$1" --hash "$2" -o "$TMP/c-$1.vod"
done
csum() { "$VOX" info "$1" | sed -n 's/.*content checksum \([0-9a-f]*\).*/\1/p'; }
a=$(csum "$TMP/c-zlib.vod") b=$(csum "$TMP/c-none.vod") c=$(csum "$TMP/c-runl.vod")
if [ -n "$a" ] && [ "$a" = "$b" ] && [ "$a" = "$c" ]; then pass "content checksum ignores compression and hash"
else fail "content checksum ignores compression and hash" "$a $b $c"; fi
check "sphere, other voxels" "$VOX" voxelize -e "$S" -r 47 -o "$TMP/c-47.vod"
d=$(csum "$TMP/c-47.vod")
if [ -n "$d" ] && [ "$d" != "$a" ]; then pass "content checksum tells other voxels apart"
else fail "content checksum tells other voxels apart" "$a $d"; fi
refuse "info counts the voxels" 0 "voxels +[0-9]+ non-empty at full resolution" "$VOX" info "$TMP/c-47.vod"
# --compress-level: other bytes, the same voxels; the summary's stage times.
for l in 1 9 12; do
    check "sphere, zlib level $l" "$VOX" voxelize -e "$S" -r 48 --compress-level "$l" -o "$TMP/l$l.vod"
    e=$(csum "$TMP/l$l.vod")
    if [ -n "$e" ] && [ "$e" = "$a" ]; then pass "level $l: the same voxels"
    else fail "level $l: the same voxels" "$a $e"; fi
done
check "level 1 = level 6 for surface bricks (one-pass encoder)" cmp "$TMP/l1.vod" "$TMP/c-zlib.vod"
if ! cmp -s "$TMP/l9.vod" "$TMP/c-zlib.vod"; then pass "level 9 (libdeflate): other bytes"
else fail "level 9 (libdeflate): other bytes"; fi
refuse "level 13" 2 "bad --compress-level '13': want 1..12" "$VOX" voxelize -e "$S" -r 8 --compress-level 13 -o "$TMP/bad.vod"
refuse "level with --daemon" 2 "--compress-level are the embedded engine's" "$VOX" voxelize -e "$S" -r 8 --compress-level 9 --daemon -o "$TMP/bad.vod"
refuse "submit takes voxd's level only" 2 "voxd writes at level 6" "$VOX" submit -e "$S" -r 8 --compress-level 9 -o "$TMP/bad.vod"
refuse "summary: VOD stage times" 0 "^  VOD stages: fill [0-9.]+ s, hash [0-9.]+ s, compress [0-9.]+ s, assemble [0-9.]+ s, write [0-9.]+ s" "$VOX" voxelize -e "$S" -r 48 -w 2 -o "$TMP/st.vod"
refuse "progress line" 0 "level" "$VOX" voxelize -e "$S" -r 64 --progress -o "$TMP/p.vod"

# Errors: clear message, exit 2, no output file left behind.
refuse "parse error has line:col" 2 "<expr>:1:11: expected .\).* at 1:9" "$VOX" voxelize -e "x + y * (z" -r 8 -o "$TMP/bad.vod"
refuse "unknown function" 2 "<expr>:1:1: unknown function 'sinn'" "$VOX" voxelize -e "sinn(x)" -r 8 -o "$TMP/bad.vod"
refuse "res 0" 2 "bad --res" "$VOX" voxelize -e x -r 0 -o "$TMP/bad.vod"
refuse "res 4097" 2 "bad --res" "$VOX" voxelize -e x -r 4097 -o "$TMP/bad.vod"
refuse "empty domain" 2 "bad --domain" "$VOX" voxelize -e x -d 1,0 -o "$TMP/bad.vod"
refuse "no output" 2 "missing -o" "$VOX" voxelize -e x
refuse "unwritable output" 1 "cannot create" "$VOX" voxelize -e x -r 8 -o /nonexistent/dir/x.vod
[ -e "$TMP/bad.vod" ] && fail "no partial file" || pass "no partial file"
[ -z "$(ls "$TMP" | grep tmp)" ] && pass "no temporary file left" || fail "no temporary file left" "$(ls "$TMP")"

# The file gets the mode of any file the user writes: 0666 less the umask.
(umask 022 && "$VOX" voxelize -q -e "$S" -r 8 -o "$TMP/m022.vod")
(umask 077 && "$VOX" voxelize -q -e "$S" -r 8 -o "$TMP/m077.vod")
modes="$(stat -c %a "$TMP/m022.vod" "$TMP/m077.vod" 2>&1 | tr '\n' ' ')"
[ "$modes" = "644 600 " ] && pass "output mode follows the umask" ||
    fail "output mode follows the umask" "modes $modes (want 644 600)"

# A damaged file is refused by name.
head -c 200 "$TMP/s1.vod" >"$TMP/trunc.vod"
refuse "truncated file refused" 1 "file is truncated or corrupted" "$VOX" info "$TMP/trunc.vod"

# Pictures.
check "render" "$VOX" render "$TMP/s1.vod" -o "$TMP/s.png" --size 128
[ "$(head -c 8 "$TMP/s.png" | od -An -tx1 | tr -d ' ')" = "89504e470d0a1a0a" ] && pass "render writes a PNG" || fail "render writes a PNG"
check "render level 1, perspective" "$VOX" render "$TMP/s1.vod" -o "$TMP/s1.png" --size 64 --level 1 -p
refuse "render bad level" 2 "levels 0" "$VOX" render "$TMP/s1.vod" -o "$TMP/x.png" --level 9
# the PNG as every output: a write that fails (a file size limit, as a full
# disk) is named, and the file there before is left as it was
echo old >"$TMP/kept.png"
refuse "render past a file size limit is refused" 1 "cannot write .*kept\.png: File too large" \
    sh -c 'trap "" XFSZ; ulimit -f 1; exec "$@"' sh "$VOX" render "$TMP/s1.vod" -o "$TMP/kept.png" --size 128
[ "$(cat "$TMP/kept.png")" = old ] && pass "render: a failed write leaves the old file" ||
    fail "render: a failed write leaves the old file"
check "render occupancy" "$VOX" render "$TMP/occ.vod" -o "$TMP/occ.png" --size 64
# meshes (by their extension): flat and smooth, and the options of the other kind refused
cat >"$TMP/tet.obj" <<'OBJ'
v 0 0 0
v 1 0 0
v 0 1 0
v 0 0 1
f 1 3 2
f 1 2 4
f 1 4 3
f 2 3 4
OBJ
refuse "render a mesh" 0 "tet.png: 4 triangles drawn, 64x64" "$VOX" render "$TMP/tet.obj" -o "$TMP/tet.png" --size 64
refuse "render a mesh, smooth" 0 "4 triangles drawn" "$VOX" render "$TMP/tet.obj" -o "$TMP/tets.png" --size 64 --smooth
if cmp -s "$TMP/tet.png" "$TMP/tets.png"; then fail "smooth shading differs from flat"
else pass "smooth shading differs from flat"; fi
refuse "render: --level is for VOD files" 2 "not meshes" "$VOX" render "$TMP/tet.obj" -o "$TMP/x.png" --level 1
refuse "render: --smooth is for meshes" 2 "not VOD files" "$VOX" render "$TMP/s1.vod" -o "$TMP/x.png" --smooth
printf 'v 0 0 0\nf 1 2 3\n' >"$TMP/bad.obj"
refuse "render: a bad mesh is named with its line" 1 "bad.obj: line 2" "$VOX" render "$TMP/bad.obj" -o "$TMP/x.png"

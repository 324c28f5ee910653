#!/bin/bash
# vox_mpi (docs/mpi.md) under mpirun, its ranks talking over TCP as on
# separate machines (--mca btl self,tcp; --oversubscribe: more ranks than
# this machine's cores):
#  - the file from R ranks x W workers is byte for byte vox voxelize -w W's,
#    R = 1..4 x W = 0..2 on the sphere and Scene 1, and on the other shapes
#    and scenes and a few options at some of them;
#  - mesh jobs (a closed torus the test writes as OBJ, and one with holes
#    for the repairs) and CSG jobs (examples/part.csg, a tree with a mesh
#    leaf, erosion and dilation) the same way, against vox voxelize --mesh
#    and vox csg -w W: R = 1..4 x W = 0..2, and the channels, modes and
#    repairs at some of them;
#  - bad input on rank 0 (an expression, a mesh, a CSG tree): its message,
#    and every rank exits non-zero, no file;
#  - a rank that fails (its engine's limit): rank 0 names it and its host;
#  - a rank killed mid-job: the job ends within seconds, mpirun names the
#    rank and the host, and no file, temporary file, process or shared
#    memory is left.
#  - make bench-mpi's table in its quick mode, so that it cannot rot.
# The release build (the runner's $VOX): Open MPI's own allocations are not
# this project's to answer for under LeakSanitizer, and the sanitizers add
# nothing to a comparison of outputs.
VOXR=${VOX:-build/release/vox}
. "$(dirname "$0")/lib.sh"
VOXMPI=$(dirname "$VOXR")/vox_mpi
export VOXD_SOCKET=/nonexistent/voxd.sock
# CI runs as root, which mpirun refuses unless told
[ "$(id -u)" -eq 0 ] && export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
MPIRUN=(mpirun --oversubscribe --mca btl self,tcp)

if ! command -v mpirun >/dev/null || [ ! -x "$VOXMPI" ]; then
    fail "mpi: mpirun and $VOXMPI" "make deps installs openmpi-bin; make builds vox_mpi"
    exit 0
fi

# same_as CMD NAME R W ARGS...: vox_mpi CMD on R ranks x W workers writes
# vox CMD -w W's bytes (CMD voxelize or csg)
same_as() {
    local cmd=$1 name=$2 r=$3 w=$4; shift 4
    local ref="$TMP/ref-$name-$w.vod" emb=()
    [ "$cmd" = voxelize ] && emb=(--embedded)
    [ -f "$ref" ] || "$VOXR" "$cmd" "${emb[@]}" -q -w "$w" "$@" -o "$ref" >"$TMP/ref.log" 2>&1
    if ! timeout 60 "${MPIRUN[@]}" -np "$r" "$VOXMPI" "$cmd" -q -w "$w" "$@" \
        -o "$TMP/m.vod" >"$TMP/m.log" 2>&1; then
        fail "mpi: $name on $r ranks x $w workers ran" "$(tail -5 "$TMP/m.log")"
    elif cmp -s "$ref" "$TMP/m.vod"; then
        pass "mpi: $name on $r ranks x $w workers: vox voxelize's bytes"
    else
        fail "mpi: $name on $r ranks x $w workers: vox voxelize's bytes" "$(cmp "$ref" "$TMP/m.vod")"
    fi
    rm -f "$TMP/m.vod"
}
same() { same_as voxelize "$@"; }

for r in 1 2 3 4; do
    for w in 0 1 2; do
        same sphere $r $w -f examples/sphere.vx -r 96
        same scene1 $r $w -f examples/scene1.vx -r 128
    done
done
i=0
for s in torus blend2 union64 scene2 scene3; do
    same "$s" $((2 + i % 3)) $((i % 3)) -f "examples/$s.vx" -r 100
    i=$((i + 1))
done
same "scene3 at 256" 4 1 -f examples/scene3.vx -r 256
same "scene2, occupancy, bricks of 8" 3 1 -f examples/scene2.vx -r 120 --channel occupancy --brick 8
same "torus, RUNL, xx32, a flat domain" 2 2 -f examples/torus.vx -r 90 --compress runl --hash xx32 -d -1,1,-1,1,-0.4,0.4
same "sphere at 8^3 (one brick)" 3 1 -e 'x^2+y^2+z^2-0.5' -r 8

# A torus of 576 triangles, closed, and open (every 37th triangle left out:
# the repairs have something to do): lib.sh's torus_obj.
torus_obj 24 12 >"$TMP/torus.obj"
torus_obj 24 12 37 >"$TMP/open.obj"
refuse "mpi: the test's torus is watertight" 0 'watertight  yes' "$VOXR" mesh-info "$TMP/torus.obj"
refuse "mpi: the test's open torus is not" 0 'watertight  no' "$VOXR" mesh-info "$TMP/open.obj"
# the CSG tree with a mesh leaf: its name relative to the tree's folder
cat >"$TMP/leaf.csg" <<'EOF'
ring = mesh "torus.obj" fit 0,0,0.1 scale 1.5
ball = implicit "x^2 + y^2 + z^2 - 0.3"
all  = union(erode(ring, 1), dilate(ball, 2))
result all
EOF

for r in 1 2 3 4; do
    for w in 0 1 2; do
        same "torus mesh" $r $w --mesh "$TMP/torus.obj" -r 150
        same_as csg part $r $w examples/part.csg -r 96
    done
done
i=0
for a in "--channel density" "--channel surface" "--mode surface6" \
         "--mode interior --supersample 3" "--supersample 3 --channel density" "--pad 5 --brick 8" \
         "--bbox -0.9,0.5,-0.9,0.9,-0.3,0.3"; do
    # shellcheck disable=SC2086 # the options are words
    same "torus mesh, $a" $((2 + i % 3)) $((i % 3)) --mesh "$TMP/torus.obj" -r 130 $a
    i=$((i + 1))
done
same "open torus, --repair vote" 3 1 --mesh "$TMP/open.obj" -r 200 --repair vote
same "open torus, --repair winding" 2 2 --mesh "$TMP/open.obj" -r 100 --repair winding --mode interior
same "closed torus, --repair vote (not needed)" 4 0 --mesh "$TMP/torus.obj" -r 100 --repair vote
for r in 1 2 3 4; do
    same_as csg "tree with a mesh leaf" $r $((r % 3)) "$TMP/leaf.csg" -r 80
done
same_as csg "tree with a mesh leaf, surface" 3 1 "$TMP/leaf.csg" -r 90 -c surface
same_as csg "part, occupancy, RUNL, a flat domain" 2 2 examples/part.csg -r 110 -c occupancy -Z runl \
    -d -1,1,-0.6,0.6,-0.5,0.5
same_as csg "part at 8^3" 3 0 examples/part.csg -r 8

# The distance channel (channel 4): the levels above the subtrees the float
# mean, no empty node; a mesh's columns without triangles (the box larger
# than the torus) handed out and made of the band's width; an expression's
# distance as a tree of one leaf; a tree's band in its leaves.
two_balls_csg >"$TMP/balls.csg"
for r in 1 3; do
    for w in 0 2; do
        same "torus mesh, distance, a box with empty columns" $r $w --mesh "$TMP/torus.obj" \
            -r 160 --bbox -2,2,-2,2,-0.5,0.5 --channel distance
        same "sphere, distance, band 5" $r $w -e 'sqrt(x^2+y^2+z^2) - 0.6' -r 80 \
            --channel distance --band 5
        same_as csg "two balls, distance, band 4" $r $w "$TMP/balls.csg" -r 72 --channel distance \
            --band 4
    done
done
same "open torus, distance, --repair vote, band 2" 4 1 --mesh "$TMP/open.obj" -r 160 \
    --bbox -2,2,-2,2,-0.5,0.5 --channel distance --repair vote --band 2
same "torus file, distance, a flat domain" 2 1 -f examples/torus.vx -r 90 --channel distance \
    -d -1,1,-1,1,-0.4,0.4
printf '%s\n' 'ring = mesh "torus.obj" fit 0,0,0.1 scale 1.5' \
    'ball = implicit "x^2 + y^2 + z^2 - 0.3"' 'all  = difference(ring, ball)' 'result all' \
    >"$TMP/dist.csg"
same_as csg "tree with a mesh leaf, distance" 2 1 "$TMP/dist.csg" -r 80 -c distance --band 3
same_as csg "tree with a mesh leaf, distance, serial ranks" 3 0 "$TMP/dist.csg" -r 80 -c distance

# Under AddressSanitizer and UBSan (the runner's $VOX_ASAN build): no error
# in any rank, the same bytes.  Leaks are not looked for here: Open MPI's
# plugins keep allocations past MPI_Finalize and are unloaded before
# LeakSanitizer looks, so it cannot even name them; test_mpi_part runs
# vox_mpi's own parts under LeakSanitizer.
ASANMPI=$(dirname "${VOX_ASAN:-build/asan/vox}")/vox_mpi
# asan_same WHAT W REF ARGS...: vox_mpi ARGS on 3 ranks x W workers
asan_same() {
    local what=$1 w=$2 ref=$3; shift 3
    if ! [ -x "$ASANMPI" ]; then fail "mpi: the sanitizers' build $ASANMPI is there"; return; fi
    local s0; s0=$(san_files)
    # lib.sh's options (the sanitizers' exit code, the runner's report files) kept
    ASAN_OPTIONS="$ASAN_OPTIONS:detect_leaks=0:abort_on_error=0" \
        UBSAN_OPTIONS="$UBSAN_OPTIONS:halt_on_error=1:print_stacktrace=1" \
        timeout 120 "${MPIRUN[@]}" -x ASAN_OPTIONS -x UBSAN_OPTIONS -np 3 "$ASANMPI" "$@" -q \
        -w "$w" -o "$TMP/asan.vod" >"$TMP/asan.log" 2>&1
    local rc=$?
    if [ "$rc" -eq 0 ] && ! san_in "$TMP/asan.log" "$s0" &&
       cmp -s "$ref" "$TMP/asan.vod"; then
        pass "mpi: $what on 3 ranks x $w workers under the sanitizers: no error, the same bytes"
    else
        fail "mpi: $what on 3 ranks x $w workers under the sanitizers: no error, the same bytes" \
            "exit $rc: $(grep -m3 -E 'ERROR|runtime error|^sanitizer report' "$TMP/asan.log")"
    fi
    rm -f "$TMP/asan.vod"
}
for w in 0 2; do
    asan_same "Scene 1" $w "$TMP/ref-scene1-$w.vod" voxelize -f examples/scene1.vx -r 128
done
asan_same "the torus mesh" 1 "$TMP/ref-torus mesh-1.vod" voxelize --mesh "$TMP/torus.obj" -r 150
asan_same "the torus mesh's distance, empty columns" 2 \
    "$TMP/ref-torus mesh, distance, a box with empty columns-2.vod" voxelize --mesh "$TMP/torus.obj" \
    -r 160 --bbox -2,2,-2,2,-0.5,0.5 --channel distance
asan_same "the CSG tree with a mesh leaf" 0 "$TMP/ref-tree with a mesh leaf-0.vod" \
    csg "$TMP/leaf.csg" -r 80

# The summary says what each rank sent.
timeout 60 "${MPIRUN[@]}" -np 2 "$VOXMPI" voxelize -w 1 --stats -f examples/sphere.vx -r 96 \
    -o "$TMP/s.vod" >"$TMP/s.log" 2>&1
if grep -Eq '^  sent to rank 0: [0-9]+ bytes \(rank 0 [0-9]+, rank 1 [1-9][0-9]*\)' "$TMP/s.log" &&
   [ "$(grep -Ec '^ +[01]  [^ ]+ +[0-9]+' "$TMP/s.log")" -eq 2 ]; then
    pass "mpi: the summary and --stats give the bytes each rank sent"
else
    fail "mpi: the summary and --stats give the bytes each rank sent" "$(cat "$TMP/s.log")"
fi
# --stats' rank 0's end by stage: the top levels run beside the records'
# order, then the assembly (the sink's writes inside it) and the commit,
# all within "VOD written in T s" (each figure rounded to a millisecond).
end_ok=$(/usr/bin/python3 - "$TMP/s.log" 2>&1 <<'PY'
import re, sys
log = open(sys.argv[1]).read()
n = r"(\d+\.\d{3})"
whole = re.search(r"VOD written in " + n + " s$", log, re.M)
end = re.search(r"^  rank 0's end: top levels " + n + r" s beside the records' order " + n +
                r" s, assembly " + n + r" s \(writes " + n + r" s\), commit " + n + " s$", log, re.M)
if not whole or not end:
    sys.exit("no 'VOD written in' or no 'rank 0\'s end' line of its format")
top, order, asm, writes, commit = map(float, end.groups())
t = float(whole.group(1))
if writes > asm + 0.001:
    sys.exit(f"writes {writes} s over the assembly's {asm} s")
if max(top, order) + asm + commit > t + 0.002:
    sys.exit(f"max({top}, {order}) + {asm} + {commit} s over the {t} s the VOD took")
print("ok")
PY
)
if [ "$end_ok" = ok ]; then
    pass "mpi: --stats gives rank 0's end by stage, within the time the file took"
else
    fail "mpi: --stats gives rank 0's end by stage, within the time the file took" \
        "$end_ok $(grep -E "VOD written|rank 0's end" "$TMP/s.log")"
fi

# ranks_exit R CODE ARGS...: vox_mpi's every rank exits with CODE
ranks_exit() {
    local r=$1 code=$2; shift 2
    timeout 60 "${MPIRUN[@]}" -np "$r" sh -c '"$0" "$@"; echo "rank $OMPI_COMM_WORLD_RANK exit $?"' \
        "$VOXMPI" "$@" >"$TMP/b.log" 2>&1
    [ "$(grep -c "^rank [0-9] exit $code\$" "$TMP/b.log")" -eq "$r" ]
}
if ranks_exit 3 2 voxelize -e 'sqrt(x' -o "$TMP/bad.vod" &&
   grep -q "expected ')'" "$TMP/b.log" && [ ! -e "$TMP/bad.vod" ]; then
    pass "mpi: a bad expression on rank 0: its message, every rank exits 2, no file"
else
    fail "mpi: a bad expression on rank 0: its message, every rank exits 2, no file" "$(head -8 "$TMP/b.log")"
fi
if ranks_exit 2 2 voxelize -f "$TMP/missing.vx" -o "$TMP/bad.vod" && grep -q 'missing.vx' "$TMP/b.log"; then
    pass "mpi: a missing file on rank 0: every rank exits 2"
else
    fail "mpi: a missing file on rank 0: every rank exits 2" "$(head -8 "$TMP/b.log")"
fi
printf 'v 0 0 0\nv 1 0 0\nf 1 2 3\n' >"$TMP/bad.obj"
if ranks_exit 3 2 voxelize --mesh "$TMP/bad.obj" -r 64 -o "$TMP/bad.vod" &&
   grep -q "bad.obj: " "$TMP/b.log" && [ ! -e "$TMP/bad.vod" ]; then
    pass "mpi: a malformed mesh on rank 0: its message, every rank exits 2, no file"
else
    fail "mpi: a malformed mesh on rank 0: its message, every rank exits 2, no file" "$(head -8 "$TMP/b.log")"
fi
printf 'a = cuboid center 0,0 size 1,1,1\nresult a\n' >"$TMP/bad.csg"
if ranks_exit 3 2 csg "$TMP/bad.csg" -r 64 -o "$TMP/bad.vod" &&
   grep -q "bad.csg:1:" "$TMP/b.log" && [ ! -e "$TMP/bad.vod" ]; then
    pass "mpi: a bad CSG tree on rank 0: its message, every rank exits 2, no file"
else
    fail "mpi: a bad CSG tree on rank 0: its message, every rank exits 2, no file" "$(head -8 "$TMP/b.log")"
fi
printf 'm = mesh "gone.obj"\nresult m\n' >"$TMP/gone.csg"
if ranks_exit 2 2 csg "$TMP/gone.csg" -r 64 -o "$TMP/bad.vod" && grep -q "gone.obj" "$TMP/b.log"; then
    pass "mpi: a CSG leaf's missing file on rank 0: every rank exits 2"
else
    fail "mpi: a CSG leaf's missing file on rank 0: every rank exits 2" "$(head -8 "$TMP/b.log")"
fi
refuse "mpi: an output directory that does not exist" 1 'cannot create' \
    timeout 60 "${MPIRUN[@]}" -np 2 "$VOXMPI" voxelize -e x -o "$TMP/no/such/dir.vod"
refuse "mpi: --help tells what vox_mpi runs" 0 'vox_mpi voxelize' \
    timeout 60 "${MPIRUN[@]}" -np 2 "$VOXMPI" --help

# A rank's own failure: rank 0 names the rank and the host, nothing is left.
host=$(hostname)
refuse "mpi: a rank's failure is told by rank 0 with the rank and host" 1 \
    "rank [0-9] on $host failed: .*raise the shared memory size" \
    timeout 60 "${MPIRUN[@]}" -np 2 "$VOXMPI" voxelize -w 1 --shm-size 16 --subtrees 1 \
    -f examples/scene1.vx -r 2048 -o "$TMP/lim.vod"
left=$(ls "$TMP" | grep -c '^lim\.vod')
[ "$left" -eq 0 ] && pass "mpi: no file after a rank's failure" ||
    fail "mpi: no file after a rank's failure" "$(ls "$TMP")"

# A rank killed mid-job.
shm_before=$(ls /dev/shm | sort) ranks=
timeout 120 "${MPIRUN[@]}" -np 3 "$VOXMPI" voxelize -w 1 -f examples/scene1.vx -r 1024 \
    -o "$TMP/kill.vod" >"$TMP/k.log" 2>&1 &
job=$!
victim=""
for _ in $(seq 200); do  # rank 1 with its worker forked: the job is under way
    for p in $(pgrep -f "$TMP/kill.vod"); do
        rank=$(tr '\0' '\n' <"/proc/$p/environ" 2>/dev/null | sed -n 's/^OMPI_COMM_WORLD_RANK=//p')
        [ "$rank" = 1 ] && [ -n "$(pgrep -P "$p")" ] && victim=$p
    done
    [ -n "$victim" ] && ranks=$(pgrep -f "$TMP/kill.vod") && break
    sleep 0.05
done
sleep 0.5
t0=$(date +%s.%N)
[ -n "$victim" ] && kill -9 "$victim"
wait $job
rc=$?
secs=$(echo "$(date +%s.%N) - $t0" | bc)
# (30 s, room for a loaded machine: without the rank's death noticed, the
# job runs on for minutes at 1024^3)
if [ -n "$victim" ] && [ "$rc" -ne 0 ] && [ "$(echo "$secs < 30" | bc)" -eq 1 ]; then
    pass "mpi: a rank killed mid-job ends the job (in $secs s)"
else
    fail "mpi: a rank killed mid-job ends the job" "victim '${victim}', exit $rc after $secs s: $(tail -5 "$TMP/k.log")"
fi
if grep -Eq "rank 1 .*on node $host" "$TMP/k.log"; then
    pass "mpi: the killed rank is named with its host"
else
    fail "mpi: the killed rank is named with its host" "$(cat "$TMP/k.log")"
fi
[ -z "$(ls "$TMP" | grep '^kill\.vod')" ] && pass "mpi: no file or temporary file after a killed rank" ||
    fail "mpi: no file or temporary file after a killed rank" "$(ls "$TMP")"
for _ in $(seq 300); do [ -z "$(pgrep -f "$TMP/kill.vod")" ] && break; sleep 0.1; done  # 30 s at most
[ -z "$(pgrep -f "$TMP/kill.vod")" ] && pass "mpi: no process left after a killed rank" ||
    fail "mpi: no process left after a killed rank" "$(pgrep -af "$TMP/kill.vod")"
# (what another program on the machine has open for a moment is not ours:
# only what is still there two seconds later counts; and only the job's
# own: a rank's segment is /voxd.PID.*, PID the rank's, and another
# checkout's voxd beside this run is not this job's)
ours=$(echo $ranks | sed 's/ /|/g')
new=$(comm -13 <(echo "$shm_before") <(ls /dev/shm | sort) | grep -E "^voxd\.(${ours:-none})\." || true)
[ -n "$new" ] && sleep 2 && new=$(comm -12 <(echo "$new") <(ls /dev/shm | sort))
[ -n "$ours" ] && [ -z "$new" ] && pass "mpi: no shared memory left after a killed rank" ||
    fail "mpi: no shared memory left after a killed rank" "$new"

# make bench-mpi's table (scripts/bench-mpi.sh), quick: every command has a
# time and every vox_mpi row its bytes per rank (no timing is asserted)
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
if mk V=release "$(dirname "$VOXR")/voxwhole" >"$TMP/mk.log" 2>&1 &&
   BENCH_QUICK=1 scripts/bench-mpi.sh "$(dirname "$VOXR")" >"$TMP/bench.md" 2>"$TMP/bench.err" &&
   [ "$(grep -cE '^\| vox voxelize -w [24] \| [24] \| [0-9]+\.[0-9]{3} \| 1 \| [0-9]+ \|' "$TMP/bench.md")" -eq 4 ] &&
   [ "$(grep -cE '^\| vox_mpi [124] x [124] \| [24] \| [0-9]+\.[0-9]{3} \| [0-9.]+ \| [0-9]+ \| [0-9]+ of [0-9]+\^3 \| [0-9]+ \(rank 0 [0-9]+' "$TMP/bench.md")" -eq 10 ]; then
    pass "mpi: make bench-mpi's table, quick"
else
    fail "mpi: make bench-mpi's table, quick" "$(tail -5 "$TMP/mk.log" "$TMP/bench.err" "$TMP/bench.md")"
fi

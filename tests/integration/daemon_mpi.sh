#!/bin/bash
# voxd with an mpi_hostfile (docs/daemon.md, "Large jobs through MPI"): a
# real voxd on a temporary socket, the real `vox submit`, a localhost host
# file, ranks over TCP (--oversubscribe: more ranks than cores):
#  - a job at or above mpi_min_res runs through mpirun ... vox_mpi (the log
#    says so) and its file is byte for byte `vox voxelize`'s; so is a job
#    below it, which the local engine runs;
#  - a cancel and a job_timeout mid-run end mpirun's session: no
#    rank, no job directory, no shared memory left;
#  - vox_mpi's progress reaches the client as Progress replies;
#  - a broken mpirun path: a clear error, and the daemon goes on serving.
# vox_mpi is the release build's (as in mpi.sh: Open MPI's own allocations
# are not this project's to answer for under LeakSanitizer); voxd and vox
# are the test build's.
. "$(dirname "$0")/daemon_lib.bash"
VOXMPI=$ROOT/build/release/vox_mpi
VOXR=$ROOT/build/release/vox
# CI runs as root: voxd lets its mpirun run as root then (docs/mpi.md)
if ! command -v mpirun >/dev/null || [ ! -x "$VOXMPI" ]; then
    fail "daemon_mpi: mpirun and $VOXMPI" "make deps installs openmpi-bin; make builds vox_mpi"
    exit 0
fi
echo "localhost slots=2" >"$TMP/hosts"
mkdir -p "$TMP/tmp"
export TMPDIR=$TMP/tmp   # the daemon's job directories, to look for leftovers

# conf FILE EXTRA...: a daemon that sends jobs of res >= 64 to 2 ranks x 1 worker
conf() {
    local f=$1
    shift
    {
        echo "workers 1"
        echo "shm_size 64M"
        echo "mpi_hostfile $TMP/hosts"
        echo "mpi_min_res 64"
        echo "mpi_ranks 2"
        echo "mpi_workers 1"
        echo "vox_mpi $VOXMPI"
        printf '%s\n' "$@"
    } >"$f"
}
submit() { timeout 120 "$VOX" --socket "$S" submit "$@"; }
ref() { "$VOXR" voxelize --embedded -q -w 1 "$@"; }
same() {
    if cmp -s "$1" "$2"; then pass "$3"; else fail "$3" "$(cmp "$1" "$2" 2>&1)"; fi
}

# ---------------------------------------------------------------- jobs
conf "$TMP/a.conf"
refuse "daemon_mpi: check-config takes the mpi keys" 0 "^mpi_hostfile $TMP/hosts" \
    "$VOXD" --check-config "$TMP/a.conf"
if ! start_voxd "$TMP/a.log" -c "$TMP/a.conf"; then
    fail "daemon_mpi: voxd starts" "$(tail -5 "$TMP/a.log")"
    exit 0
fi
refuse "daemon_mpi: scene1 at 96 through voxd: the summary says MPI on 2 ranks" 0 \
    "voxd job 1, .* through MPI on 2 ranks" submit -f examples/scene1.vx -r 96 -o "$TMP/s1.vod"
ref -f examples/scene1.vx -r 96 -o "$TMP/s1-ref.vod"
same "$TMP/s1.vod" "$TMP/s1-ref.vod" "daemon_mpi: scene1 at 96 (MPI): vox voxelize's bytes"
grep -q "job 1 runs through MPI: .* -np 2" "$TMP/a.log" && grep -q "job 1 ran through MPI on 2 rank" "$TMP/a.log" \
    && pass "daemon_mpi: the log says job 1 ran through MPI on 2 ranks" \
    || fail "daemon_mpi: the log says job 1 ran through MPI on 2 ranks" "$(tail -5 "$TMP/a.log")"
check "daemon_mpi: an inline expression at 64" submit -e 'x^2+y^2+z^2-0.5' -r 64 --brick 8 \
    --compress runl -o "$TMP/e.vod"
ref -e 'x^2+y^2+z^2-0.5' -r 64 --brick 8 --compress runl -o "$TMP/e-ref.vod"
same "$TMP/e.vod" "$TMP/e-ref.vod" "daemon_mpi: inline sphere at 64 (MPI), bricks of 8, RUNL: vox voxelize's bytes"
submit -f examples/torus.vx -r 63 -o "$TMP/t.vod" >"$TMP/t.out" 2>&1 && ! grep -q MPI "$TMP/t.out" \
    && pass "daemon_mpi: torus at 63 through voxd, on its workers" \
    || fail "daemon_mpi: torus at 63 through voxd, on its workers" "$(cat "$TMP/t.out")"
ref -f examples/torus.vx -r 63 -o "$TMP/t-ref.vod"
same "$TMP/t.vod" "$TMP/t-ref.vod" "daemon_mpi: torus at 63 (the engine): vox voxelize's bytes"
grep -q "job 3 r" "$TMP/a.log" && fail "daemon_mpi: job 3, below mpi_min_res, did not go to MPI" \
    "$(grep 'job 3' "$TMP/a.log")" || pass "daemon_mpi: job 3, below mpi_min_res, did not go to MPI"

# ---------------------------------------------------------------- cancel
# mpi_pid JOB: mpirun's pid as the log gave it (its session's id)
mpi_pid() { sed -n "s/.*job $1 runs through MPI: .*(pid \([0-9]*\)).*/\1/p" "$2" | head -1; }
# nothing_left PGID NAME: no process of mpirun's session, no job directory, and
# no shared memory of the ranks seen while it ran ($RANKS)
nothing_left() {
    local left="" r
    # the ranks were seen running in mpirun's group, so the checks below mean something
    [ -n "$(echo "$RANKS" | tr -d ' ')" ] || left="no rank of session $1 was seen running"
    until_true 10 sh -c "! pgrep -s $1" || left="processes: $(pgrep -a -s "$1")"
    [ -z "$(ls -A "$TMP/tmp")" ] || left="$left files: $(ls -A "$TMP/tmp")"
    for r in $RANKS; do
        ls /dev/shm 2>/dev/null | grep -q "^voxd\.$r\." && left="$left shm of pid $r"
    done
    [ -z "$left" ] && pass "$2: nothing left" || fail "$2: nothing left" "$left"
}
(submit -f examples/scene1.vx -r 2048 -o "$TMP/c.vod" >"$TMP/c.out" 2>&1; echo "rc=$?" >>"$TMP/c.out") &
PIDS+=($!)
until_true 20 grep -q "job 4 runs through MPI" "$TMP/a.log"
P=$(mpi_pid 4 "$TMP/a.log")
until_true 10 sh -c "pgrep -s $P vox_mpi"
sleep 0.5
RANKS=$(pgrep -s "$P" | tr '\n' ' ')
check "daemon_mpi: vox cancel 4" "$VOX" --socket "$S" cancel 4
until_true 20 grep -q "rc=" "$TMP/c.out"
grep -q "CANCELLED" "$TMP/c.out" && ! grep -q "rc=0" "$TMP/c.out" \
    && pass "daemon_mpi: the cancelled MPI job ends CANCELLED" \
    || fail "daemon_mpi: the cancelled MPI job ends CANCELLED" "$(cat "$TMP/c.out")"
[ -n "$P" ] && nothing_left "$P" "daemon_mpi: cancel" || fail "daemon_mpi: cancel: mpirun's pid in the log"
[ ! -e "$TMP/c.vod" ] && pass "daemon_mpi: cancel: no output file" || fail "daemon_mpi: cancel: no output file"
# progress: vox_mpi's line, by subtrees done, as the job's Progress replies
vc submit 'x^2+y^2+z^2-0.5' 1024 -1,1 "$TMP/p.vod" >"$TMP/p.out" 2>&1
n=$(sed -n 's/.* \([0-9]*\) progress,.*/\1/p' "$TMP/p.out")
[ "${n:-0}" -gt 0 ] && pass "daemon_mpi: an MPI job sends progress ($n)" \
    || fail "daemon_mpi: an MPI job sends progress" "$(cat "$TMP/p.out")"

# ---------------------------------------------------------------- mesh and CSG jobs
# A torus of 576 triangles (lib.sh's torus_obj), closed, and open
# (every 37th triangle left out) for the repairs; a CSG tree with a mesh leaf.
torus_obj 24 12 >"$TMP/torus.obj"
torus_obj 24 12 37 >"$TMP/open.obj"
printf '%s\n' 'ring = mesh "torus.obj" fit 0,0,0.1 scale 1.5' \
    'ball = implicit "x^2 + y^2 + z^2 - 0.3"' \
    'all  = union(erode(ring, 1), dilate(ball, 2))' 'result all' >"$TMP/leaf.csg"
# mpi_job NAME REF_ARGS... -- SUBMIT_ARGS...: through MPI (the summary says
# so), with the bytes of REF (vox voxelize --embedded or vox csg, one process)
mpi_job() {
    local name=$1 ref=()
    shift
    while [ $# -gt 0 ] && [ "$1" != "--" ]; do ref+=("$1"); shift; done
    shift
    rm -f "$TMP/m.vod"
    if submit "$@" -o "$TMP/m.vod" >"$TMP/m.out" 2>&1 && grep -q "through MPI on 2 ranks" "$TMP/m.out"; then
        pass "daemon_mpi: $name through MPI"
    else
        fail "daemon_mpi: $name through MPI" "$(cat "$TMP/m.out")"
    fi
    "$VOXR" "${ref[@]}" -q -w 1 -o "$TMP/m-ref.vod"
    same "$TMP/m.vod" "$TMP/m-ref.vod" "daemon_mpi: $name: the bytes of vox ${ref[0]}, one process"
}
mpi_job "torus mesh at 96" voxelize --embedded --mesh "$TMP/torus.obj" -r 96 -- \
    --mesh "$TMP/torus.obj" -r 96
mpi_job "open torus, --repair vote, density, --pad 3" voxelize --embedded --mesh "$TMP/open.obj" \
    -r 100 --repair vote --channel density --supersample 3 --pad 3 -- \
    --mesh "$TMP/open.obj" -r 100 --repair vote --channel density --supersample 3 --pad 3
mpi_job "open torus, --repair winding, surface, a domain, --weld" voxelize --embedded \
    --mesh "$TMP/open.obj" -r 80 --repair winding --channel surface --bbox -1,1,-1,1,-0.5,0.5 \
    --weld 1e-4 -- --mesh "$TMP/open.obj" -r 80 --repair winding --channel surface \
    --bbox -1,1,-1,1,-0.5,0.5 --weld 1e-4
mpi_job "examples/part.csg at 96" csg examples/part.csg -r 96 -- --csg examples/part.csg -r 96
mpi_job "a CSG tree with a mesh leaf, occupancy, RUNL, a flat domain" csg "$TMP/leaf.csg" \
    -r 90 -c occupancy -Z runl -d -1.2,1.2,-1.2,1.2,-0.6,0.6 -- --csg "$TMP/leaf.csg" -r 90 \
    --channel occupancy --compress runl -d -1.2,1.2,-1.2,1.2,-0.6,0.6
# the distance channel, every kind, through MPI with its band
mpi_job "torus mesh's distance, band 4, a box with empty columns" voxelize --embedded \
    --mesh "$TMP/torus.obj" -r 128 --bbox -2,2,-2,2,-0.5,0.5 --channel distance --band 4 -- \
    --mesh "$TMP/torus.obj" -r 128 --bbox -2,2,-2,2,-0.5,0.5 --channel distance --band 4
mpi_job "a sphere's distance, band 5" voxelize --embedded -e 'sqrt(x^2+y^2+z^2) - 0.6' -r 72 \
    --channel distance --band 5 -- -e 'sqrt(x^2+y^2+z^2) - 0.6' -r 72 --channel distance --band 5
printf '%s\n' 'ring = mesh "torus.obj" fit 0,0,0.1 scale 1.5' \
    'ball = implicit "x^2 + y^2 + z^2 - 0.3"' 'all  = union(ring, ball)' 'result all' >"$TMP/dist.csg"
mpi_job "a CSG tree with a mesh leaf, distance, band 2" csg "$TMP/dist.csg" -r 80 -c distance \
    --band 2 -- --csg "$TMP/dist.csg" -r 80 --channel distance --band 2
submit --mesh "$TMP/torus.obj" -r 48 -o "$TMP/m48.vod" >"$TMP/m48.out" 2>&1 && ! grep -q MPI "$TMP/m48.out" \
    && pass "daemon_mpi: a mesh at 48, below mpi_min_res, on the workers" \
    || fail "daemon_mpi: a mesh at 48, below mpi_min_res, on the workers" "$(cat "$TMP/m48.out")"
# bad input is refused as without MPI: typed errors, and the daemon goes on
printf 'v 0 0 0\nv 1 0 0\nf 1 2 3\n' >"$TMP/bad.obj"
refuse "daemon_mpi: a bad mesh at 96: INVALID_INPUT, as on the workers" 2 "INVALID_INPUT: mesh: line 3" \
    submit --mesh "$TMP/bad.obj" -r 96 -o "$TMP/bad.vod"
[ -z "$(ls -A "$TMP/tmp")" ] && pass "daemon_mpi: mesh and CSG jobs: no job directory left" \
    || fail "daemon_mpi: mesh and CSG jobs: no job directory left" "$(ls -A "$TMP/tmp")"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20

# ---------------------------------------------------------------- job_timeout
conf "$TMP/b.conf" "job_timeout 1"
start_voxd "$TMP/b.log" -c "$TMP/b.conf" || fail "daemon_mpi: voxd with job_timeout 1 starts" "$(tail -5 "$TMP/b.log")"
submit -f examples/scene1.vx -r 1024 -o "$TMP/to.vod" >"$TMP/to.out" 2>&1 &
PIDS+=($!)
until_true 20 grep -q "job 1 runs through MPI" "$TMP/b.log"
P=$(mpi_pid 1 "$TMP/b.log")
until_true 10 sh -c "pgrep -s $P vox_mpi"
RANKS=$(pgrep -s "$P" | tr '\n' ' ')
until_true 20 grep -q "job_timeout" "$TMP/to.out"
grep -q "TIMEOUT\|job_timeout of 1 s" "$TMP/to.out" && pass "daemon_mpi: an MPI job past job_timeout ends TIMEOUT" \
    || fail "daemon_mpi: an MPI job past job_timeout ends TIMEOUT" "$(cat "$TMP/to.out")"
[ -n "$P" ] && nothing_left "$P" "daemon_mpi: job_timeout" || fail "daemon_mpi: job_timeout: mpirun's pid in the log"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20

# ---------------------------------------------------------------- a broken mpirun
conf "$TMP/c.conf" "mpirun /nonexistent/mpirun"
start_voxd "$TMP/c.log" -c "$TMP/c.conf" || fail "daemon_mpi: voxd with a broken mpirun starts" "$(tail -5 "$TMP/c.log")"
refuse "daemon_mpi: a broken mpirun path: a clear error" 1 \
    "INTERNAL.*cannot start the MPI run \(/nonexistent/mpirun\): No such file" \
    submit -f examples/scene1.vx -r 96 -o "$TMP/x.vod"
check "daemon_mpi: ... and the daemon serves the next job (below mpi_min_res)" \
    submit -f examples/torus.vx -r 32 -o "$TMP/t32.vod"
ref -f examples/torus.vx -r 32 -o "$TMP/t32-ref.vod"
same "$TMP/t32.vod" "$TMP/t32-ref.vod" "daemon_mpi: ... with vox voxelize's bytes"
[ -z "$(ls -A "$TMP/tmp")" ] && pass "daemon_mpi: a broken mpirun: no job directory left" \
    || fail "daemon_mpi: a broken mpirun: no job directory left" "$(ls -A "$TMP/tmp")"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20

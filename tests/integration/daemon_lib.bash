# Helpers for the daemon's integration tests (sourced by daemon*.sh): a voxd
# on a socket in $TMP, the python protocol client, bounded waits, and a
# trap that stops whatever the test started and checks that no daemon left
# its shared memory behind.
. "$(dirname "${BASH_SOURCE[0]}")/lib.sh"
VOXD=${VOXD:-$(dirname "$VOX")/voxd}
CLIENT=(python3 "$ROOT/tests/integration/daemon_client.py")
S=$TMP/voxd.sock
PIDS=()
cleanup() {
    stop_all "${PIDS[@]}"
    shm_left
    san_scan
    rm -rf "$TMP"
}
trap cleanup EXIT
export VOXD_TEST_TIMEOUT=30

# vc ARGS...: the protocol client on $S, never longer than 5 minutes (a
# loaded 2-core machine makes a flood or a big job take minutes under ASan)
vc() { timeout 300 "${CLIENT[@]}" "$S" "$@"; }
# bg CMD...: run in the background, remembered for the trap; $! as usual
bg() { "$@" & PIDS+=($!); }

# bgsubmit OUT ARGS...: `vc submit ARGS` in the background (BG_PID), its
# output and then "rc=N" in OUT (emptied here, before the background
# starts: a wait on OUT must not find what an earlier client wrote there;
# daemon_life.sh's TERM test once sent its signal on a stale line)
bgsubmit() {
    local out=$1
    shift
    : >"$out"
    # (10 min at most: a job of a minute alone takes several on a loaded machine)
    (timeout 600 "${CLIENT[@]}" "$S" submit "$@" >"$out" 2>&1; echo "rc=$?" >>"$out") &
    BG_PID=$!
    PIDS+=($BG_PID)
}

# bgclient OUT ARGS...: the client in the background as one process
# (BG_PID: killing it closes the connection), its output in OUT
bgclient() {
    local out=$1
    shift
    : >"$out" # (as bgsubmit's)
    (exec timeout 600 "${CLIENT[@]}" "$S" "$@" >"$out" 2>&1) &
    BG_PID=$!
    PIDS+=($BG_PID)
}

# start_voxd LOG ARGS...: voxd in the background on $S (VOXD_PID), ready
# when it answers a ping (20 s at most)
start_voxd() {
    local log=$1 i
    shift
    "$VOXD" --socket "$S" "$@" >"$log" 2>&1 &
    VOXD_PID=$!
    PIDS+=($VOXD_PID)
    for i in $(seq 200); do
        [ -S "$S" ] && vc ping >/dev/null 2>&1 && return 0
        kill -0 "$VOXD_PID" 2>/dev/null || return 1
        sleep 0.1
    done
    return 1
}
# wait_gone PID SECONDS: 0 when the process has exited; WAIT_RC is its
# exit status when it was our child (127 otherwise)
wait_gone() {
    local i
    for i in $(seq $(($2 * 10))); do
        if ! kill -0 "$1" 2>/dev/null; then wait "$1" 2>/dev/null; WAIT_RC=$?; return 0; fi
        sleep 0.1
    done
    return 1
}
# until_true SECONDS CMD...: poll every 0.1 s
until_true() {
    local n=$(($1 * 10)) i
    shift
    for i in $(seq "$n"); do "$@" >/dev/null 2>&1 && return 0; sleep 0.1; done
    return 1
}
running() { vc status | grep -q 'running=[0-9]'; }
# kill_busy_worker: kill -9 a worker that holds a task of the running job:
# the worker whose CPU time grew most over 0.3 s while the job ran (an
# idle worker sleeps on its queue and gains none), killed while the job
# still runs.  VICTIM its pid.  1 when none was caught working (the job
# ended first).
cpu_ticks() { awk '{ print $14 + $15 }' "/proc/$1/stat" 2>/dev/null || echo 0; }
busiest_worker() {
    local p best= most=0 d
    declare -A t0
    for p in $(worker_pids); do t0[$p]=$(cpu_ticks "$p"); done
    sleep 0.3
    for p in "${!t0[@]}"; do
        d=$(($(cpu_ticks "$p") - t0[$p]))
        [ "$d" -gt "$most" ] && most=$d best=$p
    done
    echo "$best"
}
kill_busy_worker() {
    local p end=$((SECONDS + 180))
    VICTIM=
    while [ "$SECONDS" -lt "$end" ] && running; do
        p=$(busiest_worker)
        if [ -n "$p" ] && running; then
            VICTIM=$p
            kill -9 "$p"
            return 0
        fi
    done
    return 1
}
idle() { vc status | grep -q 'queued=0 .*running=none'; }
worker_pids() { vc status | sed -n 's/^worker pid=\([0-9]*\).*/\1/p'; }
# the shared memory name the daemon logged
shm_of() { sed -n 's/.*shared memory \(\/voxd-[0-9a-f]*\).*/\1/p' "$1" | head -1; }
# a job that keeps 2 workers busy for a few seconds under ASan, with a
# small result: a sphere with 39 wobbles on a long tape
SLOW="sqrt(x^2+y^2+z^2)-0.8+$(python3 -c "print('+'.join('0.001*sin(%d*x+%d*y+%d*z)'%(i,i+1,i+2) for i in range(1,40)))")"
SPHERE='sqrt(x^2+y^2+z^2) - 0.8'
# a second or two, and short enough (<= 200 bytes, one line) that `vox
# voxelize` puts it in the metadata as the daemon does: same bytes
MEDIUM='sqrt(x^2+y^2+z^2)-0.8+0.01*sin(3*x+4*y)+0.01*sin(4*x+5*y)+0.01*sin(5*x+6*y)+0.01*sin(6*x+7*y)+0.01*sin(7*x+8*y)+0.01*sin(8*x+9*y)+0.01*sin(9*x+10*y)'

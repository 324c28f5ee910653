#!/bin/bash
# Using the daemon from vox: `vox status` lists every job (the running one
# and the queued ones, with id, uid, kind, resolution, state, progress), a
# queued job is cancelled by the id it lists; `vox submit` says the job's id
# on standard error also when that is not a terminal; a detached `voxd -d`
# logs to its log_file, or to syslog without one, and never to the terminal
# it was started from.
. "$(dirname "${BASH_SOURCE[0]}")/daemon_lib.bash"

v() { timeout 60 "$VOX" --socket "$S" "$@"; }

# ---------------------------------------------------------------- status: every job

start_voxd "$TMP/voxd.log" --workers 1 || fail "voxd starts" "$(cat "$TMP/voxd.log")"
(v submit -e "$SLOW" -r 160 -o "$TMP/slow.vod" >"$TMP/slow.out" 2>"$TMP/slow.err"; echo "rc=$?" >>"$TMP/slow.out") &
PIDS+=($!)
until_true 20 running || fail "the slow job runs" "$(vc status)"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n' >"$TMP/tet.obj"
(v submit --mesh "$TMP/tet.obj" -r 24 -o "$TMP/tet.vod" >"$TMP/tet.out" 2>"$TMP/tet.err"; echo "rc=$?" >>"$TMP/tet.out") &
PIDS+=($!)
# the mesh job queued first, then this one behind it
until_true 20 sh -c "timeout 60 '$VOX' --socket '$S' status | grep -q '^queue: 1 job waiting'" ||
    fail "one job queued" "$(v status)"
(v submit -e "$SPHERE" -r 40 -o "$TMP/q.vod" >"$TMP/q.out" 2>"$TMP/q.err"; echo "rc=$?" >>"$TMP/q.out") &
PIDS+=($!)
until_true 20 sh -c "timeout 60 '$VOX' --socket '$S' status | grep -q '^queue: 2 jobs waiting'" ||
    fail "two jobs queued" "$(v status)"
v status >"$TMP/st" 2>&1
# the ids each submit said on its (non-terminal) stderr
id_of() { sed -n 's/^vox: voxd job \([0-9]*\).*/\1/p' "$1"; }
SLOW_ID=$(id_of "$TMP/slow.err") TET_ID=$(id_of "$TMP/tet.err") Q_ID=$(id_of "$TMP/q.err")
[ -n "$SLOW_ID" ] && [ -n "$TET_ID" ] && [ -n "$Q_ID" ] && pass "submit says the job's id on a non-terminal stderr" ||
    fail "submit says the job's id on a non-terminal stderr" "$(cat "$TMP/slow.err" "$TMP/tet.err" "$TMP/q.err")"
grep -q "^vox: voxd job $Q_ID, 2 ahead of it in the queue$" "$TMP/q.err" && pass "submit says its place in the queue" ||
    fail "submit says its place in the queue" "$(cat "$TMP/q.err")"
grep -q '^jobs: 3$' "$TMP/st" && pass "status: 3 jobs" || fail "status: 3 jobs" "$(cat "$TMP/st")"
grep -qE "^ +ID +UID +KIND +RES +STATE +DONE +FOR$" "$TMP/st" && pass "status: the jobs' columns" ||
    fail "status: the jobs' columns" "$(cat "$TMP/st")"
# job_line ID: its row, with the uid of this test
U=$(id -u)
grep -qE "^ +$SLOW_ID +$U +implicit +160 +running +[0-9.]+% +[0-9.]+ s$" "$TMP/st" &&
    pass "status: the running job (id, uid, kind, res, state, progress)" ||
    fail "status: the running job (id, uid, kind, res, state, progress)" "$(cat "$TMP/st")"
grep -qE "^ +$TET_ID +$U +mesh +24 +queued +0\.0% +[0-9.]+ s$" "$TMP/st" && pass "status: the queued mesh job" ||
    fail "status: the queued mesh job" "$(cat "$TMP/st")"
grep -qE "^ +$Q_ID +$U +implicit +40 +queued +0\.0% +[0-9.]+ s$" "$TMP/st" && pass "status: the queued implicit job" ||
    fail "status: the queued implicit job" "$(cat "$TMP/st")"
# running first, then the queue in its order
order=$(sed -n 's/^ *\([0-9][0-9]*\) .* \(running\|queued\) .*/\1/p' "$TMP/st" | tr '\n' ' ')
[ "$order" = "$SLOW_ID $TET_ID $Q_ID " ] && pass "status: running first, then the queue in order" ||
    fail "status: running first, then the queue in order" "got '$order'"
refuse "cancel the queued job by its listed id" 0 "job $Q_ID: cancel taken" v cancel "$Q_ID"
until_true 20 grep -q "rc=" "$TMP/q.out"
grep -q "rc=1" "$TMP/q.out" && grep -q "job $Q_ID failed: CANCELLED" "$TMP/q.err" && pass "its client: CANCELLED" ||
    fail "its client: CANCELLED" "$(cat "$TMP/q.out" "$TMP/q.err")"
until_true 20 sh -c "! timeout 60 '$VOX' --socket '$S' status | grep -qE '^ +$Q_ID '" &&
    pass "status: the cancelled job is gone" || fail "status: the cancelled job is gone" "$(v status)"
v cancel "$SLOW_ID" >/dev/null 2>&1
until_true 60 grep -q "rc=" "$TMP/tet.out"
grep -q "rc=0" "$TMP/tet.out" && pass "the mesh job ran after the cancels" || fail "the mesh job ran after the cancels" "$(cat "$TMP/tet.out" "$TMP/tet.err")"
v status >"$TMP/st" 2>&1
grep -q '^jobs: 0$' "$TMP/st" && ! grep -q '^  *ID ' "$TMP/st" && pass "status: no jobs, no table" ||
    fail "status: no jobs, no table" "$(cat "$TMP/st")"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20 || fail "voxd stops"

# ---------------------------------------------------------------- voxd -d: where the log goes

# detached CONF TERMINAL: voxd --daemon from a "terminal" (a file); the
# daemon's pid in DPID
detached() {
    "$VOXD" --daemon --config "$1" >"$2" 2>&1 </dev/null
    local rc=$?
    DPID=$(cat "$TMP/d.pid" 2>/dev/null)
    [ -n "$DPID" ] && PIDS+=("$DPID")
    return $rc
}
stop_detached() { kill -TERM "$DPID" 2>/dev/null; wait_gone "$DPID" 20; }

printf 'socket %s\nworkers 1\npidfile %s\nlog_file %s\n' "$S" "$TMP/d.pid" "$TMP/d.log" >"$TMP/d1.conf"
check "voxd -d with a log_file starts" detached "$TMP/d1.conf" "$TMP/term1"
check "and serves a job" v submit -e "$SPHERE" -r 24 -q -o "$TMP/d1.vod"
stop_detached
grep -q "voxd\[$DPID\] info: " "$TMP/d.log" && grep -q "job" "$TMP/d.log" && pass "voxd -d: its log in log_file" ||
    fail "voxd -d: its log in log_file" "$(head -5 "$TMP/d.log")"
[ ! -s "$TMP/term1" ] && pass "voxd -d with a log_file: nothing on the terminal" ||
    fail "voxd -d with a log_file: nothing on the terminal" "$(head -5 "$TMP/term1")"

# Without a log_file: syslog.  /dev/log here is a socket of the test's,
# in a mount namespace of voxd's own (so the machine's /dev is untouched).
mkdir -p "$TMP/dev/shm"
# (it ends when the file STOP appears, or after 5 minutes)
python3 - "$TMP/dev/log" "$TMP/syslog" "$TMP/stop" <<'PY' &
import os, socket, sys, time
s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
s.bind(sys.argv[1])
s.settimeout(0.2)
end = time.monotonic() + 300
with open(sys.argv[2], "ab", buffering=0) as f:
    while not os.path.exists(sys.argv[3]) and time.monotonic() < end:
        try:
            f.write(s.recv(65536) + b"\n")
        except socket.timeout:
            pass
PY
SYSLOG_PID=$!
until_true 10 test -S "$TMP/dev/log" || fail "the syslog socket"
printf 'socket %s\nworkers 1\npidfile %s\n' "$S" "$TMP/d.pid" >"$TMP/d2.conf"
in_ns() {
    unshare -m bash -c '
        set -e
        mount --make-rprivate /
        d=$1; shift
        for e in null zero full random urandom tty; do
            [ -e /dev/$e ] && touch "$d/$e" && mount --bind /dev/$e "$d/$e"
        done
        mount --bind /dev/shm "$d/shm"
        ln -sf /proc/self/fd "$d/fd"
        mount --bind "$d" /dev
        exec "$@"' ns "$TMP/dev" "$@"
}
if ! unshare -m true 2>/dev/null; then
    fail "voxd -d without a log_file: syslog" "this check needs unshare -m (root or user namespaces)"
else
    ns_detached() { in_ns "$VOXD" --daemon --config "$TMP/d2.conf" >"$TMP/term2" 2>&1 </dev/null; }
    check "voxd -d without a log_file starts" ns_detached
    DPID=$(cat "$TMP/d.pid" 2>/dev/null)
    [ -n "$DPID" ] && PIDS+=("$DPID")
    check "and serves a job" v submit -e "$SPHERE" -r 24 -q -o "$TMP/d2.vod"
    stop_detached
    until_true 10 grep -q "voxd\[$DPID\]: info: .*job" "$TMP/syslog" &&
        pass "voxd -d without a log_file: its log in syslog (facility daemon)" ||
        fail "voxd -d without a log_file: its log in syslog (facility daemon)" "$(head -5 "$TMP/syslog")"
    grep -q "^<30>" "$TMP/syslog" && pass "syslog: info lines at daemon.info" ||
        fail "syslog: info lines at daemon.info" "$(head -2 "$TMP/syslog")"
    [ ! -s "$TMP/term2" ] && pass "voxd -d without a log_file: nothing on the terminal" ||
        fail "voxd -d without a log_file: nothing on the terminal" "$(head -5 "$TMP/term2")"
fi
touch "$TMP/stop"
wait "$SYSLOG_PID"

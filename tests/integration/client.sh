#!/bin/bash
# vox and libvox against a real voxd on a socket in $TMP: the daemon's file
# is the embedded engine's, byte for byte; vox voxelize picks the daemon when
# it answers and the embedded engine when it does not; status, ping, cancel
# (from another process and by an interrupt), typed errors, exit codes.
# Every command runs under `timeout`; the trap stops what the test started
# (lib.sh's stop_all) and checks that no daemon left its shared memory.
. "$(dirname "$0")/lib.sh"
VOXD=${VOXD:-$(dirname "$VOX")/voxd}
SOCK=$TMP/voxd.sock
PIDS=()
cleanup() {
    stop_all "${PIDS[@]}"
    shm_left
    san_scan
    rm -rf "$TMP"
}
trap cleanup EXIT

# v ARGS...: vox on the test's socket, never longer than 120 s
v() { timeout 120 "$VOX" --socket "$SOCK" "$@"; }
# until_true SECONDS CMD...: poll every 0.1 s
until_true() {
    local i
    for i in $(seq $(($1 * 10))); do "${@:2}" >/dev/null 2>&1 && return 0; sleep 0.1; done
    return 1
}
# running_job: the id of the job voxd runs now ("" when none)
running_job() { v status 2>/dev/null | sed -n 's/^running: job \([0-9]*\).*/\1/p'; }
has_running() { [ -n "$(running_job)" ]; }
no_running() { v status 2>/dev/null | grep -q '^running: nothing'; }
gone() { ! kill -0 "$1" 2>/dev/null; }
no_tmp_left() { [ -z "$(ls "$TMP" | grep '\.tmp\.')" ]; }

S='sqrt(x^2+y^2+z^2) - 0.8'
SLOW='sin(20*x)*sin(20*y)*sin(20*z)' # minutes at res 1024: a job to cancel

# ---------------------------------------------------------------- no daemon yet

check "vox --help names the commands" sh -c "'$VOX' --help | grep -q 'submit' && '$VOX' --help | grep -q -- '--socket PATH'"
check "submit --help" "$VOX" submit --help
check "status --help" "$VOX" status --help
check "cancel --help" "$VOX" cancel --help
check "ping --help" "$VOX" ping --help
refuse "voxelize --help tells of the daemon" 0 "--embedded" "$VOX" voxelize --help
refuse "submit: no daemon" 3 "no voxd answering on $SOCK \(no such socket\); start one with" v submit -e "$S" -r 16 -o "$TMP/n.vod"
refuse "status: no daemon" 3 "no voxd answering" v status
refuse "cancel: no daemon" 3 "no voxd answering" v cancel 1
refuse "ping: no daemon" 3 "no voxd answering" v ping
refuse "voxelize --daemon: no daemon" 3 "leave out --daemon" v voxelize --daemon -e "$S" -r 16 -o "$TMP/n.vod"
[ -e "$TMP/n.vod" ] && fail "no file without a daemon" || pass "no file without a daemon"
refuse "voxelize without a daemon: embedded" 0 "CPU: master" v voxelize -e "$S" -r 64 -o "$TMP/auto0.vod"
refuse "--daemon with --workers" 2 "embedded engine's" v voxelize --daemon -w 2 -e "$S" -o "$TMP/x.vod"
refuse "--daemon and --embedded" 2 "at most one" v voxelize --daemon --embedded -e "$S" -o "$TMP/x.vod"
refuse "submit takes no --workers" 2 "belongs to the daemon" v submit -w 2 -e "$S" -o "$TMP/x.vod"
refuse "cancel needs a job id" 2 "missing JOB_ID" v cancel
refuse "cancel: bad job id" 2 "bad JOB_ID" v cancel 12x
refuse "unknown vox option" 2 "unknown option" "$VOX" --frobnicate status
refuse "bad expression: local message" 2 "<expr>:1:[0-9]+: " v submit -e "x + (" -o "$TMP/x.vod"

# ---------------------------------------------------------------- a daemon

if [ ! -x "$VOXD" ]; then
    fail "voxd is built" "no $VOXD"
    exit 0
fi
"$VOXD" --socket "$SOCK" --workers 2 >"$TMP/voxd.log" 2>&1 &
VOXD_PID=$!
PIDS+=($VOXD_PID)
if until_true 20 v ping; then pass "voxd starts"; else
    fail "voxd starts" "$(tail -5 "$TMP/voxd.log")"
    exit 0
fi

refuse "ping" 0 "voxd .* on $SOCK: protocol 1, 2 workers, round trip" v ping
refuse "VOXD_SOCKET" 0 "2 workers" env VOXD_SOCKET="$SOCK" timeout 60 "$VOX" ping
refuse "--socket=PATH" 0 "2 workers" timeout 60 "$VOX" --socket="$SOCK" ping
printf 'socket %s\n' "$SOCK" >"$TMP/vox.conf"
printf 'sockt %s\n' "$SOCK" >"$TMP/bad.conf"
refuse "the socket of \$VOXD_CONFIG" 0 "on $SOCK: protocol 1" env -u VOXD_SOCKET VOXD_CONFIG="$TMP/vox.conf" timeout 60 "$VOX" ping
refuse "\$VOXD_SOCKET before the config" 3 "no voxd answering on $TMP/none.sock" env VOXD_SOCKET="$TMP/none.sock" VOXD_CONFIG="$TMP/vox.conf" timeout 60 "$VOX" ping
refuse "a config that does not load is said" 3 "bad.conf:1: unknown key 'sockt'; using the socket " env -u VOXD_SOCKET VOXD_CONFIG="$TMP/bad.conf" timeout 60 "$VOX" ping
v status >"$TMP/st" 2>&1
grep -q '^workers: 2$' "$TMP/st" && [ "$(grep -cE '^ +[0-9]+ +[0-9-]+ +(idle|busy|starting) ' "$TMP/st")" -eq 2 ] &&
    pass "status shows 2 workers" || fail "status shows 2 workers" "$(cat "$TMP/st")"
grep -q '^running: nothing' "$TMP/st" && grep -q '^queue: 0 jobs waiting' "$TMP/st" &&
    pass "status: idle, empty queue" || fail "status: idle, empty queue" "$(cat "$TMP/st")"
grep -qE '^voxd .* on .*: up .*, [0-9]+ clients?$' "$TMP/st" && pass "status: uptime, clients" ||
    fail "status: uptime, clients" "$(head -1 "$TMP/st")"

# The daemon's file is the embedded engine's.
same_job() { # NAME ARGS...: submit and voxelize --embedded, same bytes
    local n=$1; shift
    if v submit "$@" -o "$TMP/d.vod" >"$TMP/out" 2>&1 &&
        v voxelize --embedded "$@" -o "$TMP/e.vod" >>"$TMP/out" 2>&1 &&
        cmp "$TMP/d.vod" "$TMP/e.vod" >>"$TMP/out" 2>&1; then pass "$n"
    else fail "$n" "$(tail -5 "$TMP/out")"; fi
}
same_job "submit = embedded: sphere" -e "$S" -r 64
same_job "submit = embedded: box, res 100, paper" -e "$S" -d -1,1,-0.5,0.5,-0.25,0.25 -r 100 --schedule paper
same_job "submit = embedded: occupancy runl xx32 brick 8" -e "$S" -r 32 --channel occupancy --compress runl --hash xx32 --brick 8
same_job "submit = embedded: no compression, res 1" -e "x" -r 1 --compress none
refuse "submit summary" 0 "voxd job [0-9]+, .* in the queue" v submit -e "$S" -r 32 -o "$TMP/sum.vod"
refuse "submit summary names the grid" 0 "on a 32x32x32 grid" v submit -e "$S" -r 32 -o "$TMP/sum.vod"
refuse "the summary's grid is the daemon's" 0 "on a 100x50x25 grid" \
    v submit -e "$S" -d -1,1,-0.5,0.5,-0.25,0.25 -r 100 -o "$TMP/sum.vod"
check "submit -q prints only the job's id" sh -c "[ -z \"\$(timeout 60 '$VOX' --socket '$SOCK' submit -q -e '$S' -r 16 -o '$TMP/q.vod' 2>&1 | grep -v '^vox: voxd job [0-9]*\$')\" ]"
refuse "the daemon's file validates" 0 "valid VOD.*CRC-32 checked" "$VOX" info "$TMP/d.vod"
refuse "submit --progress" 0 "level .*voxels" v submit --progress -e "$S" -r 64 -o "$TMP/p.vod"
refuse "submit --progress names the job" 0 "vox: voxd job [0-9]+" v submit --progress -e "$S" -r 16 -o "$TMP/p.vod"

# A .vx file: vox sends the file's name, so the daemon's file is the
# embedded engine's, byte for byte, metadata included.
v submit -f examples/scene2.vx -r 48 -o "$TMP/fd.vod" >/dev/null 2>&1
v voxelize --embedded -f examples/scene2.vx -r 48 -o "$TMP/fe.vod" >/dev/null 2>&1
if [ -s "$TMP/fd.vod" ] && cmp "$TMP/fd.vod" "$TMP/fe.vod" >"$TMP/out" 2>&1; then
    pass "file job: the same bytes through the daemon"
else fail "file job: the same bytes through the daemon" "$(cat "$TMP/out")"; fi
refuse "file job: the metadata names the file" 0 "meta +source=file:examples/scene2.vx" "$VOX" info "$TMP/fd.vod"

# An expression longer than a frame: libvox sends it in InputChunks after
# the Submit (a second voxd, with 4K frames and 1K chunks), and the file is
# the embedded engine's, byte for byte.
SOCK2=$TMP/small.sock
printf 'max_frame 4K\nchunk_size 1K\n' >"$TMP/small.conf"
"$VOXD" --config "$TMP/small.conf" --socket "$SOCK2" --workers 1 >"$TMP/small.log" 2>&1 &
SMALL=$!
PIDS+=($SMALL)
python3 -c "
print('#@ domain -1,1')
for i in range(120): print('# padding line %3d so that the source is longer than a 4K frame' % i)
print('min(' + ','.join('sqrt((x-%.2f)^2+y^2+z^2)-0.3' % (0.05 * k - 0.5) for k in range(21)) + ')')
" >"$TMP/long.vx"
v2() { timeout 120 "$VOX" --socket "$SOCK2" "$@"; }
if until_true 20 v2 ping; then
    if v2 submit -f "$TMP/long.vx" -r 40 -o "$TMP/l1.vod" >"$TMP/out" 2>&1 &&
        v voxelize --embedded -f "$TMP/long.vx" -r 40 -o "$TMP/l2.vod" >>"$TMP/out" 2>&1 &&
        cmp "$TMP/l1.vod" "$TMP/l2.vod" >>"$TMP/out" 2>&1; then
        pass "an expression over max_frame goes in chunks: same bytes"
    else fail "an expression over max_frame goes in chunks: same bytes" "$(tail -5 "$TMP/out")"; fi
    n=$(stat -c %s "$TMP/long.vx")
    grep -q "waiting for $n bytes of expression" "$TMP/small.log" &&
        grep -q "input complete ($n bytes); queued" "$TMP/small.log" &&
        pass "the daemon took it as input" || fail "the daemon took it as input" "$(tail -5 "$TMP/small.log")"
    refuse "a short expression still goes inline" 0 "on a 16x16x16 grid" v2 submit -e "$S" -r 16 -o "$TMP/l3.vod"
    grep -q "23 bytes of expression" "$TMP/small.log" && pass "inline: 23 bytes in the submit" ||
        fail "inline: 23 bytes in the submit" "$(tail -3 "$TMP/small.log")"
else
    fail "a voxd with 4K frames starts" "$(tail -5 "$TMP/small.log")"
fi
kill -TERM "$SMALL"

# vox voxelize picks the daemon when it answers.
refuse "voxelize with a daemon: the daemon" 0 "voxd job [0-9]+" v voxelize -e "$S" -r 64 -o "$TMP/auto1.vod"
check "voxelize: daemon = embedded (bytes)" cmp "$TMP/auto0.vod" "$TMP/auto1.vod"
refuse "voxelize --embedded with a daemon" 0 "CPU: master" v voxelize --embedded -e "$S" -r 64 -o "$TMP/x.vod"
refuse "voxelize -w selects the embedded engine" 0 "CPU: master" v voxelize -w 1 -e "$S" -r 64 -o "$TMP/x.vod"
refuse "voxelize --daemon" 0 "voxd job" v voxelize --daemon -e "$S" -r 64 -o "$TMP/x.vod"

# Typed errors: the daemon's words, exit 1, no file.
refuse "LIMIT_EXCEEDED reaches the user" 1 "vox: job failed: LIMIT_EXCEEDED: res 5000 is over this server's limit of 4096" v submit -e "$S" -r 5000 -o "$TMP/big.vod"
refuse "voxelize --daemon: LIMIT_EXCEEDED" 1 "LIMIT_EXCEEDED" v voxelize --daemon -e "$S" -r 5000 -o "$TMP/big.vod"
[ -e "$TMP/big.vod" ] && fail "no file after a refused job" || pass "no file after a refused job"
refuse "unwritable output" 1 "cannot create /nonexistent/dir/x.vod" v submit -e "$S" -r 16 -o /nonexistent/dir/x.vod
no_tmp_left && pass "no temporary file left" || fail "no temporary file left" "$(ls "$TMP")"

# Cancel from another process: the submitter sees CANCELLED, no file.
(v submit -e "$SLOW" -r 1024 -o "$TMP/c.vod" >"$TMP/sub.out" 2>&1; echo "rc=$?" >>"$TMP/sub.out") &
SUB=$!
PIDS+=($SUB)
if until_true 60 has_running; then
    id=$(running_job)
    refuse "vox cancel" 0 "job $id: cancel taken" v cancel "$id"
    if until_true 30 gone "$SUB"; then
        grep -q "^vox: job $id failed: CANCELLED: " "$TMP/sub.out" && grep -q '^rc=1$' "$TMP/sub.out" &&
            pass "the submitter sees CANCELLED, exit 1" || fail "the submitter sees CANCELLED, exit 1" "$(cat "$TMP/sub.out")"
    else fail "the submitter ends after a cancel" "still running after 30 s"; fi
    [ -e "$TMP/c.vod" ] && fail "no file after a cancel" || pass "no file after a cancel"
    until_true 10 no_running && pass "nothing runs after a cancel" || fail "nothing runs after a cancel" "$(v status)"
    refuse "cancel of a finished job is refused" 1 "cannot cancel job $id: INVALID_INPUT: " v cancel "$id"
else
    fail "a slow job runs" "$(cat "$TMP/sub.out")"
fi

# An interrupt cancels the job on the daemon.  --foreground: timeout would
# otherwise pass the INT on to its process group as well, a second interrupt
# that ends vox at once (as a second Ctrl-C should).
timeout --foreground 120 "$VOX" --socket "$SOCK" submit -e "$SLOW" -r 1024 -o "$TMP/i.vod" >"$TMP/int.out" 2>&1 &
SUB=$!
PIDS+=($SUB)
if until_true 60 has_running; then
    kill -INT "$SUB"
    if until_true 30 gone "$SUB"; then
        wait "$SUB"; rc=$?
        [ "$rc" -eq 1 ] && grep -q "cancelled (interrupted)" "$TMP/int.out" &&
            pass "Ctrl-C cancels the job, exit 1" || fail "Ctrl-C cancels the job, exit 1" "exit $rc: $(cat "$TMP/int.out")"
    else fail "Ctrl-C ends vox submit" "still running after 30 s"; fi
    [ -e "$TMP/i.vod" ] && fail "no file after Ctrl-C" || pass "no file after Ctrl-C"
    until_true 10 no_running && pass "nothing runs after Ctrl-C" || fail "nothing runs after Ctrl-C" "$(v status)"
else
    fail "a slow job runs (Ctrl-C)" "$(cat "$TMP/int.out")"
fi
no_tmp_left && pass "no temporary file left after cancels" || fail "no temporary file left after cancels" "$(ls "$TMP")"

# A job waits its turn behind a running one.
(v submit -e "$SLOW" -r 1024 -o "$TMP/c2.vod" >"$TMP/sub2.out" 2>&1) &
SUB=$!
PIDS+=($SUB)
if until_true 60 has_running; then
    id=$(running_job)
    (v submit -e "$S" -r 32 -o "$TMP/q2.vod" >"$TMP/q.out" 2>&1; echo "rc=$?" >>"$TMP/q.out") &
    Q=$!
    PIDS+=($Q)
    until_true 20 sh -c "timeout 60 '$VOX' --socket '$SOCK' status | grep -q '^queue: 1 job waiting'" &&
        pass "status shows the queued job" || fail "status shows the queued job" "$(v status)"
    v cancel "$id" >/dev/null 2>&1
    until_true 60 gone "$Q" && grep -q '^rc=0$' "$TMP/q.out" && pass "the queued job runs after the cancel" ||
        fail "the queued job runs after the cancel" "$(cat "$TMP/q.out")"
    check "queued job's file = embedded" sh -c "timeout 60 '$VOX' voxelize --embedded -e '$S' -r 32 -o '$TMP/q3.vod' -q && cmp '$TMP/q2.vod' '$TMP/q3.vod'"
else
    fail "a slow job runs (queue)" "$(cat "$TMP/sub2.out")"
fi

# The daemon stops: vox voxelize goes back to the embedded engine.
kill -TERM "$VOXD_PID"
if until_true 30 gone "$VOXD_PID"; then pass "voxd stops on SIGTERM"; else fail "voxd stops on SIGTERM"; fi
refuse "voxelize after the daemon left: embedded" 0 "CPU: master" v voxelize -e "$S" -r 64 -o "$TMP/auto2.vod"
check "embedded after the daemon = daemon (bytes)" cmp "$TMP/auto1.vod" "$TMP/auto2.vod"
refuse "submit after the daemon left" 3 "no voxd answering" v submit -e "$S" -r 16 -o "$TMP/x.vod"

#!/bin/bash
# voxd's life: --check-config, QUIT and TERM with jobs running, a crashed
# daemon's leftovers, a second daemon, --daemon with its pidfile, USR1.
. "$(dirname "$0")/daemon_lib.bash"

# --check-config: the effective settings, or FILE:LINE and exit 1.
printf 'workers 2\nmax_res 512\njob_timeout 5m\nclient_timeout 1m\n' >"$TMP/good.conf"
refuse "check-config: good file" 0 "^max_res 512" "$VOXD" --check-config "$TMP/good.conf"
refuse "check-config: prints every option" 0 "^job_timeout 300" "$VOXD" --check-config "$TMP/good.conf"
refuse "check-config: client_timeout" 0 "^client_timeout 60$" "$VOXD" --check-config "$TMP/good.conf"
printf 'max_expr_depth 1025\n' >"$TMP/deep.conf"
refuse "check-config: max_expr_depth over the parser's 1024" 1 \
    "deep.conf:1: max_expr_depth 1025 is out of range \(1 to 1024\)" "$VOXD" --check-config "$TMP/deep.conf"
printf 'workers 2\n\nmax_res lots\n' >"$TMP/bad.conf"
refuse "check-config: bad value, FILE:LINE" 1 "bad.conf:3: " "$VOXD" --check-config "$TMP/bad.conf"
printf 'frobnicate 1\n' >"$TMP/bad2.conf"
refuse "check-config: unknown key" 1 "bad2.conf:1: .*frobnicate" "$VOXD" --check-config "$TMP/bad2.conf"
refuse "check-config: missing file" 1 "nothere.conf" "$VOXD" --check-config "$TMP/nothere.conf"
refuse "start with a bad config" 1 "bad.conf:3: " "$VOXD" --config "$TMP/bad.conf" --socket "$S"

cat >"$TMP/voxd.conf" <<CONF
workers 2
socket_mode 0600
client_timeout 45
pidfile $TMP/voxd.pid
log_file $TMP/voxd.log
CONF

# QUIT: no new connections; the running and the queued job finish; then
# the daemon exits and removes its socket, shared memory and pidfile.
start_voxd "$TMP/out1" --config "$TMP/voxd.conf" || { fail "voxd starts" "$(cat "$TMP/out1")"; exit 1; }
SHM=$(shm_of "$TMP/voxd.log")
[ "$(cat "$TMP/voxd.pid")" = "$VOXD_PID" ] && pass "pidfile holds the pid" || fail "pidfile holds the pid"
[ "$(stat -c %a "$S")" = 600 ] && pass "socket_mode 0600" || fail "socket_mode 0600" "$(stat -c %a "$S")"
grep -q "client timeout 45 s" "$TMP/voxd.log" && pass "client_timeout from the file" ||
    fail "client_timeout from the file" "$(grep listening "$TMP/voxd.log")"
bgsubmit "$TMP/a.out" "$MEDIUM" 384 -1,1 "$TMP/a.vod"
A=$BG_PID
until_true 20 running
bgsubmit "$TMP/b.out" "$SPHERE" 64 -1,1 "$TMP/b.vod"
B=$BG_PID
until_true 10 grep -q "accepted job" "$TMP/b.out"
kill -QUIT "$VOXD_PID"
until_true 5 grep -q "stopping when the running and queued jobs are done" "$TMP/voxd.log"
refuse "QUIT: no new connections" 4 "CLOSED" vc ping
wait_gone "$A" 30
wait_gone "$B" 30
grep -q "rc=0" "$TMP/a.out" && pass "QUIT: the running job finishes" || fail "QUIT: the running job finishes" "$(cat "$TMP/a.out")"
grep -q "rc=0" "$TMP/b.out" && pass "QUIT: the queued job finishes" || fail "QUIT: the queued job finishes" "$(cat "$TMP/b.out")"
check "QUIT: the results are whole" "$VOX" info "$TMP/a.vod"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "QUIT: exit 0" || fail "QUIT: exit 0" "rc $WAIT_RC"
[ ! -e "$S" ] && [ ! -e "/dev/shm$SHM" ] && [ ! -e "$TMP/voxd.pid" ] &&
    pass "QUIT: socket, shared memory and pidfile removed" ||
    fail "QUIT: socket, shared memory and pidfile removed" "$(ls "$S" "/dev/shm$SHM" "$TMP/voxd.pid" 2>&1)"

# QUIT during an upload (a job accepted, its input half sent): the daemon
# waits for the rest, runs the job and delivers it, then exits.
start_voxd "$TMP/out1b" --config "$TMP/voxd.conf" || fail "voxd starts for an upload"
bgsubmit "$TMP/c.out" "$SPHERE" 32 -1,1 "$TMP/c.vod" --chunked 5 --pause 4
C=$BG_PID
until_true 10 grep -q "sent the first 5 of 23 bytes" "$TMP/c.out"
kill -QUIT "$VOXD_PID"
# (the QUIT taken, polled for: the upload's success below is the proof that
# the daemon waited)
until_true 30 grep -q "stopping when the running and queued jobs are done" "$TMP/voxd.log"
kill -0 "$VOXD_PID" 2>/dev/null && pass "QUIT: the daemon waits for an upload in progress" ||
    fail "QUIT: the daemon waits for an upload in progress" "$(tail -3 "$TMP/voxd.log")"
wait_gone "$C" 30
grep -q "rc=0" "$TMP/c.out" && grep -q "input complete (23 bytes)" "$TMP/voxd.log" &&
    pass "QUIT: the upload finishes, then its job" ||
    fail "QUIT: the upload finishes, then its job" "$(cat "$TMP/c.out")"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "QUIT after the upload: exit 0" ||
    fail "QUIT after the upload: exit 0" "rc $WAIT_RC"

# TERM: the running and the queued job end with SHUTTING_DOWN, at once,
# and so does an upload in progress.
start_voxd "$TMP/out2" --config "$TMP/voxd.conf" || fail "voxd starts again"
bgsubmit "$TMP/a.out" "$SLOW" 512 -1,1 "$TMP/a.vod"
A=$BG_PID
until_true 20 running
bgsubmit "$TMP/b.out" "$SPHERE" 64 -1,1 "$TMP/b.vod"
B=$BG_PID
until_true 10 grep -q "accepted job" "$TMP/b.out"
bgsubmit "$TMP/c.out" "$SPHERE" 32 -1,1 "$TMP/c.vod" --chunked 5 --pause 30
C=$BG_PID
until_true 10 grep -q "sent the first 5 of 23 bytes" "$TMP/c.out"
kill -TERM "$VOXD_PID"
# (within seconds: 2 s for the clients to read; 30 s for a loaded machine)
wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0 within seconds" ||
    fail "TERM: exit 0 within seconds" "rc $WAIT_RC"
wait_gone "$A" 30
wait_gone "$B" 30
wait_gone "$C" 30
grep -q "ERROR SHUTTING_DOWN" "$TMP/c.out" && pass "TERM: an upload in progress: SHUTTING_DOWN" ||
    fail "TERM: an upload in progress: SHUTTING_DOWN" "$(cat "$TMP/c.out")"
grep -q "ERROR SHUTTING_DOWN" "$TMP/a.out" && pass "TERM: the running job: SHUTTING_DOWN" ||
    fail "TERM: the running job: SHUTTING_DOWN" "$(cat "$TMP/a.out")"
grep -q "ERROR SHUTTING_DOWN" "$TMP/b.out" && pass "TERM: the queued job: SHUTTING_DOWN" ||
    fail "TERM: the queued job: SHUTTING_DOWN" "$(cat "$TMP/b.out")"

# INT (^C in a terminal) is TERM: the running job ends with SHUTTING_DOWN,
# the daemon exits 0 and removes its socket and shared memory.
start_voxd "$TMP/out2i" --config "$TMP/voxd.conf" || fail "voxd starts for INT"
SHM=$(shm_of "$TMP/voxd.log")
bgsubmit "$TMP/i.out" "$SLOW" 512 -1,1 "$TMP/i.vod"
I=$BG_PID
until_true 30 running
kill -INT "$VOXD_PID"
wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "INT: exit 0 within seconds" ||
    fail "INT: exit 0 within seconds" "rc $WAIT_RC"
wait_gone "$I" 30
grep -q "ERROR SHUTTING_DOWN" "$TMP/i.out" && pass "INT: the running job: SHUTTING_DOWN" ||
    fail "INT: the running job: SHUTTING_DOWN" "$(cat "$TMP/i.out")"
[ ! -e "$S" ] && [ -n "$SHM" ] && [ ! -e "/dev/shm$SHM" ] && pass "INT: socket and shared memory removed" ||
    fail "INT: socket and shared memory removed" "shm '$SHM'"
[ ! -e "$TMP/i.vod" ] && pass "INT: no file from the stopped job" || fail "INT: no file from the stopped job"

# kill -9 of the master: the workers die with it; the socket and shared
# memory are left, and the next daemon removes them and serves.
start_voxd "$TMP/out3" --config "$TMP/voxd.conf" || fail "voxd starts a third time"
SHM=$(shm_of "$TMP/voxd.log")
workers=$(worker_pids)
kill -9 "$VOXD_PID"
wait_gone "$VOXD_PID" 10
gone() { local p; for p in $workers; do kill -0 "$p" 2>/dev/null && return 1; done; return 0; }
until_true 5 gone && pass "kill -9 master: the workers die with it" || fail "kill -9 master: the workers die with it"
[ -S "$S" ] && [ -e "/dev/shm$SHM" ] && pass "kill -9 master: socket and shared memory left" ||
    fail "kill -9 master: socket and shared memory left"
start_voxd "$TMP/out4" --config "$TMP/voxd.conf" && pass "restart after a crash" ||
    fail "restart after a crash" "$(cat "$TMP/out4")"
grep -q "removed the stale socket" "$TMP/voxd.log" && grep -q "removed the stale shared memory" "$TMP/voxd.log" &&
    pass "stale socket and shared memory removed" || fail "stale socket and shared memory removed"
check "serving after the restart" vc submit "$SPHERE" 32 -1,1 "$TMP/c.vod"

# A second daemon on the same socket refuses to start and leaves the
# first one alone.
refuse "a second daemon refuses" 1 "another voxd is running on $S" \
    timeout 20 "$VOXD" --config "$TMP/voxd.conf" --socket "$S"
check "the first one still serves" vc ping

# Workers hold none of the daemon's descriptors (its log and lock, the
# listening socket, clients' sockets, results waiting in memfds): neither
# those forked at start nor one forked again, between jobs, while a client
# that does not read holds a result.
only_stdio() { [ -d "/proc/$1/fd" ] && [ -z "$(ls "/proc/$1/fd" | grep -vx '[012]')" ]; }
bad=""
for p in $(worker_pids); do until_true 5 only_stdio "$p" || bad="$bad $p: $(ls "/proc/$p/fd" | tr '\n' ' ')"; done
[ -z "$bad" ] && pass "workers forked at start hold only fds 0-2" ||
    fail "workers forked at start hold only fds 0-2" "$bad"
holds_result() { ls -l "/proc/$VOXD_PID/fd" | grep -q 'memfd:voxd-result'; }
bgclient "$TMP/n.out" submit "$SPHERE" 256 -1,1 "$TMP/n.vod" --no-read
until_true 60 holds_result && until_true 30 idle
before=$(worker_pids)
victim=$(head -1 <<<"$before")
kill -9 "$victim"
new_worker() { local p; for p in $(worker_pids); do grep -qx "$p" <<<"$before" || { echo "$p"; return 0; }; done; return 1; }
until_true 10 new_worker && fresh=$(new_worker)
if [ -n "$fresh" ] && holds_result; then
    pass "a worker killed between jobs is forked again (a result waiting)"
else
    fail "a worker killed between jobs is forked again (a result waiting)" "$(vc status; ls -l "/proc/$VOXD_PID/fd")"
fi
grep -q "(pid $victim) died; forked again as pid $fresh" "$TMP/voxd.log" && pass "idle death logged" ||
    fail "idle death logged" "$(tail -3 "$TMP/voxd.log")"
until_true 5 only_stdio "$fresh" && pass "a worker forked again holds only fds 0-2" ||
    fail "a worker forked again holds only fds 0-2" "$(ls -l "/proc/$fresh/fd" 2>&1)"
kill "$BG_PID" 2>/dev/null
wait_gone "$BG_PID" 10
until_true 10 eval '! holds_result' && pass "the result is freed when its client leaves" ||
    fail "the result is freed when its client leaves"

# USR1 reopens the log (after logrotate moved it).
mv "$TMP/voxd.log" "$TMP/voxd.log.1"
kill -USR1 "$VOXD_PID"
until_true 5 grep -q "log reopened" "$TMP/voxd.log" && pass "USR1 reopens the log" || fail "USR1 reopens the log"
kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 10 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"

# --daemon: the command returns once the daemon serves; pidfile; TERM.
check "--daemon returns when serving" timeout 30 "$VOXD" --daemon --config "$TMP/voxd.conf" --socket "$S"
DPID=$(cat "$TMP/voxd.pid" 2>/dev/null)
[ -n "$DPID" ] && PIDS+=("$DPID")
check "--daemon: serving" vc ping
[ -n "$DPID" ] && [ "$(ps -o ppid= -p "$DPID" | tr -d ' ')" != "$$" ] && pass "--daemon: detached" ||
    fail "--daemon: detached"
kill -TERM "$DPID"
wait_gone "$DPID" 10 && pass "--daemon: TERM stops it" || fail "--daemon: TERM stops it"
[ ! -e "$TMP/voxd.pid" ] && [ ! -e "$S" ] && pass "--daemon: pidfile and socket removed" ||
    fail "--daemon: pidfile and socket removed"

# Something that is not a socket at the path is never removed.
touch "$S"
refuse "a file at the socket path is left alone" 1 "is not a socket" timeout 20 "$VOXD" --config "$TMP/voxd.conf" --socket "$S"
[ -f "$S" ] && pass "the file is still there" || fail "the file is still there"

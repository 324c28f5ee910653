#!/bin/bash
# voxd against bad clients: malformed frames, garbage, slow senders, every
# limit; each gets its typed error or a closed connection, and the daemon
# serves another client right after.  Limits changed with SIGHUP.
. "$(dirname "$0")/daemon_lib.bash"

cat >"$TMP/voxd.conf" <<CONF
workers 2
log_file $TMP/voxd.log
CONF
start_voxd "$TMP/voxd.out" --config "$TMP/voxd.conf" --client-timeout 2 &&
    pass "voxd starts" || { fail "voxd starts" "$(cat "$TMP/voxd.out" "$TMP/voxd.log")"; exit 1; }

# abuse KIND PATTERN: the abuse client passes with output matching PATTERN,
# then the daemon still answers a ping
abuse() {
    refuse "$1" 0 "$2" vc abuse "$1"
    vc ping >/dev/null 2>&1 && pass "serving after $1" || fail "serving after $1"
}
abuse len0 "closed after \\['INVALID_INPUT'\\]"
abuse lenmax "closed after \\['INVALID_INPUT'\\]"
abuse len4g "closed after \\['INVALID_INPUT'\\]"
abuse truncated "^closed after nothing$"  # (no frame to answer: closed, and logged below)
abuse garbage "closed after \\['INVALID_INPUT'\\]"
abuse nohello "closed after \\['INVALID_INPUT'\\]"
abuse badversion "closed after \\['INVALID_INPUT'\\]"
abuse unknown-request "INVALID_INPUT: request of no type"
abuse unknown-enum "INVALID_INPUT: unknown channel 99"
abuse nul "INVALID_INPUT: .*NUL byte"
abuse huge-expr "LIMIT_EXCEEDED: expression is 80001 bytes, limit 65536"
abuse deep-expr "LIMIT_EXCEEDED: .*nests too deeply"
abuse res "LIMIT_EXCEEDED: res 5000 is over this server's limit of 4096"
abuse bad-expr "INVALID_INPUT: expression:1:1: unknown function 'sinn'"
abuse bad-cancel "INVALID_INPUT: no job 999999"
abuse slow "^after [0-9]+ s: closed after \\['INVALID_INPUT'\\]$"
# Chunked input (InputChunk after a Submit with input_bytes): each mistake
# ends its one job or request with a typed error, the connection goes on
# (the abuse client pings after it) and so does the daemon.
abuse input-over-cap "LIMIT_EXCEEDED: input is 67108865 bytes, over this server's max_input_bytes of 67108864"
abuse input-over-expr "LIMIT_EXCEEDED: expression is 65537 bytes, limit 65536"
abuse input-and-inline "INVALID_INPUT: the expression comes either inline or as input_bytes, not both"
abuse input-chunk-over-cap "LIMIT_EXCEEDED: input chunk at offset 67108864 passes this server's max_input_bytes"
abuse input-past-total "INVALID_INPUT: input chunk of 23 bytes at offset 0 passes the 10 bytes the job declared .*\(job [0-9]+\)"
abuse input-order "INVALID_INPUT: input chunk at offset 10 where 5 was due .*\(job [0-9]+\)"
grep -q "no job [0-9]* of this connection is waiting for input" "$TMP/out" &&
    pass "a chunk after its job ended: no such job" || fail "a chunk after its job ended: no such job"
abuse input-nul "INVALID_INPUT: expression source contains a NUL byte at offset 2 \(job [0-9]+\)"
abuse input-unknown "INVALID_INPUT: no job 999999 of this connection is waiting for input"
abuse input-foreign "job [0-9]+ done by its own connection"
abuse input-cancel "CANCELLED: cancelled by a client \(job [0-9]+\)"
abuse input-stall "TIMEOUT: the job's input stopped: no chunk for 2 s \(client_timeout\); 10 of 100 bytes came"
abuse input-close "leaving job [0-9]+ after 1000 of 60000 bytes"
until_true 10 grep -q "dropped, its client left during its upload (1000 of 60000 bytes)" "$TMP/voxd.log" &&
    pass "a connection closed mid-upload drops its job" ||
    fail "a connection closed mid-upload drops its job" "$(tail -3 "$TMP/voxd.log")"
refuse "nothing left queued after the uploads" 0 "queued=0 .*running=none" vc status
grep -q "connection ended inside a frame" "$TMP/voxd.log" && pass "a truncated frame is logged as such" ||
    fail "a truncated frame is logged as such" "$(grep -c . "$TMP/voxd.log") lines"
grep -q "within 2 s; closing" "$TMP/voxd.log" && pass "slow sender closed by the client timeout" ||
    fail "slow sender closed by the client timeout"

# Limits, reloaded with SIGHUP: the queue, max_result_bytes, jobs per uid,
# job_timeout.  reload N: HUP and wait for the N-th "configuration reloaded".
reload() {
    kill -HUP "$VOXD_PID"
    until_true 10 eval "[ \$(grep -c 'configuration reloaded' '$TMP/voxd.log') -ge $1 ]"
}
pids_before=$(worker_pids | sort)
cat >>"$TMP/voxd.conf" <<CONF
max_queued_jobs 1
max_jobs_per_uid 2
max_result_bytes 64K
CONF
reload 1 && pass "HUP rereads the config" || fail "HUP rereads the config"
bgclient "$TMP/a.out" submit "$SLOW" 512 -1,1 "$TMP/a.vod"
A=$BG_PID
until_true 60 running
bgclient "$TMP/b.out" submit "$SLOW" 512 -1,1 "$TMP/b.vod"
B=$BG_PID
until_true 60 grep -q "accepted job" "$TMP/b.out"
refuse "queue full: BUSY" 3 "ERROR BUSY: .*max_queued_jobs 1" vc submit "$SPHERE" 16 -1,1 "$TMP/c.vod"
kill "$A" "$B"
until_true 10 idle && pass "idle once their clients are gone" || fail "idle once their clients are gone" "$(vc status)"
refuse "max_result_bytes: LIMIT_EXCEEDED" 3 "ERROR LIMIT_EXCEEDED: the result is over .*max_result_bytes" \
    vc submit "$SPHERE" 128 -1,1 "$TMP/r.vod"
check "a small job fits" vc submit "$SPHERE" 16 -1,1 "$TMP/s.vod"
pids_after=$(worker_pids | sort)
[ -n "$pids_after" ] && [ "$pids_before" != "$pids_after" ] && pass "HUP replaced the workers" ||
    fail "HUP replaced the workers" "$pids_before / $pids_after"

sed -i 's/^max_queued_jobs 1$/max_queued_jobs 8/; s/^max_jobs_per_uid 2$/max_jobs_per_uid 1/' "$TMP/voxd.conf"
reload 2
bgclient "$TMP/a.out" submit "$SLOW" 512 -1,1 "$TMP/a.vod"
until_true 20 running
refuse "jobs per uid: LIMIT_EXCEEDED" 3 "ERROR LIMIT_EXCEEDED: uid [0-9]+ already has 1 jobs" \
    vc submit "$SPHERE" 16 -1,1 "$TMP/c.vod"
kill "$BG_PID"
until_true 10 idle
refuse "an upload counts against max_jobs_per_uid" 0 "LIMIT_EXCEEDED: uid [0-9]+ already has 1 jobs" \
    vc abuse input-hold

echo "job_timeout 1" >>"$TMP/voxd.conf"
reload 3
refuse "job_timeout: TIMEOUT" 3 "ERROR TIMEOUT: .*job_timeout of 1 s" vc submit "$SLOW" 512 -1,1 "$TMP/a.vod"

# A bad config on HUP keeps the running one.
echo "max_res lots" >>"$TMP/voxd.conf"
kill -HUP "$VOXD_PID"
until_true 10 grep -q "reload: .*voxd.conf:[0-9]*: .*keeping the running configuration" "$TMP/voxd.log" &&
    pass "a bad config on HUP is refused with FILE:LINE" || fail "a bad config on HUP is refused with FILE:LINE"
check "still serving after a bad reload" vc submit "$SPHERE" 16 -1,1 "$TMP/s2.vod"

# Who may connect, and how many.
sed -i '$d' "$TMP/voxd.conf"
printf 'allow_uids 12345\n' >>"$TMP/voxd.conf"
reload 4
refuse "uid not in allow_uids: refused" 3 "ERROR LIMIT_EXCEEDED: this uid may not use this server" vc ping
sed -i 's/^allow_uids 12345$/max_clients 2\nmax_clients_per_uid 2/' "$TMP/voxd.conf"
reload 5
# (two clients that said hello and hold their connections, each waited
# for: slow senders, closed by the 2 s client timeout, left too short a
# window on a loaded machine)
bgclient "$TMP/h1.out" hold 1
S1=$BG_PID
bgclient "$TMP/h2.out" hold 1
S2=$BG_PID
until_true 60 grep -q holding "$TMP/h1.out"
until_true 60 grep -q holding "$TMP/h2.out"
refuse "max_clients: BUSY" 3 "ERROR BUSY: too many connections" vc ping
# (the clients themselves, not only the timeout that runs each)
pkill -9 -P "$S1"; pkill -9 -P "$S2"; kill -9 "$S1" "$S2"
until_true 10 vc ping && pass "serving when the connections are gone" || fail "serving when the connections are gone"

kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"

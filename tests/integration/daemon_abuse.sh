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
abuse truncated "closed after"
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
abuse slow "closed after"
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
until_true 20 running
bgclient "$TMP/b.out" submit "$SLOW" 512 -1,1 "$TMP/b.vod"
B=$BG_PID
until_true 10 grep -q "accepted job" "$TMP/b.out"
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
sed -i 's/^allow_uids 12345$/max_clients 2/' "$TMP/voxd.conf"
reload 5
(exec "${CLIENT[@]}" "$S" abuse slow >/dev/null 2>&1) &
S1=$!
PIDS+=($S1)
(exec "${CLIENT[@]}" "$S" abuse slow >/dev/null 2>&1) &
S2=$!
PIDS+=($S2)
sleep 0.5
refuse "max_clients: BUSY" 3 "ERROR BUSY: too many connections" vc ping
kill -9 "$S1" "$S2"
until_true 10 vc ping && pass "serving when the connections are gone" || fail "serving when the connections are gone"

kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"

#!/bin/bash
# voxd when a worker stops answering, and its memory: a worker stopped
# (SIGSTOP) mid-job is found by its heartbeat within worker_stall_timeout,
# killed, forked again, and the job gives the embedded bytes; a client's
# cancel while a worker is stopped is answered at once; after a job that
# filled the shared memory the master gives it back (its Pss); the memory
# budget refuses a job up front; bad values of the new keys and options.
. "$(dirname "$0")/daemon_lib.bash"

cat >"$TMP/voxd.conf" <<CONF
workers 2
shm_size 128M
worker_stall_timeout 5s
log_file $TMP/voxd.log
CONF
start_voxd "$TMP/voxd.out" --config "$TMP/voxd.conf" &&
    pass "voxd starts" || { fail "voxd starts" "$(cat "$TMP/voxd.out" "$TMP/voxd.log")"; exit 1; }
grep -q "worker stall timeout 5 s, memory budget [0-9]* MiB" "$TMP/voxd.log" &&
    pass "the stall timeout and the budget are logged at start" ||
    fail "the stall timeout and the budget are logged at start" "$(head -2 "$TMP/voxd.log")"
vs() { timeout 300 "$VOX" --socket "$S" "$@"; }
# reload N: HUP and wait for the N-th "configuration reloaded"
reload() {
    kill -HUP "$VOXD_PID"
    until_true 10 eval "[ \$(grep -c 'configuration reloaded' '$TMP/voxd.log') -ge $1 ]"
}
now() { date +%s.%N; }
# seconds since $1, as an integer
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%d", b - a }'; }
# the line of `vc status` for worker pid $1
worker_line() { vc status | grep "^worker pid=$1 "; }

# ---------------------------------------------------------------- a stopped worker

# The embedded engine's bytes, the reference.
# (5 s: a worker starved of CPU on a loaded 2-core machine under ASan is not
# taken for a stopped one; the bound on the stalled job is the embedded
# job's own time, twice, plus 30 s)
# SLOW: a job whose time is the workers' interval work, so that the stop
# lands while the engine hands out subtrees (MEDIUM's engine phase, once
# the workers stored their own voxels, could end before the stop).
t0=$(now)
check "embedded reference" "$VOX" voxelize -e "$SLOW" -r 256 -w 2 -q -o "$TMP/ref.vod"
ref=$(since "$t0")
bgsubmit "$TMP/a.out" "$SLOW" 256 -1,1 "$TMP/a.vod"
A=$BG_PID
until_true 20 running && pass "a job runs" || fail "a job runs"
victim=$(worker_pids | head -1)
cpu=$(vc status | sed -n "s/^worker pid=$victim cpu=\([0-9-]*\) .*/\1/p")
kill -STOP "$victim"
t0=$(now)
wait_gone "$A" $((2 * ref + 120))
took=$(since "$t0")
grep -q "^rc=0$" "$TMP/a.out" && pass "the job completes with a worker stopped" ||
    fail "the job completes with a worker stopped" "$(cat "$TMP/a.out")"
check "... with the embedded bytes" cmp "$TMP/a.vod" "$TMP/ref.vod"
[ "$took" -lt $((2 * ref + 30)) ] && pass "... well within twice the embedded job's ${ref} s + 30 s of the stop (${took} s)" ||
    fail "... well within twice the embedded job's ${ref} s + 30 s of the stop" "${took} s"
grep -q "worker [01] (pid $victim, CPU $cpu) made no progress for [0-9.]* s (process state T); killed and forked again as pid [0-9]*" "$TMP/voxd.log" &&
    pass "the stall is logged with the pid, the CPU and the state" ||
    fail "the stall is logged with the pid, the CPU and the state" "$(grep -i worker "$TMP/voxd.log" | tail -3)"
until_true 30 eval '! kill -0 "$victim" 2>/dev/null' && pass "the stopped worker is gone" ||
    fail "the stopped worker is gone"
st=$(vc status)
if [ "$(grep -c '^worker pid=' <<<"$st")" -eq 2 ] && ! grep -q "pid=$victim " <<<"$st" &&
    grep -q "^worker pid=[0-9]* cpu=$cpu state=1 .* replaced=1 stalls=1$" <<<"$st"; then
    pass "status: 2 workers, the slot's replacement counted as a stall"
else fail "status: 2 workers, the slot's replacement counted as a stall" "$st"; fi
v_st=$(vs status)
grep -qE '^ +[0-9]+ +[0-9]+ +idle +[0-9]+ +[0-9]+ +1 +1$' <<<"$v_st" &&
    pass "vox status shows REPLACED and STALLS" || fail "vox status shows REPLACED and STALLS" "$v_st"

# ---------------------------------------------------------------- a cancel during a stall

# Stall detection off: a stopped worker stays stopped, shows as stalled,
# and a client's cancel (vox's answer to ^C or TERM) is answered at once.
sed -i 's/^worker_stall_timeout 5s$/worker_stall_timeout 0/' "$TMP/voxd.conf"
reload 1 && pass "HUP: stall detection off" || fail "HUP: stall detection off"
check "a job after the reload" vc submit "$SPHERE" 16 -1,1 "$TMP/s.vod"
(exec "$VOX" --socket "$S" submit -e "$SLOW" -r 512 -o "$TMP/c.vod" >"$TMP/c.out" 2>&1) &
C=$!
PIDS+=($C)
until_true 20 running
victim=$(worker_pids | head -1)
kill -STOP "$victim"
until_true 30 eval 'worker_line "$victim" | grep -q "state=4 "' &&
    pass "status: the stopped worker shows as stalled" ||
    fail "status: the stopped worker shows as stalled" "$(vc status)"
vs status | grep -qE "^ +$victim +[0-9]+ +stalled " && pass "vox status says stalled" ||
    fail "vox status says stalled" "$(vs status)"
t0=$(now)
kill -TERM "$C"
wait_gone "$C" 20
took=$(since "$t0")
# (at once: the daemon kills a stopped worker 0.1 s into the cancel; 10 s
# leaves room for a loaded machine)
[ "$took" -le 10 ] && pass "a cancel during a stall is answered at once (${took} s)" ||
    fail "a cancel during a stall is answered at once" "${took} s"
grep -q "cancelled" "$TMP/c.out" && pass "... and the client says cancelled" ||
    fail "... and the client says cancelled" "$(cat "$TMP/c.out")"
until_true 10 idle && pass "idle after the cancel" || fail "idle after the cancel" "$(vc status)"
grep -q "(pid $victim, CPU [0-9]*) did not let go of a stopped job (stopped, or no progress); killed and forked again" "$TMP/voxd.log" &&
    pass "the worker that did not answer is logged" ||
    fail "the worker that did not answer is logged" "$(tail -3 "$TMP/voxd.log")"
[ "$(worker_pids | wc -l)" -eq 2 ] && ! worker_pids | grep -qx "$victim" &&
    pass "2 workers again, a fresh one for the stopped one" || fail "2 workers again" "$(vc status)"
check "the next job runs" vc submit "$MEDIUM" 128 -1,1 "$TMP/b.vod"
"$VOX" voxelize -e "$MEDIUM" -r 128 -w 2 -q -o "$TMP/ref128.vod"
check "... and gives the embedded bytes" cmp "$TMP/b.vod" "$TMP/ref128.vod"

# ---------------------------------------------------------------- memory given back

# Pss of the master (its share of the shared segment included), KiB.
pss() { awk '/^Pss:/ { print $2 }' "/proc/$VOXD_PID/smaps_rollup"; }
# A plane at 4096^3 needs more octree than 128 MiB: the job fills the
# segment (its estimate stays under it) and fails; every page it touched
# beyond the 8 MiB reserve goes back.
t0=$(now)
refuse "a job that fills the shared memory: LIMIT_EXCEEDED" 3 "LIMIT_EXCEEDED: .*octree needs more than" \
    vc submit "x" 4096 -1,1 "$TMP/p.vod"
fill=$(since "$t0")
p=$(pss)
[ -n "$p" ] && [ "$p" -le 65536 ] && pass "master's Pss after filling 128 MiB: $p KiB (<= 64 MiB)" ||
    fail "master's Pss after filling 128 MiB: <= 64 MiB" "$p KiB"
# x*0: every voxel is on the surface; stopped on its estimate, not after
# filling the segment.
t0=$(now)
refuse "x*0 at 4096: stopped on its estimate" 3 "LIMIT_EXCEEDED: .*would need at least [0-9]+ MiB of shared memory" \
    vc submit "x*0" 4096 -1,1 "$TMP/z.vod"
took=$(since "$t0")
# (at once: in 10 s, or on a machine so loaded that the job that filled the
# segment took more than 20 s, in half that job's time: 12 s failed beside a
# CPU hog with the machine loaded 25 deep; one that filled the segment first
# would take about as long as that job)
lim=$((fill / 2 > 10 ? fill / 2 : 10))
[ "$took" -le "$lim" ] && pass "... at once (${took} s; filling the segment took ${fill} s)" ||
    fail "... at once" "${took} s, over ${lim} s (filling the segment took ${fill} s)"
p=$(pss)
[ -n "$p" ] && [ "$p" -le 65536 ] && pass "master's Pss after x*0: $p KiB" ||
    fail "master's Pss after x*0: <= 64 MiB" "$p KiB"
check "a job after both" vc submit "$SPHERE" 64 -1,1 "$TMP/s64.vod"

# ---------------------------------------------------------------- the memory budget

# shm_size 48M and max_memory 112M leave 64 MiB: any result held (a client
# that does not read) leaves less, so the next job is refused up front.
sed -i 's/^shm_size 128M$/shm_size 48M/' "$TMP/voxd.conf"
echo "max_memory 112M" >>"$TMP/voxd.conf"
reload 2 && pass "HUP: max_memory 112M" || fail "HUP: max_memory 112M"
check "a job within the budget" vc submit "$SPHERE" 16 -1,1 "$TMP/s2.vod"
bgclient "$TMP/n.out" submit 'sin(20*x)*sin(20*y)*sin(20*z) - 0.1' 256 -1,1 "$TMP/n.vod" --no-read
N=$BG_PID
until_true 30 eval 'grep -q "accepted job" "$TMP/n.out" && idle'
refuse "a result held fills the budget: BUSY up front" 3 \
    "BUSY: this server's memory budget \(max_memory 112 MiB\) is taken: 48 MiB of shared memory and [0-9]+ MiB of results" \
    vc submit "$SPHERE" 16 -1,1 "$TMP/s3.vod"
kill "$N"
until_true 30 vc submit "$SPHERE" 16 -1,1 "$TMP/s4.vod" && pass "room again once the result is gone" ||
    fail "room again once the result is gone" "$(tail -3 "$TMP/voxd.log")"
# A result that outgrows the budget while its job runs: the sphere's
# surface at 384^3, uncompressed in bricks of 32, is about 79 MB (the
# admission's 64 MiB lets it start); alone over max_memory less shm_size,
# it ends with LIMIT_EXCEEDED, leaves no file, and the daemon goes on.
refuse "a result that outgrows max_memory during its job: LIMIT_EXCEEDED" 1 \
    "LIMIT_EXCEEDED: the result does not fit in this server's memory budget \(max_memory less shm_size: 64 MiB\)" \
    vs submit -e "$SPHERE" -r 384 --channel surface --compress none --brick 32 -o "$TMP/big.vod"
[ ! -e "$TMP/big.vod" ] && pass "... and leaves no file" || fail "... and leaves no file"
"$VOX" voxelize --embedded -e "$SPHERE" -r 384 --channel surface --compress none --brick 32 -q -o "$TMP/bigref.vod"
big=$(stat -c %s "$TMP/bigref.vod" 2>/dev/null || echo 0)
[ "$big" -gt $((64 << 20)) ] && pass "... a result of $big bytes, over the 64 MiB it had (embedded)" ||
    fail "... a result over the 64 MiB it had (embedded)" "$big bytes"
rm -f "$TMP/bigref.vod"
check "a job after it" vc submit "$SPHERE" 16 -1,1 "$TMP/s5.vod"

# ---------------------------------------------------------------- bad values

refuse "voxd --worker-stall-timeout -1" 2 "bad --worker-stall-timeout '-1': want seconds 0..3600" \
    "$VOXD" --worker-stall-timeout -1 --check-config "$TMP/voxd.conf"
refuse "voxd --worker-stall-timeout 3601" 2 "bad --worker-stall-timeout '3601'" \
    "$VOXD" --worker-stall-timeout 3601 --check-config "$TMP/voxd.conf"
refuse "voxd --worker-stall-timeout soon" 2 "bad --worker-stall-timeout 'soon'" \
    "$VOXD" --worker-stall-timeout soon --check-config "$TMP/voxd.conf"
printf 'max_memory 1G\nshm_size 2G\n' >"$TMP/bad1.conf"
refuse "max_memory below shm_size" 1 "bad1.conf:2: max_memory 1G leaves no room for results beside shm_size 2G" \
    "$VOXD" --check-config "$TMP/bad1.conf"
printf 'max_memory plenty\n' >"$TMP/bad2.conf"
refuse "max_memory not a size" 1 "bad2.conf:1: bad value 'plenty' for max_memory: want auto or a size" \
    "$VOXD" --check-config "$TMP/bad2.conf"
printf 'worker_stall_timeout 2d\n' >"$TMP/bad3.conf"
refuse "worker_stall_timeout out of range" 1 "bad3.conf:1: worker_stall_timeout 2d is out of range \(0 to 3600 seconds\)" \
    "$VOXD" --check-config "$TMP/bad3.conf"
refuse "--check-config prints both" 0 "^worker_stall_timeout 0$" "$VOXD" --check-config "$TMP/voxd.conf"
grep -q "^max_memory 112M$" "$TMP/out" && pass "--check-config prints max_memory" ||
    fail "--check-config prints max_memory" "$(grep max_memory "$TMP/out")"

kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 20 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"

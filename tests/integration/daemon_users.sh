#!/bin/bash
# voxd's security with real users on a real socket.  As root (CI runs as
# root) the test creates users and a group (removed at the end) and runs
# clients as them (setpriv): who may connect (socket_group and socket_mode
# for the file, allow_uids for the peer's uid), the per-uid caps
# (max_clients_per_uid, max_jobs_per_uid: one uid at its cap, another still
# served), and that one uid can neither cancel another's job nor receive any
# of its frames, while the job's own uid and root may cancel it.  Not root:
# a NOTE says what did not run, and the one-uid part runs.  Root that cannot
# create users: a NOTE and a FAIL.
. "$(dirname "$0")/daemon_lib.bash"

# ------------------------------------------------ one uid: allow_uids
# (whoever runs the test: a uid not in the list is refused at accept; the
# daemon is ready once it logs that it listens, since it answers no ping)
printf 'workers 1\nallow_uids %d\n' $(($(id -u) + 4242)) >"$TMP/one.conf"
bg "$VOXD" --socket "$TMP/one.sock" --config "$TMP/one.conf" >"$TMP/one.log" 2>&1
ONE=$!
if until_true 30 grep -q listening "$TMP/one.log"; then
    refuse "a uid not in allow_uids is refused at accept" 3 \
        "ERROR LIMIT_EXCEEDED: this uid may not use this server" timeout 60 "${CLIENT[@]}" "$TMP/one.sock" ping
else
    fail "voxd starts with allow_uids" "$(tail -3 "$TMP/one.log")"
fi
kill -TERM "$ONE"
wait_gone "$ONE" 30 && [ "$WAIT_RC" = 0 ] && pass "the one-uid voxd stops on TERM, exit 0" ||
    fail "the one-uid voxd stops on TERM, exit 0" "rc $WAIT_RC"

if [ "$(id -u)" -ne 0 ]; then
    echo "NOTE: daemon_users.sh runs as uid $(id -u), not root: it cannot create users, so"
    echo "NOTE: socket_group, allow_uids, the per-uid caps and cross-uid cancels were NOT tested"
    exit 0
fi

# ------------------------------------------------ users
tag=$$
G=vxg$tag UA=vxa$tag UB=vxb$tag UC=vxc$tag UD=vxd$tag
MADE=()
users_cleanup() {
    local u
    cleanup  # the processes first: a user with a process cannot be removed
    for u in "${MADE[@]}"; do
        userdel "$u" >/dev/null 2>&1 || echo "NOTE: userdel $u failed: remove the test user by hand"
    done
    getent group "$G" >/dev/null && groupdel "$G" >/dev/null 2>&1
}
trap users_cleanup EXIT
mkusers() {
    local u
    groupadd "$G" || return 1
    for u in "$UA" "$UB" "$UD"; do
        useradd -M -s /usr/sbin/nologin -G "$G" "$u" && MADE+=("$u") || return 1
    done
    useradd -M -s /usr/sbin/nologin "$UC" && MADE+=("$UC")
}
if ! mkusers >"$TMP/useradd.log" 2>&1; then
    echo "NOTE: ******** running as root, but useradd/groupadd failed: the security checks"
    echo "NOTE: ******** with several users did NOT run: $(tail -2 "$TMP/useradd.log")"
    fail "the test users are created (useradd, groupadd)" "$(tail -3 "$TMP/useradd.log")"
    exit 1
fi
pass "4 test users and a group created"
uid() { id -u "$1"; }

# as USER CMD...: CMD as USER with its groups (AS: the prefix, for exec);
# its sanitizer reports on its standard error (the runner's report folder is
# root's)
asv() {
    AS=(setpriv --reuid="$(uid "$1")" --regid="$(id -g "$1")" --init-groups
        env HOME=/ ASAN_OPTIONS="$ASAN_OPTIONS:log_path=stderr")
}
as() { asv "$1"; shift; "${AS[@]}" "$@"; }
uvc() { local u=$1; shift; as "$u" timeout 60 "${CLIENT[@]}" "$S" "$@"; }
uvox() { local u=$1; shift; as "$u" timeout 60 "$VOX" --socket "$S" "$@"; }
# ubgsubmit OUT USER ARGS...: USER's `submit ARGS` in the background (10 min
# at most: its job is cancelled long before), its output then "rc=N" in OUT
ubgsubmit() {
    local out=$1 u=$2
    shift 2
    (as "$u" timeout 600 "${CLIENT[@]}" "$S" submit "$@" >"$out" 2>&1; echo "rc=$?" >>"$out") &
    BG_PID=$!
    PIDS+=($BG_PID)
}
job_of() { sed -n 's/^accepted job \([0-9]*\).*/\1/p' "$1" | head -1; }

chmod 711 "$TMP"             # the users reach the socket, list nothing
mkdir -m 1777 "$TMP/u"       # their results
cat >"$TMP/voxd.conf" <<CONF
workers 2
socket_group $G
socket_mode 0660
allow_uids $UA $UB $UC root
max_clients_per_uid 2
max_jobs_per_uid 1
CONF
start_voxd "$TMP/voxd.log" --config "$TMP/voxd.conf" && pass "voxd starts with socket_group and allow_uids" ||
    { fail "voxd starts with socket_group and allow_uids" "$(tail -5 "$TMP/voxd.log")"; exit 1; }
[ "$(stat -c '%G %a' "$S")" = "$G 660" ] && pass "the socket: group $G, mode 0660" ||
    fail "the socket: group $G, mode 0660" "$(stat -c '%G %a' "$S")"

# ------------------------------------------------ who may connect
refuse "a member of socket_group in allow_uids connects" 0 "pong 42" uvc "$UA" ping
refuse "vox ping as that user" 0 "protocol 1" uvox "$UA" ping
uvc "$UC" ping >"$TMP/c.out" 2>&1
rc=$?
[ "$rc" -ne 0 ] && grep -q "Permission denied" "$TMP/c.out" &&
    pass "in allow_uids but not in socket_group: the socket's mode refuses it" ||
    fail "in allow_uids but not in socket_group: the socket's mode refuses it" "exit $rc: $(tail -2 "$TMP/c.out")"
refuse "in socket_group but not in allow_uids: refused by uid" 3 \
    "ERROR LIMIT_EXCEEDED: this uid may not use this server" uvc "$UD" ping
until_true 10 grep -q "uid $(uid "$UD")" "$TMP/voxd.log" && pass "the refused uid is logged" ||
    fail "the refused uid is logged" "$(tail -3 "$TMP/voxd.log")"

# ------------------------------------------------ max_clients_per_uid
HOLD=()
for i in 1 2; do
    asv "$UA"
    (exec "${AS[@]}" timeout 120 "${CLIENT[@]}" "$S" hold 1 >"$TMP/hold$i.out" 2>&1) &
    HOLD+=($!) PIDS+=($!)
    until_true 30 grep -q holding "$TMP/hold$i.out"
done
grep -q holding "$TMP/hold2.out" && pass "$UA holds its 2 connections" ||
    fail "$UA holds its 2 connections" "$(cat "$TMP"/hold*.out)"
refuse "$UA's 3rd connection: LIMIT_EXCEEDED" 3 \
    "ERROR LIMIT_EXCEEDED: uid $(uid "$UA") already has 2 connections to this server \(max_clients_per_uid 2\)" \
    uvc "$UA" ping
refuse "$UB is served while $UA is at its cap" 0 "pong 42" uvc "$UB" ping
kill "${HOLD[@]}"
until_true 30 uvc "$UA" ping && pass "$UA served again once its connections closed" ||
    fail "$UA served again once its connections closed"

# ------------------------------------------------ jobs across uids
ubgsubmit "$TMP/a.out" "$UA" "$SLOW" 512 -1,1 "$TMP/u/a.vod"
A_PID=$BG_PID
until_true 60 grep -q "accepted job" "$TMP/a.out"
JA=$(job_of "$TMP/a.out")
until_true 60 eval 'vc status | grep -q "running=$JA "' && pass "$UA's job $JA runs" ||
    fail "$UA's job $JA runs" "$(cat "$TMP/a.out"; vc status)"
refuse "$UA's 2nd job: LIMIT_EXCEEDED (max_jobs_per_uid 1)" 3 \
    "ERROR LIMIT_EXCEEDED: uid $(uid "$UA") already has 1 jobs" uvc "$UA" submit "$SPHERE" 16 -1,1 "$TMP/u/a2.vod"
ubgsubmit "$TMP/b.out" "$UB" "$SPHERE" 40 -1,1 "$TMP/u/b.vod"
B_PID=$BG_PID
until_true 60 grep -q "accepted job" "$TMP/b.out" && pass "$UB's job accepted while $UA is at its cap" ||
    fail "$UB's job accepted while $UA is at its cap" "$(cat "$TMP/b.out")"
JB=$(job_of "$TMP/b.out")
refuse "$UB cannot cancel $UA's job" 1 \
    "cannot cancel job $JA: INVALID_INPUT: no job $JA of this uid is " \
    uvox "$UB" cancel "$JA"
refuse "$UA's job still runs after $UB's cancel" 0 "running=$JA " vc status
refuse "$UD, not allowed, cannot cancel it either" 3 "voxd refused this client: this uid may not use this server" \
    uvox "$UD" cancel "$JA"
check "$UA cancels its own job from another process" uvox "$UA" cancel "$JA"
wait_gone "$A_PID" 60
grep -q "CANCELLED" "$TMP/a.out" && pass "$UA's client gets CANCELLED" ||
    fail "$UA's client gets CANCELLED" "$(cat "$TMP/a.out")"
# B's client dies on any frame of another job ("chunk of job N ... expected
# job M"): it received its own job alone, whole
wait_gone "$B_PID" 120
grep -q "^done job $JB:" "$TMP/b.out" && grep -q "rc=0" "$TMP/b.out" &&
    pass "$UB receives its own job, no frame of $UA's" || fail "$UB receives its own job, no frame of $UA's" "$(cat "$TMP/b.out")"
check "$UB's file is the embedded engine's" bash -c "'$VOX' voxelize -e '$SPHERE' -r 40 -w 1 -q -o '$TMP/be.vod' && cmp '$TMP/be.vod' '$TMP/u/b.vod'"
[ "$(stat -c %U "$TMP/u/b.vod")" = "$UB" ] && pass "written by $UB's client as $UB" || fail "written by $UB's client as $UB"

# root may cancel any job
ubgsubmit "$TMP/a3.out" "$UA" "$SLOW" 512 -1,1 "$TMP/u/a3.vod"
A_PID=$BG_PID
until_true 60 grep -q "accepted job" "$TMP/a3.out"
JA=$(job_of "$TMP/a3.out")
check "root cancels $UA's job" timeout 60 "$VOX" --socket "$S" cancel "$JA"
wait_gone "$A_PID" 60
grep -q "CANCELLED" "$TMP/a3.out" && pass "$UA's client gets CANCELLED from root's cancel" ||
    fail "$UA's client gets CANCELLED from root's cancel" "$(cat "$TMP/a3.out")"
until_true 30 idle && pass "idle at the end" || fail "idle at the end" "$(vc status)"

kill -TERM "$VOXD_PID"
wait_gone "$VOXD_PID" 30 && [ "$WAIT_RC" = 0 ] && pass "TERM: exit 0" || fail "TERM: exit 0" "rc $WAIT_RC"

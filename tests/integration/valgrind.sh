#!/bin/bash
# voxd and vox under valgrind's memcheck: "no leaks in the daemon's normal
# lifecycle", checked.  voxd serves ping, status, a job, a job it refuses
# (bad expression), a cancelled job, a client that leaves mid-job, inputs
# in chunks (whole, out of order, left mid-upload), takes
# HUP (the workers are replaced) and USR1, and stops on QUIT; then vox
# voxelize --embedded, vox info, vox render (a VOD file and a mesh) and vox
# export (gzip NRRD: its threads).  Every process valgrind
# watches must end with no error and no leak (definite, indirect or
# possible; still-reachable memory is allowed): the master and vox by
# valgrind's exit status, and each forked worker (valgrind follows forks) by
# its own log, since the master does not look at a worker's exit status.
#
# Valgrind cannot run the ASan build: this uses the release build (-O2 -g),
# which `make test` builds too (VOX from run-tests.sh), or builds it.
. "$(dirname "$0")/daemon_lib.bash"
BIN=${VOX_VALGRIND_BUILD:-$ROOT/build/release}
VOX=$BIN/vox
VOXD=$BIN/voxd
SUPP=$ROOT/tests/integration/valgrind.supp
VG_LOGS=$TMP/vg
mkdir -p "$VG_LOGS"

if ! command -v valgrind >/dev/null; then
    fail "valgrind is installed" "scripts/deps.sh installs it (make deps)"
    exit 0
fi
if [ ! -x "$VOX" ] || [ ! -x "$VOXD" ]; then
    make -C "$ROOT" --no-print-directory -s V=release all >"$TMP/make.out" 2>&1 ||
        { fail "release build for valgrind" "$(tail -5 "$TMP/make.out")"; exit 0; }
fi
if grep -q __asan_init "$VOX" "$VOXD"; then
    fail "non-sanitized binaries in $BIN" "valgrind cannot run ASan binaries"
    exit 0
fi

# vg NAME: the valgrind command line in VG (CMD... goes after it): its
# log, and each forked child's, in $VG_LOGS/NAME.PID; exit status 99 on any
# error or leak.  Run directly (not in a function) so that $! is the
# program's pid: valgrind runs the program in its own process.
vg() {
    VG=(valgrind --leak-check=full --show-leak-kinds=definite,indirect,possible
        --errors-for-leak-kinds=definite,indirect,possible --error-exitcode=99
        --trace-children=no --child-silent-after-fork=no --num-callers=30
        --suppressions="$SUPP" -s --log-file="$VG_LOGS/$1.%p")
}

# The errors of a valgrind log (the first lines of each), then its summaries
vg_excerpt() {
    sed -n '/Parent PID/,$p' "$1" | grep -v -e '^[=-][=-][0-9]*[=-][=-] *$' -e 'Parent PID' \
        -e 'used_suppression' -e 'For lists of detected' -e 'SUMMARY' -e '    [a-z ]*: [0-9,]* bytes' |
        head -30
    grep -e 'LEAK SUMMARY' -e '    [a-z ]*: [0-9,]* bytes' -e 'ERROR SUMMARY' "$1" | uniq
}

# The log's summary, waited for up to 30 s: vox's workers outlive the
# command by design (engine_abandon: they unmap the segment after it exits),
# so their logs end a little after it.
wait_summary() {
    local i
    for i in $(seq 300); do
        grep -q 'ERROR SUMMARY' "$1" && return 0
        sleep 0.1
    done
}

# vg_clean NAME RC WANT [MAIN_PID]: the command NAME ended with RC (WANT
# expected); every log of NAME says "0 errors" and the main process's log
# uses no suppression meant for the workers
vg_clean() {
    local name=$1 rc=$2 want=$3 main=${4:-} f bad="" n=0
    for f in "$VG_LOGS/$name".*; do
        [ -f "$f" ] || continue
        n=$((n + 1))
        wait_summary "$f"
        if ! grep -q 'ERROR SUMMARY: 0 errors' "$f"; then
            bad="$bad
$(basename "$f"): $(grep -q 'ERROR SUMMARY' "$f" && echo "errors" || echo "no summary: killed before its exit checks (the engine kills a worker that takes over 2 s to exit)?")
$(vg_excerpt "$f")"
        elif [ -n "$main" ] && [ "$f" = "$VG_LOGS/$name.$main" ] &&
            grep -q 'used_suppression:.*glibc-dtv-of-the-thread-that-forked' "$f"; then
            bad="$bad
$(basename "$f"): a thread of the main process was never joined (it used the workers' suppression)"
        fi
    done
    if [ "$rc" != "$want" ]; then
        bad="
exit status $rc (want $want; 99: valgrind found errors)$bad"
    fi
    [ "$n" -gt 0 ] || bad="
no valgrind log$bad"
    if [ -z "$bad" ]; then pass "valgrind: $name ($n process(es)), no error or leak"
    else fail "valgrind: $name: no error or leak" "${bad#?}"; fi
    VG_COUNT=$n
}

# vgv NAME WANT ARGS...: vox ARGS under memcheck (300 s at most), then vg_clean
vgv() {
    local name=$1 want=$2
    shift 2
    vg "$name"
    timeout 300 "${VG[@]}" "$VOX" "$@" >"$TMP/$name.out" 2>&1
    vg_clean "$name" $? "$want"
}

# shm_size: see --shm-size below
cat >"$TMP/voxd.conf" <<CONF
workers 2
shm_size 64M
log_file $TMP/voxd.log
CONF
t0=$(date +%s)

# ---------------------------------------------------------------- the daemon

vg voxd
"${VG[@]}" "$VOXD" --config "$TMP/voxd.conf" --socket "$S" >"$TMP/voxd.out" 2>&1 &
VOXD_PID=$!
PIDS+=($VOXD_PID)
until_true 60 vc ping || { fail "voxd starts under valgrind" "$(cat "$TMP/voxd.out" "$TMP/voxd.log" 2>&1 | tail -5)"; exit 0; }
pass "voxd starts under valgrind"

vgv ping 0 --socket "$S" ping
vgv status 0 --socket "$S" status
grep -q 'idle' "$TMP/status.out" && pass "status shows the workers" ||
    fail "status shows the workers" "$(head -8 "$TMP/status.out")"
vgv submit 0 --socket "$S" submit -e "$SPHERE" -r 32 -o "$TMP/a.vod"
vgv submit-bad 2 --socket "$S" submit -e 'x + (' -r 32 -o "$TMP/bad.vod"
# the daemon's own validation: vox would refuse the expression itself
refuse "bad expression: INVALID_INPUT from voxd" 3 "ERROR INVALID_INPUT" vc submit 'x + (' 32 -1,1 "$TMP/bad.vod"

# A job cancelled by an interrupt of vox (vox sends the cancel); vox
# status meanwhile shows it running
SLOW_RES=256
vg cancel
"${VG[@]}" "$VOX" --socket "$S" submit -e "$SLOW" -r $SLOW_RES -o "$TMP/c.vod" >"$TMP/cancel.out" 2>&1 &
CPID=$!
PIDS+=($CPID)
until_true 60 running || fail "the job to cancel runs" "$(vc status)"
vgv status-running 0 --socket "$S" status
grep -q '^running: job' "$TMP/status-running.out" && pass "status shows the running job" ||
    fail "status shows the running job" "$(head -4 "$TMP/status-running.out")"
kill -INT "$CPID"
if wait_gone "$CPID" 60; then
    grep -q 'cancelled (interrupted)' "$TMP/cancel.out" && pass "cancel: the job is cancelled" ||
        fail "cancel: the job is cancelled" "$(tail -3 "$TMP/cancel.out")"
    vg_clean cancel "$WAIT_RC" 1
else
    fail "cancel: vox ends after an interrupt" "$(tail -3 "$TMP/cancel.out")"
fi
until_true 60 idle && pass "idle after the cancel" || fail "idle after the cancel" "$(vc status)"

# Clients that leave mid-job, one with the running job and one with a
# queued job: both jobs are stopped and freed.  The client is the process
# killed (not a timeout around it), so its connection closes.  (disown: no
# "Killed" message from bash, the kill is the test.)
# leaver OUT ARGS...: `submit ARGS` in the background, its output in OUT
leaver() { local out=$1; shift; (exec "${CLIENT[@]}" "$S" submit "$@" >"$out" 2>&1) & PIDS+=($!); }
leaver "$TMP/g.out" "$SLOW" $SLOW_RES -1,1 "$TMP/g.vod"
G=$!
until_true 60 running || fail "the job of the client that leaves runs" "$(vc status)"
leaver "$TMP/h.out" "$SPHERE" 32 -1,1 "$TMP/h.vod"
H=$!
until_true 30 grep -q "accepted job" "$TMP/h.out" || fail "a second job is queued" "$(cat "$TMP/h.out")"
disown "$G" "$H"
kill -9 "$H" "$G"
until_true 60 idle && pass "clients gone: their jobs stop" || fail "clients gone: their jobs stop" "$(vc status)"
grep -q "cancelled, its client left" "$TMP/voxd.log" && grep -q "stopping, its client left" "$TMP/voxd.log" &&
    pass "clients gone: the queued and the running job" ||
    fail "clients gone: the queued and the running job" "$(grep "client left" "$TMP/voxd.log")"

# Inputs sent in chunks: one whole, one refused mid-upload, one whose
# client leaves mid-upload; their buffers are freed (QUIT's leak check).
check "a job's input in chunks" vc submit "$SPHERE" 32 -1,1 "$TMP/k.vod" --chunked 7
check "in chunks: the same bytes" cmp "$TMP/a.vod" "$TMP/k.vod"
refuse "an upload out of order ends its job" 0 "input chunk at offset 10 where 5 was due" vc abuse input-order
refuse "a client leaves mid-upload" 0 "leaving job [0-9]+ after 1000" vc abuse input-close
until_true 30 grep -q "dropped, its client left during its upload" "$TMP/voxd.log" &&
    pass "the upload of a client gone is dropped" || fail "the upload of a client gone is dropped"

# HUP: the configuration is read again, the workers are replaced
old=$(worker_pids | sort | tr '\n' ' ')
sed -i 's/^workers 2/workers 1/' "$TMP/voxd.conf"
kill -HUP "$VOXD_PID"
until_true 60 grep -q "workers replaced: 1 worker" "$TMP/voxd.log" &&
    pass "HUP: the workers are replaced" || fail "HUP: the workers are replaced" "$(tail -3 "$TMP/voxd.log")"
new=$(worker_pids | sort | tr '\n' ' ')
[ -n "$new" ] && [ "$new" != "$old" ] && pass "HUP: new worker pids" || fail "HUP: new worker pids" "$old -> $new"
check "a job after HUP" vc submit "$SPHERE" 32 -1,1 "$TMP/b.vod"
check "same bytes after HUP" cmp "$TMP/a.vod" "$TMP/b.vod"

# USR1: the log is reopened
mv "$TMP/voxd.log" "$TMP/voxd.log.1"
kill -USR1 "$VOXD_PID"
until_true 30 grep -q "log reopened" "$TMP/voxd.log" && pass "USR1 reopens the log" || fail "USR1 reopens the log"

# QUIT: the daemon exits 0 and valgrind with it (99 on any error or leak)
kill -QUIT "$VOXD_PID"
if wait_gone "$VOXD_PID" 60; then
    vg_clean voxd "$WAIT_RC" 0 "$VOXD_PID"
    # 2 workers at start, 1 after HUP
    [ "$VG_COUNT" -ge 4 ] && pass "the workers' logs checked too ($((VG_COUNT - 1)))" ||
        fail "the workers' logs checked too" "$VG_COUNT logs: $(ls "$VG_LOGS")"
else
    fail "QUIT: voxd exits under valgrind" "$(tail -5 "$TMP/voxd.log")"
fi
daemon_s=$(($(date +%s) - t0))

# ---------------------------------------------------------------- vox alone

t1=$(date +%s)
# --shm-size: a worker's leak check at exit scans every mapping, the
# segment too; all 2 GiB of the default take longer than the 2 s the engine
# waits for a worker to exit before it kills it (and its report with it)
vgv embedded 0 voxelize --embedded -w 2 --shm-size 64 -e "$SPHERE" -r 32 -o "$TMP/e.vod"
[ "$VG_COUNT" -ge 3 ] && pass "embedded: the workers' logs checked too" ||
    fail "embedded: the workers' logs checked too" "$VG_COUNT logs"
check "embedded: the daemon's bytes" cmp "$TMP/a.vod" "$TMP/e.vod"
vgv info 0 info "$TMP/e.vod"
vgv render 0 render "$TMP/e.vod" -o "$TMP/e.png" -s 64
[ -s "$TMP/e.png" ] && pass "render wrote the picture" || fail "render wrote the picture"
printf 'v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n' >"$TMP/tet.obj"
vgv render-mesh 0 render "$TMP/tet.obj" -o "$TMP/tet.png" -s 64 --smooth
vgv export-gzip 0 export "$TMP/e.vod" -o "$TMP/e.nrrd" --gzip
echo "NOTE: valgrind: daemon lifecycle ${daemon_s} s, vox alone $(($(date +%s) - t1)) s"

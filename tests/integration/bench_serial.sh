#!/bin/bash
# bench/voxserial, which measures a command's serial share from outside
# (make bench-serial), on commands whose answer is known: one busy thread
# (all serial), two busy threads (all parallel), busy children and
# grandchildren (seen through the process tree), a sleeper (idle), the
# serial spans of a command that is serial then parallel; then
# scripts/bench-serial.sh in its quick mode, so that it cannot rot.  Its
# "runnable" measure does not depend on the shared machine's load (a thread
# waiting for a CPU still counts), so the bounds hold on a loaded machine.
. "$(dirname "$0")/lib.sh"
REL=build/release # the benchmark's build; make test builds it beside asan
S=$ROOT/$REL/voxserial
mk() { env -u MAKEFLAGS -u MFLAGS -u MAKELEVEL make --no-print-directory -C "$ROOT" "$@"; }
check "voxserial builds" mk V=release "$REL/voxserial"

LINE='^wall_s=[0-9.]+ serial_s=[0-9.]+ idle_s=[0-9.]+ parallel_s=[0-9.]+ share=[0-9.]+ cap16=[0-9.]+ cap64=[0-9.]+ ran_serial_s=[0-9.]+ ran_parallel_s=[0-9.]+ ran_share=[0-9.]+ cpu_s=[0-9.]+ samples=[0-9]+ threads=[0-9]+ procs=[0-9]+$'
refuse "voxserial: the command's exit status, one line" 3 "$LINE" "$S" -- sh -c 'exit 3'
refuse "voxserial: a signal as 128 + its number" 143 "$LINE" "$S" -- sh -c 'kill -TERM $$'
refuse "voxserial: a command that is not there" 127 "No such file" "$S" -- "$TMP/none"
refuse "voxserial: a bad option" 125 "usage" "$S" -t 2 -- true

# measure NAME ARGS...: runs voxserial ARGS into $TMP/NAME; val NAME KEY.
measure() { local n=$1; shift; "$S" -o "$TMP/$n" "$@" >/dev/null 2>&1; }
val() { sed -n "s/.*\\b$2=\\([0-9.]*\\).*/\\1/p" "$TMP/$1" | head -1; }
# expect NAME CHECK: passes when the awk condition over the line's keys holds.
expect() {
    local n=$1 cond=$2 line; line=$(head -1 "$TMP/$n" 2>/dev/null)
    if awk -v m="$line" "BEGIN { k = split(m, kv, \" \")
        for (i = 1; i <= k; i++) { split(kv[i], p, \"=\"); v[p[1]] = p[2] + 0 }
        exit !($cond) }"; then pass "voxserial: $n ($cond)"
    else fail "voxserial: $n ($cond)" "$line"; fi
}

measure one -- "$S" -S 1:1
expect one 'v["share"] >= 0.95 && v["parallel_s"] <= 0.05 && v["wall_s"] >= 0.95 && v["threads"] == 1'
expect one 'v["ran_share"] >= 0.95' # at most one thread can run: whatever the load

measure two -- "$S" -S 2:1
# (the start, exec and the second thread's creation, is serial: a few
# windows, longer on a loaded machine)
expect two 'v["share"] <= 0.1 && v["parallel_s"] >= 0.85 && v["threads"] == 2'
# runnable_s: the seconds by runnable threads; three busy threads are three
# runnable (on a CPU or waiting for one), whatever the cores.
measure three -- "$S" -S 3:0.6
runnable() { sed -n 's/^runnable_s=//p' "$TMP/$1" | tr ',' '\n' | awk -F: -v k="$2" '$1 == k { print $2 }'; }
r3=$(runnable three 3) r1=$(runnable three 1)
if awk -v a="${r3:-0}" -v b="${r1:-0}" 'BEGIN { exit !(a >= 0.5 && b <= 0.05) }'; then
    pass "voxserial: three busy threads: 3 runnable ${r3}s, 1 runnable ${r1:-0}s"
else fail "voxserial: three busy threads runnable" "$(sed -n 2p "$TMP/three")"; fi
measure two-n4 -n 4 -- "$S" -S 2:1 # a parallel second is 4 workers' work
expect two-n4 'v["share"] <= 0.05 && v["share"] * 4 >= 0.9 * (v["serial_s"] / (v["serial_s"] + 2 * v["parallel_s"]))'

# A parent that forks one busy child and waits: serial, the child seen.
measure child -- sh -c "'$S' -S 1:1 & wait"
expect child 'v["share"] >= 0.8 && v["procs"] >= 2 && v["cpu_s"] >= 0.05'
# Two busy children, and two busy grandchildren: parallel only when the
# whole tree is sampled.
measure children -- sh -c "'$S' -S 1:1 & '$S' -S 1:1; wait"
expect children 'v["share"] <= 0.1 && v["procs"] >= 3'
measure grandchildren -- sh -c "sh -c \"'$S' -S 1:1 & '$S' -S 1:1; wait\"; true"
expect grandchildren 'v["share"] <= 0.1 && v["procs"] >= 4'

measure sleep -- sleep 0.5
expect sleep 'v["idle_s"] >= 0.4 && v["parallel_s"] <= 0.05'

# Serial for 0.6 s, then parallel for 0.6 s: one serial span at the start
# (its first window may be parallel: the shell and its child, just forked).
measure spans -l 100 -- sh -c "'$S' -S 1:0.6; '$S' -S 2:0.6"
spans=$(sed -n 's/^serial_spans=//p' "$TMP/spans")
if awk -v s="$spans" 'BEGIN { n = split(s, a, ","); split(a[1], b, "-")
        exit !(n >= 1 && b[1] + 0 <= 0.15 && b[2] + 0 >= 0.5 && b[2] + 0 <= 0.75) }'; then
    pass "voxserial: the serial span of a serial-then-parallel command ($spans)"
else fail "voxserial: the serial span of a serial-then-parallel command" "$(cat "$TMP/spans")"; fi

# -w: where the serial time went.  A busy child for 0.6 s, two for 0.6 s,
# then a sleeping one for 0.4 s: two spans, the first charged to the busy
# child (still named voxserial: -S does not exec), runnable (R), the last
# to the sleeper in its system call; the charges add up to the serial
# seconds.
refuse "voxserial: -w without -l" 125 "usage" "$S" -w -- true
measure where -l 100 -w -- sh -c "'$S' -S 1:0.6; '$S' -S 2:0.6; sleep 0.4"
sh_pid=$(sed -n 's/^serial_by=.* [a-z]* \([0-9]*\)\/[0-9]* (command) .*/\1/p' "$TMP/where" | head -1)
first=$(grep -m1 '^serial_span=0\.0' "$TMP/where")
last=$(grep '^serial_span=' "$TMP/where" | tail -1)
if [[ $first =~ ^serial_span=0\.0[0-9]+-0\.[5-7][0-9]+\ [0-9]+\ ms:\ ([0-9]+)\ ms\ voxserial\ ([0-9]+)/([0-9]+)\ \(child\ of\ ([0-9]+)\)\ R ]] &&
    [ "${BASH_REMATCH[1]}" -ge 450 ] && [ "${BASH_REMATCH[2]}" = "${BASH_REMATCH[3]}" ] &&
    { [ -z "$sh_pid" ] || [ "${BASH_REMATCH[4]}" = "$sh_pid" ]; }; then
    pass "voxserial -w: the busy child's span charged to it (${first%%;*})"
else fail "voxserial -w: the busy child's span charged to it" "$(cat "$TMP/where")"; fi
if [[ $last =~ ^serial_span=1\.[0-9]+-1\.[5-9][0-9]+\ [0-9]+\ ms:\ ([0-9]+)\ ms\ sleep\ [0-9]+/[0-9]+\ \(child\ of\ [0-9]+\)\ S\ clock_nanosleep ]] &&
    [ "${BASH_REMATCH[1]}" -ge 300 ]; then
    pass "voxserial -w: the sleeper's span charged to its system call (${last%%;*})"
else fail "voxserial -w: the sleeper's span charged to its system call" "$(cat "$TMP/where")"; fi
if awk -v s="$(val where serial_s)" '/^serial_by=/ { sub(/^serial_by=/, ""); t += $1 }
        END { exit !(t > 0.99 * s && t < 1.01 * s + 0.001) }' "$TMP/where"; then
    pass "voxserial -w: the charges add up to the serial seconds"
else fail "voxserial -w: the charges add up to the serial seconds" "$(cat "$TMP/where")"; fi

# vox names its stages and workers (thread_name): a small job's serial
# time is charged to "vox STAGE" names only (whichever stage: a list of
# them here missed `vox sync`, the flushes' thread, once), its workers seen
# as children.
check "vox builds" mk V=release "$REL/vox"
measure vox -l 1 -w -- "$ROOT/$REL/vox" voxelize -f "$ROOT/examples/sphere.vx" -r 256 \
    --embedded -q -w 2 -o "$TMP/where.vod"
names=$(sed -n 's/^serial_by=[0-9.]* s \(vox [a-z]*\|[^ ]*\) .*/\1/p' "$TMP/vox" | sort -u | paste -sd,)
if [ -n "$names" ] && [[ ,$names, =~ ^(,vox\ [a-z]+|,vox|,voxserial)+,$ ]] &&
    [ "$(val vox procs)" -ge 3 ]; then
    pass "voxserial -w: vox's serial time charged to its stages ($names)"
else fail "voxserial -w: vox's serial time charged to its stages" "$names: $(cat "$TMP/vox")"; fi

# ---------------------------------------------------------------- the table
check "bench-serial builds" mk V=release "$REL/vox"
BENCH_QUICK=1 scripts/bench-serial.sh "$REL" >"$TMP/table" 2>"$TMP/table.err"
rc=$?
if [ "$rc" -eq 0 ]; then pass "bench-serial: quick mode runs"
else fail "bench-serial: quick mode runs" "exit $rc: $(tail -3 "$TMP/table.err")"; fi
grep -q "^### .*([0-9]* cores: " "$TMP/table" && pass "bench-serial: the core count in the header" ||
    fail "bench-serial: the core count in the header" "$(head -1 "$TMP/table")"
# the measures' table, then (after "Where each run's") the charges' table, then
# (after "What a process pays") the references' table
sed '/^Where each run/,$d' "$TMP/table" >"$TMP/measures"
sed -n '/^Where each run/,/^What a process pays/p' "$TMP/table" >"$TMP/charges"
sed -n '/^What a process pays/,$p' "$TMP/table" >"$TMP/refs"
rows=$(grep -c '^| [A-Za-z1-9]' "$TMP/measures" | head -1)
want=6
grep -q 'The dragon is skipped' "$TMP/table" && want=5
# every row: a number in each of the nine measure columns, shares <= 100%,
# the command's own stages beside them
bad=$(awk -F'|' '/^\| [A-Za-z1-9]/ && !/^\| job/ {
        ok = $12 != ""
        for (i = 3; i <= 11; i++) if ($i !~ /^ *[0-9.]+%? *$/) ok = 0
        if ($7 + 0 > 100 || $10 + 0 > 100 || $13 !~ /[0-9] s/) ok = 0
        if (!ok) print }' "$TMP/measures")
if [ "$((rows - 1))" -eq "$want" ] && [ -z "$bad" ]; then pass "bench-serial: $want rows, every column filled"
else fail "bench-serial: $want rows, every column filled" "rows $((rows - 1)); $bad"; fi
# the charges: a row for each run of each job, its label, the seconds
# charged to vox's threads (a quick run's serial time may be spread over
# charges under 5 ms: then the largest, marked; none at all only where the
# measures' row of that job says 0.000 serial seconds)
crows=$(grep -c '^| [A-Za-z1-9]' "$TMP/charges" | head -1)
cbad=$(awk -F'|' 'FNR == NR { if ($5 ~ /^ 0\.000 $/) zero[$2] = 1; next }
        /^\| [A-Za-z1-9]/ && !/^\| job/ && $3 !~ /^ (largest: )?[0-9.]+ s vox/ &&
        !($3 == " no serial window " && ($2 in zero))' "$TMP/measures" "$TMP/charges")
if [ "$((crows - 1))" -eq "$want" ] && [ -z "$cbad" ]; then
    pass "bench-serial: where each run's serial time went, $want rows"
else fail "bench-serial: where each run's serial time went, $want rows" "rows $((crows - 1)); $cbad"; fi

# the references: a row for each run, the run's work, its output's size, the
# two references' seconds and shares (a share is its seconds over the work,
# within what the printed digits allow: seconds to 0.0001, a quick run's
# references a millisecond or two) and the run's own share as the measures'
# row has it
rrows=$(grep -c '^| [A-Za-z1-9]' "$TMP/refs" | head -1)
rbad=$(awk -F'|' 'function off(sec, pct, work,  e, d) {
            e = 100 * (0.00005 / work + sec * 0.00005 / work ^ 2) + 0.006
            d = 100 * sec / work - pct
            return d * d > e * e
        }
        FNR == NR { if (/^\| [A-Za-z1-9]/ && !/^\| job/) share[$2] = $8 + 0; next }
        /^\| [A-Za-z1-9]/ && !/^\| job/ {
        ok = $3 + 0 > 0 && ($2 in share)
        for (i = 3; i <= 9; i++) if ($i !~ /^ *[0-9.]+%? *$/) ok = 0
        if ($5 + 0 <= 0 || $7 + 0 <= 0) ok = 0
        if (ok && (off($5, $6, $3) || off($7, $8, $3))) ok = 0
        if (($9 - share[$2]) ^ 2 > 0.000225) ok = 0
        if (!ok) print }' "$TMP/measures" "$TMP/refs")
if [ "$((rrows - 1))" -eq "$want" ] && [ -z "$rbad" ]; then
    pass "bench-serial: the references (start and exit, the output written durably), $want rows"
else fail "bench-serial: the references, $want rows" "rows $((rrows - 1)); $rbad"; fi

# BENCH_SERIAL_JOBS: the named jobs only, in the table's order
BENCH_QUICK=1 BENCH_SERIAL_JOBS="iso csg" scripts/bench-serial.sh "$REL" >"$TMP/some" 2>"$TMP/some.err"
rc=$?
labels=$(sed '/^Where each run/,$d' "$TMP/some" | awk -F'|' '/^\| [A-Za-z1-9]/ && !/^\| job/ { print $2 }' |
    sed 's/^ *//; s/ *$//' | paste -sd';')
if [ "$rc" -eq 0 ] && [ "$labels" = "10-node CSG tree, 64^3;vox mesh of Scene 1, 32^3" ]; then
    pass "bench-serial: BENCH_SERIAL_JOBS runs the named jobs only ($labels)"
else fail "bench-serial: BENCH_SERIAL_JOBS runs the named jobs only" "exit $rc: $labels"; fi

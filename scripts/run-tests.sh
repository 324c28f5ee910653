#!/bin/bash
# Run every suite of the build in $1 and end with one line: "N passed, N failed".
#  - unit: each Criterion binary; its "Synthesis" line gives the counts
#  - fuzz: each harness replays its seed corpus (one test per corpus file)
#  - integration: each tests/integration/*.sh prints "PASS: name" / "FAIL: name"
# A suite also fails (one failure more, with its reason) when it
#  - runs past its time limit: TEST_TIMEOUT_<suite> seconds, else the long
#    suites' limits below, else TEST_TIMEOUT (default 1800); a hang is named;
#  - exits non-zero, or with the sanitizers' exit code (SAN_EXIT);
#  - ran no check (no test, no corpus file, no PASS/FAIL line);
#  - left a sanitizer report in its output or in its report files
#    (ASan and LSan write them under $VOX_SAN_DIR, one folder per suite).
# A fuzz replay must end with "REPLAYED: N inputs, 0 failed", N the number of
# its corpus files, and as many PASS lines; if not, none of its PASS lines count.
# VOX_TEST_INTEG_DIR and VOX_TEST_CORPUS point the runner elsewhere (its
# self-test, tests/integration/runner_selftest.sh, feeds it toy suites);
# VOX_TEST_ONLY="name ..." runs only the suites so named (test_engine,
# daemon_stall, ...: scripts/stress-tests.sh), under the same rules.
set -u
build=${1:-build/asan}
root=$(cd "$(dirname "$0")/.." && pwd)
integ=${VOX_TEST_INTEG_DIR:-$root/tests/integration}
corpora=${VOX_TEST_CORPUS:-$root/tests/fuzz/corpus}
export VOX="$root/build/release/vox" VOX_ASAN="$root/$build/vox" VOXD_ROOT="$root"
# The sanitizers exit with 86, a code no program of ours uses, so that a
# report never passes for an expected exit status (tests/integration/lib.sh
# sets the same when run alone).
SAN_EXIT=86
SAN_RE='ERROR: AddressSanitizer|ERROR: LeakSanitizer|runtime error:'
with_exitcode() { case ":$1:" in *:exitcode=*) echo "$1" ;; *) echo "${1:+$1:}exitcode=$SAN_EXIT" ;; esac; }
ASAN_BASE=$(with_exitcode "${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0}")
export LSAN_OPTIONS=$(with_exitcode "${LSAN_OPTIONS:-suppressions=$root/tests/lsan.supp:print_suppressions=0}")
export UBSAN_OPTIONS=$(with_exitcode "${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}")
TEST_TIMEOUT=${TEST_TIMEOUT:-1800}
passed=0 failed=0
log=$(mktemp -d)
trap 'rm -rf "$log"' EXIT

# limit NAME: the suite's time limit in seconds
limit() {
    local var="TEST_TIMEOUT_${1//[^A-Za-z0-9_]/_}"
    if [ -n "${!var:-}" ]; then echo "${!var}"; return; fi
    case $1 in  # the long ones, with room for a loaded 2-core machine
        valgrind | mpi | daemon_mpi | golden | docs | bench_* | test_mesh_vox*) echo $((TEST_TIMEOUT * 2)) ;;
        *) echo "$TEST_TIMEOUT" ;;
    esac
}

# run NAME CMD...: CMD under its time limit, its output in $log/NAME, ASan's
# and LSan's reports in $log/san.NAME; RC its exit status, WHY the reasons
# (one per line) that make the suite fail whatever it printed
run() {
    local name=$1 lim
    shift
    lim=$(limit "$name")
    T0=$SECONDS
    export VOX_SAN_DIR="$log/san.$name"
    mkdir -p "$VOX_SAN_DIR"
    export ASAN_OPTIONS="$ASAN_BASE:log_path=$VOX_SAN_DIR/asan"
    timeout -k 20 "$lim" "$@" >"$log/$name" 2>&1 </dev/null
    RC=$? WHY= SECS=$((SECONDS - T0))
    case $RC in
        0) ;;
        124 | 137) WHY="timed out after $lim s (hung? TEST_TIMEOUT_$name=SECONDS to change)" ;;
        "$SAN_EXIT") WHY="exited with $SAN_EXIT, the sanitizers' exit code" ;;
        *) WHY="exited with $RC" ;;
    esac
    if grep -aEq "$SAN_RE" "$log/$name"; then why "a sanitizer report in its output"; fi
    if [ -n "$(ls -A "$VOX_SAN_DIR")" ]; then
        why "sanitizer report files: $(cd "$VOX_SAN_DIR" && echo *)"
        head -n 30 "$VOX_SAN_DIR"/* >>"$log/$name"
    fi
}
why() { WHY="${WHY:+$WHY$'\n'}$1"; }

# report KIND NAME P F: add up, print the suite's line (with its seconds, so
# that the suites that make CI long are seen), and on a failure its reasons and
# the tail of its output
report() {
    local kind=$1 name=$2 p=$3 f=$4 n
    n=$(grep -c . <<<"$WHY")
    f=$((f + n))
    passed=$((passed + p)); failed=$((failed + f))
    printf '%-5s %-28s %4d passed, %d failed %6d s\n' "$kind" "$name" "$p" "$f" "$SECS"
    [ -n "$WHY" ] && sed "s/^/FAIL: $name: /" <<<"$WHY"
    [ "$f" -gt 0 ] && grep -a -v '^PASS:' "$log/$name" | tail -40
    grep -a '^NOTE:' "$log/$name" | sort
}

unit() {
    local t=$1 name syn p f c n
    name=$(basename "$t")
    run "$name" "$t" -j2
    syn=$(grep -a 'Synthesis:' "$log/$name" | tail -1)
    n=$(sed -n 's/.*Tested: \([0-9]*\).*/\1/p' <<<"$syn")
    p=$(sed -n 's/.*Passing: \([0-9]*\).*/\1/p' <<<"$syn")
    f=$(sed -n 's/.*Failing: \([0-9]*\).*/\1/p' <<<"$syn")
    c=$(sed -n 's/.*Crashing: \([0-9]*\).*/\1/p' <<<"$syn")
    if [ -z "$syn" ]; then p=0 f=0 c=0; why "no Synthesis line"
    elif [ "${n:-0}" -eq 0 ]; then why "ran no test"; fi
    # Criterion exits 1 when a test failed: that failure is already counted
    [ "$RC" -eq 1 ] && [ $((f + c)) -gt 0 ] && WHY=$(grep -v '^exited with 1$' <<<"$WHY")
    report unit "$name" "${p:-0}" $((${f:-0} + ${c:-0}))
}

fuzz() {
    local d=$1 name corpus n p f last
    name=$(basename "$d")
    corpus="$corpora/$name"
    n=$(find "$corpus" -mindepth 1 -maxdepth 1 ! -name '.*' 2>/dev/null | wc -l)
    run "$name" "$d" "$corpus"
    p=$(grep -ac '^PASS:' "$log/$name"); f=$(grep -ac '^FAIL:' "$log/$name")
    last=$(grep -a '^REPLAYED:' "$log/$name" | tail -1)
    [ "$n" -eq 0 ] && why "no corpus file in $corpus"
    [ "$last" = "REPLAYED: $n inputs, $f failed" ] || why "wanted 'REPLAYED: $n inputs, $f failed' at the end, got '${last:-nothing}'"
    [ "$p" -eq $((n - f)) ] || why "$p PASS lines for $n inputs and $f failures"
    # the replay exits 1 when an input failed: that failure is already counted
    [ "$RC" -eq 1 ] && [ "$f" -gt 0 ] && WHY=$(grep -v '^exited with 1$' <<<"$WHY")
    # a replay that did not finish cleanly proves none of its inputs
    if [ -n "$WHY" ]; then p=0; fi
    report fuzz "$name" "$p" "$f"
}

integration() {
    local s=$1 name p f
    name=$(basename "$s" .sh)
    run "$name" bash "$s"
    p=$(grep -ac '^PASS:' "$log/$name"); f=$(grep -ac '^FAIL:' "$log/$name")
    [ $((p + f)) -eq 0 ] && why "ran no check (no PASS or FAIL line)"
    report integ "$name" "$p" "$f"
}

# wanted NAME: whether VOX_TEST_ONLY (when set) names the suite
wanted() { [ -z "${VOX_TEST_ONLY:-}" ] || [[ " $VOX_TEST_ONLY " == *" $1 "* ]]; }

for t in "$build"/tests/test_*; do [ -x "$t" ] && wanted "$(basename "$t")" && unit "$t"; done
for d in "$build"/fuzz-replay/fuzz_*; do [ -x "$d" ] && wanted "$(basename "$d")" && fuzz "$d"; done
for s in "$integ"/*.sh; do
    # lib.sh: sourced by the others
    [ -f "$s" ] && [ "$(basename "$s")" != lib.sh ] && wanted "$(basename "$s" .sh)" && integration "$s"
done

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ] && [ "$passed" -gt 0 ]

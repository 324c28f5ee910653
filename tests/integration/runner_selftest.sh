#!/bin/bash
# The runner (scripts/run-tests.sh) against toy suites that lie: it must
# count as a failure a suite that exits non-zero after printing PASS lines,
# one that hangs, one that runs no check, one with a sanitizer report; a
# fuzz replay that aborts on its 110th of 120 inputs (having flushed 109
# PASS lines) proves none of them; lib.sh's `refuse` does not take a
# sanitizer's exit for the refusal it wants.  Honest toys pass with their
# exact counts.  The toys' output stays under $TMP/toy: it holds reports.
. "$(dirname "$0")/lib.sh"
T=$TMP/toy
B=$T/build
mkdir -p "$B/tests" "$B/fuzz-replay" "$T/integ" "$T/corpus" "$T/good/tests" "$T/good/fuzz-replay" "$T/good/integ"

# toy NAME BODY: an executable shell script
toy() { printf '#!/bin/bash\n%s\n' "$2" >"$1"; chmod +x "$1"; }
SYN='echo "[====] Synthesis: Tested: 3 | Passing: 3 | Failing: 0 | Crashing: 0"'

# unit suites, Criterion's last line imitated
toy "$T/good/tests/test_good" "$SYN"
toy "$B/tests/test_good" "$SYN"
toy "$B/tests/test_exit" "$SYN; exit 134"
toy "$B/tests/test_none" 'echo "[====] Synthesis: Tested: 0 | Passing: 0 | Failing: 0 | Crashing: 0"'
toy "$B/tests/test_hang" 'sleep 600'
toy "$B/tests/test_san" "$SYN; echo 't.c:1:2: runtime error: signed integer overflow' >&2"

# fuzz replays: the real replay_main over a toy harness, under ASan
cat >"$T/harness.c" <<'C'
#include <stdint.h>
#include <stdlib.h>
#include <unistd.h>
int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n);
int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n)
{
    static int calls;
    if (n && d[0] == 'L' && ++calls == 110) abort(); /* 'L': the 110th aborts */
    if (n && d[0] == 'H') sleep(600);                /* 'H': hangs */
    if (n && d[0] == 'A') {                          /* 'A': use after free */
        volatile char *p = malloc(8);
        free((void *)p);
        return p[3];
    }
    return 0;
}
C
cat >"$T/refuser.c" <<'C'
#include <stdio.h>
#include <stdlib.h>
int main(void) /* prints the refusal it is asked for, then corrupts memory */
{
    volatile char *p = malloc(8);
    fputs("error: bad input\n", stderr);
    free((void *)p);
    return p[2] ? 1 : 1;
}
C
check "the toy harness builds" cc -g -fsanitize=address -o "$T/fuzz_toy" "$T/harness.c" tests/fuzz/replay_main.c
check "the toy refuser builds" cc -g -fsanitize=address -o "$T/refuser" "$T/refuser.c"
corpus() {  # corpus NAME COUNT CONTENT
    local i
    mkdir -p "$T/corpus/$1"
    for i in $(seq "$2"); do echo "$3" >"$T/corpus/$1/in$i"; done
}
for f in good late hang asan empty; do cp "$T/fuzz_toy" "$B/fuzz-replay/fuzz_$f"; done
cp "$T/fuzz_toy" "$T/good/fuzz-replay/fuzz_good"
corpus fuzz_good 5 ok
corpus fuzz_late 120 L
corpus fuzz_hang 3 H
corpus fuzz_asan 4 ok
echo A >"$T/corpus/fuzz_asan/z"
mkdir -p "$T/corpus/fuzz_empty"

# integration scripts
toy "$T/good/integ/good.sh" 'echo "PASS: a"; echo "PASS: b"'
toy "$T/integ/good.sh" 'echo "PASS: a"; echo "PASS: b"'
toy "$T/integ/abort.sh" 'echo "PASS: a"; echo "PASS: b"; kill -ABRT $$'
toy "$T/integ/hang.sh" 'echo "PASS: a"; sleep 600'
toy "$T/integ/silent.sh" 'exit 0'
toy "$T/integ/report.sh" 'echo "PASS: a"; echo "==1==ERROR: AddressSanitizer: heap-use-after-free" >&2; exit 1'
toy "$T/integ/refuse.sh" ". $ROOT/tests/integration/lib.sh
clean() { echo 'error: bad input' >&2; return 1; }
texty() { echo 'error: bad input' >&2; echo 'x.c:3:4: runtime error: load of null pointer' >&2; return 1; }
refuse 'a clean refusal' 1 'bad input' clean
refuse 'a refusal with a UBSan report' 1 'bad input' texty
refuse 'a refusal that corrupts memory' 1 'bad input' $T/refuser"

# runner BUILD INTEG: the runner on toys, its output in $T/out; a limit of
# 2 s for the hanging ones (the per-suite override), 120 s for the others
runner() {
    env -u ASAN_OPTIONS -u LSAN_OPTIONS -u UBSAN_OPTIONS -u VOX_SAN_DIR TEST_TIMEOUT=120 \
        TEST_TIMEOUT_test_hang=2 TEST_TIMEOUT_fuzz_hang=2 TEST_TIMEOUT_hang=2 \
        VOX_TEST_INTEG_DIR="$2" VOX_TEST_CORPUS="$T/corpus" scripts/run-tests.sh "$1" >"$T/out" 2>&1
    RC=$?
}
# counts KIND NAME: "P F" from the suite's line
counts() { sed -n "s/^$1 *$2  *\([0-9]*\) passed, \([0-9]*\) failed  *[0-9]* s$/\1 \2/p" "$T/out"; }
said() { sed 's/Sanitizer/S.nitizer/; s/runtime error/runtime e.ror/' "$T/out" | grep -v '^PASS:' | head -40; }

runner "$T/good" "$T/good/integ"
[ "$RC" -eq 0 ] && [ "$(tail -1 "$T/out")" = "10 passed, 0 failed" ] &&
    pass "honest toys: 10 passed, 0 failed, exit 0" || fail "honest toys: 10 passed, 0 failed, exit 0" "$(said)"

runner "$B" "$T/integ"
[ "$RC" -ne 0 ] && pass "lying toys: the runner fails" || fail "lying toys: the runner fails" "$(said)"
want() {  # want KIND NAME P F-MIN [REASON]: the suite's line, and its reason
    local c p f
    c=$(counts "$1" "$2"); p=${c% *} f=${c#* }
    if [ -n "$c" ] && [ "$p" -eq "$3" ] && [ "$f" -ge "$4" ] &&
        { [ -z "${5:-}" ] || grep -q "^FAIL: $2: .*$5" "$T/out"; }; then
        pass "runner: $1 $2 counts $p passed, $f failed${5:+ ($5)}"
    else fail "runner: $1 $2 counts $3 passed, at least $4 failed${5:+ ($5)}" "got '$c'; $(said | grep -m3 "$2")"; fi
}
want unit test_good 3 0
want unit test_exit 3 1 "exited with 134"
want unit test_none 0 1 "ran no test"
want unit test_hang 0 1 "timed out after 2 s"
want unit test_san 3 1 "sanitizer report in its output"
want fuzz fuzz_good 5 0
want fuzz fuzz_late 0 1 "got 'nothing'"
want fuzz fuzz_hang 0 1 "timed out after 2 s"
want fuzz fuzz_asan 0 1 "exited with 86, the sanitizers' exit code"
want fuzz fuzz_asan 0 1 "sanitizer report files"
want fuzz fuzz_empty 0 1 "no corpus file"
want integ good 2 0
want integ abort 2 1 "exited with 134"
want integ hang 1 1 "timed out after 2 s"
want integ silent 0 1 "ran no check"
want integ report 1 1 "sanitizer report in its output"
want integ refuse 1 2
grep -q '^FAIL: a refusal with a UBSan report' "$T/out" && grep -q '^FAIL: a refusal that corrupts memory' "$T/out" &&
    pass "refuse: a sanitizer report fails the check, printed or in a report file (exit 86)" ||
    fail "refuse: a sanitizer report fails the check, printed or in a report file (exit 86)" "$(said | grep -A2 refusal)"
# the replay itself flushed its first 109 PASS lines, which the runner did not count
n=$("$B/fuzz-replay/fuzz_late" "$T/corpus/fuzz_late" 2>/dev/null | grep -c '^PASS:')
[ "$n" -eq 109 ] && pass "the aborting replay printed 109 PASS lines first" || fail "the aborting replay printed 109 PASS lines first" "$n"

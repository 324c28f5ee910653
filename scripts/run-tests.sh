#!/bin/bash
# Run every suite of the build in $1 and end with one line: "N passed, N failed".
#  - unit: each Criterion binary; its "Synthesis" line gives the counts
#  - fuzz: each harness replays its seed corpus (one test per corpus file)
#  - integration: each tests/integration/*.sh prints "PASS: name" / "FAIL: name"
set -u
build=${1:-build/asan}
root=$(cd "$(dirname "$0")/.." && pwd)
export VOX="$root/build/release/vox" VOX_ASAN="$root/$build/vox" VOXD_ROOT="$root"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/lsan.supp:print_suppressions=0}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
passed=0 failed=0
log=$(mktemp -d)
trap 'rm -rf "$log"' EXIT

for t in "$build"/tests/test_*; do
    [ -x "$t" ] || continue
    name=$(basename "$t")
    "$t" -j2 >"$log/$name" 2>&1
    rc=$?
    syn=$(grep -a 'Synthesis:' "$log/$name" | tail -1)
    p=$(sed -n 's/.*Passing: \([0-9]*\).*/\1/p' <<<"$syn")
    f=$(sed -n 's/.*Failing: \([0-9]*\).*/\1/p' <<<"$syn")
    c=$(sed -n 's/.*Crashing: \([0-9]*\).*/\1/p' <<<"$syn")
    if [ -z "$syn" ]; then p=0; f=1; c=0; fi
    if [ "$rc" -ne 0 ] && [ $((f + c)) -eq 0 ]; then f=1; fi
    passed=$((passed + p)); failed=$((failed + f + c))
    printf 'unit  %-28s %4d passed, %d failed\n' "$name" "$p" $((f + c))
    [ $((f + c)) -gt 0 ] && grep -a -v '^\[----\]' "$log/$name" | tail -40
    grep -a '^NOTE:' "$log/$name" | sort
done

for d in "$build"/fuzz-replay/fuzz_*; do
    [ -x "$d" ] || continue
    name=$(basename "$d")
    corpus="$root/tests/fuzz/corpus/$name"
    out=$("$d" "$corpus" 2>&1)
    p=$(grep -c '^PASS:' <<<"$out"); f=$(grep -c '^FAIL:' <<<"$out")
    if [ "$p" -eq 0 ] && [ "$f" -eq 0 ]; then f=1; out="$out (no corpus replayed)"; fi
    passed=$((passed + p)); failed=$((failed + f))
    printf 'fuzz  %-28s %4d passed, %d failed\n' "$name" "$p" "$f"
    [ "$f" -gt 0 ] && tail -40 <<<"$out"
done

for s in "$root"/tests/integration/*.sh; do
    [ -f "$s" ] || continue
    name=$(basename "$s" .sh)
    [ "$name" = lib ] && continue  # sourced by the others
    out=$(bash "$s" 2>&1)
    rc=$?
    p=$(grep -c '^PASS:' <<<"$out"); f=$(grep -c '^FAIL:' <<<"$out")
    if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; out="$out
FAIL: $name exited with $rc"; fi
    passed=$((passed + p)); failed=$((failed + f))
    printf 'integ %-28s %4d passed, %d failed\n' "$name" "$p" "$f"
    [ "$f" -gt 0 ] && grep -v '^PASS:' <<<"$out" | tail -40
    grep '^NOTE:' <<<"$out"
done

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ] && [ "$passed" -gt 0 ]

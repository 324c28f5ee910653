# Helpers for integration tests: each check prints "PASS: name" or
# "FAIL: name" (the runner counts them); a test never skips silently.
VOX=${VOX_ASAN:-${VOX:-build/asan/vox}}
ROOT=${VOXD_ROOT:-$(pwd)}
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
cd "$ROOT" || exit 1
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}

pass() { echo "PASS: $1"; }
fail() { echo "FAIL: $1"; [ -n "${2:-}" ] && printf '  %s\n' "$2"; }
# check NAME COMMAND...: passes when the command succeeds
check() { local n=$1; shift; if "$@" >"$TMP/out" 2>&1; then pass "$n"; else fail "$n" "$(tail -5 "$TMP/out")"; fi; }
# refuse NAME CODE PATTERN COMMAND...: passes when the command exits with CODE
# and its output matches the extended regex PATTERN
refuse() {
    local n=$1 code=$2 pat=$3; shift 3
    "$@" >"$TMP/out" 2>&1; local rc=$?
    if [ "$rc" -eq "$code" ] && grep -Eq -- "$pat" "$TMP/out"; then pass "$n"
    else fail "$n" "exit $rc (want $code), output: $(head -3 "$TMP/out")"; fi
}

#!/bin/bash
# The timing-sensitive suites, N rounds in a row beside a CPU hog, and the
# failures counted per suite: what "make test twenty times beside another
# make test" would find, in the time one session on a shared machine has.
# Not part of make test or CI.
#
#     scripts/stress-tests.sh [-n ROUNDS] [-j HOGS] [-b BUILD] [SUITE ...]
#
# ROUNDS (default 3) runs of the suites, each through scripts/run-tests.sh
# (VOX_TEST_ONLY: the runner's own rules, time limits and sanitizer checks);
# HOGS (default 1) busy loops at the same priority beside them the whole
# time; BUILD the sanitizer build (default build/asan; `make test-build` and
# `make` first).  SUITE: test_engine, daemon_stall, ... (default: the suites
# that wait on time or kill a busy worker, below).  Every round's whole
# output is kept in a folder that the summary names; a suite that failed is
# listed with its round and its FAIL lines.  Exit status 0 when no round of
# any suite failed.
set -u
root=$(cd "$(dirname "$0")/.." && pwd)
rounds=3 hogs=1 build=build/asan
while getopts "n:j:b:h" o; do
    case $o in
        n) rounds=$OPTARG ;;
        j) hogs=$OPTARG ;;
        b) build=$OPTARG ;;
        *) sed -n '2,/^set -u/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 2 ;;
    esac
done
shift $((OPTIND - 1))
# test_engine, test_engine_death, test_libvox and test_libvox_wait (stall
# timeouts, destroy and cancel times),
# the daemon's state waits, the scripts whose kill_busy_worker must find a
# worker mid-job (daemon.sh, daemon_csg.sh), and MPI's rank kills
suites=${*:-test_engine test_engine_death test_libvox test_libvox_wait daemon_stall daemon_fair daemon_life daemon_abuse daemon daemon_csg mpi}
case $rounds in '' | *[!0-9]*) echo "stress-tests.sh: -n wants a whole number" >&2; exit 2 ;; esac
case $hogs in '' | *[!0-9]*) echo "stress-tests.sh: -j wants a whole number" >&2; exit 2 ;; esac
cd "$root" || exit 2
for s in $suites; do
    [ -x "$build/tests/$s" ] || [ -f "tests/integration/$s.sh" ] ||
        { echo "stress-tests.sh: no suite '$s' (in $build/tests or tests/integration)" >&2; exit 2; }
done

out=$(mktemp -d "${TMPDIR:-/tmp}/stress.XXXXXX")
hog_pids=()
stop_hogs() {
    local p
    for p in "${hog_pids[@]}"; do kill "$p" 2>/dev/null; done
    for p in "${hog_pids[@]}"; do wait "$p" 2>/dev/null; done
    hog_pids=()
}
trap 'stop_hogs; exit 130' INT TERM
trap stop_hogs EXIT
for _ in $(seq "$hogs"); do
    (while :; do :; done) &
    hog_pids+=($!)
done

declare -A runs fails
t0=$(date +%s)
for r in $(seq "$rounds"); do
    VOX_TEST_ONLY="$suites" scripts/run-tests.sh "$build" >"$out/round$r.log" 2>&1
    # the runner's line per suite: "unit  test_engine    21 passed, 0 failed"
    while read -r kind name p _ f _; do
        case $kind in unit | fuzz | integ) ;; *) continue ;; esac
        runs[$name]=$((${runs[$name]:-0} + 1))
        if [ "$f" -gt 0 ]; then
            fails[$name]=$((${fails[$name]:-0} + 1))
            echo "round $r: $name: $f failed" >>"$out/failures"
            awk -v n="$name" '$2 == n {on = 1; next} /^(unit|fuzz|integ) / {on = 0} on && /FAIL/' \
                "$out/round$r.log" | head -20 | sed 's/^/    /' >>"$out/failures"
        fi
    done <"$out/round$r.log"
    echo "round $r of $rounds: $(tail -1 "$out/round$r.log") ($(( $(date +%s) - t0 )) s so far)"
done
stop_hogs

echo
echo "$rounds rounds beside $hogs CPU hog(s), $(( $(date +%s) - t0 )) s; logs in $out"
bad=0
for s in $suites; do
    n=${runs[$s]:-0} f=${fails[$s]:-0}
    printf '  %-14s %2d of %2d rounds failed\n' "$s" "$f" "$n"
    [ "$n" -eq "$rounds" ] || { echo "    (ran $n times: see the logs)"; bad=1; }
    [ "$f" -eq 0 ] || bad=1
done
[ -f "$out/failures" ] && { echo; cat "$out/failures"; }
exit "$bad"

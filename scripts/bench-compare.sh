#!/bin/bash
# make bench-compare BASE=REV: the whole `vox voxelize` command, as a user
# times it, for this tree and for commit REV built beside it, measured in
# one run, alternating, so both see the same machine.  Prints a Markdown
# table with the core count: per job the median wall time of each, the
# engine's and the writer's times (vox's summary line) and the ratio.
# BENCH_REPEATS (default 5) runs per job and side; BENCH_JOBS overrides
# the job list (lines "name|vox voxelize arguments").
set -euo pipefail
base=${1:?usage: bench-compare.sh REV [BUILD]}
build=${2:-build/release}
root=$(cd "$(dirname "$0")/.." && pwd)
repeats=${BENCH_REPEATS:-5}
tmp=$(mktemp -d)
trap 'git -C "$root" worktree remove --force "$tmp/base" >/dev/null 2>&1 || true; rm -rf "$tmp"' EXIT
rev=$(git -C "$root" rev-parse --short "$base")
git -C "$root" worktree add --detach "$tmp/base" "$rev" >/dev/null 2>&1
echo "building $rev ..." >&2
make -C "$tmp/base" -j"$(nproc)" V=release >/dev/null
jobs=${BENCH_JOBS:-"sphere 512, 2 workers|-f examples/sphere.vx -r 512 -w 2
sphere 512, 1 worker|-f examples/sphere.vx -r 512 -w 1
sphere 512, serial|-f examples/sphere.vx -r 512 -w 0
union64 512, 2 workers|-f examples/union64.vx -r 512 -w 2
blend2 512, 2 workers|-f examples/blend2.vx -r 512 -w 2
scene1 512, 2 workers|-f examples/scene1.vx -r 512 -w 2
sphere 1024, 2 workers|-f examples/sphere.vx -r 1024 -w 2"}

# run VOX ARGS: prints "wall engine write" for one run (summary line of vox)
run() {
    local vox=$1; shift
    local t0 t1 line
    t0=$(date +%s.%N)
    line=$(cd "$root" && VOXD_SOCKET=/nonexistent "$vox" voxelize "$@" --embedded -o "$tmp/out.vod" | head -1)
    t1=$(date +%s.%N)
    local eng wr
    eng=$(sed -n 's/.* in \([0-9.]*\) s (.*/\1/p' <<<"$line")
    wr=$(sed -n 's/.*VOD written in \([0-9.]*\) s.*/\1/p' <<<"$line")
    echo "$(awk -v a="$t0" -v b="$t1" 'BEGIN { print b - a }') $eng $wr"
}
median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }

echo "### Whole \`vox voxelize\` command: $rev vs this tree ($(nproc) cores, median of $repeats runs each, alternating)"
echo
echo "| job | $rev wall (s) | now wall (s) | now / $rev | $rev engine / write (s) | now engine / write (s) |"
echo "|---|---:|---:|---:|---:|---:|"
while IFS='|' read -r name args; do
    [ -n "$name" ] || continue
    : >"$tmp/a"; : >"$tmp/b"
    for _ in $(seq "$repeats"); do
        # shellcheck disable=SC2086  # the arguments are words
        run "$tmp/base/build/release/vox" $args >>"$tmp/a"
        # shellcheck disable=SC2086
        run "$root/$build/vox" $args >>"$tmp/b"
    done
    wa=$(cut -d' ' -f1 <"$tmp/a" | median); wb=$(cut -d' ' -f1 <"$tmp/b" | median)
    ea=$(cut -d' ' -f2 <"$tmp/a" | median); eb=$(cut -d' ' -f2 <"$tmp/b" | median)
    ra=$(cut -d' ' -f3 <"$tmp/a" | median); rb=$(cut -d' ' -f3 <"$tmp/b" | median)
    printf '| %s | %.3f | %.3f | %.2f | %.3f / %.3f | %.3f / %.3f |\n' "$name" "$wa" "$wb" \
        "$(awk -v a="$wa" -v b="$wb" 'BEGIN { print b / a }')" "$ea" "$ra" "$eb" "$rb"
done <<<"$jobs"

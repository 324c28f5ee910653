#!/bin/bash
# bench-export.sh [BUILD]: the whole `vox export` command as a user times it
# (issue 12's export targets): a RES^3 solid, a sphere of radius 0.8 in
# [-1,1]^3 written by `vox csg` as occupancy (1 bit) and as density (8 bit),
# exported to NRRD with gzip and to OpenVDB; the median wall time of
# REPEATS runs of each command under bench/voxwhole, the CPU time it took
# (user + system, all threads: bash's times for the children), its peak
# memory (ru_maxrss), the output's size, and the issue's target (<= 2 s each at
# 1024^3) with a pass/FAIL mark.  Raw NRRD is there for scale (it writes a
# dense RES^3 array of bytes), without a target.  Markdown on stdout.
#
#   BENCH_QUICK=1      a quick run for tests: defaults RES=96, REPEATS=1
#   BENCH_EXPORT_RES   the solid's resolution (default 1024); targets are
#                      marked only at 1024
#   BENCH_REPEATS      timed runs per command, the median is shown (default 3)
#
# The 1-minute load average before each command's runs is in its row: the
# machine is shared, and a busy one shows in the figures.  Exits 1 when a
# command failed (its row says why).
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, bench_start, medians
bench_root "${1:-}"
if [ "${BENCH_QUICK:-0}" = 1 ]; then dres=96 drep=1; else dres=1024 drep=3; fi
res=${BENCH_EXPORT_RES:-$dres}
repeats=${BENCH_REPEATS:-$drep}
vox=$build/vox whole=$build/voxwhole
bench_start bench-export "$vox" "$whole" "$build/vox-vdb.so"
failed=0

printf 's = ellipsoid radius 0.8\nresult s\n' >"$tmp/solid.csg"
for ch in occupancy density; do
    "$vox" csg "$tmp/solid.csg" -r "$res" --channel "$ch" -q -o "$tmp/$ch.vod"
done

echo "### vox export of a ${res}^3 solid ($(nproc) cores)"
echo
echo "A sphere of radius 0.8 in [-1,1]^3 (vox csg), $(sed -n 's/^  voxels *\([0-9]*\) non-empty.*/\1/p' \
    < <("$vox" info "$tmp/occupancy.vod")) voxels set; the whole command, median of $repeats run(s)."
echo
echo "| input | output | wall s | CPU s | peak RSS MiB | output MB | load before | target |"
echo "|---|---|---|---|---|---|---|---|"
for ch in occupancy density; do
    for fmt in "nrrd --gzip" vdb nrrd; do
        ext=${fmt%% *} opt=${fmt#"$ext"}
        load=$(cut -d' ' -f1 /proc/loadavg)
        : >"$tmp/kv"
        ok=1
        for _ in $(seq "$repeats"); do
            # a subshell: its times line 2 is the CPU of its children alone
            # shellcheck disable=SC2086 # opt is empty or one word
            if ! ( "$whole" -o "$tmp/m" -- "$vox" export "$tmp/$ch.vod" -o "$tmp/out.$ext" $opt \
                >"$tmp/out" 2>&1 && times >"$tmp/times" ); then ok=0; break; fi
            cpu=$(sed -n 2p "$tmp/times" | awk '{
                n = split($0, t, " "); s = 0
                for (i = 1; i <= n; i++) { split(t[i], ms, "m"); s += ms[1] * 60 + ms[2] }
                printf "%.3f", s }')
            echo "$(cat "$tmp/m") cpu_s=$cpu" >>"$tmp/kv"
        done
        name=$ch
        if [ "$ok" = 0 ]; then
            echo "| $name | .$ext$opt | failed: $(tail -1 "$tmp/out") | | | | $load | |"
            failed=1
            continue
        fi
        wall=$(medians <"$tmp/kv" | awk '$1 == "wall_s" {print $2}')
        rss=$(medians <"$tmp/kv" | awk '$1 == "maxrss_kib" {printf "%.0f", $2 / 1024}')
        cpu=$(medians <"$tmp/kv" | awk '$1 == "cpu_s" {print $2}')
        size=$(stat -c %s "$tmp/out.$ext" | awk '{printf "%.1f", $1 / 1e6}')
        target=""
        if [ "$res" = 1024 ] && [ "$fmt" != nrrd ]; then
            target=$(awk -v w="$wall" 'BEGIN { print (w <= 2.0 ? "<= 2 s: pass" : "<= 2 s: FAIL") }')
        fi
        printf '| %s | .%s%s | %.3f | %.3f | %s | %s | %s | %s |\n' "$name" "$ext" "$opt" "$wall" \
            "$cpu" "$rss" "$size" "$load" "$target"
        rm -f "$tmp/out.$ext"
    done
done
echo
echo "NRRD with --gzip is one gzip stream deflated by one thread per CPU; .vdb goes through"
echo "the vox-vdb.so module (libopenvdb), its load included. Plain NRRD writes the dense"
echo "${res}^3 bytes to $(df -P "$tmp" | awk 'NR == 2 {print $1}') (no target: it measures the disk)."
exit "$failed"

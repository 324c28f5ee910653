#!/bin/bash
# bench-csg.sh [BUILD]: volume CSG jobs (issue 11) as a user runs them, the
# whole `vox csg` command on the release build's embedded engine, run by
# `make bench` and `make bench-csg`.  Markdown on stdout:
#
#  1. the layout of the Isovox thesis's Tables 3 and 4: RAW size (one byte a
#     voxel), VOD size and ratio without per-brick compression (--compress
#     none: only the octree's empty and duplicate bricks shared), and with
#     it (zlib per brick), on the thesis's synthetic sets made as CSG trees:
#     the Small and Large Ellipsoid (200x160x160, 512^3; the Large one's
#     52.18:1 is the ratio to beat), a Small and Large World (a height field
#     z = h(x, y), h a sum of four octaves of sines standing in for the
#     thesis's Perlin noise), and a CSG part (the issue's tree, 512^3);
#  2. CSG at 512^3 and 1024^3 with 1 and 2 workers, for a 10-node tree of
#     primitives, for the issue's part (with an implicit leaf and a
#     dilation) and for a VOD leaf (Scene 1's surface voxels at 256^3,
#     resampled onto the job's grid, unioned with an ellipsoid): the
#     evaluation's seconds (vox's summary), the whole
#     command's, the yield t1 / (2 t2) of the evaluation, the fraction of
#     bricks decided uniform, and the peak memory of the command and its
#     workers (shared memory included) against a dense 1 GiB grid; the
#     10-node tree at 1024^3 with 2 workers against the issue's target of
#     1 s.
#
# Per job: BENCH_REPEATS timed runs under bench/voxwhole (the median shown),
# the 1- and 2-worker runs alternating so that a change of the shared
# machine's load falls on both; then one run sampled for the memory.  The
# 1-minute load average is printed before each table.
#
#   BENCH_QUICK=1      a quick run for tests: one run each, 64^3 and 128^3
#                      for the second table, the sets of the first at a
#                      quarter of their size, no targets marked
#   BENCH_REPEATS      timed runs per job (default 3; quick 1)
set -euo pipefail
. "$(dirname "$0")/bench-lib.sh" # bench_root, bench_start, medians
bench_root "${1:-}"
quick=${BENCH_QUICK:-0}
if [ "$quick" = 1 ]; then drep=1 div=4 sizes="64 128"; else drep=3 div=1 sizes="512 1024"; fi
repeats=${BENCH_REPEATS:-$drep}
vox=$build/vox whole=$build/voxwhole
bench_start bench-csg "$vox" "$whole"
failed=0
load() { cut -d' ' -f1 /proc/loadavg; }

# ---------------------------------------------------------------- the trees
printf 'e = ellipsoid radii 0.95,0.75,0.75\nresult e\n' >"$tmp/ellipsoid.csg"
h='0.2*sin(3.1*x+0.3)*cos(2.7*y) + 0.1*sin(6.3*x+1.1)*sin(5.9*y+0.7) + 0.05*sin(12.7*x+2)*cos(11.9*y+0.4) + 0.025*sin(25.1*x)*sin(23.3*y+1.3)'
printf 'w = implicit "z + 0.1 - (%s)"\nresult w\n' "$h" >"$tmp/world.csg"
cat >"$tmp/part.csg" <<'EOT'
base  = cuboid center 0,0,0 size 1.6,1.0,0.6
hole  = cylinder center 0,0,0 radius 0.3 height 2 axis z
bump  = implicit "x^2 + y^2 + (z-0.3)^2 - 0.2" domain -1,1
out   = difference(union(base, bump), hole)
out2  = union(out, dilate(bump, 2))
result out2
EOT
cat >"$tmp/ten.csg" <<'EOT'
base  = cuboid size 1.6,1.0,0.6 rotate 0,0,10
boss  = ellipsoid center 0,0,0.3 radii 0.35,0.3,0.25
hole1 = cylinder center -0.45,0,0 radius 0.2 height 2 axis z
hole2 = cylinder center 0.45,0,0 radius 0.15 height 2 axis z
slot  = cuboid center 0,0.35,0 size 1.8,0.12,0.2 rotate 0,0,10
peg   = cone center 0,-0.3,0.3 radius 0.12 height 0.5 axis z
a = union(base, boss)
b = difference(a, hole1)
c = difference(b, hole2)
d = difference(union(c, peg), slot)
result d
EOT
# a VOD leaf: Scene 1's surface voxels at 256^3 (a quarter of that in quick)
"$vox" voxelize -f examples/scene1.vx -r $((256 / div)) -q -o "$tmp/leaf.vod"
printf 's = vod "leaf.vod"\nb = ellipsoid radius 0.5\nr = union(s, b)\nresult r\n' >"$tmp/vodleaf.csg"

# run NAME ARGS...: one vox csg run under voxwhole; "key=value" words on
# stdout: wall, eval (vox's evaluation), write, bricks, uniform, bytes.
run() {
    local name=$1; shift
    if ! "$whole" -o "$tmp/$name.w" -- "$vox" csg "$@" -o "$tmp/$name.vod" >"$tmp/$name.out" 2>&1; then
        echo "FAILED: vox csg $*: $(tail -1 "$tmp/$name.out")" >&2
        failed=1
        return 1
    fi
    local o; o=$(cat "$tmp/$name.out")
    echo "wall=$(sed -n 's/.*wall_s=\([0-9.]*\).*/\1/p' "$tmp/$name.w")" \
         "eval=$(sed -n 's/.*evaluated in \([0-9.]*\) s.*/\1/p' <<<"$o")" \
         "write=$(sed -n 's/.*written in \([0-9.]*\) s.*/\1/p' <<<"$o")" \
         "bricks=$(sed -n 's/.* \([0-9]*\) bricks (.*/\1/p' <<<"$o")" \
         "uniform=$(sed -n 's/.*bricks (\([0-9]*\) uniform.*/\1/p' <<<"$o")" \
         "bytes=$(stat -c %s "$tmp/$name.vod")"
}
get() { awk -v k="$1" '$1 == k { print $2 }'; }

# ---------------------------------------------------------------- Tables 3 and 4
echo "## CSG: the layout of the Isovox thesis's Tables 3 and 4 (8-bit densities, 16^3 bricks)"
echo
echo "Load average before: $(load). Small sets $((200 / div))x$((160 / div))x$((160 / div)), large ones $((512 / div))^3."
echo
echo "| data set | voxels | RAW (KB) | VOD, no brick compression (KB) | ratio | VOD, zlib per brick (KB) | ratio |"
echo "|---|---|---|---|---|---|---|"
set_row() { # NAME TREE RES DOMAIN
    local name=$1 tree=$2 res=$3 dom=$4 n
    case $dom in
        small) dom=-1,1,-0.8,0.8,-0.8,0.8; n=$((res * res * 4 / 5 * res * 4 / 5)) ;;
        *) dom=-1,1; n=$((res * res * res)) ;;
    esac
    run "t-$name-none" "$tmp/$tree.csg" -r "$res" -d "$dom" -w 2 -q -Z none >"$tmp/none" || return 0
    run "t-$name-zlib" "$tmp/$tree.csg" -r "$res" -d "$dom" -w 2 -q -Z zlib >"$tmp/zlib" || return 0
    local none zlib
    none=$(medians <"$tmp/none" | get bytes) zlib=$(medians <"$tmp/zlib" | get bytes)
    awk -v s="$name" -v n="$n" -v a="$none" -v b="$zlib" 'BEGIN {
        printf "| %s | %d | %.0f | %.0f | %.2f : 1 | %.0f | %.2f : 1 |\n", s, n, n / 1024, a / 1024, n / a, b / 1024, n / b }'
}
set_row "Small Ellipsoid" ellipsoid $((200 / div)) small
set_row "Large Ellipsoid" ellipsoid $((512 / div)) large
set_row "Small World" world $((200 / div)) small
set_row "Large World" world $((512 / div)) large
set_row "CSG part (the issue's tree)" part $((512 / div)) large
echo

# ---------------------------------------------------------------- scaling
echo "## CSG: evaluation at $(echo $sizes | sed 's/ /^3 and /')^3 with 1 and 2 workers"
echo
echo "Median of $repeats run(s); the 1- and 2-worker runs alternate. eval: vox's evaluation"
echo "(the engine's CSG kind, the bricks into shared memory); whole: the whole command (start,"
echo "evaluation, VOD write). yield = eval(1) / (2 eval(2)). uniform: the bricks decided without"
echo "storing a voxel. memory: the peak of vox and its workers, shared memory included, 2 workers."
echo
echo "| tree | res | load | eval 1 w (s) | eval 2 w (s) | whole 2 w (s) | yield | uniform bricks | memory (MiB) | dense 8-bit grid (MiB) |"
echo "|---|---|---|---|---|---|---|---|---|---|"
for tree in ten part vodleaf; do
    for r in $sizes; do
        l=$(load)
        : >"$tmp/one"; : >"$tmp/two"
        for i in $(seq "$repeats"); do
            run "s-$tree-$r-1" "$tmp/$tree.csg" -r "$r" -w 1 >>"$tmp/one" || continue
            run "s-$tree-$r-2" "$tmp/$tree.csg" -r "$r" -w 2 >>"$tmp/two" || continue
        done
        [ -s "$tmp/one" ] && [ -s "$tmp/two" ] || { echo "| $tree | $r^3 | $l | failed | | | | | | |"; continue; }
        "$whole" -s 2000 -o "$tmp/mem.w" -- "$vox" csg "$tmp/$tree.csg" -r "$r" -w 2 -q -o "$tmp/mem.vod" >/dev/null 2>&1 || failed=1
        peak=$(sed -n 's/.*tree_peak_kib=\([0-9]*\).*/\1/p' "$tmp/mem.w")
        m1=$(medians <"$tmp/one") m2=$(medians <"$tmp/two")
        e1=$(get eval <<<"$m1") e2=$(get eval <<<"$m2") w2=$(get wall <<<"$m2")
        b=$(get bricks <<<"$m2") u=$(get uniform <<<"$m2")
        case $tree in
            ten) name="10 primitives" ;; part) name="the issue's part" ;;
            *) name="a VOD leaf ($((256 / div))^3) and an ellipsoid" ;;
        esac
        awk -v t="$name" -v r="$r" -v l="$l" -v e1="$e1" -v e2="$e2" -v w2="$w2" -v b="$b" -v u="$u" \
            -v p="${peak:-0}" 'BEGIN {
            printf "| %s | %d^3 | %s | %.3f | %.3f | %.3f | %.0f%% | %.1f%% | %.0f | %.0f |\n",
                t, r, l, e1, e2, w2, 100 * e1 / (2 * e2), 100 * u / b, p / 1024, r * r * r / 1048576 }'
        if [ "$quick" != 1 ] && [ "$tree" = ten ] && [ "$r" = 1024 ]; then
            target=$(awk -v e="$e2" 'BEGIN { print (e <= 1.0) ? "met" : "MISSED" }')
            echo "$target" >"$tmp/target"
        fi
    done
done
echo
if [ -e "$tmp/target" ]; then
    echo "Target (issue 11): the 10-node tree of primitives at 1024^3 with 2 workers in <= 1 s: $(cat "$tmp/target")."
    echo
fi
exit "$failed"

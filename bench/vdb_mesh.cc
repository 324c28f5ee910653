// vdb_mesh: OpenVDB's meshToVolume on a mesh, the reference beside which
// scripts/bench-mesh-whole.sh puts `vox voxelize --mesh` (issue 10).
//
//   vdb_mesh FILE RES [REPEATS]
//
// The mesh is loaded by voxd's own loader (not timed), then converted
// REPEATS times (default 1) at the voxel size of `vox voxelize --mesh FILE
// --res RES` with its default padding (the bounding box's longest side over
// RES - 2 voxels) into OpenVDB's solid: a level set (meshToLevelSet, a
// narrow band of 3 voxels on each side) whose inside is told by the sign,
// the interior's tiles and voxels negative.  Prints one line:
//   threads T seconds S active A inside I
// T: the threads TBB runs it on (every CPU, as OpenVDB does by default), S:
// the median wall time of one conversion, A: the grid's active voxels (the
// band), I: the voxels inside (value < 0, active or not, tiles counted by
// their voxels).  Exit status 1 with a message on any error.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <tbb/task_arena.h>

extern "C" {
#include "mesh.h"
}

namespace {

double now()
{
    using namespace std::chrono;
    return duration<double>(steady_clock::now().time_since_epoch()).count();
}

int fail(const char *what, const char *why)
{
    std::fprintf(stderr, "vdb_mesh: %s: %s\n", what, why);
    return 1;
}

} // namespace

int main(int argc, char **argv)
{
    if (argc < 3 || argc > 4) {
        std::fprintf(stderr, "usage: vdb_mesh FILE RES [REPEATS]\n");
        return 2;
    }
    long res = std::strtol(argv[2], nullptr, 10);
    long reps = argc == 4 ? std::strtol(argv[3], nullptr, 10) : 1;
    if (res < 8 || res > 8192) return fail(argv[2], "RES wants 8..8192");
    if (reps < 1 || reps > 100) return fail(argv[3], "REPEATS wants 1..100");
    mesh m;
    mesh_error err;
    if (mesh_load(argv[1], MESH_FORMAT_AUTO, nullptr, &m, &err)) return fail(argv[1], err.msg);
    float ext = 0;
    for (int a = 0; a < 3; a++) ext = std::max(ext, m.hi[a] - m.lo[a]);
    if (!(ext > 0)) return fail(argv[1], "a flat mesh");
    double vs = ext / double(res - 2);
    std::vector<openvdb::Vec3s> points(m.n_vertices);
    std::vector<openvdb::Vec3I> tris(m.n_triangles);
    std::vector<openvdb::Vec4I> quads;
    for (uint32_t i = 0; i < m.n_vertices; i++)
        points[i] = openvdb::Vec3s(m.vertices[i][0], m.vertices[i][1], m.vertices[i][2]);
    for (uint32_t i = 0; i < m.n_triangles; i++)
        tris[i] = openvdb::Vec3I(m.triangles[i][0], m.triangles[i][1], m.triangles[i][2]);
    mesh_free(&m);
    openvdb::initialize();
    auto xform = openvdb::math::Transform::createLinearTransform(vs);
    std::vector<double> secs;
    openvdb::FloatGrid::Ptr grid;
    for (long r = 0; r < reps; r++) {
        double t0 = now();
        grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, points, tris,
                                                                   quads, 3.0f);
        secs.push_back(now() - t0);
    }
    std::sort(secs.begin(), secs.end());
    uint64_t inside = 0;
    for (auto it = grid->cbeginValueAll(); it; ++it)
        if (*it < 0) inside += it.getVoxelCount();
    std::printf("threads %d seconds %.3f active %llu inside %llu\n",
                tbb::this_task_arena::max_concurrency(), secs[secs.size() / 2],
                (unsigned long long)grid->activeVoxelCount(), (unsigned long long)inside);
    return 0;
}

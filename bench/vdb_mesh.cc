// vdb_mesh: OpenVDB's meshToVolume on a mesh, the reference beside which
// scripts/bench-mesh-whole.sh puts `vox voxelize --mesh` (issue 10).
//
//   vdb_mesh FILE RES [REPEATS [DISTANCE.vod [WELD]]]
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
// their voxels).
//
// With DISTANCE.vod (`vox voxelize --mesh FILE -r RES --channel distance
// --band K`, channel 4), the level set is made at that file's voxel size,
// on its voxel centres (the transform moved to its origin plus half a
// voxel) and with its band K (distance_band=K in its metadata), and the two
// are compared; the line goes on:
//   ours B maxdiff D maxabs E signs N compared C
// B: the file's voxels inside its band (|d| < K voxels), D: the largest
// |ours - OpenVDB| in voxels over OpenVDB's active voxels that lie in both
// bands, E: the same of the unsigned distances, N: of those voxels the
// ones whose signs differ, C: how many were compared.
// With WELD (a distance in the mesh's units, 0: equal positions) the
// vertices are merged first, as `vox voxelize --weld WELD` does (mesh_weld).
// Exit status 1 with a message on any error.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <tbb/task_arena.h>

#include <cmath>
#include <cstring>

extern "C" {
#include "mesh.h"
#include "vod.h"
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

struct distance_file {
    vod_file *f = nullptr;
    double vs = 0, origin[3] = {0, 0, 0};
    uint32_t dims[3] = {0, 0, 0};
    int band = 3;
};

int open_distance(const char *path, distance_file *d)
{
    char err[256];
    if (vod_open(path, &d->f, err, sizeof err)) return fail(path, err);
    const vod_info *in = vod_get_info(d->f);
    if (in->channel != 4) return fail(path, "not a distance file (channel 4)");
    d->vs = in->voxel_scale[0];
    for (int a = 0; a < 3; a++) d->origin[a] = in->origin[a], d->dims[a] = in->volume[a];
    const char *b = std::strstr(in->metadata, "distance_band=");
    if (b) d->band = std::atoi(b + 14);
    if (d->band < 1 || d->band > 32) return fail(path, "distance_band is not 1..32");
    return 0;
}

float voxel_f32(const vod_file *f, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t u = vod_voxel(f, 0, x, y, z);
    float v;
    std::memcpy(&v, &u, 4);
    return v;
}

// The file against OpenVDB's grid (the same voxels: see the transform).
void compare(const distance_file &d, const openvdb::FloatGrid &grid)
{
    float w = (float)(d.band * d.vs);
    uint64_t ours = 0, compared = 0, signs = 0;
    for (uint32_t z = 0; z < d.dims[2]; z++)
        for (uint32_t y = 0; y < d.dims[1]; y++)
            for (uint32_t x = 0; x < d.dims[0]; x++) ours += std::fabs(voxel_f32(d.f, x, y, z)) < w;
    double maxdiff = 0, maxabs = 0;
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        openvdb::Coord c = it.getCoord();
        if (c.x() < 0 || c.y() < 0 || c.z() < 0 || (uint32_t)c.x() >= d.dims[0] ||
            (uint32_t)c.y() >= d.dims[1] || (uint32_t)c.z() >= d.dims[2])
            continue;
        float o = voxel_f32(d.f, (uint32_t)c.x(), (uint32_t)c.y(), (uint32_t)c.z()), t = *it;
        if (!(std::fabs(o) < w && std::fabs(t) < w)) continue;
        compared++;
        signs += std::signbit(o) != std::signbit(t);
        maxdiff = std::max(maxdiff, std::fabs((double)o - t) / d.vs);
        maxabs = std::max(maxabs, std::fabs(std::fabs((double)o) - std::fabs((double)t)) / d.vs);
    }
    std::printf(" ours %llu maxdiff %.4f maxabs %.4f signs %llu compared %llu",
                (unsigned long long)ours, maxdiff, maxabs, (unsigned long long)signs,
                (unsigned long long)compared);
}

} // namespace

int main(int argc, char **argv)
{
    if (argc < 3 || argc > 6) {
        std::fprintf(stderr, "usage: vdb_mesh FILE RES [REPEATS [DISTANCE.vod [WELD]]]\n");
        return 2;
    }
    long res = std::strtol(argv[2], nullptr, 10);
    long reps = argc >= 4 ? std::strtol(argv[3], nullptr, 10) : 1;
    distance_file dist;
    if (argc >= 5 && open_distance(argv[4], &dist)) return 1;
    if (res < 8 || res > 8192) return fail(argv[2], "RES wants 8..8192");
    if (reps < 1 || reps > 100) return fail(argv[3], "REPEATS wants 1..100");
    mesh m;
    mesh_error err;
    if (mesh_load(argv[1], MESH_FORMAT_AUTO, nullptr, &m, &err)) return fail(argv[1], err.msg);
    uint32_t merged = 0;
    if (argc == 6 && mesh_weld(&m, std::strtod(argv[5], nullptr), &merged))
        return fail(argv[5], "the weld failed");
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
    float band = 3.0f;
    if (dist.f) { // the file's voxels: index (i, j, k) at origin + (i + 0.5) vs
        xform = openvdb::math::Transform::createLinearTransform(dist.vs);
        xform->postTranslate(openvdb::Vec3d(dist.origin[0] + 0.5 * dist.vs,
                                            dist.origin[1] + 0.5 * dist.vs,
                                            dist.origin[2] + 0.5 * dist.vs));
        band = (float)dist.band;
    }
    std::vector<double> secs;
    openvdb::FloatGrid::Ptr grid;
    for (long r = 0; r < reps; r++) {
        double t0 = now();
        grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, points, tris,
                                                                   quads, band);
        secs.push_back(now() - t0);
    }
    std::sort(secs.begin(), secs.end());
    uint64_t inside = 0;
    for (auto it = grid->cbeginValueAll(); it; ++it)
        if (*it < 0) inside += it.getVoxelCount();
    std::printf("threads %d seconds %.3f active %llu inside %llu",
                tbb::this_task_arena::max_concurrency(), secs[secs.size() / 2],
                (unsigned long long)grid->activeVoxelCount(), (unsigned long long)inside);
    if (dist.f) compare(dist, *grid), vod_close(dist.f);
    std::printf("\n");
    return 0;
}

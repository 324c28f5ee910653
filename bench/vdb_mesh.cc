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
// then:
//   samesign S over05 O flipped F
// S: D over the compared voxels whose signs agree, O: of those, the ones
// that differ by more than 0.05 voxel, F: the voxels of N within 0.5 voxel
// of the surface by both (|d| < 0.5: a sign decided at the surface); then
//   near S0 S1 S2
// S as above over the voxels with vox's |d| in [0, 1), [1, 2), [2, K) voxels.
// With WELD (a distance in the mesh's units, 0: equal positions) the
// vertices are merged first, as `vox voxelize --weld WELD` does (mesh_weld).
//
// Environment (the diagnosis of docs/meshes.md's comparison):
//   VDB_MESH_FLAGS=N   meshToVolume's flags (openvdb::tools::MeshToVolumeFlags,
//                      0 by default: meshToLevelSet's); 4 turns off its
//                      renormalization, 2 its removal of voxels it takes for
//                      self-intersections
//   VDB_MESH_WORST=N   to stderr, the N compared voxels that differ most in
//                      each of two groups (signs equal, signs opposite): index,
//                      vox's value, OpenVDB's and the exact unsigned distance
//                      (double, every triangle: brute force), in voxels, and
//                      the generalized winding number there (brute force);
//                      then N of the voxels whose signs differ, evenly
//                      spaced, and whose sign the winding number there takes
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

static double now()
{
    using namespace std::chrono;
    return duration<double>(steady_clock::now().time_since_epoch()).count();
}

static int fail(const char *what, const char *why)
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

static int open_distance(const char *path, distance_file *d)
{
    err_info err = {};
    if (vod_open(path, &d->f, &err)) return fail(path, err.msg);
    const vod_info *in = vod_get_info(d->f);
    if (in->channel != 4) return fail(path, "not a distance file (channel 4)");
    d->vs = in->voxel_scale[0];
    for (int a = 0; a < 3; a++) d->origin[a] = in->origin[a], d->dims[a] = in->volume[a];
    const char *b = std::strstr(in->metadata, "distance_band=");
    if (b) d->band = std::atoi(b + 14);
    if (d->band < 1 || d->band > 32) return fail(path, "distance_band is not 1..32");
    return 0;
}

static float voxel_f32(const vod_file *f, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t u = vod_voxel(f, 0, x, y, z);
    float v;
    std::memcpy(&v, &u, 4);
    return v;
}

struct worst {
    double diff;
    openvdb::Coord c;
    float ours, theirs;
};

// The mesh in world units, for the brute force.
struct world_mesh {
    const std::vector<openvdb::Vec3s> *points;
    const std::vector<openvdb::Vec3I> *tris;
};

typedef openvdb::Vec3d v3;

// The closest point on triangle abc to p (Ericson, Real-Time Collision
// Detection, 5.1.5), in double.
static v3 closest_on_triangle(const v3 &p, const v3 &a, const v3 &b, const v3 &c)
{
    v3 ab = b - a, ac = c - a, ap = p - a;
    double d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return a;
    v3 bp = p - b;
    double d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return b;
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
    v3 cp = p - c;
    double d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return c;
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0)
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    double den = 1 / (va + vb + vc);
    return a + ab * (vb * den) + ac * (vc * den);
}

// The exact distance from p to the mesh: every triangle.
static double brute_distance(const world_mesh &m, const v3 &p)
{
    double best = HUGE_VAL;
    for (const openvdb::Vec3I &t : *m.tris) {
        v3 a((*m.points)[t[0]]), b((*m.points)[t[1]]), c((*m.points)[t[2]]);
        best = std::min(best, (closest_on_triangle(p, a, b, c) - p).lengthSqr());
    }
    return std::sqrt(best);
}

// The generalized winding number of the mesh at p (the solid angles of
// every triangle, Van Oosterom and Strackee, over 4 pi): 1 inside a closed
// mesh, 0 outside, 2 where two parts of it overlap.
static double brute_winding(const world_mesh &m, const v3 &p)
{
    double sum = 0;
    for (const openvdb::Vec3I &t : *m.tris) {
        v3 a = v3((*m.points)[t[0]]) - p, b = v3((*m.points)[t[1]]) - p,
           c = v3((*m.points)[t[2]]) - p;
        double la = a.length(), lb = b.length(), lc = c.length();
        sum += 2 * std::atan2(a.dot(b.cross(c)),
                              la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la);
    }
    return sum / (4 * M_PI);
}

static void keep_worst(std::vector<worst> &w, size_t n, const worst &x)
{
    if (!n) return;
    auto less = [](const worst &a, const worst &b) { return a.diff > b.diff; };
    if (w.size() < n) {
        w.push_back(x), std::push_heap(w.begin(), w.end(), less);
    } else if (x.diff > w.front().diff) {
        std::pop_heap(w.begin(), w.end(), less), w.back() = x;
        std::push_heap(w.begin(), w.end(), less);
    }
}

static void print_worst(const char *group, std::vector<worst> w, const distance_file &d,
                        const world_mesh &m)
{
    std::sort(w.begin(), w.end(), [](const worst &a, const worst &b) { return a.diff > b.diff; });
    for (const worst &x : w) {
        v3 p(d.origin[0] + (x.c.x() + 0.5) * d.vs, d.origin[1] + (x.c.y() + 0.5) * d.vs,
             d.origin[2] + (x.c.z() + 0.5) * d.vs);
        std::fprintf(stderr, "%s %d %d %d vox %+.5f openvdb %+.5f exact %.5f winding %+.4f\n",
                     group, x.c.x(), x.c.y(), x.c.z(), x.ours / d.vs, x.theirs / d.vs,
                     brute_distance(m, p) / d.vs, brute_winding(m, p));
    }
}

// n of the voxels whose signs differ, evenly spaced in the grid's order,
// and which of the two the winding number agrees with: one line each, then
//   winding agrees with vox V openvdb O of n
static void sign_sample(const std::vector<worst> &all, size_t n, const distance_file &d,
                        const world_mesh &m)
{
    size_t votes[2] = {0, 0}, k = 0;
    for (size_t i = 0; i < n && i < all.size(); i++, k++) {
        const worst &x = all[i * all.size() / std::min(n, all.size())];
        v3 p(d.origin[0] + (x.c.x() + 0.5) * d.vs, d.origin[1] + (x.c.y() + 0.5) * d.vs,
             d.origin[2] + (x.c.z() + 0.5) * d.vs);
        double wn = brute_winding(m, p);
        bool inside = std::fabs(wn) >= 0.5;
        votes[inside == std::signbit(x.theirs)]++;
        std::fprintf(stderr, "sample %d %d %d vox %+.5f openvdb %+.5f winding %+.4f\n", x.c.x(),
                     x.c.y(), x.c.z(), x.ours / d.vs, x.theirs / d.vs, wn);
    }
    std::fprintf(stderr, "winding agrees with vox %zu openvdb %zu of %zu\n", votes[0], votes[1], k);
}

// The file against OpenVDB's grid (the same voxels: see the transform).
static void compare(const distance_file &d, const openvdb::FloatGrid &grid, const world_mesh &m)
{
    /* vox writes the band's width as (float)(K vs) from the grid's double
     * voxel size, the file holds vs as a float: a hair less than K vs (1e-6
     * of it) keeps the voxels beyond the band out whichever rounds up */
    float w = (float)(d.band * d.vs * (1 - 1e-6));
    uint64_t ours = 0, compared = 0, signs = 0, over = 0, flipped = 0;
    for (uint32_t z = 0; z < d.dims[2]; z++)
        for (uint32_t y = 0; y < d.dims[1]; y++)
            for (uint32_t x = 0; x < d.dims[0]; x++) ours += std::fabs(voxel_f32(d.f, x, y, z)) < w;
    const char *nw = std::getenv("VDB_MESH_WORST");
    size_t nworst = nw ? (size_t)std::strtoul(nw, nullptr, 10) : 0;
    std::vector<worst> same, opposite, all_opposite;
    double maxdiff = 0, maxabs = 0, maxsame = 0, byband[3] = {0, 0, 0};
    for (auto it = grid.cbeginValueOn(); it; ++it) {
        openvdb::Coord c = it.getCoord();
        if (c.x() < 0 || c.y() < 0 || c.z() < 0 || (uint32_t)c.x() >= d.dims[0] ||
            (uint32_t)c.y() >= d.dims[1] || (uint32_t)c.z() >= d.dims[2])
            continue;
        float o = voxel_f32(d.f, (uint32_t)c.x(), (uint32_t)c.y(), (uint32_t)c.z()), t = *it;
        if (!(std::fabs(o) < w && std::fabs(t) < w)) continue;
        compared++;
        bool differ = std::signbit(o) != std::signbit(t);
        double diff = std::fabs((double)o - t) / d.vs;
        signs += differ;
        flipped += differ && std::fabs(o) < 0.5 * d.vs && std::fabs(t) < 0.5 * d.vs;
        maxdiff = std::max(maxdiff, diff);
        maxabs = std::max(maxabs, std::fabs(std::fabs((double)o) - std::fabs((double)t)) / d.vs);
        if (!differ) maxsame = std::max(maxsame, diff), over += diff > 0.05;
        int k = std::min(2, (int)(std::fabs(o) / d.vs)); // vox's |d| in whole voxels
        if (!differ) byband[k] = std::max(byband[k], diff);
        keep_worst(differ ? opposite : same, nworst, worst{diff, c, o, t});
        if (differ && nworst) all_opposite.push_back(worst{diff, c, o, t});
    }
    std::printf(" ours %llu maxdiff %.4f maxabs %.4f signs %llu compared %llu"
                " samesign %.4f over05 %llu flipped %llu near %.6f %.6f %.6f",
                (unsigned long long)ours, maxdiff, maxabs, (unsigned long long)signs,
                (unsigned long long)compared, maxsame, (unsigned long long)over,
                (unsigned long long)flipped, byband[0], byband[1], byband[2]);
    print_worst("same", same, d, m);
    print_worst("opposite", opposite, d, m);
    if (nworst) sign_sample(all_opposite, nworst, d, m);
}

// meshToLevelSet with meshToVolume's flags: the points taken to index
// space first, as meshToLevelSet does (doMeshConversion).
static openvdb::FloatGrid::Ptr convert(const openvdb::math::Transform &xform,
                                       const std::vector<openvdb::Vec3s> &points,
                                       const std::vector<openvdb::Vec3I> &tris, float band,
                                       int flags)
{
    std::vector<openvdb::Vec3s> ip(points.size());
    for (size_t i = 0; i < points.size(); i++) ip[i] = xform.worldToIndex(points[i]);
    openvdb::tools::QuadAndTriangleDataAdapter<openvdb::Vec3s, openvdb::Vec3I> mesh(ip, tris);
    return openvdb::tools::meshToVolume<openvdb::FloatGrid>(mesh, xform, band, band, flags);
}

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
    const char *fl = std::getenv("VDB_MESH_FLAGS");
    int flags = fl ? std::atoi(fl) : 0;
    std::vector<double> secs;
    openvdb::FloatGrid::Ptr grid;
    for (long r = 0; r < reps; r++) {
        double t0 = now();
        grid = flags ? convert(*xform, points, tris, band, flags)
                     : openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*xform, points, tris,
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
    if (dist.f) compare(dist, *grid, world_mesh{&points, &tris}), vod_close(dist.f);
    std::printf("\n");
    return 0;
}

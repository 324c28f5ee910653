// vdb_out: see vdb_out.h.  The one C++ file of the tree, built with g++
// as the module vox-vdb.so: its one exported symbol is the C table at the
// end, and every exception stops at that interface.
#include "vdb_out.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <new>
#include <string>

#include <openvdb/io/Archive.h>
#include <openvdb/math/Maps.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Prune.h>

namespace {

using openvdb::Coord;
using openvdb::CoordBBox;

// err_set's work (common/err.h), done here: the module does not link
// libvoxd.  "what: why", or why alone without what.  code returned.
int say(err_info *err, int code, const char *what, const char *why)
{
    if (!err) return code;
    err->code = code;
    if (what) std::snprintf(err->msg, sizeof err->msg, "%s: %s", what, why);
    else std::snprintf(err->msg, sizeof err->msg, "%s", why);
    return code;
}

// io::File's write on a stream of our own, whose failures we see:
// File::writeGrids (OpenVDB 10) never looks at its stream after writing,
// so a full disk or a file size limit left a truncated .vdb reported as
// written.  The same bytes: Archive::write, seekable, as File's.
struct checked_archive : openvdb::io::Archive {
    void write_to(std::ostream &os, const openvdb::GridPtrVec &grids,
                  const openvdb::MetaMap &meta) const
    {
        Archive::write(os, grids, /*seekable=*/true, meta);
    }
};

// grids and meta into path: 0, or a negative errno said in err (why alone:
// the caller names the file).
int write_checked(const char *path, const openvdb::GridPtrVec &grids,
                  const openvdb::MetaMap &meta, err_info *err)
{
    std::ofstream os(path, std::ios_base::out | std::ios_base::binary | std::ios_base::trunc);
    if (os.fail()) {
        int e = errno ? errno : EIO;
        return say(err, -e, nullptr, std::strerror(e));
    }
    errno = 0;
    checked_archive().write_to(os, grids, meta);
    os.flush();
    int e = os.fail() ? errno : 0; // the failed write's, before close may change it
    os.close();
    if (!e && os.fail()) e = errno ? errno : EIO;
    if (e) return say(err, -e, nullptr, std::strerror(e));
    return 0;
}

} // namespace

struct vdb_out {
    int kind;
    float bg; // a level set's background
    openvdb::BoolGrid::Ptr occ;
    openvdb::FloatGrid::Ptr dens;
    openvdb::Vec3SGrid::Ptr nrm;

    openvdb::GridBase::Ptr scalar() const
    {
        if (occ) return occ;
        return dens;
    }
};

namespace {

// Voxels of a dense block through an accessor (it caches the path to the
// last leaf, so neighbours cost little); zero bytes stay inactive.
template <typename GridT, typename F>
void block(GridT &g, const int32_t lo[3], const uint32_t n[3], const uint8_t *v, F value)
{
    auto acc = g.getAccessor();
    size_t i = 0;
    for (uint32_t z = 0; z < n[2]; z++)
        for (uint32_t y = 0; y < n[1]; y++)
            for (uint32_t x = 0; x < n[0]; x++, i++)
                if (v[i])
                    acc.setValueOn(Coord(lo[0] + int32_t(x), lo[1] + int32_t(y),
                                         lo[2] + int32_t(z)),
                                   value(i));
}

CoordBBox box_of(const int32_t lo[3], const uint32_t n[3])
{
    return CoordBBox(Coord(lo[0], lo[1], lo[2]),
                     Coord(lo[0] + int32_t(n[0]) - 1, lo[1] + int32_t(n[1]) - 1,
                           lo[2] + int32_t(n[2]) - 1));
}

template <typename GridT>
typename GridT::Ptr make_grid(const vdb_out_grid *g, openvdb::math::Transform::Ptr xf,
                              openvdb::GridClass cls)
{
    auto grid = GridT::create();
    grid->setName(g->name);
    grid->setTransform(xf);
    grid->setGridClass(cls);
    return grid;
}

} // namespace

static int vdb_out_open(vdb_out **out, const vdb_out_grid *g, err_info *err)
{
    *out = nullptr;
    if (g->kind != VDB_OUT_BOOL && g->kind != VDB_OUT_FLOAT && g->kind != VDB_OUT_LEVEL_SET) {
        return say(err, -EINVAL, "vdb", "unknown grid kind");
    }
    try {
        openvdb::initialize(); // registers the grid types; idempotent
        // index (i, j, k) -> centre + (i, j, k) * spacing, per axis
        openvdb::math::MapBase::Ptr map(new openvdb::math::ScaleTranslateMap(
            openvdb::Vec3d(g->spacing[0], g->spacing[1], g->spacing[2]),
            openvdb::Vec3d(g->centre[0], g->centre[1], g->centre[2])));
        auto xf = openvdb::math::Transform::Ptr(new openvdb::math::Transform(map));
        vdb_out *w = new vdb_out();
        w->kind = g->kind;
        if (g->kind == VDB_OUT_BOOL)
            w->occ = make_grid<openvdb::BoolGrid>(g, xf, openvdb::GRID_UNKNOWN);
        else if (g->kind == VDB_OUT_LEVEL_SET) {
            if (!(g->background > 0)) {
                delete w;
                return say(err, -EINVAL, "vdb", "a level set needs a background > 0");
            }
            w->bg = float(g->background);
            w->dens = openvdb::FloatGrid::create(w->bg);
            w->dens->setName(g->name);
            w->dens->setTransform(xf);
            w->dens->setGridClass(openvdb::GRID_LEVEL_SET);
        } else
            w->dens = make_grid<openvdb::FloatGrid>(g, xf, openvdb::GRID_FOG_VOLUME);
        if (g->normals) {
            vdb_out_grid ng = *g;
            ng.name = "normal";
            w->nrm = make_grid<openvdb::Vec3SGrid>(&ng, xf, openvdb::GRID_UNKNOWN);
            w->nrm->setVectorType(openvdb::VEC_COVARIANT_NORMALIZE);
        }
        *out = w;
        return 0;
    } catch (const std::exception &e) {
        return say(err, -ENOMEM, "openvdb", e.what());
    }
}

static int vdb_out_meta_int(vdb_out *w, const char *key, int64_t v)
{
    try {
        w->scalar()->insertMeta(key, openvdb::Int64Metadata(v));
        if (w->nrm) w->nrm->insertMeta(key, openvdb::Int64Metadata(v));
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

static int vdb_out_meta_str(vdb_out *w, const char *key, const char *v)
{
    try {
        w->scalar()->insertMeta(key, openvdb::StringMetadata(v));
        if (w->nrm) w->nrm->insertMeta(key, openvdb::StringMetadata(v));
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

static int vdb_out_block(vdb_out *w, const int32_t lo[3], const uint32_t n[3],
                             const uint8_t *v, const float *nrm)
{
    try {
        if (w->occ) block(*w->occ, lo, n, v, [v](size_t i) { return v[i] != 0; });
        else block(*w->dens, lo, n, v, [v](size_t i) { return float(v[i]) / 255.0f; });
        if (w->nrm)
            block(*w->nrm, lo, n, v, [nrm](size_t i) {
                return openvdb::Vec3s(nrm[3 * i], nrm[3 * i + 1], nrm[3 * i + 2]);
            });
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

static int vdb_out_fill(vdb_out *w, const int32_t lo[3], const uint32_t n[3], uint8_t v)
{
    if (!v || w->nrm) return -EINVAL;
    try {
        // Tree::fill makes a tile of every node the box covers whole
        if (w->occ) w->occ->tree().fill(box_of(lo, n), true, true);
        else w->dens->tree().fill(box_of(lo, n), float(v) / 255.0f, true);
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

// A distance as a level set holds it: active in the band (|d| below the
// background, with a relative margin for the last bit of the file's
// width), else inactive at the background with the distance's sign.
static void set_distance(openvdb::FloatGrid::Accessor &acc, const Coord &c, float d, float bg)
{
    if (std::fabs(d) < bg * (1.0f - 1e-6f)) acc.setValueOn(c, d);
    else if (d < 0) acc.setValueOff(c, -bg);
}

static int vdb_out_block_f(vdb_out *w, const int32_t lo[3], const uint32_t n[3], const float *d)
{
    if (w->kind != VDB_OUT_LEVEL_SET) return -EINVAL;
    try {
        auto acc = w->dens->getAccessor();
        size_t i = 0;
        for (uint32_t z = 0; z < n[2]; z++)
            for (uint32_t y = 0; y < n[1]; y++)
                for (uint32_t x = 0; x < n[0]; x++, i++)
                    set_distance(acc, Coord(lo[0] + int32_t(x), lo[1] + int32_t(y), lo[2] + int32_t(z)),
                                 d[i], w->bg);
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

static int vdb_out_fill_f(vdb_out *w, const int32_t lo[3], const uint32_t n[3], float v)
{
    if (w->kind != VDB_OUT_LEVEL_SET) return -EINVAL;
    try {
        bool band = std::fabs(v) < w->bg * (1.0f - 1e-6f);
        if (band) w->dens->tree().fill(box_of(lo, n), v, true);
        else if (v < 0) w->dens->tree().fill(box_of(lo, n), -w->bg, false);
        return 0;
    } catch (const std::exception &) {
        return -ENOMEM;
    }
}

static int vdb_out_write(vdb_out *w, const char *path, err_info *err)
{
    try {
        openvdb::GridPtrVec grids;
        if (w->occ) openvdb::tools::prune(w->occ->tree());
        else if (w->kind == VDB_OUT_LEVEL_SET) openvdb::tools::pruneLevelSet(w->dens->tree());
        else openvdb::tools::prune(w->dens->tree());
        grids.push_back(w->scalar());
        if (w->nrm) {
            openvdb::tools::prune(w->nrm->tree());
            grids.push_back(w->nrm);
        }
        openvdb::MetaMap file_meta;
        file_meta.insertMeta("creator", openvdb::StringMetadata("vox export"));
        return write_checked(path, grids, file_meta, err);
    } catch (const std::bad_alloc &) {
        return say(err, -ENOMEM, nullptr, "out of memory");
    } catch (const std::exception &e) {
        return say(err, -EIO, nullptr, e.what());
    }
}

static uint64_t vdb_out_active(const vdb_out *w)
{
    return w->scalar()->activeVoxelCount();
}

static void vdb_out_free(vdb_out *w)
{
    delete w;
}

extern "C" __attribute__((visibility("default"))) const vdb_out_api vdb_out_api_v3 = {
    vdb_out_open,    vdb_out_meta_int, vdb_out_meta_str, vdb_out_block,   vdb_out_fill,
    vdb_out_block_f, vdb_out_fill_f,   vdb_out_write,    vdb_out_active, vdb_out_free,
};

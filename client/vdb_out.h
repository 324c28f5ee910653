/* vdb_out — an OpenVDB file written from C: the shim between vox export
 * (C11) and libopenvdb (C++).  vdb_out.cc is the only C++ in the tree; it
 * catches every exception at this interface, so a C caller sees 0 or a
 * negative errno and a message, never an unwinding stack.
 *
 * One file holds one scalar grid (a BoolGrid, a FloatGrid of the voxel
 * byte / 255, or a level set: a FloatGrid of signed distances, class level
 * set, active in the narrow band) and optionally a Vec3SGrid "normal",
 * active on the same voxels.
 * Voxel (i, j, k) is the index-space point (i, j, k); the transform maps it
 * to world centre + (i, j, k) * spacing, so an index is a voxel's centre, as
 * OpenVDB has it.  The grids are sparse: a box of one value becomes tiles
 * (vdb_out_fill), never a voxel at a time.
 */
#ifndef VOXD_VDB_OUT_H
#define VOXD_VDB_OUT_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct vdb_out vdb_out;

enum vdb_out_kind {
    VDB_OUT_BOOL = 1,  /* active and true where the byte is non-zero */
    VDB_OUT_FLOAT = 2, /* byte / 255 where non-zero, inactive 0 elsewhere */
    VDB_OUT_LEVEL_SET = 3, /* distances: active where |d| < background, else
                              inactive +-background (the distance's sign) */
};

typedef struct {
    int kind;                  /* enum vdb_out_kind */
    const char *name;          /* the scalar grid's name */
    int normals;               /* 1: a Vec3SGrid "normal" beside it */
    double spacing[3];         /* a voxel's size, world units */
    double centre[3];          /* world position of index (0, 0, 0) */
    double background;         /* a level set's: the band's width, world units */
} vdb_out_grid;

/* The interface, as a table: vdb_out.cc is built as a module of its own
 * (vox-vdb.so) that vox opens with dlopen when it writes a .vdb, so that
 * libopenvdb, its C++ runtime and their static constructors (tens of
 * milliseconds) load for that command only, not for every vox run. */
typedef struct {
    /* 0, or -ENOMEM / -EINVAL with err set (common/err.h; the module
     * fills it itself, not linking libvoxd's err_set). */
    int (*open)(vdb_out **w, const vdb_out_grid *g, err_info *err);
    /* Metadata on every grid: an integer or a string (0 or -ENOMEM). */
    int (*meta_int)(vdb_out *w, const char *key, int64_t v);
    int (*meta_str)(vdb_out *w, const char *key, const char *v);
    /* Voxels lo + [0, n) from v (x fastest, then y, then z; 0 leaves a
     * voxel inactive) and, when the file has normals, nrm (3 floats per
     * voxel, read where v is non-zero).  0 or -ENOMEM. */
    int (*block)(vdb_out *w, const int32_t lo[3], const uint32_t n[3], const uint8_t *v,
                 const float *nrm);
    /* Every voxel of lo + [0, n) active with byte v (non-zero), as tiles
     * where the box covers whole nodes; not for a file with normals.
     * 0, -EINVAL or -ENOMEM. */
    int (*fill)(vdb_out *w, const int32_t lo[3], const uint32_t n[3], uint8_t v);
    /* A level set's voxels lo + [0, n) from the distances d (x fastest),
     * and every voxel of lo + [0, n) := the distance v (as tiles where the
     * box covers whole nodes).  0, -EINVAL (not a level set) or -ENOMEM. */
    int (*block_f)(vdb_out *w, const int32_t lo[3], const uint32_t n[3], const float *d);
    int (*fill_f)(vdb_out *w, const int32_t lo[3], const uint32_t n[3], float v);
    /* Prune the trees (equal leaves become tiles) and write the file at
     * path.  0, or a negative errno with err set to why alone (the caller
     * names the file: path may be a /proc/self/fd link to it). */
    int (*write)(vdb_out *w, const char *path, err_info *err);
    /* Active voxels of the scalar grid. */
    uint64_t (*active)(const vdb_out *w);
    void (*free)(vdb_out *w);
} vdb_out_api;

/* The module's one exported symbol, a const vdb_out_api; its name carries
 * a version, so a stale module is refused rather than misread. */
#define VDB_OUT_MODULE "vox-vdb.so"
#define VDB_OUT_SYMBOL "vdb_out_api_v3"

#ifdef __cplusplus
}
#endif

#endif

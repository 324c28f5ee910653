/* vox export to OpenVDB: the level's bricks handed to vdb_out one at a time
 * (export.h), through the vox-vdb.so module (vdb_out.h) opened here.  A brick
 * of one value becomes tiles (vdb_out_fill), so a solid's inside costs
 * nothing per voxel; the others go in pieces of OpenVDB's 8^3 leaves, each
 * gathered by export_gather: a whole leaf of one value is a tile too, the
 * rest are set voxel by voxel.  Memory: the sparse grid and one leaf. */
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "export.h"
#include "vdb_out.h"

/* OpenVDB's leaf nodes: 8^3 voxels at multiples of 8. */
#define LEAF 8u

typedef struct {
    const export_box *b;
    const vdb_out_api *api;
    vdb_out *w;
    uint8_t v[LEAF * LEAF * LEAF];     /* one leaf's piece: bytes, x fastest */
    float nrm[3 * LEAF * LEAF * LEAF]; /* and its normals */
} vdb_job;

/* The brick's one value when every voxel holds it (the byte a voxel
 * exports as), else -1.  Bricks with normals are never uniform here. */
static int uniform_byte(const export_box *b, const uint8_t *raw)
{
    size_t B = b->in->brick, bytes = B * B * B * b->in->voxel_bits / 8;
    size_t w = b->in->voxel_bits == 32 ? 4 : 1; /* 1 bit: every byte 0x00 or 0xff */
    if (b->normals || memcmp(raw, raw + w, bytes - w)) return -1;
    if (b->in->voxel_bits == 1) return raw[0] == 0xff ? 1 : raw[0] == 0 ? 0 : -1;
    return raw[0]; /* 8 bits: the byte; 32: the occupancy, bits 0-7 (little-endian) */
}

/* The piece [s, e) of the level, inside one leaf: a tile when it is a
 * whole leaf of one value (and there are no normals), else its voxels. */
static int one_leaf(vdb_job *j, const uint32_t s[3], const uint32_t e[3])
{
    uint32_t n[3] = {e[0] - s[0], e[1] - s[1], e[2] - s[2]};
    size_t k = (size_t)n[0] * n[1] * n[2];
    export_gather(j->b, s, e, j->v);
    int same = !memcmp(j->v, j->v + 1, k - 1);
    int32_t lo[3] = {(int32_t)s[0], (int32_t)s[1], (int32_t)s[2]};
    if (same && !j->v[0]) return 0;
    if (same && !j->b->normals && k == LEAF * LEAF * LEAF)
        return j->api->fill(j->w, lo, n, j->v[0]);
    if (j->b->normals) export_gather_normals(j->b, s, e, j->nrm, 3);
    return j->api->block(j->w, lo, n, j->v, j->b->normals ? j->nrm : NULL);
}

/* A channel-4 brick's part [s, e) of the box into the level set: one
 * value (a brick beyond the band, or inside it) as tiles, else its
 * distances voxel by voxel. */
static int distance_brick(vdb_job *j, const uint8_t *raw, const uint32_t s[3],
                          const uint32_t e[3])
{
    const export_box *b = j->b;
    size_t B = b->in->brick, bytes = B * B * B * 4;
    uint32_t n[3] = {e[0] - s[0], e[1] - s[1], e[2] - s[2]};
    int32_t lo[3] = {(int32_t)s[0], (int32_t)s[1], (int32_t)s[2]};
    if (!memcmp(raw, raw + 4, bytes - 4)) {
        float v;
        memcpy(&v, raw, 4);
        return j->api->fill_f(j->w, lo, n, v);
    }
    float *d = malloc((size_t)n[0] * n[1] * n[2] * sizeof *d);
    if (!d) return -ENOMEM;
    export_gather_normals(b, s, e, d, 1);
    int rc = j->api->block_f(j->w, lo, n, d);
    free(d);
    return rc;
}

static int one_brick(vdb_job *j, const uint32_t bk[3])
{
    const export_box *b = j->b;
    const uint8_t *raw = vod_brick(b->f, b->level, bk);
    if (!raw) return 0;
    uint32_t B = b->in->brick, s[3], e[3], n[3];
    int32_t lo[3];
    for (int a = 0; a < 3; a++) {
        s[a] = bk[a] * B > b->lo[a] ? bk[a] * B : b->lo[a];
        e[a] = bk[a] * B + B < b->hi[a] ? bk[a] * B + B : b->hi[a];
        n[a] = e[a] - s[a];
        lo[a] = (int32_t)s[a];
    }
    if (b->distance) return distance_brick(j, raw, s, e);
    int u = uniform_byte(b, raw);
    if (u == 0) return 0;
    if (u > 0) return j->api->fill(j->w, lo, n, (uint8_t)u);
    /* bricks smaller than a leaf give pieces of it, which OpenVDB merges */
    uint32_t ls[3], le[3];
    for (ls[2] = s[2]; ls[2] < e[2]; ls[2] = le[2])
        for (ls[1] = s[1]; ls[1] < e[1]; ls[1] = le[1])
            for (ls[0] = s[0]; ls[0] < e[0]; ls[0] = le[0]) {
                for (int a = 0; a < 3; a++) {
                    le[a] = (ls[a] / LEAF + 1) * LEAF;
                    if (le[a] > e[a]) le[a] = e[a];
                }
                int rc = one_leaf(j, ls, le);
                if (rc) return rc;
            }
    return 0;
}

static int walk(vdb_job *j)
{
    const export_box *b = j->b;
    uint32_t B = b->in->brick, bk[3];
    for (bk[2] = b->lo[2] / B; bk[2] * B < b->hi[2]; bk[2]++)
        for (bk[1] = b->lo[1] / B; bk[1] * B < b->hi[1]; bk[1]++)
            for (bk[0] = b->lo[0] / B; bk[0] * B < b->hi[0]; bk[0]++) {
                int rc = one_brick(j, bk);
                if (rc) return rc;
            }
    return 0;
}

static int describe(const vdb_job *j, const char *src)
{
    const vdb_out_api *api = j->api;
    int rc = api->meta_int(j->w, "vod_channel", j->b->in->channel);
    if (!rc) rc = api->meta_int(j->w, "vod_level", j->b->level);
    if (!rc) rc = api->meta_str(j->w, "vod_source", src);
    if (!rc && j->b->distance)
        rc = api->meta_str(j->w, "vod_value", "signed distance, world units, negative inside");
    else if (!rc && j->b->in->voxel_bits > 1)
        rc = api->meta_str(j->w, "vod_value",
                           "voxel byte / 255 (channel 3: its occupancy byte)");
    return rc;
}

/* The module beside the running vox (the build tree), else in ../lib/voxd
 * from it (make install).  It stays loaded until exit: libopenvdb's
 * registries and thread pool are not made to be unloaded. */
static const vdb_out_api *load_api(err_info *err)
{
    char exe[PATH_MAX], path[PATH_MAX + 32];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    if (n <= 0) n = 0;
    exe[n] = '\0';
    char *slash = strrchr(exe, '/');
    if (slash) *slash = '\0';
    static const char *const where[] = {"%s/" VDB_OUT_MODULE, "%s/../lib/voxd/" VDB_OUT_MODULE};
    char why[512] = ""; /* dlerror's string lasts until the next dl call: copied */
    for (int i = 0; i < 2; i++) {
        snprintf(path, sizeof path, where[i], exe);
        void *h = dlopen(path, RTLD_LAZY | RTLD_LOCAL);
        if (!h) {
            if (!i) snprintf(why, sizeof why, "%s", dlerror()); /* the build tree's reason */
            continue;
        }
        const vdb_out_api *api = dlsym(h, VDB_OUT_SYMBOL);
        if (api) return api;
        err_set(err, -ENOENT, "%s: no %s (a module of another version)", path, VDB_OUT_SYMBOL);
        return NULL;
    }
    err_set(err, -ENOENT, ".vdb needs the OpenVDB module %s beside vox or in its "
            "../lib/voxd: %s", VDB_OUT_MODULE, why);
    return NULL;
}

int export_vdb(const export_box *b, const char *src, const char *path, const char *name,
               err_info *err)
{
    vdb_out_grid g = {.kind = b->in->voxel_bits == 1 ? VDB_OUT_BOOL : VDB_OUT_FLOAT,
                      .name = b->in->voxel_bits == 1 ? "occupancy" : "density",
                      .normals = b->normals};
    if (b->distance) { /* a level set, background the band's width */
        g.kind = VDB_OUT_LEVEL_SET;
        g.name = "surface";
        g.background = export_band_width(b->in, NULL);
    }
    for (int a = 0; a < 3; a++) {
        g.spacing[a] = b->spacing[a];
        /* index (0,0,0) is level voxel (0,0,0), centred half a voxel in */
        g.centre[a] = (double)b->in->origin[a] + 0.5 * b->spacing[a];
    }
    static vdb_job j; /* its leaf buffers are 8 KiB: not on the stack */
    memset(&j, 0, sizeof j);
    j.b = b;
    if (!(j.api = load_api(err))) return -ENOENT;
    int rc = j.api->open(&j.w, &g, err);
    if (rc) return rc;
    rc = describe(&j, src);
    if (!rc) rc = walk(&j);
    if (rc) err_set(err, rc, "%s", strerror(-rc));
    else if ((rc = j.api->write(j.w, path, err))) { /* the module says why, we name it */
        char why[sizeof err->msg];
        snprintf(why, sizeof why, "%s", err->msg);
        err_set(err, rc, "%s: %s", name, why);
    }
    j.api->free(j.w);
    return rc;
}

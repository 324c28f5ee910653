/* csg_leaf — a mesh or VOD file leaf made an 8-bit volume on the job's
 * grid, once per job, before any brick is evaluated (csg.h says what
 * each gives).  The bricks then read it like any operand. */
#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "mesh_vox.h"
#include "par.h"
#include "voxel.h"

/* Mesh samples per voxel and axis: 4^3, so the density ramps in steps of
 * 4 across the surface and half coverage is S. */
#define CSG_MESH_SUPERSAMPLE 4u

/* The leaf's placement: fit moves the bounding box's centre to fit[] and
 * makes its longest side `scale`; else every coordinate times scale. */
static int place_mesh(const csg_node *n, mesh *m, err_info *err)
{
    double c[3], ext = 0, k = n->scale > 0 ? n->scale : 1, to[3] = {0, 0, 0};
    for (int a = 0; a < 3; a++) {
        c[a] = n->has_fit ? ((double)m->lo[a] + m->hi[a]) / 2 : 0;
        if ((double)m->hi[a] - m->lo[a] > ext) ext = (double)m->hi[a] - m->lo[a];
        if (n->has_fit) to[a] = n->fit[a];
    }
    if (n->has_fit) {
        if (!(ext > 0)) {
            return err_set(err, -EINVAL,
                           "node '%s': mesh: an empty bounding box cannot be fitted", n->name);
        }
        k /= ext;
    }
    for (uint32_t v = 0; v < m->n_vertices; v++)
        for (int a = 0; a < 3; a++)
            m->vertices[v][a] = (float)((m->vertices[v][a] - c[a]) * k + to[a]);
    for (int a = 0; a < 3; a++) {
        m->lo[a] = (float)((m->lo[a] - c[a]) * k + to[a]);
        m->hi[a] = (float)((m->hi[a] - c[a]) * k + to[a]);
    }
    return 0;
}

int csg_leaf_mesh(const csg_tree *t, uint32_t i, mesh *m, mesh_vox_opts *o, err_info *err)
{
    const csg_node *n = &t->node[i];
    mesh_error me = {0};
    err_clear(err);
    if (n->kind != CSG_MESH || !t->data[i] || !t->data_len[i]) {
        return err_set(err, -EINVAL, "node '%s': no file data for a %s leaf", n->name,
                       csg_kind_name(n->kind));
    }
    int rc = mesh_parse(t->data[i], t->data_len[i], MESH_FORMAT_AUTO, NULL, m, &me);
    if (rc) {
        char why[256];
        return err_set(err, rc, "node '%s': mesh: %s", n->name,
                       mesh_error_str(&me, why, sizeof why));
    }
    if (!m->n_triangles) {
        err_set(err, -EINVAL, "node '%s': mesh: no triangles", n->name);
        mesh_free(m);
        return -EINVAL;
    }
    if ((rc = place_mesh(n, m, err))) {
        mesh_free(m);
        return rc;
    }
    *o = (mesh_vox_opts){.mode = MESH_SOLID, .repair = MESH_REPAIR_NONE,
                         .channel = VOXEL_CH_DENSITY, .supersample = CSG_MESH_SUPERSAMPLE};
    if (csg_leaf_bits(n) == VOD_VOLUME_F32) /* channel 4: its exact distance (mesh_dist) */
        *o = (mesh_vox_opts){.mode = MESH_SOLID, .repair = MESH_REPAIR_NONE,
                             .channel = VOXEL_CH_DISTANCE, .band = n->k};
    return 0;
}

static int mesh_leaf(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                     err_info *err)
{
    mesh m;
    mesh_vox_opts o;
    int rc = csg_leaf_mesh(t, i, &m, &o, err);
    if (rc) return rc;
    mesh_tile_stats st = {0};
    rc = mesh_voxelize(&m, g, &o, vol, &st);
    if (rc && !err->msg[0])
        err_set(err, rc, "node '%s': voxelizing the mesh: %s", t->node[i].name,
                strerror(-rc));
    mesh_free(&m);
    return rc;
}

/* A file voxel's value as a density. */
static uint8_t file_density(uint32_t channel, uint32_t v)
{
    if (channel == VOXEL_CH_DENSITY) return (uint8_t)v;
    return v ? CSG_H : CSG_L; /* occupancy, surface: occupied or not */
}

/* The job voxel x's centre along axis a in the file's voxels, floor'd;
 * -1 outside the file. */
static int64_t file_index(const grid_spec *g, const vod_info *in, int a, uint32_t x)
{
    double p = grid_coord(g, a, x + 0.5);
    double f = floor((p - in->origin[a]) / in->voxel_scale[a]);
    return f >= 0 && f < in->volume[a] ? (int64_t)f : -1;
}

/* A VOD leaf resampled by several threads: the job's storage bricks in
 * rows along x that the threads claim in turn (the leaf was one thread's
 * before: a 256^3 file at 1024^3 took 9.6 s), each voxel read from the
 * file brick that holds it (the last one kept), and a job brick under no
 * non-empty file brick left empty without a voxel read.  The volume takes
 * bricks from several threads at once (vod_volume_put_brick). */
typedef struct {
    const vod_file *f;
    const vod_info *in;
    const grid_spec *g;
    vod_volume *vol;
    int64_t *ix[3];  /* each job voxel's file voxel on each axis, -1 outside */
    uint32_t nb[3];  /* the job's storage bricks on each axis */
    uint32_t shift;  /* log2 of the file's brick side */
    /* The next row of bricks to claim, and the first failure (0: none).
     * Relaxed: a claim orders nothing, and the volume's bricks and rc
     * are read after par_run joins the threads. */
    atomic_uint next;
    atomic_int rc;
} vod_resample;

/* The file voxels job brick b's voxels read on axis a: [lo, hi]; false
 * when none (the brick lies outside the file on that axis). */
static bool file_range(const vod_resample *r, const uint32_t b[3], int a, int64_t *lo,
                       int64_t *hi)
{
    const uint32_t S = CSG_VOLUME_BRICK;
    *lo = INT64_MAX, *hi = -1;
    for (uint32_t x = b[a] * S; x < (b[a] + 1) * S && x < r->g->res[a]; x++) {
        int64_t f = r->ix[a][x];
        if (f < 0) continue;
        *lo = f < *lo ? f : *lo;
        *hi = f > *hi ? f : *hi;
    }
    return *hi >= 0;
}

/* Whether job brick b reads a non-empty file brick (else all its voxels
 * are L, the file's 0). */
static bool reads_any(const vod_resample *r, const uint32_t b[3])
{
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; a++)
        if (!file_range(r, b, a, &lo[a], &hi[a])) return false;
    uint32_t fb[3];
    for (fb[2] = (uint32_t)(lo[2] >> r->shift); fb[2] <= (uint32_t)(hi[2] >> r->shift); fb[2]++)
        for (fb[1] = (uint32_t)(lo[1] >> r->shift); fb[1] <= (uint32_t)(hi[1] >> r->shift); fb[1]++)
            for (fb[0] = (uint32_t)(lo[0] >> r->shift); fb[0] <= (uint32_t)(hi[0] >> r->shift);
                 fb[0]++)
                if (vod_brick(r->f, 0, fb)) return true;
    return false;
}

/* What a thread keeps from voxel to voxel: the file brick it read last
 * (at: its brick coordinates, UINT32_MAX none yet; raw NULL: empty). */
typedef struct {
    uint32_t at[3];
    const uint8_t *raw;
} brick_seen;

/* File voxel f's density, from the file brick that holds it (seen's, or
 * the tree's, then kept in seen). */
static uint8_t file_voxel(const vod_resample *r, const int64_t f[3], brick_seen *seen)
{
    const uint32_t m = (1u << r->shift) - 1;
    uint32_t fb[3] = {(uint32_t)f[0] >> r->shift, (uint32_t)f[1] >> r->shift,
                      (uint32_t)f[2] >> r->shift};
    if (memcmp(fb, seen->at, sizeof fb)) {
        memcpy(seen->at, fb, sizeof fb);
        seen->raw = vod_brick(r->f, 0, fb);
    }
    if (!seen->raw) return 0;
    size_t i = (((size_t)f[2] & m) * (m + 1) + ((size_t)f[1] & m)) * (m + 1) + ((size_t)f[0] & m);
    uint32_t v = vod_raw_voxel(seen->raw, r->in->voxel_bits, i);
    return v ? file_density(r->in->channel, v) : 0;
}

/* The row of job brick b at (y, z) in the brick into row (S voxels): fy
 * and fz the file voxels it reads on y and z (both >= 0); 0 where it is
 * past the grid or the file.  Whether any voxel is not 0. */
static int resample_row(const vod_resample *r, const uint32_t b[3], int64_t fy, int64_t fz,
                        brick_seen *seen, uint8_t *row)
{
    const uint32_t S = CSG_VOLUME_BRICK;
    int any = 0;
    int64_t last_fx = -1; /* a finer grid reads a file voxel again: its density d */
    uint8_t d = 0;
    for (uint32_t x = 0, vx = b[0] * S; x < S; x++, vx++) {
        int64_t fx = vx < r->g->res[0] ? r->ix[0][vx] : -1;
        if (fx != last_fx) {
            last_fx = fx;
            d = fx < 0 ? 0 : file_voxel(r, (const int64_t[3]){fx, fy, fz}, seen);
        }
        row[x] = d;
        any |= d;
    }
    return any;
}

/* Job brick b into buf (its voxels, x fastest) and the volume. */
static int resample_brick(const vod_resample *r, const uint32_t b[3], uint8_t *buf)
{
    const uint32_t S = CSG_VOLUME_BRICK;
    if (!reads_any(r, b)) return 0;
    brick_seen seen = {{UINT32_MAX, UINT32_MAX, UINT32_MAX}, NULL};
    int any = 0;
    int64_t last[2] = {-1, -1}; /* the file row (fy, fz) the last row read */
    const uint8_t *last_row = NULL;
    for (uint32_t z = 0, vz = b[2] * S; z < S; z++, vz++) {
        int64_t fz = vz < r->g->res[2] ? r->ix[2][vz] : -1;
        for (uint32_t y = 0, vy = b[1] * S; y < S; y++, vy++) {
            int64_t fy = vy < r->g->res[1] ? r->ix[1][vy] : -1;
            uint8_t *row = buf + ((size_t)z * S + y) * S;
            if (fz < 0 || fy < 0) {
                memset(row, 0, S);
            } else if (last_row && fy == last[0] && fz == last[1]) {
                memcpy(row, last_row, S); /* a finer grid reads a file row again */
            } else {
                any |= resample_row(r, b, fy, fz, &seen, row);
                last[0] = fy, last[1] = fz, last_row = row;
            }
        }
    }
    return any ? vod_volume_put_brick(r->vol, b, buf) : 0;
}

/* A thread's share: rows of bricks until none is left or one failed. */
static void resample_part(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n; /* the threads share one counter of rows */
    vod_resample *r = ud;
    uint8_t *buf = malloc((size_t)CSG_VOLUME_BRICK * CSG_VOLUME_BRICK * CSG_VOLUME_BRICK);
    int rc = buf ? 0 : -ENOMEM;
    for (unsigned row; !rc && !atomic_load_explicit(&r->rc, memory_order_relaxed) &&
                       (row = atomic_fetch_add_explicit(&r->next, 1, memory_order_relaxed)) <
                           r->nb[1] * r->nb[2];)
        for (uint32_t b[3] = {0, row % r->nb[1], row / r->nb[1]}; !rc && b[0] < r->nb[0]; b[0]++)
            rc = resample_brick(r, b, buf);
    if (rc) {
        int none = 0;
        atomic_compare_exchange_strong_explicit(&r->rc, &none, rc, memory_order_relaxed,
                                                memory_order_relaxed);
    }
    free(buf);
}

/* The file's checks a leaf needs beyond vod_read's: a channel that is a
 * density, voxels of a size. */
static int check_vod_leaf(const csg_node *n, const vod_info *in, err_info *err)
{
    if (in->channel != VOXEL_CH_OCCUPANCY && in->channel != VOXEL_CH_DENSITY &&
        in->channel != VOXEL_CH_SURFACE)
        return err_set(err, -EINVAL, "node '%s': vod: channel %u cannot be a density "
                       "(occupancy, density or surface)", n->name, in->channel);
    for (int a = 0; a < 3; a++)
        if (!(in->voxel_scale[a] > 0))
            return err_set(err, -EINVAL, "node '%s': vod: voxel size %g along axis %d",
                           n->name, in->voxel_scale[a], a);
    return 0;
}

static int vod_leaf(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                    unsigned threads, err_info *err)
{
    const csg_node *n = &t->node[i];
    vod_file *f;
    err_info why;
    /* level 0 alone, its bricks inflated by the leaf's threads */
    int rc = vod_read_levels(t->data[i], t->data_len[i], (int)threads, 1, &f, &why);
    if (rc) return err_set(err, rc, "node '%s': vod: %s", n->name, why.msg);
    const vod_info *in = vod_get_info(f);
    if ((rc = check_vod_leaf(n, in, err))) {
        vod_close(f);
        return rc;
    }
    assert((in->brick & (in->brick - 1)) == 0); /* the reader's tree needs it */
    const uint32_t S = CSG_VOLUME_BRICK;
    vod_resample r = {.f = f, .in = in, .g = g, .vol = vol,
                      .shift = (uint32_t)__builtin_ctz(in->brick)};
    atomic_init(&r.next, 0);
    atomic_init(&r.rc, 0);
    for (int a = 0; a < 3; a++) {
        r.nb[a] = (g->res[a] + S - 1) / S;
        r.ix[a] = malloc(g->res[a] * sizeof(int64_t));
        rc = rc ? rc : r.ix[a] ? 0 : -ENOMEM;
        for (uint32_t x = 0; !rc && x < g->res[a]; x++) r.ix[a][x] = file_index(g, in, a, x);
    }
    unsigned rows = r.nb[1] * r.nb[2];
    if (!rc) par_run(threads < rows ? threads : rows, resample_part, &r);
    if (!rc) rc = atomic_load_explicit(&r.rc, memory_order_relaxed);
    if (rc) err_set(err, rc, "node '%s': resampling the VOD: %s", n->name, strerror(-rc));
    for (int a = 0; a < 3; a++) free(r.ix[a]);
    vod_close(f);
    return rc;
}

int csg_leaf_build(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                   unsigned threads, err_info *err)
{
    err_clear(err);
    const csg_node *n = &t->node[i];
    if ((n->kind != CSG_MESH && n->kind != CSG_VOD) || !t->data[i] || !t->data_len[i]) {
        return err_set(err, -EINVAL, "node '%s': no file data for a %s leaf", n->name,
                       csg_kind_name(n->kind));
    }
    return n->kind == CSG_MESH ? mesh_leaf(t, i, g, vol, err)
                               : vod_leaf(t, i, g, vol, threads < 1 ? 1 : threads, err);
}

int csg_has_file_leaves(const csg_tree *t)
{
    for (uint32_t i = 0; i < t->n; i++)
        if (t->node[i].kind == CSG_MESH || t->node[i].kind == CSG_VOD) return 1;
    return 0;
}

int csg_leaves_build(const csg_tree *t, const grid_spec *g, csg_arena *a,
                     vod_volume *leaves[CSG_MAX_NODES], err_info *err)
{
    size_t off = 0;
    err_clear(err);
    memset(leaves, 0, CSG_MAX_NODES * sizeof *leaves);
    for (uint32_t i = 0; i < t->n; i++) {
        const csg_node *n = &t->node[i];
        if (n->kind != CSG_MESH && n->kind != CSG_VOD) continue;
        int rc = off < a->bytes ? vod_volume_init(&leaves[i], (uint8_t *)a->base + off,
                                                  a->bytes - off, g->res, csg_leaf_bits(n),
                                                  CSG_VOLUME_BRICK)
                                : -ENOSPC;
        if (!rc) rc = csg_leaf_build(t, i, g, leaves[i], 1, err);
        if (rc) {
            if (!err->msg[0])
                err_set(err, rc, "node '%s': its volume does not fit (%s)", n->name,
                        strerror(-rc));
            return rc;
        }
        /* read only from now on: the next leaf's arena starts past its pool's use */
        vod_volume_info in;
        vod_volume_get_info(leaves[i], &in);
        off += (in.bytes_used + 63) / 64 * 64;
    }
    a->used = off;
    return 0;
}

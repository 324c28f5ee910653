/* csg_leaf — a mesh or VOD file leaf made an 8-bit volume on the job's
 * grid, once per job, before any brick is evaluated (csg.h says what
 * each gives).  The bricks then read it like any operand. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "mesh_vox.h"
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

static int vod_leaf(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                    err_info *err)
{
    const csg_node *n = &t->node[i];
    vod_file *f;
    err_info why;
    int rc = vod_read(t->data[i], t->data_len[i], &f, &why);
    if (rc) {
        return err_set(err, rc, "node '%s': vod: %s", n->name, why.msg);
    }
    const vod_info *in = vod_get_info(f);
    if (in->channel != VOXEL_CH_OCCUPANCY && in->channel != VOXEL_CH_DENSITY &&
        in->channel != VOXEL_CH_SURFACE) {
        err_set(err, -EINVAL, "node '%s': vod: channel %u cannot be a density (occupancy, "
                "density or surface)", n->name, in->channel);
        vod_close(f);
        return -EINVAL;
    }
    for (int a = 0; a < 3; a++)
        if (!(in->voxel_scale[a] > 0)) {
            err_set(err, -EINVAL, "node '%s': vod: voxel size %g along axis %d", n->name,
                    in->voxel_scale[a], a);
            vod_close(f);
            return -EINVAL;
        }
    const uint32_t S = CSG_VOLUME_BRICK;
    uint8_t *buf = malloc((size_t)S * S * S);
    int64_t *ix[3] = {malloc(g->res[0] * sizeof(int64_t)), malloc(g->res[1] * sizeof(int64_t)),
                      malloc(g->res[2] * sizeof(int64_t))};
    rc = buf && ix[0] && ix[1] && ix[2] ? 0 : -ENOMEM;
    for (int a = 0; a < 3 && !rc; a++)
        for (uint32_t x = 0; x < g->res[a]; x++) ix[a][x] = file_index(g, in, a, x);
    uint32_t b[3];
    for (b[2] = 0; b[2] * S < g->res[2] && !rc; b[2]++)
        for (b[1] = 0; b[1] * S < g->res[1] && !rc; b[1]++)
            for (b[0] = 0; b[0] * S < g->res[0] && !rc; b[0]++) {
                int any = 0;
                for (uint32_t k = 0; k < S * S * S; k++) {
                    uint32_t x = b[0] * S + k % S, y = b[1] * S + k / S % S,
                             z = b[2] * S + k / (S * S);
                    int in_grid = x < g->res[0] && y < g->res[1] && z < g->res[2];
                    int64_t fx = in_grid ? ix[0][x] : -1, fy = in_grid ? ix[1][y] : -1,
                            fz = in_grid ? ix[2][z] : -1;
                    buf[k] = fx < 0 || fy < 0 || fz < 0
                                 ? 0
                                 : file_density(in->channel,
                                                vod_voxel(f, 0, (uint32_t)fx, (uint32_t)fy,
                                                          (uint32_t)fz));
                    any |= buf[k];
                }
                if (any) rc = vod_volume_put_brick(vol, b, buf);
            }
    if (rc) err_set(err, rc, "node '%s': resampling the VOD: %s", n->name, strerror(-rc));
    free(buf);
    for (int a = 0; a < 3; a++) free(ix[a]);
    vod_close(f);
    return rc;
}

int csg_leaf_build(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                   err_info *err)
{
    err_clear(err);
    const csg_node *n = &t->node[i];
    if ((n->kind != CSG_MESH && n->kind != CSG_VOD) || !t->data[i] || !t->data_len[i]) {
        return err_set(err, -EINVAL, "node '%s': no file data for a %s leaf", n->name,
                       csg_kind_name(n->kind));
    }
    return n->kind == CSG_MESH ? mesh_leaf(t, i, g, vol, err) : vod_leaf(t, i, g, vol, err);
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
        if (!rc) rc = csg_leaf_build(t, i, g, leaves[i], err);
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

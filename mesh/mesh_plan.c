/* mesh_plan — a mesh job's options, and what a tile needs for them: the
 * plan and the layout of the scratch (mesh_vox.h, mesh_vox_int.h). */
#include "mesh_vox_int.h"

#include <errno.h>
#include <stdio.h>
#include <string.h>

#include "voxel.h"

uint32_t mesh_vox_bits(const mesh_vox_opts *o)
{
    return o->channel == VOXEL_CH_SURFACE ? 32 : o->channel == VOXEL_CH_DISTANCE ? VOD_VOLUME_F32 : 8;
}

uint32_t mesh_vox_band(const mesh_vox_opts *o)
{
    return o->band ? o->band : VOXEL_BAND_DEFAULT;
}

int mesh_vox_check(const mesh_vox_opts *o, err_info *err)
{
    const char *why = NULL;
    if ((unsigned)o->mode > MESH_INTERIOR) why = "unknown mesh mode";
    else if ((unsigned)o->repair > MESH_REPAIR_WINDING) why = "unknown repair";
    else if (o->channel != VOXEL_CH_OCCUPANCY && o->channel != VOXEL_CH_DENSITY &&
             o->channel != VOXEL_CH_SURFACE && o->channel != VOXEL_CH_DISTANCE)
        why = "a mesh job gives channel 1 (occupancy), 2 (density), 3 (surface) or 4 (distance)";
    else if (o->supersample != 0 && (o->supersample < 2 || o->supersample > 8))
        why = "supersample must be 2..8";
    else if (o->channel == VOXEL_CH_DENSITY && o->mode != MESH_SOLID)
        why = "the density channel is the solid's coverage: mode solid only";
    else if (o->channel == VOXEL_CH_DISTANCE && o->mode != MESH_SOLID)
        why = "the distance channel's sign is the solid's: mode solid only";
    else if (o->band > VOXEL_BAND_MAX || (o->band && o->channel != VOXEL_CH_DISTANCE))
        why = "the band is 1..32 voxels, for the distance channel";
    if (why) return err_set(err, -EINVAL, "%s", why);
    return 0;
}

bool mesh_vox_lends_tree(const mesh_vox_opts *o)
{
    return o->repair == MESH_REPAIR_WINDING && !mesh_wind_exact;
}

bool mesh_vox_every_tile(const grid_spec *g, const mesh_vox_opts *o)
{
    mesh_vox_plan p;
    mesh_vox_plan_make(g, o, &p);
    return p.every_tile;
}

uint32_t mesh_vox_sbrick(const mesh_vox_opts *o)
{
    return o->channel == VOXEL_CH_DISTANCE ? MESH_DIST_BRICK : MESH_VOLUME_BRICK;
}

/* ---- what a tile needs, and where it lies in the scratch ---- */

#define DENS_BUDGET (4u << 20) /* bytes of one fine block's bits */
#define MAX_S VOD_VOLUME_MAX_BRICK

void mesh_vox_plan_make(const grid_spec *g, const mesh_vox_opts *o, mesh_vox_plan *p)
{
    memset(p, 0, sizeof *p);
    bool dens_ch = o->channel == VOXEL_CH_DENSITY;
    p->solid1 = !dens_ch && (o->mode == MESH_SOLID || o->mode == MESH_CONSERVATIVE ||
                             o->mode == MESH_INTERIOR);
    p->surf = !dens_ch && o->mode != MESH_SOLID;
    p->dens = dens_ch || o->channel == VOXEL_CH_SURFACE;
    p->rep = o->repair != MESH_REPAIR_NONE && (p->solid1 || p->dens);
    p->count = p->solid1 && o->repair == MESH_REPAIR_WINDING;
    /* the caps give every K = 1 block its parities along x and y; the
     * coverage's fine blocks and the exact sum (a test's) rasterize rows */
    p->capped = p->solid1 && !p->dens && mesh_vox_lends_tree(o);
    p->apron = o->channel == VOXEL_CH_SURFACE ? 1 : 0;
    p->K = o->supersample ? o->supersample : 2;
    p->nz = g->res[2];
    p->dist = o->channel == VOXEL_CH_DISTANCE;
    p->band = p->dist ? mesh_vox_band(o) : 0;
    p->every_tile = p->capped || p->dist;
    if (!p->dens) return;
    uint32_t dn = MESH_TILE + 2 * p->apron, rows = dn * p->K;
    p->fnw = (rows + 63) / 64;
    p->zs = MAX_S;
    while (p->zs > 1 && (size_t)rows * p->fnw * p->zs * p->K * 8 > DENS_BUDGET)
        p->zs /= 2;
    p->ring = MAX_S + 2 * p->apron + p->zs;
}

#define ALIGN64(n) (((n) + 63) & ~(size_t)63)

/* The buffers of plan p in base (NULL: only the size).  The bytes used. */
size_t mesh_vox_layout(const mesh_vox_plan *p, uint32_t bits, void *base, mesh_vox_bufs *b)
{
    size_t off = 0;
    memset(b, 0, sizeof *b);
#define TAKE(ptr, bytes)                                                  \
    do {                                                                  \
        (ptr) = base ? (void *)((uint8_t *)base + off) : NULL;            \
        off += ALIGN64((size_t)(bytes));                                  \
    } while (0)
    size_t col = (size_t)MESH_TILE * p->nz * 8, nz8 = (size_t)p->nz * 8;
    if (p->solid1) TAKE(b->a, col);
    if (p->solid1 && p->rep) {
        TAKE(b->bx, col);
        TAKE(b->by, col);
        TAKE(b->cx, nz8);
        TAKE(b->cy, nz8);
    }
    if (p->surf) TAKE(b->surf, col);
    if (p->rep) TAKE(b->dis, col);
    if (p->count) TAKE(b->count, col * 8 * sizeof(uint16_t)); /* one a voxel */
    TAKE(b->brick, (size_t)MAX_S * MAX_S * MAX_S * (bits == VOD_VOLUME_F32 ? 4 : bits / 8));
    if (p->dist) TAKE(b->d2, (size_t)MAX_S * MAX_S * MAX_S * sizeof(double));
    if (p->dens) {
        size_t dn = MESH_TILE + 2 * p->apron, rows = dn * p->K;
        size_t slab = (size_t)p->zs * p->K, words = rows * p->fnw * slab;
        TAKE(b->fa, words * 8);
        TAKE(b->fzc, rows * p->fnw * 8);
        if (p->rep) {
            TAKE(b->fbx, words * 8);
            TAKE(b->fby, words * 8);
            TAKE(b->fcx, (slab * rows + 63) / 64 * 8);
            TAKE(b->fcy, slab * p->fnw * 8);
            TAKE(b->fdis, words * 8);
        }
        TAKE(b->ring, dn * dn * p->ring * sizeof(uint16_t));
    }
#undef TAKE
    return off;
}

size_t mesh_tile_scratch_bytes(const grid_spec *g, const mesh_vox_opts *o)
{
    mesh_vox_plan p;
    mesh_vox_bufs b;
    mesh_vox_plan_make(g, o, &p);
    return mesh_vox_layout(&p, mesh_vox_bits(o), NULL, &b);
}


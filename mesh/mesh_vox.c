/* mesh_vox — one tile of a mesh job: the occupancy of the mode and the
 * tile's storage bricks, and every tile serially (mesh_vox.h).  The options
 * and the scratch are mesh_plan.c; the kernels mesh_raster.c (crossings),
 * mesh_solid.c (parities and their repair), mesh_surface.c (triangle/box
 * overlap), mesh_density.c (supersampled coverage, normals) and
 * mesh_dist.c (the signed distance). */
#include "mesh_vox_int.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "voxel.h"

/* ---- bricks ---- */

/* The 8 bytes of 8 occupancy bits, a table made by the compiler: bit i
 * spread to byte i, times 255 (VOXEL_FULL for inside). */
#define LUT_B(i, k) ((uint64_t)((i) >> (k) & 1) * VOXEL_FULL << 8 * (k))
#define LUT_1(i) \
    (LUT_B(i, 0) | LUT_B(i, 1) | LUT_B(i, 2) | LUT_B(i, 3) | LUT_B(i, 4) | LUT_B(i, 5) | \
     LUT_B(i, 6) | LUT_B(i, 7))
#define LUT_4(i) LUT_1(i), LUT_1(i + 1), LUT_1(i + 2), LUT_1(i + 3)
#define LUT_16(i) LUT_4(i), LUT_4(i + 4), LUT_4(i + 8), LUT_4(i + 12)
#define LUT_64(i) LUT_16(i), LUT_16(i + 16), LUT_16(i + 32), LUT_16(i + 48)
static const uint64_t byte_lut[256] = {LUT_64(0), LUT_64(64), LUT_64(128), LUT_64(192)};

static uint64_t field(uint64_t w, uint32_t off, uint32_t S)
{
    return S == 64 ? w : w >> off & ((1ull << S) - 1);
}

/* The kind of every brick of row (by, bz) of the tile's bits (one word a
 * row): 0 none set, 2 every voxel set and inside the grid, 1 otherwise.
 * One pass over the row's words gathers which bits are set in any and in
 * all of them; each brick reads its field of both. */
static void brick_kinds(const mesh_vox_tile *t, const uint64_t *bits, uint32_t by,
                        uint32_t bz, uint8_t *kind)
{
    uint32_t S = t->S;
    uint64_t any = 0, all = ~0ull;
    for (uint32_t z = bz * S; z < (bz + 1) * S && z < t->nz; z++)
        for (uint32_t y = by * S; y < (by + 1) * S && y < t->ny; y++) {
            uint64_t w = bits[(size_t)z * t->ny + y];
            any |= w;
            all &= w;
        }
    bool rows = (by + 1) * S <= t->ny && (bz + 1) * S <= t->nz;
    uint64_t full = S == 64 ? ~0ull : (1ull << S) - 1;
    for (uint32_t bx = 0; bx * S < t->nx; bx++)
        kind[bx] = !field(any, bx * S, S) ? 0
                   : rows && (bx + 1) * S <= t->nx && field(all, bx * S, S) == full ? 2
                                                                                    : 1;
}

static int put(mesh_vox_tile *t, uint32_t bx, uint32_t by, uint32_t bz, const void *vox)
{
    uint32_t b[3] = {t->x0 / t->S + bx, t->y0 / t->S + by, bz};
    return vod_volume_put_brick(t->vol, b, vox);
}

static int put_uniform(mesh_vox_tile *t, uint32_t bx, uint32_t by, uint32_t bz, uint32_t value)
{
    uint32_t b[3] = {t->x0 / t->S + bx, t->y0 / t->S + by, bz};
    return vod_volume_put_uniform(t->vol, b, value);
}

/* Occupancy bricks: 0 or VOXEL_FULL from the tile's bits; the voxels set
 * go to the stats. */
static int emit_occupancy(mesh_vox_tile *t, const uint64_t *bits, uint8_t *brick)
{
    uint32_t S = t->S, nbz = (t->nz + S - 1) / S;
    uint8_t kind[MESH_TILE];
    for (uint32_t bz = 0; bz < nbz; bz++)
        for (uint32_t by = 0; by * S < t->ny; by++) {
            brick_kinds(t, bits, by, bz, kind);
            for (uint32_t bx = 0; bx * S < t->nx; bx++) {
                int rc;
                if (kind[bx] == 0) continue; /* the volume starts empty */
                if (kind[bx] == 2) {
                    t->st->voxels += (uint64_t)S * S * S;
                    rc = put_uniform(t, bx, by, bz, VOXEL_FULL);
                    if (rc) return rc;
                    continue;
                }
                /* rows and columns past the grid stay 0 */
                if ((bx + 1) * S > t->nx || (by + 1) * S > t->ny || (bz + 1) * S > t->nz)
                    memset(brick, 0, (size_t)S * S * S);
                uint32_t nx = t->nx - bx * S < S ? t->nx - bx * S : S;
                uint64_t in = nx == 64 ? ~0ull : (1ull << nx) - 1;
                for (uint32_t z = 0; z < S && bz * S + z < t->nz; z++)
                    for (uint32_t y = 0; y < S && by * S + y < t->ny; y++) {
                        uint64_t f = field(bits[(size_t)(bz * S + z) * t->ny + by * S + y],
                                           bx * S, S) & in;
                        uint8_t *row = brick + ((size_t)z * S + y) * S;
                        t->st->voxels += bits_popcount64(f);
                        for (uint32_t i = 0; i < S; i += 8) {
                            uint64_t v = byte_lut[f >> i & 0xff];
                            if (S - i >= 8) memcpy(row + i, &v, 8); /* one store */
                            else memcpy(row + i, &v, S - i);
                        }
                    }
                rc = put(t, bx, by, bz, brick);
                if (rc) return rc;
            }
        }
    return 0;
}

/* Storage bricks holding a disagreement. */
static uint64_t count_disagree_bricks(const mesh_vox_tile *t, const uint64_t *dis)
{
    uint32_t S = t->S, nbz = (t->nz + S - 1) / S;
    uint64_t n = 0;
    uint8_t kind[MESH_TILE];
    for (uint32_t bz = 0; bz < nbz; bz++)
        for (uint32_t by = 0; by * S < t->ny; by++) {
            brick_kinds(t, dis, by, bz, kind);
            for (uint32_t bx = 0; bx * S < t->nx; bx++) n += kind[bx] != 0;
        }
    return n;
}

static uint64_t popcount_words(const uint64_t *w, size_t n)
{
    uint64_t c = 0;
    for (size_t i = 0; i < n; i++) c += (uint64_t)bits_popcount64(w[i]);
    return c;
}

/* ---- the tile ---- */

/* The voxel bits of the mode (K = 1): parity solid and/or surface. */
static void occupancy_bits(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b)
{
    mesh_vox_frame f;
    mesh_vox_frame_init(&f, t->m, t->g, 1);
    f.lat = t->lat;
    f.pulse = &t->pulse;
    f.wt = t->pulse.env ? t->pulse.env->wtree : NULL;
    f.caps = t->caps;
    mesh_vox_block blk = {{t->x0, t->y0, 0}, {(int32_t)t->nx, (int32_t)t->ny, (int32_t)t->nz}, 1};
    if (p->solid1) {
        mesh_vox_solid_in in = {&f, t->ids, t->n, t->o->repair, true, NAN, NAN, p->capped};
        mesh_vox_solid_buf sb = {b->a, b->bx, b->by, b->cx, b->cy, NULL, b->dis, b->count};
        t->st->disagreements += mesh_vox_solid(&in, &blk, &sb);
    }
    if (p->surf) {
        bool six = t->o->mode == MESH_SURFACE6;
        memset(b->surf, 0, mesh_vox_block_words(&blk) * 8);
        for (size_t i = 0; i < t->n; i++) {
            int64_t P[3][3];
            if (mesh_vox_beat(f.pulse, 32)) return; /* the tile is abandoned */
            if (i + MESH_VOX_AHEAD < t->n) mesh_vox_prefetch(&f, t->ids[i + MESH_VOX_AHEAD]);
            mesh_vox_triangle(&f, t->ids[i], P);
            mesh_vox_surface(P, six, &blk, b->surf);
        }
    }
    size_t nwords = mesh_vox_block_words(&blk);
    switch (t->o->mode) {
    case MESH_SOLID: t->occ = b->a; break;
    case MESH_SURFACE:
    case MESH_SURFACE6: t->occ = b->surf; break;
    case MESH_CONSERVATIVE:
        for (size_t i = 0; i < nwords; i++) b->a[i] |= b->surf[i];
        t->occ = b->a;
        break;
    case MESH_INTERIOR:
        for (size_t i = 0; i < nwords; i++) b->a[i] &= ~b->surf[i];
        t->occ = b->a;
        break;
    }
}

static int check_volume(const vod_volume *vol, const grid_spec *g,
                        const mesh_vox_opts *o, uint32_t tx, uint32_t ty)
{
    vod_volume_info vi;
    vod_volume_get_info(vol, &vi);
    for (int a = 0; a < 3; a++)
        if (vi.dims[a] != g->res[a]) return -EINVAL;
    if (vi.bits != mesh_vox_bits(o) || MESH_TILE % vi.sbrick) return -EINVAL;
    if (tx >= (g->res[0] + MESH_TILE - 1) / MESH_TILE ||
        ty >= (g->res[1] + MESH_TILE - 1) / MESH_TILE)
        return -EINVAL;
    return 0;
}

int mesh_tile_run(const mesh_tiles *j, const uint32_t *ids, size_t n, uint32_t tx,
                  uint32_t ty, mesh_tile_stats *st)
{
    const grid_spec *g = j->g;
    const mesh_vox_opts *o = j->o;
    int rc = check_volume(j->vol, g, o, tx, ty);
    if (rc) return rc;
    mesh_vox_plan p;
    mesh_vox_bufs b;
    mesh_vox_plan_make(g, o, &p);
    mesh_vox_layout(&p, mesh_vox_bits(o), j->scratch, &b);
    vod_volume_info vi;
    vod_volume_get_info(j->vol, &vi);
    mesh_vox_tile t = {.m = j->m, .lat = j->lattice, .g = g, .o = o, .ids = ids, .n = n,
                 .vol = j->vol, .S = vi.sbrick, .x0 = tx * MESH_TILE, .y0 = ty * MESH_TILE,
                 .nz = g->res[2], .st = st, .dis = b.dis, .pulse = {.env = j->env}};
    t.nx = g->res[0] - t.x0 < MESH_TILE ? g->res[0] - t.x0 : MESH_TILE;
    t.ny = g->res[1] - t.y0 < MESH_TILE ? g->res[1] - t.y0 : MESH_TILE;
    if (b.dis) memset(b.dis, 0, (size_t)t.ny * t.nz * 8);
    /* a capped plan's bins have no rows: the caps give the parities along
     * x and y, the lent tree's or, lent none (the exact sum), the tile's */
    mesh_wtree *own = NULL;
    t.caps = j->env ? j->env->wtree : NULL;
    if (p.capped && !t.caps && (rc = mesh_wtree_build(j->m, g, &own))) return rc;
    if (own) t.caps = own;
    if (o->channel == VOXEL_CH_DENSITY) {
        rc = mesh_vox_density_run(&t, &p, &b);
    } else {
        occupancy_bits(&t, &p, &b);
        if (t.pulse.stop) {
            rc = t.pulse.err ? t.pulse.err : -ECANCELED;
        } else if (o->channel == VOXEL_CH_OCCUPANCY) {
            rc = emit_occupancy(&t, t.occ, b.brick);
        } else if (o->channel == VOXEL_CH_DISTANCE) {
            rc = mesh_vox_dist_run(&t, &p, &b);
        } else {
            rc = mesh_vox_density_run(&t, &p, &b);
            st->voxels += popcount_words(t.occ, (size_t)t.ny * t.nz);
        }
    }
    if (b.dis) st->disagree_bricks += count_disagree_bricks(&t, b.dis);
    mesh_wtree_free(own);
    return rc;
}

/* Every tile of box (tx0, ty0, tx1, ty1) in turn. */
static int run_tiles(const mesh_tiles *j, const mesh_bins *bins, const uint32_t box[4],
                     mesh_tile_stats *st)
{
    int rc = 0;
    uint32_t x1 = box[2] < bins->tiles[0] ? box[2] : bins->tiles[0];
    uint32_t y1 = box[3] < bins->tiles[1] ? box[3] : bins->tiles[1];
    for (uint32_t ty = box[1]; ty < y1 && !rc; ty++)
        for (uint32_t tx = box[0]; tx < x1 && !rc; tx++) {
            uint64_t i = (uint64_t)ty * bins->tiles[0] + tx;
            rc = mesh_tile_run(j, bins->ids + bins->start[i],
                               (size_t)(bins->start[i + 1] - bins->start[i]), tx, ty, st);
        }
    return rc;
}

int mesh_voxelize_tiles(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                        const uint32_t *tiles, vod_volume *vol, mesh_tile_stats *st)
{
    mesh_bins bins;
    mesh_tile_env env = {0};
    mesh_lattice *lat = malloc(((size_t)m->n_vertices + 1) * sizeof *lat);
    void *scratch = malloc(mesh_tile_scratch_bytes(g, o));
    int rc = lat && scratch ? 0 : -ENOMEM;
    if (!rc && mesh_vox_lends_tree(o)) rc = mesh_wtree_build(m, g, (mesh_wtree **)&env.wtree);
    if (!rc) rc = mesh_bin(m, g, o, lat, 1, &bins);
    if (!rc) {
        uint32_t all[4] = {0, 0, bins.tiles[0], bins.tiles[1]};
        mesh_tiles j = {.m = m, .lattice = lat, .g = g, .o = o, .vol = vol, .env = &env,
                        .scratch = scratch};
        rc = run_tiles(&j, &bins, tiles ? tiles : all, st);
        mesh_bins_free(&bins);
    }
    mesh_wtree_free((mesh_wtree *)env.wtree);
    free(scratch);
    free(lat);
    return rc;
}

int mesh_voxelize(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                  vod_volume *vol, mesh_tile_stats *st)
{
    return mesh_voxelize_tiles(m, g, o, NULL, vol, st);
}

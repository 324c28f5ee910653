/* mesh_density — the coverage of each voxel by the solid, from K x K x K
 * samples (Eisemann and Décoret's density from a finer solid, section 6),
 * for the density channel and for the surface channel's normals.
 *
 * The tile's column of samples is computed in fine blocks of a few voxel
 * slices, bottom to top, each starting from the parities the one below
 * left (the z carry); the counts of samples inside each voxel go to a ring
 * of voxel slices from which the bricks are written.  For normals the
 * counts cover a one-voxel apron around the tile, computed from the mesh
 * like the tile itself, so a normal is the same whatever the tiling.
 *
 * Density value of c samples inside out of K^3:
 *     d = floor((510 c + K^3 - 1) / (2 K^3)),
 * 255 c / K^3 rounded to the nearest integer, halves down: half coverage
 * gives 127, the ICVG surface threshold S, and d > S exactly when more
 * than half of the voxel's samples are inside. */
#include "mesh_vox_int.h"

#include <errno.h>
#include <math.h>
#include <string.h>

#include "voxel.h"

typedef struct {
    mesh_vox_tile *t;
    const mesh_vox_plan *p;
    const mesh_vox_bufs *b;
    mesh_vox_frame f;
    int64_t vx0, vy0;     /* the region's first voxel (the tile less the apron) */
    uint32_t dnx, dny;    /* its voxels per row and rows */
    int64_t next_z, z_end; /* the next voxel slice to compute, and the end */
    uint8_t dval[513];    /* density of c samples inside */
} dens;

static uint16_t *slice_of(const dens *d, int64_t z)
{
    size_t slot = (size_t)((z + d->p->apron) % d->p->ring);
    return d->b->ring + slot * d->dnx * d->dny;
}

/* The state of a fine row's first n bits: 0 clear, 2 set, 1 mixed. */
static int row_state(const uint64_t *w, uint32_t nw, uint32_t nbits)
{
    uint64_t any = 0, all = ~0ull;
    for (uint32_t i = 0; i + 1 < nw; i++) any |= w[i], all &= w[i];
    unsigned tail = nbits & 63;
    uint64_t last = tail ? (1ull << tail) - 1 : ~0ull, l = w[nw - 1] & last;
    any |= l;
    all &= l | ~last;
    return !any ? 0 : all == ~0ull ? 2 : 1;
}

static inline uint32_t field_count(const uint64_t *w, uint32_t off, uint32_t K)
{
    uint32_t i = off / 64, sh = off & 63;
    uint64_t v = w[i] >> sh;
    if (sh + K > 64) v |= w[i + 1] << (64 - sh);
    return (uint32_t)bits_popcount64(v & ((1ull << K) - 1));
}

/* Counts of voxel row (yy, zz) of fine block fb (region-relative). */
static void count_row(const dens *d, const mesh_vox_block *fb, uint32_t zz,
                      uint32_t yy, uint16_t *out)
{
    uint32_t K = d->p->K, nbits = (uint32_t)fb->n[0], rows = (uint32_t)fb->n[1];
    const uint64_t *r[64];
    int state = -1;
    for (uint32_t fz = 0; fz < K; fz++)
        for (uint32_t fy = 0; fy < K; fy++) {
            const uint64_t *w = d->b->fa + ((size_t)(zz * K + fz) * rows + yy * K + fy) * fb->nw;
            int s = row_state(w, fb->nw, nbits);
            state = state < 0 ? s : state == s ? s : 1;
            r[fz * K + fy] = w;
        }
    if (state != 1) { /* all out, or all in */
        uint16_t v = state == 2 ? (uint16_t)(K * K * K) : 0;
        for (uint32_t x = 0; x < d->dnx; x++) out[x] = v;
        return;
    }
    for (uint32_t x = 0; x < d->dnx; x++) {
        uint32_t c = 0;
        for (uint32_t i = 0; i < K * K; i++) c += field_count(r[i], x * K, K);
        out[x] = (uint16_t)c;
    }
}

/* Voxels of the tile holding a sample whose parities differ. */
static void fold_disagreements(const dens *d, const mesh_vox_block *fb, int64_t z0,
                               uint32_t nzs)
{
    uint32_t K = d->p->K, rows = (uint32_t)fb->n[1], a = d->p->apron;
    mesh_vox_tile *t = d->t;
    for (uint32_t zz = 0; zz < nzs; zz++) {
        int64_t z = z0 + zz;
        if (z < 0 || z >= (int64_t)t->nz) continue;
        for (uint32_t y = 0; y < t->ny; y++)
            for (uint32_t fz = 0; fz < K; fz++)
                for (uint32_t fy = 0; fy < K; fy++) {
                    const uint64_t *w = d->b->fdis +
                        ((size_t)(zz * K + fz) * rows + (y + a) * K + fy) * fb->nw;
                    for (uint32_t x = 0; x < t->nx; x++)
                        if (field_count(w, (x + a) * K, K))
                            t->dis[(size_t)z * t->ny + y] |= 1ull << x;
                }
    }
}

/* Counts of voxel slices [z0, z0 + nzs) from one fine block. */
static void fine_block(dens *d, int64_t z0, uint32_t nzs)
{
    const mesh_vox_plan *p = d->p;
    const mesh_vox_bufs *b = d->b;
    uint32_t K = p->K;
    mesh_vox_block fb = {{d->vx0 * K, d->vy0 * K, z0 * K},
                   {(int32_t)(d->dnx * K), (int32_t)(d->dny * K), (int32_t)(nzs * K)},
                   (d->dnx * K + 63) / 64};
    const grid_spec *g = d->t->g;
    double h = g->vs / K;
    bool first = z0 == -(int64_t)p->apron;
    mesh_vox_solid_in in = {&d->f, d->t->ids, d->t->n, d->t->o->repair, first,
                      g->lo[2] + (double)(fb.s0[2] - 1) * h,
                      g->lo[2] + (double)(fb.s0[2] + fb.n[2] + 1) * h, false};
    mesh_vox_solid_buf sb = {b->fa, b->fbx, b->fby, b->fcx, b->fcy, b->fzc, b->fdis, NULL};
    mesh_vox_solid(&in, &fb, &sb);
    /* the disagreements counted are those of the pass that decides the
     * voxels: this one only without the voxel-centre solid */
    if (p->rep && !p->solid1) fold_disagreements(d, &fb, z0, nzs);
    for (uint32_t zz = 0; zz < nzs; zz++) {
        uint16_t *s = slice_of(d, z0 + zz);
        for (uint32_t yy = 0; yy < d->dny; yy++)
            count_row(d, &fb, zz, yy, s + (size_t)yy * d->dnx);
    }
}

/* Counts up to voxel slice z (inclusive) computed. */
static void ensure(dens *d, int64_t z)
{
    while (d->next_z <= z && d->next_z < d->z_end) {
        int64_t left = d->z_end - d->next_z;
        uint32_t nzs = left < d->p->zs ? (uint32_t)left : d->p->zs;
        fine_block(d, d->next_z, nzs);
        d->next_z += nzs;
    }
}

/* Count at tile voxel (x, y, z) (z absolute, x and y in the tile; the
 * apron's -1 and n allowed). */
static inline int count_at(const dens *d, int64_t x, int64_t y, int64_t z)
{
    uint32_t a = d->p->apron;
    return slice_of(d, z)[(size_t)(y + a) * d->dnx + (size_t)(x + a)];
}

static int put(const dens *d, uint32_t bx, uint32_t by, uint32_t bz, const void *vox)
{
    const mesh_vox_tile *t = d->t;
    uint32_t b[3] = {t->x0 / t->S + bx, t->y0 / t->S + by, bz};
    return vod_volume_put_brick(t->vol, b, vox);
}

/* The density channel's bricks of row bz. */
static int emit_density_row(dens *d, uint32_t bz)
{
    mesh_vox_tile *t = d->t;
    uint32_t S = t->S;
    uint8_t *brick = d->b->brick;
    for (uint32_t by = 0; by * S < t->ny; by++)
        for (uint32_t bx = 0; bx * S < t->nx; bx++) {
            uint64_t nonzero = 0;
            memset(brick, 0, (size_t)S * S * S);
            for (uint32_t z = 0; z < S && bz * S + z < t->nz; z++)
                for (uint32_t y = 0; y < S && by * S + y < t->ny; y++) {
                    uint8_t *row = brick + ((size_t)z * S + y) * S;
                    for (uint32_t x = 0; x < S && bx * S + x < t->nx; x++) {
                        row[x] = d->dval[count_at(d, bx * S + x, by * S + y, bz * S + z)];
                        nonzero += row[x] != 0;
                    }
                }
            if (!nonzero) continue; /* the volume starts empty */
            t->st->voxels += nonzero;
            int rc = put(d, bx, by, bz, brick);
            if (rc) return rc;
        }
    return 0;
}

/* The surface channel's voxel (x, y, z) of the tile: the outward normal is
 * minus the coverage's gradient, by central differences averaged over the
 * 3 x 3 neighbours across each axis with weights 1 2 1 (Sobel): the six
 * values of plain central differences give normals tens of degrees off on
 * a sphere, since a voxel's coverage changes in steps of 1 / K^3. */
static uint32_t surface_voxel(const dens *d, int64_t x, int64_t y, int64_t z)
{
    static const int w[3] = {1, 2, 1};
    int g[3] = {0, 0, 0};
    for (int i = -1; i <= 1; i++)
        for (int j = -1; j <= 1; j++) {
            int k = w[i + 1] * w[j + 1];
            g[0] += k * (count_at(d, x - 1, y + i, z + j) - count_at(d, x + 1, y + i, z + j));
            g[1] += k * (count_at(d, x + i, y - 1, z + j) - count_at(d, x + i, y + 1, z + j));
            g[2] += k * (count_at(d, x + i, y + j, z - 1) - count_at(d, x + i, y + j, z + 1));
        }
    double n[3] = {g[0], g[1], g[2]};
    return voxel_surface(n);
}

/* The surface channel's bricks of row bz. */
static int emit_surface_row(dens *d, uint32_t bz)
{
    mesh_vox_tile *t = d->t;
    uint32_t S = t->S;
    uint32_t *brick = (uint32_t *)(void *)d->b->brick;
    for (uint32_t by = 0; by * S < t->ny; by++)
        for (uint32_t bx = 0; bx * S < t->nx; bx++) {
            bool any = false;
            memset(brick, 0, (size_t)S * S * S * 4);
            for (uint32_t z = 0; z < S && bz * S + z < t->nz; z++)
                for (uint32_t y = 0; y < S && by * S + y < t->ny; y++) {
                    uint32_t Z = bz * S + z, Y = by * S + y;
                    uint64_t occ = t->occ[(size_t)Z * t->ny + Y];
                    for (uint32_t x = 0; x < S && bx * S + x < t->nx; x++) {
                        if (!(occ >> (bx * S + x) & 1)) continue;
                        brick[((size_t)z * S + y) * S + x] = surface_voxel(d, bx * S + x, Y, Z);
                        any = true;
                    }
                }
            if (!any) continue;
            int rc = put(d, bx, by, bz, brick);
            if (rc) return rc;
        }
    return 0;
}

int mesh_vox_density_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b)
{
    dens d = {.t = t, .p = p, .b = b};
    mesh_vox_frame_init(&d.f, t->m, t->g, p->K);
    d.f.pulse = &t->pulse;
    d.f.wt = t->pulse.env ? t->pulse.env->wtree : NULL;
    d.vx0 = (int64_t)t->x0 - p->apron;
    d.vy0 = (int64_t)t->y0 - p->apron;
    d.dnx = t->nx + 2 * p->apron;
    d.dny = t->ny + 2 * p->apron;
    d.next_z = -(int64_t)p->apron;
    d.z_end = (int64_t)t->nz + p->apron;
    uint32_t K3 = p->K * p->K * p->K;
    for (uint32_t c = 0; c <= K3; c++) d.dval[c] = (uint8_t)((510 * c + K3 - 1) / (2 * K3));
    bool surface = t->o->channel == VOXEL_CH_SURFACE;
    uint32_t S = t->S;
    for (uint32_t bz = 0; bz * S < t->nz; bz++) {
        int64_t top = (int64_t)(bz * S + S < t->nz ? bz * S + S : t->nz) - 1;
        ensure(&d, top + p->apron);
        if (t->pulse.stop) return -ECANCELED;
        int rc = surface ? emit_surface_row(&d, bz) : emit_density_row(&d, bz);
        if (rc) return rc;
    }
    if (p->rep && !p->solid1)
        for (size_t i = 0; i < (size_t)t->ny * t->nz; i++)
            t->st->disagreements += (uint64_t)bits_popcount64(t->dis[i]);
    return 0;
}

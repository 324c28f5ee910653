/* mesh_solid — the solid of a block of samples: parity along z, and for
 * meshes with holes the parities along x and y, their vote or the
 * generalized winding number where they disagree (Passalis et al.'s
 * several directions as the cross-check). */
#include "mesh_vox_int.h"

#include <assert.h>
#include <math.h>
#include <string.h>

void mesh_vox_frame_init(mesh_vox_frame *f, const mesh *m, const grid_spec *g, uint32_t K)
{
    f->m = m;
    f->lat = NULL;
    for (int a = 0; a < 3; a++) f->lo[a] = g->lo[a];
    f->K = K;
    f->scale = (double)K * (double)MESH_VOX_L / g->vs;
    f->pulse = NULL;
    f->wt = NULL;
    f->caps = NULL;
}

/* Whether triangle id can cross a ray of the block: its world z range
 * against the block's (one sample of margin covers the snapping).  z-rays
 * need the triangles below the block only when it starts the column. */
static bool z_relevant(const mesh_vox_solid_in *in, uint32_t id, bool first,
                       bool *below)
{
    const mesh *m = in->f->m;
    const uint32_t *t = m->triangles[id];
    float z0 = m->vertices[t[0]][2], z1 = m->vertices[t[1]][2],
          z2 = m->vertices[t[2]][2];
    double lo = fmin(z0, fmin(z1, z2)), hi = fmax(z0, fmax(z1, z2));
    *below = hi < in->zlo;
    if (lo > in->zhi) return false;
    return first || !*below;
}

/* Every sample of d (one bit each, word w of the block) decided by the
 * winding number: the samples of a word together, each triangle read once
 * for all of them. */
static void decide_winding(const mesh_vox_frame *f, const mesh_vox_block *b, size_t w,
                           uint64_t d, uint64_t *bits)
{
    size_t row = w / b->nw, z = row / (size_t)b->n[1], y = row % (size_t)b->n[1];
    size_t x0 = (w % b->nw) * 64;
    double q[64][3], wn[64];
    unsigned idx[64], n = 0;
    for (uint64_t r = d; r; r &= r - 1) {
        unsigned i = (unsigned)__builtin_ctzll(r);
        q[n][0] = (double)(b->s0[0] + (int64_t)(x0 + i)) + 0.5;
        q[n][1] = (double)(b->s0[1] + (int64_t)y) + 0.5;
        q[n][2] = (double)(b->s0[2] + (int64_t)z) + 0.5;
        idx[n++] = i;
    }
    mesh_vox_winding_many(f, q, n, wn);
    for (unsigned k = 0; k < n; k++) {
        if (fabs(wn[k]) >= 0.5) bits[w] |= 1ull << idx[k];
        else bits[w] &= ~(1ull << idx[k]);
    }
}

uint64_t mesh_vox_solid(const mesh_vox_solid_in *in, const mesh_vox_block *b, const mesh_vox_solid_buf *buf)
{
    size_t nwords = mesh_vox_block_words(b);
    bool rep = in->repair != MESH_REPAIR_NONE, first = in->first;
    bool cull = !isnan(in->zlo);
    size_t ncx = ((size_t)b->n[2] * (size_t)b->n[1] + 63) / 64,
           ncy = (size_t)b->n[2] * b->nw;
    bool tree = in->repair == MESH_REPAIR_WINDING && in->f->wt;
    /* the capped winding numbers count the crossings of whole columns */
    uint16_t *count = tree && buf->count && first && !cull && in->f->K == 1 ? buf->count : NULL;
    if (count) memset(count, 0, nwords * 64 * sizeof *count);
    /* with the caps, S's parities along x and y follow from its own along
     * z and the caps' (mesh_vox_wcap_parities): S is rasterized along z
     * only, and the bins hold no rows of triangles for x and y */
    bool capped = in->capped;
    assert(!capped || (buf->dis && in->f->caps && in->f->pulse));
    int rc = capped ? mesh_vox_wcap_ready(in->f) : 0;
    if (rc) {
        in->f->pulse->err = rc, in->f->pulse->stop = true;
        return 0;
    }
    memset(buf->bits, 0, nwords * 8);
    if (rep) {
        memset(buf->bx, 0, nwords * 8);
        memset(buf->by, 0, nwords * 8);
        memset(buf->cx, 0, ncx * 8);
        memset(buf->cy, 0, ncy * 8);
    }
    mesh_vox_target tz = {b, buf->bits, NULL, first, count};
    mesh_vox_target tx = {b, buf->bx, buf->cx, false, NULL}, ty = {b, buf->by, buf->cy, false, NULL};
    for (size_t i = 0; i < in->n; i++) {
        uint32_t id = in->ids[i];
        if (mesh_vox_beat(in->f->pulse, 8)) return 0; /* the tile is abandoned */
        if (i + MESH_VOX_AHEAD < in->n) mesh_vox_prefetch(in->f, in->ids[i + MESH_VOX_AHEAD]);
        bool below = false;
        if (cull && !z_relevant(in, id, first, &below)) continue;
        int64_t P[3][3];
        mesh_vox_triangle(in->f, id, P);
        mesh_vox_raster(P, 2, &tz);
        if (rep && !below && !capped) { /* below the block: no x or y ray of it */
            mesh_vox_raster(P, 0, &tx);
            mesh_vox_raster(P, 1, &ty);
        }
    }
    mesh_vox_prefix_z(b, buf->bits, buf->zcarry, first);
    if (!rep) return 0;
    if (capped) {
        mesh_vox_wcap_parities(in->f, b, buf->dis, buf->bx, buf->cx, buf->by, buf->cy);
    } else {
        mesh_vox_prefix_x(b, buf->bx, buf->cx);
        mesh_vox_prefix_y(b, buf->by, buf->cy);
    }
    uint64_t ndis = 0;
    for (size_t w = 0; w < nwords; w++) {
        uint64_t a = buf->bits[w], x = buf->bx[w], y = buf->by[w];
        if (capped) { /* x, y: the caps'; dis: theirs along z */
            uint64_t flip = a ^ buf->dis[w];
            x ^= flip, y ^= flip;
        }
        uint64_t d = (a ^ x) | (a ^ y);
        if (buf->dis) buf->dis[w] = d;
        if (tree) buf->bx[w] = d; /* bx[w] read: the disagreements in its place */
        if (!d) continue;
        if (mesh_vox_beat(in->f->pulse, 1)) return ndis;
        ndis += (uint64_t)bits_popcount64(d);
        if (in->repair == MESH_REPAIR_VOTE)
            buf->bits[w] = (a & x) | (a & y) | (x & y);
        else if (!tree)
            decide_winding(in->f, b, w, d, buf->bits);
    }
    if (tree) mesh_vox_wcap_block(in->f, b, buf->bx, buf->bits, count, buf->by);
    return ndis;
}


/* mesh_bin — which triangles each tile needs, decided once for a job.
 *
 * A tile needs the triangles whose bounding box meets its footprint (its
 * columns, plus the one-voxel apron of the surface channel's normals, plus
 * a margin for the snapping).  With repair it also needs, for the parity
 * along x, every triangle of its rows of tiles that starts left of its end,
 * and for the parity along y every triangle of its column of tiles that
 * starts in front of its end.  Along z nothing is cut: a tile is a whole
 * column.  Each triangle is listed once per tile, in ascending order.
 *
 * The plain solid (parity along z only, at voxel centres) needs less: a
 * triangle flips bits only in the columns whose centre its projection
 * covers, so a tile needs it only when the box of its snapped vertices
 * holds a voxel centre of the tile, decided exactly from the same snapped
 * coordinates as the rasterizer's (mesh_vox_raster drops the others unseen).  On
 * a fine mesh most triangles hold none (half of the dragon's at 512^3). */
#include "mesh_vox_int.h"

#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "huge.h"
#include "par.h"

/* A footprint [x0, x1] x [y0, y1] in tiles, or in voxel centres for the
 * exact bins of the plain solid; empty when x0 > x1 or y0 > y1. */
typedef struct {
    int16_t x0, x1, y0, y1;
} span;

_Static_assert(GRID_MAX_RES < INT16_MAX, "a voxel index fits a span");

/* Voxel coordinate of v along a, clamped like the lattice (mesh_vox_snap). */
static double vox_coord(const grid_spec *g, int a, float v)
{
    double t = ((double)v - g->lo[a]) / g->vs, lim = 1073741824.0; /* 2^30 */
    if (!(t >= -lim)) t = -lim;
    return t > lim ? lim : t;
}

/* floor(t / MESH_TILE) for |t| <= 2^31 (a cast and a correction: floor()
 * is a library call without SSE4.1). */
static int64_t tile_floor(double t)
{
    double q = t / MESH_TILE;
    int64_t i = (int64_t)q;
    return i - (q < (double)i);
}

static int16_t clamp_tile(double t, uint32_t n)
{
    int64_t f = tile_floor(t);
    return f < 0 ? 0 : f > (int64_t)n ? (int16_t)n : (int16_t)f;
}

/* The tile range of a point at voxel coordinates (x, y): the tiles from
 * its coordinate less the margin to its coordinate plus it, clamped as a
 * triangle's range is.  Floor, subtraction and clamping are all monotonic,
 * so a triangle's range is the union (min of the starts, max of the ends)
 * of its vertices' ranges: exactly what the bounds of its box would give,
 * for two divisions a vertex instead of six a triangle. */
static span vertex_tiles(const mesh *m, const grid_spec *g, uint32_t v,
                         double margin, const uint32_t nt[2])
{
    span r;
    double x = vox_coord(g, 0, m->vertices[v][0]), y = vox_coord(g, 1, m->vertices[v][1]);
    r.x0 = clamp_tile(x - margin, nt[0]);
    r.y0 = clamp_tile(y - margin, nt[1]);
    /* the last tile whose start is <= the end, -1 when it is before the grid */
    int64_t fx = tile_floor(x + margin), fy = tile_floor(y + margin);
    r.x1 = fx < 0 ? -1 : fx >= (int64_t)nt[0] ? (int16_t)(nt[0] - 1) : (int16_t)fx;
    r.y1 = fy < 0 ? -1 : fy >= (int64_t)nt[1] ? (int16_t)(nt[1] - 1) : (int16_t)fy;
    return r;
}

static int16_t clamp_centre(int64_t i, int64_t lo, int64_t hi)
{
    return (int16_t)(i < lo ? lo : i > hi ? hi : i);
}

/* The voxel centres of a snapped vertex p along x and y: x0 the first at
 * or past it, x1 the last at or before it, clamped to [0, res] and [-1,
 * res - 1].  Like the tiles' ranges these are monotonic, so a triangle's
 * union is the centres in the box of its snapped vertices, the samples
 * mesh_vox_raster looks at. */
static span vertex_centres(const int64_t p[3], const uint32_t res[3])
{
    int64_t x = p[0] - MESH_VOX_H, y = p[1] - MESH_VOX_H;
    span r = {clamp_centre(mesh_vox_ceil_l(x), 0, res[0]),
              clamp_centre(mesh_vox_floor_l(x), -1, (int64_t)res[0] - 1),
              clamp_centre(mesh_vox_ceil_l(y), 0, res[1]),
              clamp_centre(mesh_vox_floor_l(y), -1, (int64_t)res[1] - 1)};
    return r;
}

static span triangle_span(const mesh *m, const span *vr, uint32_t t)
{
    const uint32_t *tri = m->triangles[t];
    span r = vr[tri[0]], b = vr[tri[1]], c = vr[tri[2]];
#define MIN3(f) r.f = b.f < r.f ? b.f : r.f, r.f = c.f < r.f ? c.f : r.f
#define MAX3(f) r.f = b.f > r.f ? b.f : r.f, r.f = c.f > r.f ? c.f : r.f
    MIN3(x0), MIN3(y0), MAX3(x1), MAX3(y1);
#undef MIN3
#undef MAX3
    return r;
}

/* The tiles of a span of voxel centres (empty stays empty). */
static span centre_tiles(span r)
{
    if (r.x0 > r.x1 || r.y0 > r.y1) return (span){1, 0, 1, 0};
    return (span){(int16_t)(r.x0 / MESH_TILE), (int16_t)(r.x1 / MESH_TILE),
                  (int16_t)(r.y0 / MESH_TILE), (int16_t)(r.y1 / MESH_TILE)};
}

/* Calls add(tile) for every tile r needs, each once. */
#define FOR_TILES(r, rep, nt, add)                                             \
    do {                                                                       \
        for (int ty = (r).y0; ty <= (r).y1; ty++)                              \
            for (int tx = (r).x0; tx <= ((rep) ? (int)(nt)[0] - 1 : (r).x1); tx++) \
                add((uint64_t)ty * (nt)[0] + (uint64_t)tx);                    \
        if (rep)                                                               \
            for (int ty = (r).y1 + 1 > (r).y0 ? (r).y1 + 1 : (r).y0;           \
                 ty < (int)(nt)[1]; ty++)                                      \
                for (int tx = (r).x0; tx <= (r).x1; tx++)                      \
                    add((uint64_t)ty * (nt)[0] + (uint64_t)tx);                \
    } while (0)

/* The binning, split into parts that run at once (par_run): the vertices'
 * spans, then each part counts its triangles per tile, then (once the
 * counts are summed into every part's cursors) each part files its
 * triangles.  The parts are ranges of triangles in order, and part k's
 * cursors start behind the parts before it: a tile lists its triangles in
 * ascending order, whatever the number of parts.
 *
 * The plain solid's triangles get a code first: the one tile whose
 * centres they hold (nearly all of them at any resolution that matters),
 * none, or several (then their tiles are walked as the other modes'
 * are).  Filing by code has no branch on the geometry: the triangles that
 * hold no centre, half of the dragon's at 512^3, are filed into a spare
 * slot past the end. */
typedef struct {
    const mesh *m;
    const grid_spec *g;
    mesh_vox_frame f;
    mesh_lattice *lattice;
    bool exact, rep;
    double margin;
    uint32_t nt[2], ntiles;
    span *vr;         /* a vertex's span */
    span *r;          /* the other modes: a triangle's tiles */
    uint32_t *code;   /* the plain solid: a triangle's tile, CODE_NONE or CODE_MANY */
    uint64_t *cur;    /* (ntiles + 2) per part: its counts, then its cursors */
    uint64_t *start;  /* ntiles + 1: the bins' starts */
    uint32_t *ids;    /* start[ntiles] + 1: the bins and the spare slot */
} binner;

#define CODE_NONE(b) ((b)->ntiles)
#define CODE_MANY(b) ((b)->ntiles + 1)

static void part_range(uint64_t count, unsigned k, unsigned n, uint64_t *lo, uint64_t *hi)
{
    *lo = count * k / n;
    *hi = count * (k + 1) / n;
}

/* Whether the other modes' triangle with tiles r is filed anywhere: a
 * tile's columns need it only when its footprint meets them; the repair's
 * rows also when it lies left of / in front. */
static bool filed(span r, bool rep)
{
    if (r.y0 > r.y1 && r.x0 > r.x1) return false;
    return rep || (r.y0 <= r.y1 && r.x0 <= r.x1);
}

/* The plain solid's code of triangle t. */
static uint32_t code_of(const binner *b, uint32_t t)
{
    span s = triangle_span(b->m, b->vr, t);
    bool none = s.x0 > s.x1 || s.y0 > s.y1;
    uint32_t tx0 = (uint32_t)s.x0 / MESH_TILE, ty0 = (uint32_t)s.y0 / MESH_TILE;
    bool one = tx0 == (uint32_t)s.x1 / MESH_TILE && ty0 == (uint32_t)s.y1 / MESH_TILE;
    uint32_t tile = ty0 * b->nt[0] + tx0;
    return none ? CODE_NONE(b) : one ? tile : CODE_MANY(b);
}

/* Vertex v's span (and its lattice point, when b->lattice is not NULL). */
static span vertex_span(const binner *b, uint32_t v)
{
    int64_t p[3];
    mesh_lattice *lattice = b->lattice;
    if (lattice || b->exact)
        for (int a = 0; a < (lattice ? 3 : 2); a++) p[a] = mesh_vox_vertex(&b->f, v, a);
    if (lattice) memcpy(lattice[v], p, sizeof p);
    return b->exact ? vertex_centres(p, b->g->res) : vertex_tiles(b->m, b->g, v, b->margin, b->nt);
}

static void vertices_part(void *ud, unsigned k, unsigned n)
{
    binner *b = ud;
    uint64_t lo, hi;
    part_range(b->m->n_vertices, k, n, &lo, &hi);
    for (uint64_t v = lo; v < hi; v++)
        b->vr[v] = vertex_span(b, (uint32_t)v);
}

static void prefetch_ahead(const binner *b, uint64_t t, uint64_t hi)
{
    if (t + MESH_VOX_AHEAD >= hi) return;
    const uint32_t *ahead = b->m->triangles[t + MESH_VOX_AHEAD];
    for (int i = 0; i < 3; i++) __builtin_prefetch(&b->vr[ahead[i]]);
}

/* The tiles of a plain-solid triangle of code CODE_MANY: found again
 * when it is filed (few triangles have it). */
static span many_tiles(const binner *b, uint64_t t)
{
    return centre_tiles(triangle_span(b->m, b->vr, (uint32_t)t));
}

/* Part k's counters and its range of triangles. */
static uint64_t *part_triangles(const binner *b, unsigned k, unsigned n, uint64_t *lo,
                                uint64_t *hi)
{
    part_range(b->m->n_triangles, k, n, lo, hi);
    return b->cur + (uint64_t)k * (b->ntiles + 2);
}

static void count_part(void *ud, unsigned k, unsigned n)
{
    binner *b = ud;
    uint64_t lo, hi, *c = part_triangles(b, k, n, &lo, &hi);
#define COUNT(i) c[i]++
    for (uint64_t t = lo; t < hi; t++) {
        prefetch_ahead(b, t, hi);
        if (!b->exact) {
            span r = b->r[t] = triangle_span(b->m, b->vr, (uint32_t)t);
            if (filed(r, b->rep)) FOR_TILES(r, b->rep, b->nt, COUNT);
            continue;
        }
        uint32_t code = b->code[t] = code_of(b, (uint32_t)t);
        c[code]++;
        if (code == CODE_MANY(b)) {
            span r = many_tiles(b, t);
            FOR_TILES(r, 0, b->nt, COUNT);
        }
    }
#undef COUNT
}

static void fill_part(void *ud, unsigned k, unsigned n)
{
    binner *b = ud;
    uint64_t lo, hi, *c = part_triangles(b, k, n, &lo, &hi);
    uint32_t *ids = b->ids;
#define FILL(i) ids[c[i]++] = (uint32_t)t
    for (uint64_t t = lo; t < hi; t++) {
        if (!b->exact) {
            if (filed(b->r[t], b->rep)) FOR_TILES(b->r[t], b->rep, b->nt, FILL);
            continue;
        }
        uint32_t code = b->code[t];
        if (code == CODE_MANY(b)) {
            span r = many_tiles(b, t);
            FOR_TILES(r, 0, b->nt, FILL);
            continue;
        }
        ids[c[code]] = (uint32_t)t; /* CODE_NONE's cursor: the spare slot */
        c[code] += code < b->ntiles;
    }
#undef FILL
}

/* The parts' counts summed into the bins' starts, then turned into each
 * part's cursors; 0 or -E2BIG. */
static int sum_counts(binner *b, unsigned parts)
{
    uint64_t stride = b->ntiles + 2, pos = 0;
    for (uint32_t i = 0; i < b->ntiles; i++) {
        b->start[i] = pos;
        for (unsigned k = 0; k < parts; k++) {
            uint64_t count = b->cur[k * stride + i];
            b->cur[k * stride + i] = pos;
            pos += count;
        }
    }
    b->start[b->ntiles] = pos;
    for (unsigned k = 0; k < parts; k++) b->cur[k * stride + CODE_NONE(b)] = pos;
    return pos >= SIZE_MAX / sizeof(uint32_t) ? -E2BIG : 0;
}

static void binner_free(binner *b)
{
    free(b->vr), free(b->r), free(b->code), free(b->cur), free(b->start), free(b->ids);
}

static int binner_init(binner *b, const mesh *m, const grid_spec *g,
                       const mesh_vox_opts *o, mesh_lattice *lattice, unsigned parts)
{
    memset(b, 0, sizeof *b);
    mesh_vox_plan p;
    mesh_vox_plan_make(g, o, &p);
    b->m = m, b->g = g, b->lattice = lattice;
    b->nt[0] = (g->res[0] + MESH_TILE - 1) / MESH_TILE;
    b->nt[1] = (g->res[1] + MESH_TILE - 1) / MESH_TILE;
    b->ntiles = b->nt[0] * b->nt[1];
    /* the snapping moves < 2^-17 voxel; a distance tile needs the
     * triangles within its band of its columns */
    b->margin = p.apron + p.band + 1.0 / 64;
    b->rep = o->repair != MESH_REPAIR_NONE && !p.capped;
    b->exact = p.solid1 && !p.surf && !b->rep && !p.dens && !p.dist; /* z rays only */
    mesh_vox_frame_init(&b->f, m, g, 1);
    size_t nt = (size_t)m->n_triangles + 1;
    b->vr = huge_malloc(((size_t)m->n_vertices + 1) * sizeof *b->vr);
    if (b->exact) b->code = huge_malloc(nt * sizeof *b->code);
    else b->r = huge_malloc(nt * sizeof *b->r);
    b->cur = calloc((size_t)parts * (b->ntiles + 2), sizeof *b->cur);
    b->start = malloc(((size_t)b->ntiles + 1) * sizeof *b->start);
    return b->vr && (b->code || b->r) && b->cur && b->start ? 0 : -ENOMEM;
}

int mesh_bin(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
             mesh_lattice *lattice, unsigned threads, mesh_bins *out)
{
    memset(out, 0, sizeof *out);
    /* a part of fewer triangles costs more to start than it saves */
    unsigned parts = m->n_triangles / MESH_BIN_PART_MIN;
    if (parts > threads) parts = threads;
    if (parts > PAR_MAX) parts = PAR_MAX;
    if (parts < 1) parts = 1;
    binner b;
    int rc = binner_init(&b, m, g, o, lattice, parts);
    if (!rc) {
        par_run(parts, vertices_part, &b);
        par_run(parts, count_part, &b);
        rc = sum_counts(&b, parts);
    }
    if (!rc && !(b.ids = huge_malloc((b.start[b.ntiles] + 1) * sizeof *b.ids))) rc = -ENOMEM;
    if (!rc) par_run(parts, fill_part, &b);
    if (rc) {
        binner_free(&b);
        return rc;
    }
    out->start = b.start;
    out->ids = b.ids;
    out->tiles[0] = b.nt[0];
    out->tiles[1] = b.nt[1];
    b.start = NULL, b.ids = NULL;
    binner_free(&b);
    return 0;
}

void mesh_bins_free(mesh_bins *b)
{
    free(b->start);
    free(b->ids);
    b->start = NULL;
    b->ids = NULL;
}

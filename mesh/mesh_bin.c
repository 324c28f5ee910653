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
 * coordinates as the rasterizer's (mv_raster drops the others unseen).  On
 * a fine mesh most triangles hold none (half of the dragon's at 512^3). */
#include "mesh_vox_int.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

/* A footprint [x0, x1] x [y0, y1] in tiles, or in voxel centres for the
 * exact bins of the plain solid; empty when x0 > x1 or y0 > y1. */
typedef struct {
    int16_t x0, x1, y0, y1;
} span;

_Static_assert(GRID_MAX_RES < INT16_MAX, "a voxel index fits a span");

/* Voxel coordinate of v along a, clamped like the lattice (mv_snap). */
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
 * mv_raster looks at. */
static span vertex_centres(const int64_t p[3], const uint32_t res[3])
{
    int64_t x = p[0] - MV_H, y = p[1] - MV_H;
    span r = {clamp_centre(mv_ceil_l(x), 0, res[0]),
              clamp_centre(mv_floor_l(x), -1, (int64_t)res[0] - 1),
              clamp_centre(mv_ceil_l(y), 0, res[1]),
              clamp_centre(mv_floor_l(y), -1, (int64_t)res[1] - 1)};
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

/* Vertex v's span (and its lattice point, when lattice is not NULL). */
static span vertex_span(const mesh *m, const grid_spec *g, const mv_frame *f, uint32_t v,
                        bool exact, double margin, const uint32_t nt[2],
                        mesh_lattice *lattice)
{
    int64_t p[3];
    if (lattice || exact)
        for (int a = 0; a < (lattice ? 3 : 2); a++) p[a] = mv_vertex(f, v, a);
    if (lattice) memcpy(lattice[v], p, sizeof p);
    return exact ? vertex_centres(p, g->res) : vertex_tiles(m, g, v, margin, nt);
}

int mesh_bin(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
             mesh_lattice *lattice, mesh_bins *out)
{
    memset(out, 0, sizeof *out);
    mv_plan p;
    mv_plan_make(g, o, &p);
    uint32_t nt[2] = {(g->res[0] + MESH_TILE - 1) / MESH_TILE,
                      (g->res[1] + MESH_TILE - 1) / MESH_TILE};
    uint64_t ntiles = (uint64_t)nt[0] * nt[1];
    double margin = p.apron + 1.0 / 64; /* the snapping moves < 2^-17 voxel */
    bool rep = o->repair != MESH_REPAIR_NONE;
    bool exact = p.solid1 && !p.surf && !p.rep && !p.dens; /* z rays only */
    mv_frame f;
    mv_frame_init(&f, m, g, 1);
    span *r = malloc(((size_t)m->n_triangles + 1) * sizeof *r);
    span *vr = malloc(((size_t)m->n_vertices + 1) * sizeof *vr);
    uint64_t *start = calloc(ntiles + 1, sizeof *start);
    uint64_t *cur = malloc(ntiles * sizeof *cur);
    if (!r || !vr || !start || !cur) goto nomem;
    for (uint32_t v = 0; v < m->n_vertices; v++)
        vr[v] = vertex_span(m, g, &f, v, exact, margin, nt, lattice);
#define COUNT(i) start[(i) + 1]++
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        if (t + MV_AHEAD < m->n_triangles) {
            const uint32_t *ahead = m->triangles[t + MV_AHEAD];
            for (int i = 0; i < 3; i++) __builtin_prefetch(&vr[ahead[i]]);
        }
        r[t] = triangle_span(m, vr, t);
        if (exact) r[t] = centre_tiles(r[t]);
        /* a tile's columns need the triangle only when the footprint meets
         * them; the repair's rows also when it lies left of / in front */
        if (r[t].y0 > r[t].y1 && r[t].x0 > r[t].x1) continue;
        if (!rep && (r[t].y0 > r[t].y1 || r[t].x0 > r[t].x1)) continue;
        FOR_TILES(r[t], rep, nt, COUNT);
    }
#undef COUNT
    free(vr);
    vr = NULL;
    for (uint64_t i = 0; i < ntiles; i++) start[i + 1] += start[i];
    if (start[ntiles] > SIZE_MAX / sizeof(uint32_t)) {
        free(r), free(start), free(cur);
        return -E2BIG;
    }
    out->ids = malloc(start[ntiles] ? start[ntiles] * sizeof(uint32_t) : 1);
    if (!out->ids) goto nomem;
    memcpy(cur, start, ntiles * sizeof *cur);
#define FILL(i) out->ids[cur[i]++] = t
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        if (r[t].y0 > r[t].y1 && r[t].x0 > r[t].x1) continue;
        if (!rep && (r[t].y0 > r[t].y1 || r[t].x0 > r[t].x1)) continue;
        FOR_TILES(r[t], rep, nt, FILL);
    }
#undef FILL
    free(r);
    free(cur);
    out->start = start;
    out->tiles[0] = nt[0];
    out->tiles[1] = nt[1];
    return 0;
nomem:
    free(r), free(vr), free(start), free(cur);
    free(out->ids);
    out->ids = NULL;
    return -ENOMEM;
}

void mesh_bins_free(mesh_bins *b)
{
    free(b->start);
    free(b->ids);
    b->start = NULL;
    b->ids = NULL;
}

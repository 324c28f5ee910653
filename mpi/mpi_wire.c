/* What a mesh job sends besides the job (mpi_part.h): a column's
 * triangles, sent with its task, checked on arrival as any input is:
 * every length and index before use.  A CSG job's tree travels as
 * csg_pack.h packs it. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "mpi_part.h"

/* ---- a mesh job's column ---- */

typedef struct {
    uint32_t n_vertices, n_triangles;
} mesh_head;

/* Mark (stamp) every triangle tiles need; how many. */
static uint32_t mark_triangles(const mesh *m, const mesh_bins *bins, const uint32_t tiles[4],
                               uint8_t *used)
{
    uint32_t n = 0;
    if (!tiles) {
        memset(used, 1, m->n_triangles);
        return m->n_triangles;
    }
    for (uint32_t ty = tiles[1]; ty < tiles[3]; ty++)
        for (uint32_t tx = tiles[0]; tx < tiles[2]; tx++) {
            uint64_t k = (uint64_t)ty * bins->tiles[0] + tx;
            for (uint64_t i = bins->start[k]; i < bins->start[k + 1]; i++)
                if (!used[bins->ids[i]]) used[bins->ids[i]] = 1, n++;
        }
    return n;
}

int mpi_mesh_part(const mesh *m, const mesh_bins *bins, const uint32_t tiles[4],
                  uint8_t **out, size_t *len)
{
    uint8_t *used = calloc(m->n_triangles ? m->n_triangles : 1, 1);
    uint32_t *vmap = malloc((m->n_vertices ? m->n_vertices : 1) * sizeof *vmap);
    int rc = used && vmap ? 0 : -ENOMEM;
    mesh_head h = {0};
    if (!rc) h.n_triangles = mark_triangles(m, bins, tiles, used);
    if (!rc) memset(vmap, 0xff, (size_t)m->n_vertices * sizeof *vmap);
    for (uint32_t t = 0; !rc && t < m->n_triangles; t++)
        for (int k = 0; used[t] && k < 3; k++)
            if (vmap[m->triangles[t][k]] == UINT32_MAX) vmap[m->triangles[t][k]] = h.n_vertices++;
    size_t n = sizeof h + (size_t)h.n_vertices * 12 + (size_t)h.n_triangles * 12;
    uint8_t *b = rc ? NULL : malloc(n);
    if (!rc && !b) rc = -ENOMEM;
    if (!rc) {
        /* vertices in order of first use, triangles in their order: the
         * column's tiles see the same triangles in the same order */
        memcpy(b, &h, sizeof h);
        float (*v)[3] = (float (*)[3])(b + sizeof h);
        uint32_t (*tri)[3] = (uint32_t (*)[3])(b + sizeof h + (size_t)h.n_vertices * 12);
        for (uint32_t i = 0; i < m->n_vertices; i++)
            if (vmap[i] != UINT32_MAX) memcpy(v[vmap[i]], m->vertices[i], 12);
        uint32_t k = 0;
        for (uint32_t t = 0; t < m->n_triangles; t++)
            if (used[t])
                for (int c = 0; c < 3; c++) tri[k][c] = vmap[m->triangles[t][c]], k += c == 2;
        *out = b;
        *len = n;
    }
    free(used);
    free(vmap);
    return rc;
}

int mpi_mesh_view(const uint8_t *buf, size_t len, mesh *out)
{
    mesh_head h;
    if (len < sizeof h || ((uintptr_t)buf & 3)) return -EPROTO;
    memcpy(&h, buf, sizeof h);
    /* no triangle: a distance's column far from the surface (its band's
     * width alone); never vertices without triangles */
    if (len != sizeof h + (uint64_t)h.n_vertices * 12 + (uint64_t)h.n_triangles * 12 ||
        !h.n_triangles != !h.n_vertices)
        return -EPROTO;
    memset(out, 0, sizeof *out);
    out->n_vertices = h.n_vertices;
    out->n_triangles = h.n_triangles;
    out->vertices = (float (*)[3])(buf + sizeof h);
    out->triangles = (uint32_t (*)[3])(buf + sizeof h + (size_t)h.n_vertices * 12);
    for (int a = 0; a < 3 && h.n_vertices; a++) out->lo[a] = out->hi[a] = out->vertices[0][a];
    for (uint32_t t = 0; t < h.n_triangles; t++)
        for (int c = 0; c < 3; c++)
            if (out->triangles[t][c] >= h.n_vertices) return -EPROTO;
    for (uint32_t i = 0; i < h.n_vertices; i++)
        for (int a = 0; a < 3; a++) {
            if (out->vertices[i][a] < out->lo[a]) out->lo[a] = out->vertices[i][a];
            if (out->vertices[i][a] > out->hi[a]) out->hi[a] = out->vertices[i][a];
        }
    return 0;
}

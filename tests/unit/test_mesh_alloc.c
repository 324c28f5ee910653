/* The mesh algorithms when memory runs out: every allocation of the weld,
 * the topology and the serial voxelizer (the tiles' binning, the fast
 * winding number's tree and its caps, the closest-point transform, the
 * supersampled density) fails in turn (alloc_fail.h).  Each run gives the
 * whole answer (the same volume, voxel for voxel, as a run with all its
 * memory) or -ENOMEM, and frees every block it allocated.  These calls
 * return a code alone: the engine's worker says which tile failed. */
#include "mesh_vox_fixture.h"

#include "alloc_fail.h"
#include "mesh.h"

/* ---- the serial voxelizer ---- */

typedef struct {
    const mesh *m;
    grid_spec g;
    mesh_vox_opts o;
    tvol v;             /* its arena made once, the volume set up again each run */
    size_t bytes;
    uint32_t *want;     /* the volume with all its memory, dense */
} vox_case;

static int vox_once(void *ctx, char *msg)
{
    (void)msg; /* a code alone */
    vox_case *c = ctx;
    cr_assert_eq(vod_volume_init(&c->v.v, c->v.arena, c->bytes, c->g.res, mesh_vox_bits(&c->o),
                                 mesh_vox_sbrick(&c->o)), 0);
    mesh_tile_stats st = {0};
    int rc = mesh_voxelize(c->m, &c->g, &c->o, c->v.v, &st);
    if (rc) return rc;
    for (uint32_t z = 0; z < c->g.res[2]; z++)
        for (uint32_t y = 0; y < c->g.res[1]; y++)
            for (uint32_t x = 0; x < c->g.res[0]; x++)
                cr_assert_eq(vod_volume_get(c->v.v, x, y, z), c->want[vidx(&c->g, x, y, z)],
                             "voxel %u %u %u", x, y, z);
    return 0;
}

static void voxelizes_or_fails_cleanly(const mesh *m, mesh_vox_opts o, const char *what)
{
    vox_case c = {.m = m, .g = cube_grid(32), .o = o};
    c.want = voxelize(m, &c.g, &o, mesh_vox_sbrick(&o), NULL);
    c.bytes = vod_volume_bytes(c.g.res, mesh_vox_bits(&o), mesh_vox_sbrick(&o), UINT32_MAX);
    c.v = vol_make(&c.g, mesh_vox_bits(&o), mesh_vox_sbrick(&o));
    cr_assert_geq(alloc_fail_runs(vox_once, &c, what, false), 2, "%s", what);
    free(c.v.arena);
    free(c.want);
}

Test(mesh_alloc, every_kind_of_voxelization_fails_cleanly)
{
    shape s;
    shape_holed_sphere(&s);
    const mesh_vox_opts kinds[] = {
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_VOTE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SURFACE, MESH_REPAIR_NONE, VOXEL_CH_SURFACE, 0, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, 2, 0},
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_DISTANCE, 0, 3},
    };
    const char *const names[] = {"solid", "solid, vote", "solid, winding", "surface",
                                 "density", "distance, winding"};
    for (size_t k = 0; k < sizeof kinds / sizeof *kinds; k++)
        voxelizes_or_fails_cleanly(&s.m, kinds[k], names[k]);
    shape_free(&s);
}

/* ---- the weld and the topology ---- */

/* Triangle soup: each triangle its own three vertices (an STL's), which
 * the weld merges back; made during the runs, in the test's own memory. */
static mesh soup(const mesh *m)
{
    mesh r = {.n_vertices = 3 * m->n_triangles, .n_triangles = m->n_triangles};
    r.vertices = af_test_malloc(r.n_vertices * sizeof *r.vertices);
    r.triangles = af_test_malloc(r.n_triangles * sizeof *r.triangles);
    cr_assert(r.vertices && r.triangles);
    for (uint32_t t = 0; t < m->n_triangles; t++)
        for (int k = 0; k < 3; k++) {
            memcpy(r.vertices[3 * t + k], m->vertices[m->triangles[t][k]], sizeof *r.vertices);
            r.triangles[t][k] = 3 * t + (uint32_t)k;
        }
    memcpy(r.lo, m->lo, sizeof r.lo);
    memcpy(r.hi, m->hi, sizeof r.hi);
    return r;
}

typedef struct {
    const mesh *in;
    mesh want;
    double eps;
} weld_case;

static int weld_once(void *ctx, char *msg)
{
    (void)msg;
    const weld_case *c = ctx;
    mesh m = soup(c->in);
    uint32_t merged = 0;
    int rc = mesh_weld(&m, c->eps, &merged);
    if (!rc) {
        cr_assert(m.n_vertices == c->want.n_vertices && m.n_triangles == c->want.n_triangles);
        cr_assert_eq(memcmp(m.triangles, c->want.triangles, m.n_triangles * sizeof *m.triangles), 0);
        cr_assert_eq(memcmp(m.vertices, c->want.vertices, m.n_vertices * sizeof *m.vertices), 0);
    } else {
        cr_assert_eq(m.n_vertices, 3 * c->in->n_triangles, "a failed weld changed the mesh");
    }
    mesh_free(&m);
    return rc;
}

typedef struct {
    const mesh *m;
    mesh_topo want;
    bool edges_only;
} topo_case;

static int topo_once(void *ctx, char *msg)
{
    (void)msg;
    const topo_case *c = ctx;
    mesh_topo t;
    int rc = c->edges_only ? mesh_edges(c->m, &t) : mesh_topology(c->m, &t);
    if (!rc)
        cr_assert(t.edges == c->want.edges && t.open == c->want.open &&
                  t.components == c->want.components && t.volume == c->want.volume);
    return rc;
}

/* 81,920 triangles: the weld's parallel path (65,536 vertices and up). */
Test(mesh_alloc, the_weld_and_the_topology_fail_cleanly)
{
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0, 0, 0}, 0.9, 6, false);
    const mesh *ico = shape_finish(&s);
    for (int k = 0; k < 2; k++) {
        weld_case w = {ico, soup(ico), k ? 1e-6 : 0};
        cr_assert_eq(mesh_weld(&w.want, w.eps, NULL), 0);
        cr_assert_eq(w.want.n_vertices, ico->n_vertices);
        cr_assert_geq(alloc_fail_runs(weld_once, &w, k ? "mesh_weld, eps" : "mesh_weld", false),
                      2);
        mesh_free(&w.want);
    }
    for (int k = 0; k < 2; k++) {
        topo_case t = {ico, {0}, k};
        cr_assert_eq(k ? mesh_edges(ico, &t.want) : mesh_topology(ico, &t.want), 0);
        cr_assert(t.want.watertight);
        cr_assert_geq(alloc_fail_runs(topo_once, &t, k ? "mesh_edges" : "mesh_topology", false),
                      1);
    }
    shape_free(&s);
}

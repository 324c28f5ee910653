/* The pipeline when memory runs out: every allocation of a whole job, from
 * its grid to its last byte, fails in turn (alloc_fail.h), for each kind
 * of job (an expression as occupancy, surface and distance, a mesh as a
 * solid and as its distance, and a CSG tree with implicit, mesh and VOD
 * leaves, as densities and as a distance), run serially (without an
 * engine: what vox -w 0 runs, and the reference the engine's bytes are
 * held to) and on an engine of two workers (the master's allocations:
 * the workers were forked before the test armed, so theirs never fail).
 * Each run writes the job's whole file, the same bytes as with all its
 * memory, or fails with -ENOMEM and a message, and frees every block it
 * allocated (a file cut short is the caller's to drop, as vox's temporary
 * file is); on the engine no failure is a worker's crash, and the next job
 * is whole. */
#include <criterion/criterion.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc_fail.h"
#include "csg.h"
#include "csg_fixture.h"
#include "engine.h"
#include "expr.h"
#include "mesh.h"
#include "mesh_shapes.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

typedef struct {
    engine *e;       /* NULL: serially */
    const engine_pipeline_job *job;
    vod_membuf want; /* the file with all its memory */
} job_case;

/* One run of c's job.  Its sink is the library's vod_mem_write, which
 * allocates as it grows, as voxd's memory file does: the sink's growth is
 * among the allocations that fail in turn (a sink's -ENOMEM must end the
 * job as cleanly as the job's own), unlike test_vod_alloc's writer runs,
 * whose sink is the test's memory so that only the writer's fail. */
static int job_once(void *ctx, char *msg)
{
    const job_case *c = ctx;
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    engine_pipeline_report r;
    int rc = engine_pipeline_run(c->e, c->job, &sink, &r);
    memcpy(msg, r.err.msg, sizeof r.err.msg);
    if (rc) {
        cr_assert(r.err.msg[0], "a failure (%d) without a message", rc);
        cr_assert_neq(r.err.kind, ENGINE_CRASHED, "%s", r.err.msg);
        /* the heap ran out, not the segment: no advice to raise its size */
        cr_assert(!strstr(r.err.msg, "shared memory"), "%s", r.err.msg);
    } else {
        cr_assert(m.n == c->want.n && !memcmp(m.p, c->want.p, m.n), "other bytes");
    }
    free(m.p);
    return rc;
}

/* The engine of two workers the jobs also run on (NULL before the first). */
static engine *eng;

static void engine_up(void)
{
    engine_opts eo = {.workers = 2, .shm_bytes = (size_t)64 << 20};
    err_info err = {0};
    cr_assert_eq(engine_create(&eo, &eng, &err), 0, "%s", err.msg);
}

static void engine_down(void)
{
    if (eng) engine_destroy(eng);
    eng = NULL;
}

TestSuite(pipeline_each_alloc, .init = engine_up, .fini = engine_down);

/* job serially, then on the engine, each allocation failing in turn; the
 * engine's next job after all that is whole. */
static void writes_or_fails_cleanly(const engine_pipeline_job *job, const char *what)
{
    job_case c = {NULL, job, {0}};
    vod_sink sink = {vod_mem_write, &c.want};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(NULL, job, &sink, &r), 0, "%s: %s", what, r.err.msg);
    cr_assert_geq(alloc_fail_runs(job_once, &c, what, false), 20, "%s", what);
    char on[64];
    snprintf(on, sizeof on, "%s, on an engine", what);
    c.e = eng;
    cr_assert_geq(alloc_fail_runs(job_once, &c, on, false), 5, "%s", on);
    free(c.want.p);
}

static engine_pipeline_job job_of(const engine_kind *k, int channel, uint32_t res)
{
    engine_pipeline_job job = {.kind = k, .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = res};
    vod_params_default(&job.vod);
    job.vod.channel = channel;
    return job;
}

#define BLOB "sqrt(x^2 + 1.3*y^2 + z^2) - 0.6 + 0.05*sin(7*x)"

Test(pipeline_each_alloc, an_expression_writes_or_fails_cleanly)
{
    expr_tape *t;
    expr_error ee;
    cr_assert_eq(expr_compile(BLOB, strlen(BLOB), NULL, &t, &ee), 0, "%s", ee.msg);
    const int channels[] = {VOXEL_CH_OCCUPANCY, VOXEL_CH_SURFACE, VOXEL_CH_DISTANCE};
    const char *const names[] = {"implicit, occupancy", "implicit, surface", "implicit, distance"};
    for (int k = 0; k < 3; k++) {
        engine_pipeline_job job = job_of(&engine_kind_implicit, channels[k], 32);
        job.implicit = (engine_implicit_input){.tape = t, .source = BLOB,
                                               .source_len = strlen(BLOB)};
        writes_or_fails_cleanly(&job, names[k]);
    }
    expr_tape_free(t);
}

Test(pipeline_each_alloc, a_mesh_writes_or_fails_cleanly)
{
    shape s;
    const mesh *m = shape_holed_sphere(&s);
    const mesh_vox_opts opts[] = {
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DISTANCE, 0, 3},
    };
    const char *const names[] = {"mesh, solid, winding", "mesh, distance"};
    for (int k = 0; k < 2; k++) {
        engine_pipeline_job job = job_of(&engine_kind_mesh, opts[k].channel, 32);
        job.mesh = (engine_mesh_input){.mesh = m, .opts = opts[k], .pad = 1, .fit = 1};
        job.band = opts[k].band;
        writes_or_fails_cleanly(&job, names[k]);
    }
    shape_free(&s);
}

/* The icosphere as an OBJ text, a CSG leaf's bytes. */
static char *ico_obj(size_t *len)
{
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0.1, 0, 0}, 0.5, 2, false);
    const mesh *m = shape_finish(&s);
    size_t cap = 64 * ((size_t)m->n_vertices + m->n_triangles), n = 0;
    char *p = malloc(cap);
    cr_assert(p);
    for (uint32_t i = 0; i < m->n_vertices; i++)
        n += (size_t)snprintf(p + n, cap - n, "v %.9g %.9g %.9g\n", m->vertices[i][0],
                              m->vertices[i][1], m->vertices[i][2]);
    for (uint32_t i = 0; i < m->n_triangles; i++)
        n += (size_t)snprintf(p + n, cap - n, "f %u %u %u\n", m->triangles[i][0] + 1,
                              m->triangles[i][1] + 1, m->triangles[i][2] + 1);
    shape_free(&s);
    *len = n;
    return p;
}

static void attach(csg_tree *t, const char *name, const void *data, size_t len)
{
    for (uint32_t i = 0; i < t->n; i++)
        if (!strcmp(t->node[i].name, name)) {
            t->data[i] = malloc(len);
            cr_assert(t->data[i]);
            memcpy(t->data[i], data, len);
            t->data_len[i] = len;
            return;
        }
    cr_assert_fail("no node %s", name);
}

Test(pipeline_each_alloc, a_csg_tree_writes_or_fails_cleanly)
{
    /* the VOD leaf's file: an ellipsoid's densities */
    csg_tree *pt = parse("e = ellipsoid center 0.1,0,0.2 radii 0.45,0.35,0.4\nresult e\n");
    engine_pipeline_job pj = job_of(&engine_kind_csg, VOXEL_CH_DENSITY, 16);
    pj.csg = (engine_csg_input){.tree = pt, .source_bytes = 1};
    vod_membuf prev = {0};
    vod_sink sink = {vod_mem_write, &prev};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(NULL, &pj, &sink, &r), 0, "%s", r.err.msg);
    csg_tree_free(pt);

    size_t olen;
    char *obj = ico_obj(&olen);
    csg_tree *t = parse("plane = implicit \"z - 0.1\" domain -0.8,0.8\n"
                             "ball = mesh \"ico.obj\"\n"
                             "prev = vod \"prev.vod\"\n"
                             "cut = intersection(ball, plane)\n"
                             "out = union(difference(cut, prev), erode(prev, 1))\n"
                             "result out\n");
    attach(t, "ball", obj, olen);
    attach(t, "prev", prev.p, prev.n);
    engine_pipeline_job job = job_of(&engine_kind_csg, VOXEL_CH_DENSITY, 32);
    job.csg = (engine_csg_input){.tree = t, .source_bytes = 1};
    writes_or_fails_cleanly(&job, "csg, density");
    csg_tree_free(t);

    /* a distance: implicit and mesh leaves, min and max */
    t = parse("ball = mesh \"ico.obj\"\n"
                   "blob = implicit \"" BLOB "\"\n"
                   "out = difference(blob, ball)\n"
                   "result out\n");
    attach(t, "ball", obj, olen);
    job = job_of(&engine_kind_csg, VOXEL_CH_DISTANCE, 32);
    job.csg = (engine_csg_input){.tree = t, .source_bytes = 1};
    writes_or_fails_cleanly(&job, "csg, distance");
    csg_tree_free(t);
    free(obj);
    free(prev.p);
}

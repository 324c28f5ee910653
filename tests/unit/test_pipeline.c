/* The one job pipeline: the same bytes with the serial algorithm and any
 * engine, the metadata of the job, and its failures typed and staged. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "kind_implicit.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

#define TORUS "sqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25"

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static engine_pipeline_job torus_job(const expr_tape *t, uint32_t res)
{
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = t, .source = TORUS, .source_len = strlen(TORUS)},
        .lo = {-1, -1, -0.5}, .hi = {1, 1, 0.5}, .res = res,
    };
    vod_params_default(&job.vod);
    return job;
}

static engine *make_engine(int workers)
{
    engine_opts o = {.workers = workers, .shm_bytes = (size_t)256 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    return e;
}

/* Run job on e (NULL: serial) into memory; the report and the bytes. */
static vod_membuf run(engine *e, const engine_pipeline_job *job, engine_pipeline_report *r)
{
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    cr_assert_eq(engine_pipeline_run(e, job, &sink, r), 0, "%s", r->err.msg);
    cr_assert_eq(r->err.kind, ENGINE_OK);
    cr_assert_eq(r->stage, ENGINE_PIPELINE_WRITE);
    return m;
}

Test(pipeline, serial_and_engines_give_the_same_bytes)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 80);
    engine_pipeline_report r0, r;
    vod_membuf ref = run(NULL, &job, &r0);
    cr_assert_eq(r0.grid.res[0], 80);
    cr_assert_eq(r0.grid.res[2], 40, "the box's short axis gets cubic voxels");
    cr_assert_eq(r0.st.file_bytes, ref.n);
    cr_assert_gt(r0.voxels, 1000);
    for (int w = 1; w <= 2; w++) {
        engine *e = make_engine(w);
        for (int s = 0; s < 2; s++) {
            job.schedule = (engine_schedule)s;
            vod_membuf m = run(e, &job, &r);
            cr_assert_eq(r.voxels, r0.voxels);
            cr_assert(m.n == ref.n && memcmp(m.p, ref.p, m.n) == 0,
                      "%d workers, schedule %d: other bytes", w, s);
            free(m.p);
        }
        engine_destroy(e);
    }
    free(ref.p);
    expr_tape_free(t);
}

/* The file carries the job's metadata, read back by the reader. */
Test(pipeline, the_file_names_the_job)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 32);
    job.implicit.source_name = "torus.vx";
    engine_pipeline_report r;
    vod_membuf m = run(NULL, &job, &r);
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(m.p, m.n, &f, &err), 0, "%s", err.msg);
    const vod_info *in = vod_get_info(f);
    cr_assert(strstr(in->metadata, "source=" TORUS), "%s", in->metadata);
    cr_assert(strstr(in->metadata, "grid=32x32x16"), "%s", in->metadata);
    cr_assert_eq(in->volume[0], 32);
    vod_close(f);
    free(m.p);
    expr_tape_free(t);
}

Test(pipeline, a_bad_domain_fails_before_any_work)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 32);
    job.hi[1] = job.lo[1];
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_GRID);
    cr_assert(strstr(r.err.msg, "empty on y"), "%s", r.err.msg);
    cr_assert_eq(m.n, 0);
    expr_tape_free(t);
}

static int refusing_write(void *ud, const void *buf, size_t n)
{
    (void)ud, (void)buf, (void)n;
    return -ENOSPC;
}

/* A sink's failure is the sink's, at the write stage, on either path. */
Test(pipeline, a_sink_failure_is_typed_and_staged)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 32);
    vod_sink sink = {refusing_write, NULL};
    engine *e = make_engine(2);
    engine *on[2] = {NULL, e};
    for (int k = 0; k < 2; k++) {
        engine_pipeline_report r;
        cr_assert_eq(engine_pipeline_run(on[k], &job, &sink, &r), -ENOSPC);
        cr_assert_eq(r.err.kind, ENGINE_SINK, "%s", engine_failure_name(r.err.kind));
        cr_assert_eq(r.stage, ENGINE_PIPELINE_WRITE);
        cr_assert_gt(r.voxels, 0, "voxelized before writing");
    }
    engine_destroy(e);
    expr_tape_free(t);
}

/* A cancel set before the job starts: nothing voxelized, typed. */
Test(pipeline, a_cancelled_job_says_so)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 64);
    atomic_int cancel = 1;
    job.cancel = &cancel;
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    engine *e = make_engine(1);
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(e, &job, &sink, &r), -ECANCELED);
    cr_assert_eq(r.err.kind, ENGINE_CANCELLED);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_VOXELIZE);
    cr_assert_eq(m.n, 0);
    engine_destroy(e);
    expr_tape_free(t);
}

/* Progress is one fraction over both stages: it never goes back, and it
 * says 1 once, at the end, after the file is written (the sink has every
 * byte). */
typedef struct {
    int calls, ones, monotonic, levels_while_writing;
    double last;
    size_t bytes_at_one;
    const vod_membuf *m;
} prog;

static void on_prog(void *ud, const engine_progress *p)
{
    prog *g = ud;
    if (p->fraction < g->last || p->fraction > 1.0) g->monotonic = 0;
    if (g->ones) g->monotonic = 0; /* nothing after 1 */
    if (p->fraction >= 1.0) {
        g->ones++;
        g->bytes_at_one = g->m->n;
    }
    if (p->fraction > 0.6 && p->level) g->levels_while_writing++;
    g->last = p->fraction;
    g->calls++;
}

Test(pipeline, progress_says_done_only_when_the_file_is_written)
{
    expr_tape *t = compile(TORUS);
    engine_pipeline_job job = torus_job(t, 256);
    engine *e = make_engine(2);
    vod_membuf m = {0};
    prog g = {.monotonic = 1, .m = &m};
    job.progress = on_prog;
    job.ud = &g;
    vod_sink sink = {vod_mem_write, &m};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(e, &job, &sink, &r), 0, "%s", r.err.msg);
    cr_assert_geq(g.calls, 3);
    cr_assert(g.monotonic);
    cr_assert_eq(g.ones, 1);
    cr_assert_eq(g.bytes_at_one, m.n);
    cr_assert_eq(g.bytes_at_one, r.st.file_bytes);
    cr_assert_eq(g.levels_while_writing, 0);
    cr_assert_null(engine_octree(e), "the job's octree was given back");
    free(m.p);
    engine_destroy(e);
    expr_tape_free(t);
}

/* One job from its description to a VOD sink: see pipeline.h.  What a
 * kind does differently is its engine_kind's pipeline side (master.h),
 * in its own file; this one is the same for every kind. */
#include "pipeline.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "job_meta.h"
#include "master.h"
#include "thread_name.h"

/* The job's VOD parameters: its geometry and metadata (the kind's source
 * and pairs) on the caller's choice of channel, brick, compression and
 * hash. */
static void vod_setup(vod_params *v, const engine_pipeline_job *job, const double lo[3],
                      const double hi[3], const grid_spec *g, char meta[JOB_META_MAX])
{
    const engine_kind *k = job->kind;
    job_meta m = {
        .res = job->res,
        .grid = {g->res[0], g->res[1], g->res[2]},
        .lo = {lo[0], lo[1], lo[2]},
        .hi = {hi[0], hi[1], hi[2]},
    };
    char pairs[160] = "";
    k->meta(job, &m, pairs, sizeof pairs);
    job_meta_format(meta, JOB_META_MAX, &m);
    *v = job->vod;
    v->metadata = meta;
    for (int a = 0; a < 3; a++) {
        v->volume[a] = g->res[a];
        v->voxel_scale[a] = (float)g->vs;
        v->origin[a] = (float)g->lo[a];
    }
}

/* The job's progress as one fraction: the voxelization's to
 * VOXELIZE_SHARE, the VOD's to just under 1; 1 only once the file is
 * written (engine_pipeline_run says it then), never while a stage still runs. */
#define VOXELIZE_SHARE 0.6
#define WRITE_END 0.99

typedef struct {
    const engine_pipeline_job *job;
    engine_pipeline_stage stage;
    uint64_t voxels;   /* the voxelization's, shown while writing */
} staged;

static void on_stage_progress(void *ud, const engine_progress *p)
{
    staged *s = ud;
    engine_progress q = *p;
    if (s->stage == ENGINE_PIPELINE_VOXELIZE) {
        q.fraction = VOXELIZE_SHARE * p->fraction;
    } else {
        q.fraction = VOXELIZE_SHARE + (WRITE_END - VOXELIZE_SHARE) * p->fraction;
        q.level = 0;
        q.voxels = s->voxels;
    }
    s->job->progress(s->job->ud, &q);
}

/* The engine's figures every kind has, into r (the kind's own block is
 * the kind's to copy). */
static void engine_figures_common(engine_pipeline_report *r, const engine_result *er)
{
    r->voxels = er->voxels;
    r->octants = er->octants;
    r->restarts = er->restarts;
    r->stalls = er->stalls;
    r->offered = er->offered;
    r->t_voxelize = er->seconds;
    r->master_cpu = er->master_cpu;
    r->worker_cpu = er->worker_cpu;
}

/* The kind's voxelization on e, then the VOD written. */
static int run_engine(engine *e, const engine_kind *k, engine_pipeline_job *run,
                      const vod_params *v, vod_sink *sink, engine_pipeline_report *r)
{
    staged sp = {.job = run, .stage = ENGINE_PIPELINE_VOXELIZE};
    engine_sched_watch w = {.progress = run->progress ? on_stage_progress : NULL, .ud = &sp,
                     .cancel = run->cancel};
    engine_result er;
    memset(&er, 0, sizeof er);
    r->stage = ENGINE_PIPELINE_VOXELIZE;
    r->workers = engine_workers(e);
    thread_name("engine");
    int rc = k->voxelize(e, run, &w, &er, r);
    engine_figures_common(r, &er);
    if (rc && r->err.kind) return rc; /* the kind said why */
    if (rc) return engine_pipeline_fail(r, er.err.kind, rc, "%s", er.err.msg);
    r->stage = ENGINE_PIPELINE_WRITE;
    sp.stage = ENGINE_PIPELINE_WRITE;
    sp.voxels = er.voxels;
    thread_name("write");
    double t0 = clock_now();
    rc = engine_write_vod_watched(e, v, sink, &r->st, &r->err, &w);
    r->t_write = clock_now() - t0;
    if (!rc && run->progress) {
        engine_progress done = {.fraction = 1.0, .voxels = er.voxels,
                                .seconds = r->t_voxelize + r->t_write};
        run->progress(run->ud, &done);
    }
    return rc;
}

int engine_pipeline_plan(const engine_pipeline_job *job, engine_pipeline_report *r, vod_params *v,
                  char meta[JOB_META_MAX])
{
    memset(r, 0, sizeof *r);
    r->stage = ENGINE_PIPELINE_GRID;
    const engine_kind *k = job->kind;
    if (!k) return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no expression or mesh");
    double lo[3], hi[3];
    memcpy(lo, job->lo, sizeof lo);
    memcpy(hi, job->hi, sizeof hi);
    int rc = k->domain(job, lo, hi, r); /* its checks, and its domain if its own */
    if (rc) return rc;
    err_info err = {0};
    rc = grid_make(lo, hi, job->res, &r->grid, &err);
    if (rc) return engine_pipeline_fail(r, ENGINE_BAD_JOB, rc, "%s", err.msg);
    vod_setup(v, job, lo, hi, &r->grid, meta); /* the job as asked for */
    return 0;
}

/* engine_pipeline_run from t0 on; r->t_job set before the engine's release. */
static int engine_pipeline_stages(engine *e, const engine_pipeline_job *job, vod_sink *sink,
                           double t0, engine_pipeline_report *r)
{
    char meta[JOB_META_MAX];
    vod_params v;
    int rc = engine_pipeline_plan(job, r, &v, meta);
    if (rc) return rc;
    const engine_kind *k = job->kind;
    engine_pipeline_job run = *job; /* the kind may change it (a mesh's repair not needed) */
    csg_tree *owned = NULL; /* a kind's job run as another's (rewrite) */
    if (k->rewrite && (rc = k->rewrite(&run, &owned)))
        return engine_pipeline_fail(r, ENGINE_FAULT, rc, "%s", strerror(-rc));
    k = run.kind;
    if (!e) {
        rc = k->serial(&run, &v, sink, r);
    } else {
        rc = run_engine(e, k, &run, &v, sink, r);
        r->t_job = clock_now() - t0; /* the release below is the engine's */
        engine_release(e); /* the job's pages go back, its result's too */
    }
    csg_tree_free(owned);
    return rc;
}

int engine_pipeline_run(engine *e, const engine_pipeline_job *job, vod_sink *sink,
                 engine_pipeline_report *r)
{
    double t0 = clock_now();
    int rc = engine_pipeline_stages(e, job, sink, t0, r);
    if (!r->t_job) r->t_job = clock_now() - t0;
    return rc;
}

void engine_pipeline_describe(const engine_pipeline_job *job, const engine_pipeline_report *r, char *buf,
                       size_t len)
{
    const engine_kind *k = job->kind;
    if (len) buf[0] = 0;
    if (k && k->summary) k->summary(job, r, buf, len);
}

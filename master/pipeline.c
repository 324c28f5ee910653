/* One job from its description to a VOD sink: see pipeline.h. */
#include "pipeline.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "clock.h"
#include "job_meta.h"
#include "master.h"
#include "subdiv.h"

#define SERIAL_CELLS (1u << 27) /* 4 GiB of address space, not of memory */

__attribute__((format(printf, 4, 5))) static int fail(pipeline_report *r,
                                                      engine_failure f, int rc,
                                                      const char *fmt, ...)
{
    r->err.failure = f;
    r->err.code = rc;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->err.message, sizeof r->err.message, fmt, ap);
    va_end(ap);
    return rc;
}

/* The job's VOD parameters: its geometry and metadata on the caller's
 * choice of channel, brick, compression and hash. */
static void vod_setup(vod_params *v, const pipeline_job *job, const grid_spec *g,
                      char meta[JOB_META_MAX])
{
    job_meta m = {
        .source = job->implicit.source, .source_len = job->implicit.source_len,
        .source_name = job->implicit.source_name, .res = job->res,
        .grid = {g->res[0], g->res[1], g->res[2]},
        .lo = {job->lo[0], job->lo[1], job->lo[2]},
        .hi = {job->hi[0], job->hi[1], job->hi[2]},
    };
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
 * written (pipeline_run says it then), never while a stage still runs. */
#define VOXELIZE_SHARE 0.6
#define WRITE_END 0.99

typedef struct {
    const pipeline_job *job;
    pipeline_stage stage;
    uint64_t voxels;   /* the voxelization's, shown while writing */
} staged;

static void on_stage_progress(void *ud, const engine_progress *p)
{
    staged *s = ud;
    engine_progress q = *p;
    if (s->stage == PIPELINE_VOXELIZE) {
        q.fraction = VOXELIZE_SHARE * p->fraction;
    } else {
        q.fraction = VOXELIZE_SHARE + (WRITE_END - VOXELIZE_SHARE) * p->fraction;
        q.level = 0;
        q.voxels = s->voxels;
    }
    s->job->progress(s->job->ud, &q);
}

static int run_engine(engine *e, const pipeline_job *job, const vod_params *v,
                      vod_sink *sink, pipeline_report *r)
{
    staged sp = {.job = job, .stage = PIPELINE_VOXELIZE};
    void (*prog)(void *, const engine_progress *) = job->progress ? on_stage_progress : NULL;
    engine_job ej = {.tape = job->implicit.tape, .grid = r->grid,
                     .schedule = job->schedule, .progress = prog,
                     .ud = &sp, .cancel = job->cancel};
    engine_result er;
    r->stage = PIPELINE_VOXELIZE;
    int rc = engine_voxelize(e, &ej, &er);
    r->voxels = er.voxels;
    r->octants = er.octants;
    r->restarts = er.restarts;
    r->stalls = er.stalls;
    r->t_voxelize = er.seconds;
    r->master_cpu = er.master_cpu;
    r->worker_cpu = er.worker_cpu;
    if (rc) return fail(r, er.failure, rc, "%s", er.error);
    r->stage = PIPELINE_WRITE;
    sp.stage = PIPELINE_WRITE;
    sp.voxels = er.voxels;
    double t0 = clock_now();
    rc = engine_write_vod_watched(e, v, sink, &r->st, &r->err, prog, &sp, job->cancel);
    r->t_write = clock_now() - t0;
    if (!rc && job->progress) {
        engine_progress done = {.fraction = 1.0, .voxels = er.voxels,
                                .seconds = r->t_voxelize + r->t_write};
        job->progress(job->ud, &done);
    }
    return rc;
}

/* The sink as the serial writer sees it: what the caller's sink said is
 * the sink's failure, whatever message the writer puts around it. */
typedef struct {
    vod_sink *inner;
    int rc;
} watched_sink;

static int watched_write(void *ud, const void *buf, size_t n)
{
    watched_sink *w = ud;
    int rc = w->inner->write(w->inner->ud, buf, n);
    if (rc) w->rc = rc;
    return rc;
}

/* The serial algorithm: its octree in a sparse private mapping, touched
 * only as cells are handed out. */
static int run_serial(const pipeline_job *job, const vod_params *v,
                      vod_sink *sink, pipeline_report *r)
{
    size_t bytes = octree_arena_bytes(SERIAL_CELLS);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    r->stage = PIPELINE_VOXELIZE;
    if (arena == MAP_FAILED)
        return fail(r, ENGINE_FAULT, -errno, "cannot map the octree: %s",
                    strerror(errno));
    octree t;
    octree_init(&t, arena, SERIAL_CELLS, r->grid.depth);
    double t0 = clock_now();
    int rc = subdiv_serial(job->implicit.tape, &r->grid, &t);
    r->t_voxelize = clock_now() - t0;
    r->voxels = t.voxels;
    if (rc == -ENOMEM)
        fail(r, ENGINE_LIMIT, rc, "the octree outgrew its 4 GiB arena");
    else if (rc)
        fail(r, ENGINE_FAULT, rc, "%s", strerror(-rc));
    if (!rc) {
        r->stage = PIPELINE_WRITE;
        watched_sink w = {sink, 0};
        vod_sink ws = {watched_write, &w};
        char err[sizeof r->err.message] = "";
        t0 = clock_now();
        rc = vod_write_octree(&t, v, &ws, &r->st, err, sizeof err);
        r->t_write = clock_now() - t0;
        if (rc && w.rc == rc)
            fail(r, ENGINE_SINK, rc, "%s", strerror(-rc));
        else if (rc)
            fail(r, engine_vod_failure(rc, 1), rc, "%s", err);
    }
    munmap(arena, bytes);
    return rc;
}

int pipeline_run(engine *e, const pipeline_job *job, vod_sink *sink,
                 pipeline_report *r)
{
    memset(r, 0, sizeof *r);
    r->stage = PIPELINE_GRID;
    if (job->kind != PIPELINE_IMPLICIT || !job->implicit.tape)
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no expression");
    char err[sizeof r->err.message];
    int rc = grid_make(job->lo, job->hi, job->res, &r->grid, err, sizeof err);
    if (rc) return fail(r, ENGINE_BAD_JOB, rc, "%s", err);
    char meta[JOB_META_MAX];
    vod_params v;
    vod_setup(&v, job, &r->grid, meta);
    if (!e) return run_serial(job, &v, sink, r);
    rc = run_engine(e, job, &v, sink, r);
    engine_release(e); /* the job's pages go back, the octree's too */
    return rc;
}

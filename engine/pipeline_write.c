/* What the kinds' pipeline side shares with the pipeline (master.h): the
 * report's failure, the serial write stage and the distance's band.  A
 * file of its own: the kinds call it and the pipeline calls the kinds. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "clock.h"
#include "master.h"
#include "voxel.h"

int engine_pipeline_fail(engine_pipeline_report *r, engine_failure f, int rc, const char *fmt, ...)
{
    r->err.kind = f;
    va_list ap;
    va_start(ap, fmt);
    err_vset(&r->err, rc, fmt, ap);
    va_end(ap);
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

int engine_pipeline_write_serial(octree *t, vod_source *s, const vod_params *v, vod_sink *sink,
                          engine_pipeline_report *r)
{
    r->stage = ENGINE_PIPELINE_WRITE;
    watched_sink w = {sink, 0};
    vod_sink ws = {watched_write, &w};
    err_info err = {0};
    double t0 = clock_now();
    int rc = t ? vod_write_octree(t, v, &ws, &r->st, &err)
               : vod_write(s, v, &ws, &r->st, &err);
    r->t_write = clock_now() - t0;
    if (rc && w.rc == rc) return engine_pipeline_fail(r, ENGINE_SINK, rc, "%s", strerror(-rc));
    if (rc) return engine_pipeline_fail(r, engine_vod_failure(rc, 1), rc, "%s", err.msg);
    return 0;
}

uint32_t engine_pipeline_band(const engine_pipeline_job *job)
{
    return job->band ? job->band : VOXEL_BAND_DEFAULT;
}

/* proto_check_reply — the checks of what a server says (the client's side of
 * proto_check.h); the requests and the shared pieces are in proto_check.c. */
#include "proto_check.h"
#include "proto_check_int.h"

#include <math.h>
#include <stdint.h>

#include "frame.h"


static int check_seconds(double s, const char *what, proto_error *e)
{
    if (!isfinite(s) || s < 0)
        return proto_bad(e, INVALID, "%s %g is not a finite number of seconds >= 0", what, s);
    return 0;
}

static int check_fraction(double f, proto_error *e)
{
    if (!(f >= 0 && f <= 1)) return proto_bad(e, INVALID, "fraction %g is not in [0, 1]", f);
    return 0;
}

static int check_job_id(uint64_t id, const char *what, proto_error *e)
{
    return id ? 0 : proto_bad(e, INVALID, "%s has no job id", what);
}

/* Every limit in the range a daemon's config accepts (the table's), and
 * a chunk within a frame. */
static int check_limits(const Voxd__Limits *l, proto_error *e)
{
    if (!l) return proto_bad(e, INVALID, "hello_ok has no limits");
    proto_limits lim;
    proto_limits_from_hello(l, &lim);
    for (size_t i = 0; i < proto_n_limits; i++) {
        const proto_limit_info *r = &proto_limit_table[i];
        uint64_t v = proto_limit_get(&lim, i);
        if (v < r->min || v > r->max)
            return proto_bad(e, INVALID, "server %s %llu is outside %llu to %llu", r->name,
                             (unsigned long long)v, (unsigned long long)r->min,
                             (unsigned long long)r->max);
    }
    if (l->chunk_size > l->max_frame - PROTO_FRAME_CHUNK_OVERHEAD)
        return proto_bad(e, INVALID, "server chunk_size %u does not fit its max_frame %u",
                         l->chunk_size, l->max_frame);
    return 0;
}

static int check_hello_ok(const Voxd__HelloOk *h, proto_error *e)
{
    int rc;
    if (h->version != PROTO_VERSION)
        return proto_bad(e, INVALID, "server speaks protocol version %u, this client %u",
                         h->version, PROTO_VERSION);
    if ((rc = proto_check_text(h->server, PROTO_MAX_NAME, 0, "server name", e))) return rc;
    if (h->workers > PROTO_MAX_WORKERS)
        return proto_bad(e, INVALID, "server reports %u workers, limit %u", h->workers,
                         PROTO_MAX_WORKERS);
    return check_limits(h->limits, e);
}

static int check_progress(const Voxd__Progress *p, proto_error *e)
{
    int rc = check_job_id(p->job_id, "progress", e);
    if (rc || (rc = check_fraction(p->fraction, e))) return rc;
    if (p->level > PROTO_MAX_LEVEL)
        return proto_bad(e, INVALID, "progress level %u is over %u", p->level, PROTO_MAX_LEVEL);
    return 0;
}

static int check_chunk(const Voxd__ResultChunk *c, const proto_limits *lim,
                       proto_error *e)
{
    int rc = check_job_id(c->job_id, "chunk", e);
    if (rc) return rc;
    if (c->data.len == 0) return proto_bad(e, INVALID, "chunk at offset %llu is empty",
                                           (unsigned long long)c->offset);
    if (c->data.len > lim->chunk_size)
        return proto_bad(e, INVALID, "chunk of %zu bytes is over chunk_size %u", c->data.len,
                         lim->chunk_size);
    if (c->offset > lim->max_result_bytes || c->data.len > lim->max_result_bytes - c->offset)
        return proto_bad(e, LIMIT, "chunk at offset %llu passes max_result_bytes %llu",
                         (unsigned long long)c->offset,
                         (unsigned long long)lim->max_result_bytes);
    return 0;
}

/* The grid of a job: what grid_make (common/grid.h) makes (res within max_res, the
 * octree's depth the smallest that holds it, a finite cubic voxel). */
static int check_grid(const Voxd__Grid *g, const proto_limits *lim, proto_error *e)
{
    if (!g) return proto_bad(e, INVALID, "summary has no grid");
    if (g->n_res != 3 || g->n_origin != 3)
        return proto_bad(e, INVALID, "summary grid has %zu res and %zu origin values, not 3",
                         g->n_res, g->n_origin);
    uint32_t top = 0;
    for (int a = 0; a < 3; a++) {
        if (g->res[a] == 0 || g->res[a] > lim->max_res)
            return proto_bad(e, INVALID, "summary grid res %u is outside 1 to %u", g->res[a],
                             lim->max_res);
        if (g->res[a] > top) top = g->res[a];
        if (!isfinite(g->origin[a]))
            return proto_bad(e, INVALID, "summary grid origin %g is not finite", g->origin[a]);
    }
    uint32_t depth = 1;
    while (((uint64_t)1 << depth) < top) depth++;
    if (g->depth != depth)
        return proto_bad(e, INVALID, "summary grid depth %u, where res %u needs %u", g->depth, top,
                         depth);
    if (!isfinite(g->voxel_size) || !(g->voxel_size > 0))
        return proto_bad(e, INVALID, "summary grid voxel_size %g is not finite and > 0",
                         g->voxel_size);
    return 0;
}

static int check_summary(const Voxd__Summary *s, const proto_limits *lim, proto_error *e)
{
    int rc = check_job_id(s->job_id, "summary", e);
    if (rc || (rc = check_grid(s->grid, lim, e))) return rc;
    if (s->file_bytes == 0 || s->file_bytes > lim->max_result_bytes)
        return proto_bad(e, INVALID, "summary file_bytes %llu is outside 1 to %llu",
                         (unsigned long long)s->file_bytes,
                         (unsigned long long)lim->max_result_bytes);
    if ((rc = check_seconds(s->seconds_queued, "seconds_queued", e)) ||
        (rc = check_seconds(s->seconds_voxelize, "seconds_voxelize", e)))
        return rc;
    return check_seconds(s->seconds_write, "seconds_write", e);
}

static int check_error(const Voxd__Error *x, proto_error *e)
{
    if (x->code == VOXD__ERROR_CODE__ERROR_CODE_UNSPECIFIED ||
        (unsigned)x->code > VOXD__ERROR_CODE__INTERNAL)
        return proto_bad(e, INVALID, "unknown error code %d", (int)x->code);
    return proto_check_text(x->message, PROTO_MAX_MESSAGE, 1, "error message", e);
}

static int check_worker(const Voxd__WorkerStatus *w, size_t i, proto_error *e)
{
    if (!w) return proto_bad(e, INVALID, "worker %zu is missing", i);
    if (w->pid == 0 || w->pid > INT32_MAX)
        return proto_bad(e, INVALID, "worker %zu has pid %u", i, w->pid);
    if (w->cpu < -1 || w->cpu >= PROTO_MAX_CPUS)
        return proto_bad(e, INVALID, "worker %zu has cpu %d", i, w->cpu);
    if (w->state == VOXD__WORKER_STATE__WORKER_STATE_UNSPECIFIED ||
        (unsigned)w->state > VOXD__WORKER_STATE__WORKER_STATE_STALLED)
        return proto_bad(e, INVALID, "worker %zu has unknown state %d", i, (int)w->state);
    if (w->stalls > w->replaced)
        return proto_bad(e, INVALID, "worker %zu has %u stalls but %u replacements", i,
                         w->stalls, w->replaced);
    if (!isfinite(w->voxels_per_second) || w->voxels_per_second < 0)
        return proto_bad(e, INVALID, "worker %zu has voxels_per_second %g", i,
                         w->voxels_per_second);
    return 0;
}

static int check_job_status(const Voxd__JobStatus *j, proto_error *e)
{
    int rc = check_job_id(j->job_id, "status job", e);
    if (rc || (rc = check_fraction(j->fraction, e)) ||
        (rc = check_seconds(j->seconds, "job seconds", e)))
        return rc;
    if (j->kind == VOXD__JOB_KIND__JOB_KIND_UNSPECIFIED ||
        (unsigned)j->kind > VOXD__JOB_KIND__JOB_KIND_CSG)
        return proto_bad(e, INVALID, "job %llu has unknown kind %d", (unsigned long long)j->job_id,
                         (int)j->kind);
    if (j->state == VOXD__JOB_STATE__JOB_STATE_UNSPECIFIED ||
        (unsigned)j->state > VOXD__JOB_STATE__JOB_STATE_RUNNING)
        return proto_bad(e, INVALID, "job %llu has unknown state %d", (unsigned long long)j->job_id,
                         (int)j->state);
    return 0;
}

static int check_status(const Voxd__StatusReply *s, proto_error *e)
{
    int rc = check_seconds(s->uptime, "uptime", e);
    if (rc) return rc;
    if (s->n_workers > PROTO_MAX_WORKERS)
        return proto_bad(e, INVALID, "status lists %zu workers, limit %u", s->n_workers,
                         PROTO_MAX_WORKERS);
    for (size_t i = 0; i < s->n_workers; i++)
        if ((rc = check_worker(s->workers[i], i, e))) return rc;
    if (s->n_jobs > PROTO_MAX_STATUS_JOBS)
        return proto_bad(e, INVALID, "status lists %zu jobs, limit %u", s->n_jobs,
                         PROTO_MAX_STATUS_JOBS);
    for (size_t i = 0; i < s->n_jobs; i++)
        if ((rc = check_job_status(s->jobs[i], e))) return rc;
    if (!s->running) return 0;
    if ((rc = check_job_id(s->running->job_id, "running job", e)) ||
        (rc = check_fraction(s->running->fraction, e)))
        return rc;
    return check_seconds(s->running->seconds, "running seconds", e);
}

static const void *reply_body(const Voxd__Reply *r)
{
    switch (r->msg_case) {
    case VOXD__REPLY__MSG_HELLO_OK: return r->hello_ok;
    case VOXD__REPLY__MSG_ACCEPTED: return r->accepted;
    case VOXD__REPLY__MSG_PROGRESS: return r->progress;
    case VOXD__REPLY__MSG_CHUNK: return r->chunk;
    case VOXD__REPLY__MSG_SUMMARY: return r->summary;
    case VOXD__REPLY__MSG_ERROR: return r->error;
    case VOXD__REPLY__MSG_STATUS: return r->status;
    case VOXD__REPLY__MSG_PONG: return r->pong;
    default: return NULL;
    }
}

int proto_check_reply(const Voxd__Reply *r, const proto_limits *lim, proto_error *err)
{
    int rc;
    if (!r) return proto_bad(err, INVALID, "malformed reply");
    if (r->msg_case == VOXD__REPLY__MSG__NOT_SET)
        return proto_bad(err, INVALID, "reply of no type this client knows (protocol version %u)",
                         PROTO_VERSION);
    if (!reply_body(r))
        return proto_bad(err, INVALID, "reply of unknown type %d", (int)r->msg_case);
    switch (r->msg_case) {
    case VOXD__REPLY__MSG_HELLO_OK: rc = check_hello_ok(r->hello_ok, err); break;
    case VOXD__REPLY__MSG_ACCEPTED: rc = check_job_id(r->accepted->job_id, "accepted", err); break;
    case VOXD__REPLY__MSG_PROGRESS: rc = check_progress(r->progress, err); break;
    case VOXD__REPLY__MSG_CHUNK: rc = check_chunk(r->chunk, lim, err); break;
    case VOXD__REPLY__MSG_SUMMARY: rc = check_summary(r->summary, lim, err); break;
    case VOXD__REPLY__MSG_ERROR: rc = check_error(r->error, err); break;
    case VOXD__REPLY__MSG_STATUS: rc = check_status(r->status, err); break;
    default: rc = 0; break; /* Pong */
    }
    return rc ? rc : proto_ok(err);
}

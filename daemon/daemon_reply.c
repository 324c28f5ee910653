/* The replies the daemon sends, built on the stack and framed by
 * daemon_client_send. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "clock.h"
#include "daemon.h"
#include "err.h"
#include "pipeline.h"
#include "proto_check.h"

void daemon_clean_text(char *s)
{
    for (unsigned char *p = (unsigned char *)s; *p; p++)
        if ((*p < 0x20 && *p != '\n' && *p != '\t') || *p >= 0x7f) *p = '?';
}

int daemon_client_error(daemon_client *c, uint64_t job_id, int code, const char *fmt, ...)
{
    char msg[PROTO_MAX_MESSAGE];
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(msg, sizeof msg, 0, fmt, ap);
    va_end(ap);
    daemon_clean_text(msg);
    Voxd__Error e = VOXD__ERROR__INIT;
    e.job_id = job_id;
    e.code = (Voxd__ErrorCode)code;
    e.message = msg;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ERROR;
    r.error = &e;
    return daemon_client_send(c, &r);
}

int daemon_send_hello_ok(daemon_client *c)
{
    proto_limits lim;
    config_proto_limits(&c->d->cfg, &lim);
    Voxd__Limits l = VOXD__LIMITS__INIT;
    proto_limits_to_hello(&lim, &l);
    Voxd__HelloOk h = VOXD__HELLO_OK__INIT;
    h.version = PROTO_VERSION;
    h.server = (char *)DAEMON_SERVER_NAME;
    h.limits = &l;
    pthread_mutex_lock(&c->d->mu);
    h.workers = (uint32_t)c->d->nworkers;
    pthread_mutex_unlock(&c->d->mu);
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_HELLO_OK;
    r.hello_ok = &h;
    return daemon_client_send(c, &r);
}

int daemon_send_accepted(daemon_client *c, uint64_t id, uint32_t pos)
{
    Voxd__Accepted a = VOXD__ACCEPTED__INIT;
    a.job_id = id;
    a.queue_position = pos;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ACCEPTED;
    r.accepted = &a;
    return daemon_client_send(c, &r);
}

int daemon_send_progress(daemon_client *c, const daemon_job *j, const engine_progress *p)
{
    Voxd__Progress m = VOXD__PROGRESS__INIT;
    m.job_id = j->id;
    m.fraction = p->fraction >= 0 && p->fraction <= 1 ? p->fraction : 0;
    m.level = p->level > 0 ? (uint32_t)p->level : 0;
    m.voxels = p->voxels;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PROGRESS;
    r.progress = &m;
    return daemon_client_send(c, &r);
}

int daemon_send_chunk(daemon_client *c, const daemon_job *j, const uint8_t *data, size_t n)
{
    Voxd__ResultChunk m = VOXD__RESULT_CHUNK__INIT;
    m.job_id = j->id;
    m.offset = j->sent;
    m.data.data = (uint8_t *)data;
    m.data.len = n;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_CHUNK;
    r.chunk = &m;
    return daemon_client_send(c, &r);
}

static double nonneg(double s)
{
    return s > 0 ? s : 0;
}

int daemon_send_summary(daemon_client *c, const daemon_job *j)
{
    const grid_spec *g = &j->grid;
    uint32_t res[3] = {g->res[0], g->res[1], g->res[2]};
    double origin[3] = {g->lo[0], g->lo[1], g->lo[2]};
    Voxd__Grid grid = VOXD__GRID__INIT;
    grid.res = res;
    grid.n_res = 3;
    grid.depth = (uint32_t)g->depth;
    grid.voxel_size = g->vs;
    grid.origin = origin;
    grid.n_origin = 3;
    Voxd__Summary m = VOXD__SUMMARY__INIT;
    m.grid = &grid;
    m.job_id = j->id;
    m.voxels = j->voxels;
    m.bricks = j->st.bricks;
    m.file_bytes = j->size;
    m.crc32 = j->st.crc32;
    m.seconds_queued = nonneg(j->t_start - j->t_submit);
    m.seconds_voxelize = nonneg(j->t_voxelize);
    m.seconds_write = nonneg(j->t_write);
    m.mpi_ranks = j->mpi_ranks;
    daemon_submit_summary(j, &m);
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_SUMMARY;
    r.summary = &m;
    return daemon_client_send(c, &r);
}

/* The engine's view of the worker when the engine thread last looked
 * (every 0.1 s of a job, and at its end). */
static Voxd__WorkerState worker_state(const daemon_worker_snap *s, int running)
{
    if (s->pid <= 0 || s->state == ENGINE_WORKER_STARTING)
        return VOXD__WORKER_STATE__WORKER_STATE_STARTING;
    if (!running) return VOXD__WORKER_STATE__WORKER_STATE_IDLE;
    return s->state == ENGINE_WORKER_STALLED ? VOXD__WORKER_STATE__WORKER_STATE_STALLED
                                             : VOXD__WORKER_STATE__WORKER_STATE_BUSY;
}

/* Under mu: the workers as the engine thread last saw them. */
static size_t fill_workers(daemon_ctx *d, Voxd__WorkerStatus *ws, Voxd__WorkerStatus **wp)
{
    size_t n = 0;
    for (int i = 0; i < d->nworkers; i++) {
        const daemon_worker_snap *s = &d->workers[i];
        if (s->pid <= 0) continue; /* never started: nothing to show */
        voxd__worker_status__init(&ws[n]);
        ws[n].pid = (uint32_t)s->pid;
        ws[n].cpu = s->cpu;
        ws[n].state = worker_state(s, d->running != NULL);
        ws[n].jobs = s->jobs;
        ws[n].voxels_per_second = s->vps;
        ws[n].replaced = s->replaced;
        ws[n].stalls = s->stalls;
        wp[n] = &ws[n];
        n++;
    }
    return n;
}

static void fill_job(const daemon_job *j, int state, double now, Voxd__JobStatus *js)
{
    voxd__job_status__init(js);
    js->job_id = j->id;
    js->uid = (uint32_t)j->uid;
    js->kind = daemon_submit_status_kind(j);
    js->res = j->res;
    js->state = state;
    double f = state == VOXD__JOB_STATE__JOB_STATE_RUNNING ? j->progress.fraction : 0;
    js->fraction = f >= 0 && f <= 1 ? f : 0;
    js->seconds = nonneg(now - (state == VOXD__JOB_STATE__JOB_STATE_RUNNING ? j->t_start
                                                                           : j->t_submit));
}

/* The running job, then the queued ones in their order (under d->mu). */
static size_t fill_jobs(const daemon_ctx *d, double now, Voxd__JobStatus *js,
                        Voxd__JobStatus **jp)
{
    size_t n = 0;
    if (d->running) fill_job(d->running, VOXD__JOB_STATE__JOB_STATE_RUNNING, now, &js[n++]);
    for (const daemon_job *j = d->queue; j && n < PROTO_MAX_STATUS_JOBS; j = j->next)
        fill_job(j, VOXD__JOB_STATE__JOB_STATE_QUEUED, now, &js[n++]);
    for (size_t i = 0; i < n; i++) jp[i] = &js[i];
    return n;
}

int daemon_send_status(daemon_client *c)
{
    static Voxd__JobStatus js[PROTO_MAX_STATUS_JOBS]; /* loop thread only */
    static Voxd__JobStatus *jp[PROTO_MAX_STATUS_JOBS];
    daemon_ctx *d = c->d;
    static Voxd__WorkerStatus ws[ENGINE_MAX_WORKERS]; /* loop thread only */
    Voxd__WorkerStatus *wp[ENGINE_MAX_WORKERS];
    Voxd__StatusReply s = VOXD__STATUS_REPLY__INIT;
    Voxd__RunningJob rj = VOXD__RUNNING_JOB__INIT;
    double now = clock_now();
    s.uptime = nonneg(now - d->t_start);
    s.clients = d->nclients;
    pthread_mutex_lock(&d->mu);
    s.n_workers = fill_workers(d, ws, wp);
    s.workers = wp;
    s.queued = d->nqueued;
    s.n_jobs = fill_jobs(d, now, js, jp);
    s.jobs = jp;
    if (d->running) {
        rj.job_id = d->running->id;
        rj.uid = (uint32_t)d->running->uid;
        double f = d->running->progress.fraction;
        rj.fraction = f >= 0 && f <= 1 ? f : 0;
        rj.seconds = nonneg(now - d->running->t_start);
        s.running = &rj;
    }
    pthread_mutex_unlock(&d->mu);
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_STATUS;
    r.status = &s;
    return daemon_client_send(c, &r);
}

int daemon_send_pong(daemon_client *c, uint64_t token)
{
    Voxd__Pong p = VOXD__PONG__INIT;
    p.token = token;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PONG;
    r.pong = &p;
    return daemon_client_send(c, &r);
}

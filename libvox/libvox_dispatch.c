/* Every reply the daemon sends, checked against the conversation (a reply
 * nobody asked for, a second end, progress after the result began end the
 * connection as -EPROTO), then recorded in the client's state. */
#include "vox.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "libvox_int.h"
#include "proto_check.h"

static void answer(vox_client *c, int code, uint64_t job, const char *msg)
{
    c->answered = 1;
    c->ans.code = code;
    c->ans.job_id = job;
    snprintf(c->ans.message, sizeof c->ans.message, "%s", msg ? msg : "");
}

static int on_error(vox_client *c, const Voxd__Error *m)
{
    int code = -(VOX_ESERVER_BASE + (int)m->code);
    const char *msg = m->message && *m->message ? m->message : vox_strerror(code);
    vjob *j = m->job_id ? libvox_find_job(c, m->job_id) : NULL;
    if (j && !j->done) {
        j->done = 1;
        if (!j->local_err) libvox_set_error(&j->result, code, j->id, "%s", msg);
        libvox_job_ended(c, j);
        return 0;
    }
    /* A job of ours that has ended: a late answer to a cancel of it is no
     * news; anything else is a second end. */
    if (j) {
        if (libvox_ignored(c, m->job_id)) return 0;
        return libvox_fail(c, -EPROTO, "voxd sent a second end for job %llu",
                    (unsigned long long)m->job_id);
    }
    /* What the daemon says about a cancel this client waits on. */
    if (c->pending == P_CANCEL && !c->answered &&
        (m->job_id == 0 || m->job_id == c->cancel_job)) {
        answer(c, code, m->job_id, msg);
        return 0;
    }
    if (m->job_id && libvox_ignored(c, m->job_id)) return 0;
    /* A refused request; only a Submit's refusal may name a job id (the
     * one the job would have had).  While draining an upload, an Error
     * with no job is about a chunk sent after its job ended: no news. */
    if (c->pending == P_DRAIN && m->job_id == 0) return 0;
    if (c->pending != P_NONE && !c->answered &&
        (m->job_id == 0 || c->pending == P_SUBMIT)) {
        answer(c, code, m->job_id, msg);
        return 0;
    }
    if (m->job_id)
        return libvox_fail(c, -EPROTO, "voxd sent an error for job %llu, which is not a job of this connection: %s",
                    (unsigned long long)m->job_id, msg);
    /* About the connection: kept to say why, should the daemon close it. */
    c->note_code = (int)m->code;
    snprintf(c->note, sizeof c->note, "%s", msg);
    return 0;
}

static int on_hello_ok(vox_client *c, const Voxd__HelloOk *m)
{
    if (c->ready || c->pending != P_HELLO)
        return libvox_fail(c, -EPROTO, "voxd sent a second hello");
    const Voxd__Limits *l = m->limits;
    proto_limits_from_hello(l, &c->lim);
    proto_frame_decoder_set_max(&c->dec, l->max_frame);
    vox_server_info *i = &c->info;
    snprintf(i->name, sizeof i->name, "%s", m->server ? m->server : "");
    i->version = m->version;
    i->workers = m->workers;
#define INFO_LIMIT(name, type, def, min, max, unit, doc) i->name = l->name;
    VOX_LIMITS(INFO_LIMIT)
#undef INFO_LIMIT
    c->ready = 1;
    answer(c, 0, 0, NULL);
    return 0;
}

static int on_accepted(vox_client *c, const Voxd__Accepted *m)
{
    if (c->pending != P_SUBMIT || c->answered)
        return libvox_fail(c, -EPROTO, "voxd accepted job %llu, which was never submitted",
                    (unsigned long long)m->job_id);
    if (libvox_find_job(c, m->job_id))
        return libvox_fail(c, -EPROTO, "voxd accepted job %llu a second time",
                    (unsigned long long)m->job_id);
    vjob *j = calloc(1, sizeof *j);
    if (!j) return libvox_fail(c, -ENOMEM, "out of memory");
    j->id = m->job_id;
    j->fd = -1;
    j->sink = SINK_SPOOL;
    j->t_accepted = libvox_mono();
    j->queue_position = m->queue_position;
    j->next = c->jobs;
    c->jobs = j;
    c->ans_job = m->job_id;
    c->ans_qpos = m->queue_position;
    answer(c, 0, m->job_id, NULL);
    return 0;
}

static int on_progress(vox_client *c, const Voxd__Progress *m)
{
    vjob *j = libvox_find_job(c, m->job_id);
    if (!j || j->done)
        return libvox_fail(c, -EPROTO, "voxd sent progress for job %llu, which %s",
                    (unsigned long long)m->job_id,
                    j ? "has ended" : "is not a job of this connection");
    if (j->received)
        return libvox_fail(c, -EPROTO, "voxd sent progress for job %llu after its result began",
                    (unsigned long long)m->job_id);
    j->fraction = m->fraction;
    j->level = (int)m->level;
    j->voxels = m->voxels;
    j->progress_new = 1;
    return 0;
}

static int on_status(vox_client *c, const Voxd__StatusReply *m)
{
    if (c->pending != P_STATUS || c->answered)
        return libvox_fail(c, -EPROTO, "voxd sent a status nobody asked for");
    vox_status_info *s = &c->ans_status;
    memset(s, 0, sizeof *s);
    s->uptime = m->uptime;
    s->queued = m->queued;
    s->clients = m->clients;
    if (m->n_workers) {
        s->workers = calloc(m->n_workers, sizeof *s->workers);
        if (!s->workers) return libvox_fail(c, -ENOMEM, "out of memory");
        s->n_workers = m->n_workers;
        for (size_t i = 0; i < m->n_workers; i++) {
            const Voxd__WorkerStatus *w = m->workers[i];
            s->workers[i] = (vox_worker_status){w->pid, w->cpu, (int)w->state, w->jobs,
                                                w->voxels_per_second, w->replaced,
                                                w->stalls};
        }
    }
    if (m->n_jobs && !(s->jobs = calloc(m->n_jobs, sizeof *s->jobs)))
        return libvox_fail(c, -ENOMEM, "out of memory");
    s->n_jobs = m->n_jobs;
    for (size_t i = 0; i < m->n_jobs; i++) {
        const Voxd__JobStatus *j = m->jobs[i];
        s->jobs[i] = (vox_job_status){j->job_id, j->uid, (int)j->kind, j->res,
                                      (int)j->state, j->fraction, j->seconds};
    }
    if (m->running) {
        s->has_running = 1;
        s->running_job_id = m->running->job_id;
        s->running_uid = m->running->uid;
        s->running_fraction = m->running->fraction;
        s->running_seconds = m->running->seconds;
    }
    answer(c, 0, 0, NULL);
    return 0;
}

static int on_pong(vox_client *c, const Voxd__Pong *m)
{
    if (m->token <= c->last_pong || m->token >= c->next_token)
        return libvox_fail(c, -EPROTO, "voxd answered a ping that %s (token %llu)",
                    m->token >= c->next_token ? "was never sent" : "it had answered",
                    (unsigned long long)m->token);
    c->last_pong = m->token;
    if ((c->pending == P_PING || c->pending == P_CANCEL || c->pending == P_DRAIN) &&
        !c->answered && m->token == c->ping_token)
        answer(c, 0, 0, NULL);
    return 0;
}

int libvox_dispatch(vox_client *c, const uint8_t *data, size_t len)
{
    Voxd__Reply *r = proto_frame_unpack_reply(data, len);
    if (!r && errno == ENOMEM)
        return libvox_fail(c, -ENOMEM, "out of memory unpacking a reply of %zu bytes", len);
    if (!r) return libvox_fail(c, -EPROTO, "voxd sent a reply that does not unpack (%zu bytes)", len);
    proto_error pe;
    int rc = proto_check_reply(r, &c->lim, &pe);
    if (rc) {
        rc = libvox_fail(c, -EPROTO, "voxd sent an invalid reply: %s", pe.msg);
    } else if (!c->ready && r->msg_case != VOXD__REPLY__MSG_HELLO_OK &&
               r->msg_case != VOXD__REPLY__MSG_ERROR) {
        rc = libvox_fail(c, -EPROTO, "voxd sent a reply of type %d before its hello", (int)r->msg_case);
    } else {
        switch (r->msg_case) {
        case VOXD__REPLY__MSG_HELLO_OK: rc = on_hello_ok(c, r->hello_ok); break;
        case VOXD__REPLY__MSG_ACCEPTED: rc = on_accepted(c, r->accepted); break;
        case VOXD__REPLY__MSG_PROGRESS: rc = on_progress(c, r->progress); break;
        case VOXD__REPLY__MSG_CHUNK: rc = libvox_on_chunk(c, r->chunk); break;
        case VOXD__REPLY__MSG_SUMMARY: {
            vjob *j = libvox_find_job(c, r->summary->job_id);
            if (!j || j->done)
                rc = libvox_fail(c, -EPROTO, "voxd sent a summary for job %llu, which %s",
                          (unsigned long long)r->summary->job_id,
                          j ? "has ended" : "is not a job of this connection");
            else {
                libvox_on_summary(j, r->summary);
                libvox_job_ended(c, j);
            }
            break;
        }
        case VOXD__REPLY__MSG_ERROR: rc = on_error(c, r->error); break;
        case VOXD__REPLY__MSG_STATUS: rc = on_status(c, r->status); break;
        case VOXD__REPLY__MSG_PONG: rc = on_pong(c, r->pong); break;
        default: rc = libvox_fail(c, -EPROTO, "voxd sent a reply of unknown type"); break;
        }
    }
    voxd__reply__free_unpacked(r, NULL);
    return rc;
}

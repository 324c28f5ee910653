/* Receiving a job's result: into a file or a buffer, waiting for its end
 * with progress, within a deadline the daemon's limits give. */
#include "vox.h"

#include <errno.h>
#include <math.h>
#include <string.h>

#include "libvox_int.h"
#include "outfile.h"

/* How long a job may take from its acceptance to its first result byte: the
 * daemon's job_timeout for it and each job that was ahead of it, plus a
 * silence timeout each for starting and stopping.  0: no limit (a daemon
 * without job_timeout). */
static double job_deadline(const vox_client *c, const vjob *j)
{
    if (!c->info.job_timeout) return 0;
    double ahead = j->queue_position;
    double cap = c->info.max_queued_jobs ? c->info.max_queued_jobs : 1;
    if (ahead > cap) ahead = cap;
    double t = c->timeout_ms / 1000.0;
    return (ahead + 1) * (c->info.job_timeout + t) + t;
}

/* 0 while the job may still end in time, with *ms how long the next wait
 * may be (-1: no limit); else -ETIMEDOUT with the job's result set. */
static int job_late(vox_client *c, vjob *j, int *ms)
{
    double now = libvox_mono(), t = c->timeout_ms / 1000.0, left;
    unsigned long long id = (unsigned long long)j->id;
    if (j->received) {
        /* Streaming: only result bytes count, not pongs. */
        left = j->t_data + t - now;
        if (left <= 0) {
            libvox_set_error(&j->result, -ETIMEDOUT, j->id,
                      "job %llu's result stalled: no data for %.1f s", id, t);
            return -ETIMEDOUT;
        }
    } else {
        double d = job_deadline(c, j);
        if (d == 0) {
            *ms = -1;
            return 0;
        }
        left = j->t_accepted + d - now;
        /* Results of this connection's earlier jobs streaming in may
         * hold this one's back. */
        double busy = c->t_any_data + t - now;
        if (busy > left) left = busy;
        if (left <= 0) {
            libvox_set_error(&j->result, -ETIMEDOUT, j->id,
                      "job %llu did not finish in %.1f s (the daemon's job_timeout is %u s, "
                      "%u job%s ahead of it)",
                      id, d, c->info.job_timeout, j->queue_position,
                      j->queue_position == 1 ? " was" : "s were");
            return -ETIMEDOUT;
        }
    }
    *ms = left > 86400 ? 86400000 : (int)ceil(left * 1000.0);
    return 0;
}

/* Wait for a job's end, showing its progress; the job's result code.  The
 * job may not have ended (it took too long): the caller drops it. */
static int wait_job(vox_client *c, vjob *j, vox_progress_cb cb, void *ud)
{
    while (!j->done) {
        int intr = 0, ms;
        if (job_late(c, j, &ms)) return j->result.code;
        /* Progress that came before this call is shown first. */
        int rc = j->progress_new ? 0 : libvox_step(c, ms, &intr);
        if (rc) {
            if (j->done) break; /* its end came before the failure */
            j->done = 1;
            if (!j->local_err) j->result = c->fail, j->result.job_id = j->id;
            break;
        }
        if (!cb) j->progress_new = 0;
        if (cb && (j->progress_new || intr)) {
            j->progress_new = 0;
            if (cb(ud, j->fraction, j->level, j->voxels) && !j->cancel_sent && !j->done) {
                j->cancel_sent = 1;
                libvox_add_ignored(c, j->id);
                libvox_send_cancel(c, j->id); /* a failure shows in the next step */
            }
        }
    }
    if (cb && j->progress_new && !j->result.code) {
        j->progress_new = 0;
        cb(ud, j->fraction, j->level, j->voxels);
    }
    return j->result.code;
}

static vjob *receivable(vox_client *c, uint64_t job_id, vox_error *err)
{
    vjob *j = libvox_find_job(c, job_id);
    if (!j) libvox_set_error(err, -EINVAL, job_id, "job %llu is not a job of this connection",
                      (unsigned long long)job_id);
    return j;
}

/* A receive call's options, none when o is NULL. */
static const vox_receive_opts *opts_or_none(const vox_receive_opts *o)
{
    static const vox_receive_opts none;
    return o ? o : &none;
}

int vox_receive_to_file(vox_client *c, uint64_t job_id, const char *path,
                        const vox_receive_opts *o, vox_error *err)
{
    o = opts_or_none(o);
    vjob *j = receivable(c, job_id, err);
    if (!j) return -EINVAL;
    outfile f;
    int rc = outfile_open(&f, path);
    if (rc) {
        libvox_set_error(err, rc, job_id, "cannot create %s: %s", path, strerror(-rc));
        libvox_drop_job(c, j);
        return rc;
    }
    libvox_unspool(j, SINK_FD, f.fd);
    rc = wait_job(c, j, o->progress, o->ud);
    if (rc) outfile_abort(&f);
    else rc = outfile_commit(&f, path);
    if (rc) {
        /* the file's own failure (a full disk) names the file */
        if (j->result.code && !j->local_err) libvox_copy_error(err, &j->result);
        else libvox_set_error(err, rc, job_id, "cannot write %s: %s", path, strerror(-rc));
    } else if (o->sum) {
        *o->sum = j->sum;
    }
    libvox_drop_job(c, j);
    return rc;
}

int vox_receive_to_buffer(vox_client *c, uint64_t job_id, uint8_t **buf, size_t *len,
                          const vox_receive_opts *o, vox_error *err)
{
    o = opts_or_none(o);
    *buf = NULL;
    *len = 0;
    vjob *j = receivable(c, job_id, err);
    if (!j) return -EINVAL;
    libvox_unspool(j, SINK_BUF, -1);
    int rc = wait_job(c, j, o->progress, o->ud);
    if (rc) {
        libvox_copy_error(err, &j->result);
    } else {
        *buf = j->buf;
        *len = (size_t)j->received;
        j->buf = NULL;
        if (o->sum) *o->sum = j->sum;
    }
    libvox_drop_job(c, j);
    return rc;
}

/* libvox 0.1's receive calls, kept for its ABI (vox.h, docs/libvox.md):
 * their seven and eight arguments are that version's; new code passes
 * them in a vox_receive_opts. */
int vox_receive_file(vox_client *c, uint64_t job_id, const char *path, vox_progress_cb cb,
                     void *ud, vox_summary *sum, vox_error *err)
{
    vox_receive_opts o = {.progress = cb, .ud = ud, .sum = sum};
    return vox_receive_to_file(c, job_id, path, &o, err);
}

int vox_receive_buffer(vox_client *c, uint64_t job_id, uint8_t **buf, size_t *len,
                       vox_progress_cb cb, void *ud, vox_summary *sum, vox_error *err)
{
    vox_receive_opts o = {.progress = cb, .ud = ud, .sum = sum};
    return vox_receive_to_buffer(c, job_id, buf, len, &o, err);
}

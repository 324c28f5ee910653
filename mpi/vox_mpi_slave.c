/* vox_mpi: a rank working on subtrees (every rank, rank 0 in a thread of
 * its own): it asks rank 0 for a task, runs the engine on it, sends the
 * records of its bricks and then the bytes rank 0 wants. */
#include <errno.h>
#include <sched.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "clock.h"
#include "vox_mpi.h"

void mpi_send_up(slave *s, const void *buf, size_t n, int tag)
{
    MPI_Send(buf, (int)n, MPI_BYTE, 0, tag, s->ctx->up);
    s->st.bytes += n;
    s->st.messages++;
}

/* A task's exchange: its records, then the bytes rank 0 wants. */
static int on_bricks(void *ud, const mpi_bricks *b)
{
    slave *s = ud;
    size_t recs = b->n * sizeof(mpi_rec), tops = b->ntops * sizeof(mpi_topref);
    size_t n = sizeof(wire_nodes) + recs + tops + b->npairs * sizeof(mpi_pair);
    if (n > INT32_MAX) return -E2BIG;
    uint8_t *m = malloc(n);
    if (!m) return -ENOMEM;
    wire_nodes h = {.voxels = b->voxels, .n = (uint32_t)b->n, .ntops = (uint32_t)b->ntops,
                    .npairs = (uint32_t)b->npairs};
    memcpy(m, &h, sizeof h);
    if (recs) memcpy(m + sizeof h, b->recs, recs);
    if (tops) memcpy(m + sizeof h + recs, b->tops, tops);
    if (b->npairs)
        memcpy(m + sizeof h + recs + tops, b->pairs, b->npairs * sizeof(mpi_pair));
    mpi_send_up(s, m, n, TAG_NODES);
    free(m);
    s->st.nodes += b->n;
    MPI_Status st;
    mpi_wait_msg(s->ctx->down, 0, TAG_WANT, &st);
    int wn;
    uint32_t *want = mpi_recv_msg(s->ctx, s->ctx->down, &st, &wn);
    size_t k = (size_t)wn / sizeof *want, bytes = 0;
    for (size_t i = 0; i < k; i++) {
        if (want[i] >= b->n) { free(want); return -EPROTO; }
        bytes += b->recs[want[i]].size;
    }
    int rc = 0;
    if (k && bytes <= INT32_MAX && (m = malloc(bytes))) {
        size_t at = 0;
        for (size_t i = 0; i < k; i++) {
            memcpy(m + at, b->data[want[i]], b->recs[want[i]].size);
            at += b->recs[want[i]].size;
        }
        mpi_send_up(s, m, bytes, TAG_BRICKS);
        free(m);
        s->st.bricks += k;
        s->st.brick_bytes += bytes;
    } else if (k) {
        rc = bytes > INT32_MAX ? -E2BIG : -ENOMEM;
    }
    free(want);
    return rc;
}

/* The next task from rank 0 (a mesh job's triangles with it, in *buf
 * for the task's time): 0, 1 when none is left, or -EPROTO. */
static int next_task(slave *s, wire_task *t, uint8_t **buf, mesh *m)
{
    MPI_Status st;
    int n;
    mpi_wait_msg(s->ctx->down, 0, TAG_TASK, &st);
    *buf = mpi_recv_msg(s->ctx, s->ctx->down, &st, &n);
    if ((size_t)n < sizeof *t) return -EPROTO;
    memcpy(t, *buf, sizeof *t);
    if (t->index < 0) return 1;
    if (s->sj.kind != MPI_KIND_MESH) return (size_t)n == sizeof *t ? 0 : -EPROTO;
    if (mpi_mesh_view(*buf + sizeof *t, (size_t)n - sizeof *t, m)) return -EPROTO;
    s->sj.mesh = m;
    return 0;
}

/* Ask, run, exchange, until rank 0 says there is nothing left; a failure
 * goes to rank 0 as a message (it ends the job). */
static int slave_loop(slave *s)
{
    mpi_send_up(s, "", 0, TAG_REQ);
    for (;;) {
        wire_task t;
        uint8_t *buf;
        mesh part;
        err_info err = {0};
        char m[600];
        int rc = next_task(s, &t, &buf, &part);
        if (rc == 1) {
            free(buf);
            return 0;
        }
        double t0 = clock_now();
        if (rc) err_set(&err, rc, "a task came damaged");
        else rc = mpi_subtree_run(&s->sj, t.o, on_bricks, s, &err);
        s->st.busy += clock_now() - t0;
        s->sj.mesh = NULL;
        free(buf);
        if (rc) {
            int k = snprintf(m, sizeof m, "%s", err.msg[0] ? err.msg : strerror(-rc));
            mpi_send_up(s, m, (size_t)(k < (int)sizeof m ? k : (int)sizeof m - 1) + 1, TAG_FAIL);
            return rc;
        }
        s->st.subtrees++;
    }
}

/* The CPUs this rank may run on, in order; how many. */
static int rank_cpus(int *cpus, int cap)
{
    cpu_set_t set;
    int n = 0;
    if (sched_getaffinity(0, sizeof set, &set)) return 0;
    for (int c = 0; c < CPU_SETSIZE && n < cap; c++)
        if (CPU_ISSET(c, &set)) cpus[n++] = c;
    return n;
}

/* Where the workers go without --cpus: the rank's CPUs, the list turned
 * by the workers of the ranks before it on this host, so that ranks that
 * mpirun did not bind (each sees every CPU) do not pin their workers to
 * the same ones; a bound rank's own CPUs are unchanged by it.  And how
 * many without -w: the rank's CPUs, shared with the host's other ranks
 * when they are not bound. */
static int place_workers(const mpi_ctx *ctx, const wire_job *j, uint32_t *workers, int *cpus)
{
    int all[ENGINE_MAX_WORKERS], n = rank_cpus(all, ENGINE_MAX_WORKERS);
    long online = sysconf(_SC_NPROCESSORS_ONLN);
    uint32_t w = j->workers;
    if (w == WORKERS_AUTO) {
        int share = n >= online && ctx->local_size > 1 ? n / ctx->local_size : n;
        w = share > 0 ? (uint32_t)share : 1;
    }
    *workers = w;
    if (j->cpus[0]) return cli_parse_cpus(j->cpus, cpus, ENGINE_MAX_WORKERS);
    for (int i = 0; i < n; i++) cpus[i] = all[(i + (size_t)ctx->local_rank * w) % (size_t)n];
    return n;
}

/* The engine of this rank (none with -w 0), then the loop; called in the
 * thread that then owns the engine (its workers die with that thread). */
int mpi_slave_run(slave *s, const wire_job *j)
{
    engine *e = NULL;
    int cpus[ENGINE_MAX_WORKERS], ncpus = place_workers(s->ctx, j, &s->st.workers, cpus);
    if (s->st.workers) {
        engine_opts eo = {.workers = (int)s->st.workers, .cpus = ncpus > 0 ? cpus : NULL,
                          .ncpus = ncpus > 0 ? ncpus : 0,
                          .shm_bytes = (size_t)j->shm_mib << 20,
                          .shm_option = "--shm-size"};
        char m[400];
        err_info err = {0};
        int rc = engine_create(&eo, &e, &err);
        if (rc) {
            int k = snprintf(m, sizeof m, "cannot start the engine: %s",
                             err.msg[0] ? err.msg : strerror(-rc));
            mpi_send_up(s, m, (size_t)(k < (int)sizeof m ? k : (int)sizeof m - 1) + 1, TAG_FAIL);
            return rc;
        }
    }
    mpi_leaves leaves = MPI_LEAVES_INIT;
    s->sj.e = e;
    s->sj.leaves = &leaves;
    int rc = slave_loop(s);
    s->sj.leaves = NULL;
    mpi_leaves_free(&leaves);
    engine_destroy(e);
    return rc;
}

void *mpi_slave_thread(void *ud)
{
    own_slave *o = ud;
    o->s.rc = mpi_slave_run(&o->s, &o->j);
    return NULL;
}

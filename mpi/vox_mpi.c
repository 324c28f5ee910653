/* vox_mpi — vox voxelize over the ranks of an Open MPI job (docs/mpi.md).
 *
 * Every rank is a slave of rank 0, one level above the engine's own
 * master–worker scheme: it asks rank 0 for a subtree, runs the engine that
 * vox runs (its forked, pinned workers, which never call MPI) on it,
 * encodes its bricks, sends their records and content keys, and then only
 * the bricks rank 0 asks for (those it holds no copy of).  Rank 0 cuts the
 * job into subtrees, hands them out on request, works on them too (a
 * thread of its own, a slave like the others), makes the levels above the
 * subtrees, and writes the file: the bytes vox voxelize writes.
 *
 * Messages: the job is broadcast once; then on the "up" communicator (to
 * rank 0) REQ (the first request), NODES (a subtree's records, its voxel
 * count and its top brick's voxels), BRICKS (the bytes asked for, in the
 * order asked), FAIL (a message); on the "down" one (from rank 0) TASK (a
 * subtree, or none left) and WANT (the records whose bytes to send).  A
 * rank's next TASK comes once its exchange is over.  Two communicators,
 * so that rank 0's two threads (MPI_THREAD_MULTIPLE) never take each
 * other's messages.  Waits poll (MPI_Iprobe and a short sleep) instead of
 * blocking: Open MPI's blocking calls spin, and the cores are the
 * workers'.
 */
#include <mpi.h>

#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "clock.h"
#include "vox_mpi.h"

/* Rank 0: the job prepared and broadcast, its own slave in a thread, the
 * others served, the file written. */
static int run_master(mpi_ctx *ctx, int argc, char **argv)
{
    prep *p = calloc(1, sizeof *p);
    if (!p) {
        mpi_msg("rank 0 on %s: out of memory", ctx->host);
        MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    }
    p->ctx = ctx;
    double t0 = clock_now();
    int status = mpi_prepare(p, argc, argv);
    wire_job j = status >= 0 ? (wire_job){.status = status} : mpi_job_of(p);
    MPI_Bcast(&j, sizeof j, MPI_BYTE, 0, MPI_COMM_WORLD);
    if (status >= 0) {
        mpi_prep_free(p);
        free(p);
        return status;
    }
    if (j.input_bytes) MPI_Bcast(p->input, (int)j.input_bytes, MPI_BYTE, 0, MPI_COMM_WORLD);
    mpi_catch_signals(ctx);
    /* rank 0's own slave, its job right behind it (mpi_slave_thread) */
    own_slave *own = calloc(1, sizeof *own);
    master m = {.ctx = ctx, .cut = &p->cut, .grid = &p->plan.grid, .kind = p->kind,
                .mesh = &p->mesh, .bins = p->bins.start ? &p->bins : NULL};
    m.spill = mpi_spill_open(p->o.out);
    m.rs = calloc((size_t)ctx->nranks, sizeof *m.rs);
    mpi_book_init(&m.book);
    if (!own || m.spill < 0 || !m.rs ||
        mpi_top_new(&p->L, p->plan.grid.depth, p->cut.node_level, &m.top))
        mpi_fail_master(&m, "starting", m.spill < 0 ? -errno : -ENOMEM);
    progress_init(&m.pr, p->o.progress);
    own->j = j;
    own->s.ctx = ctx;
    own->s.sj = mpi_subtree_job_of(&j, p->tape, p->tree);
    pthread_t th;
    if (pthread_create(&th, NULL, mpi_slave_thread, own))
        mpi_fail_master(&m, "starting", -EAGAIN);
    mpi_serve(&m);
    pthread_join(th, NULL);
    rank_stats *all = calloc((size_t)ctx->nranks, sizeof *all);
    MPI_Gather(&own->s.st, sizeof(rank_stats), MPI_BYTE, all, sizeof(rank_stats), MPI_BYTE,
               0, MPI_COMM_WORLD);
    mpi_finish_file(p, &m, all, t0);
    free(all);
    close(m.spill);
    mpi_top_free(m.top);
    mpi_book_free(&m.book);
    free(m.nodes);
    free(m.rs);
    free(own);
    mpi_prep_free(p);
    free(p);
    return CLI_EXIT_OK;
}

/* ---------------------------------------------------------------- others */

/* The job's input as broadcast, checked: 0, or a message's reason. */
static const char *take_input(const wire_job *j, void *input, csg_tree **tree)
{
    if (grid_check(&j->grid)) return "the job's grid came damaged";
    if (j->kind == MPI_KIND_IMPLICIT)
        return expr_tape_validate(input, j->input_bytes) ? "the job's tape came damaged" : NULL;
    if (j->kind == MPI_KIND_CSG)
        return csg_tree_unpack(input, j->input_bytes, tree) ? "the job's tree came damaged"
                                                            : NULL;
    return j->kind == MPI_KIND_MESH && !j->input_bytes ? NULL : "the job came damaged";
}

static int run_rank(const mpi_ctx *ctx)
{
    wire_job j;
    MPI_Bcast(&j, sizeof j, MPI_BYTE, 0, MPI_COMM_WORLD);
    if (j.status >= 0) return j.status;
    void *input = aligned_alloc(64, (j.input_bytes + 64) / 64 * 64);
    if (!input) {
        mpi_msg("rank %d on %s: out of memory", ctx->me, ctx->host);
        MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    }
    if (j.input_bytes) MPI_Bcast(input, (int)j.input_bytes, MPI_BYTE, 0, MPI_COMM_WORLD);
    csg_tree *tree = NULL;
    const char *bad = take_input(&j, input, &tree);
    slave s = {.ctx = ctx, .sj = mpi_subtree_job_of(&j, input, tree)};
    if (bad) {
        mpi_send_up(&s, bad, strlen(bad) + 1, TAG_FAIL);
        free(input);
        return CLI_EXIT_FAILED;
    }
    int rc = mpi_slave_run(&s, &j);
    csg_tree_free(tree);
    free(input);
    if (rc) return CLI_EXIT_FAILED;
    MPI_Gather(&s.st, sizeof(rank_stats), MPI_BYTE, NULL, 0, MPI_BYTE, 0, MPI_COMM_WORLD);
    return CLI_EXIT_OK;
}

/* The communicators, this rank's place and host: the context of every
 * rank (MPI aborts the job should one fail). */
static void ctx_init(mpi_ctx *ctx)
{
    MPI_Comm_rank(MPI_COMM_WORLD, &ctx->me);
    MPI_Comm_size(MPI_COMM_WORLD, &ctx->nranks);
    MPI_Comm_dup(MPI_COMM_WORLD, &ctx->up);
    MPI_Comm_dup(MPI_COMM_WORLD, &ctx->down);
    int len = 0;
    char name[MPI_MAX_PROCESSOR_NAME];
    MPI_Get_processor_name(name, &len);
    name[HOST_MAX - 1] = '\0'; /* a host name is shorter; cut, not refused */
    memcpy(ctx->host, name, HOST_MAX);
    if (ctx->me == 0 && !(ctx->all_hosts = calloc((size_t)ctx->nranks, HOST_MAX)))
        MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    MPI_Gather(ctx->host, HOST_MAX, MPI_CHAR, ctx->all_hosts, HOST_MAX, MPI_CHAR, 0,
               MPI_COMM_WORLD);
    MPI_Comm host;
    MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, 0, MPI_INFO_NULL, &host);
    MPI_Comm_rank(host, &ctx->local_rank);
    MPI_Comm_size(host, &ctx->local_size);
    MPI_Comm_free(&host);
}

int main(int argc, char **argv)
{
    int provided;
    if (MPI_Init_thread(&argc, &argv, MPI_THREAD_MULTIPLE, &provided) != MPI_SUCCESS) {
        mpi_msg("MPI_Init_thread failed");
        return CLI_EXIT_FAILED;
    }
    mpi_ctx ctx = {0};
    ctx_init(&ctx);
    if (ctx.me == 0 && provided < MPI_THREAD_MULTIPLE) {
        /* rank 0's own slave thread talks MPI beside its master */
        mpi_msg("this MPI library gives thread level %d, vox_mpi needs MPI_THREAD_MULTIPLE",
                provided);
        MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    }
    int rc = ctx.me == 0 ? run_master(&ctx, argc, argv) : run_rank(&ctx);
    free(ctx.all_hosts);
    MPI_Comm_free(&ctx.up);
    MPI_Comm_free(&ctx.down);
    MPI_Finalize();
    return rc;
}

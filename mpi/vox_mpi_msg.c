/* vox_mpi: its messages on standard error, and the messages between ranks
 * waited for without spinning and received into a buffer of their size. */
#include <mpi.h>

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "vox_mpi.h"

void mpi_msg(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "vox_mpi: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
}

/* Wait for a message without spinning: probe, then sleep a little longer
 * each time up to half a millisecond. */
void mpi_wait_msg(MPI_Comm c, int src, int tag, MPI_Status *st)
{
    int flag = 0;
    long ns = 20000;
    for (;;) {
        MPI_Iprobe(src, tag, c, &flag, st);
        if (flag) return;
        struct timespec ts = {0, ns};
        nanosleep(&ts, NULL);
        if (ns < 500000) ns *= 2;
    }
}

/* The message st announced, into a new buffer (its size in *n). */
void *mpi_recv_msg(const mpi_ctx *ctx, MPI_Comm c, MPI_Status *st, int *n)
{
    MPI_Get_count(st, MPI_BYTE, n);
    void *buf = malloc(*n ? (size_t)*n : 1);
    if (!buf) {
        mpi_msg("rank %d on %s: out of memory for a message of %d bytes", ctx->me, ctx->host, *n);
        MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    }
    MPI_Recv(buf, *n, MPI_BYTE, st->MPI_SOURCE, st->MPI_TAG, c, MPI_STATUS_IGNORE);
    return buf;
}

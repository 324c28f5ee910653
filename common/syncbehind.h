/* syncbehind — a file's data made durable while it is still being
 * written, so that the fsync before its commit (outfile_commit) waits for
 * the last few MiB only.
 *
 * Starting write-back early (outfile's OUTFILE_KICK, sync_file_range) is
 * not enough on a virtual disk: an fsync's cost there is mostly the
 * device's cache flush, in proportion to the bytes written since the last
 * one (0.7 ms a MiB on the 2-core machine: 45 ms for a 64 MiB file, 13 ms
 * for its last 16 MiB after an fdatasync of the first 48).  A thread of
 * its own checks the file's size every SYNCBEHIND_PERIOD_MS and, once it
 * has grown by SYNCBEHIND_BYTES, calls fdatasync: the flushes run while
 * the job still computes, the user waits for the last one only.  It reads
 * the size (fstat), not the writers' counts: any writer (write, pwrite
 * from several threads) is seen. */
#ifndef VOXD_SYNCBEHIND_H
#define VOXD_SYNCBEHIND_H

#include <pthread.h>
#include <stdatomic.h>

#define SYNCBEHIND_PERIOD_MS 5
#define SYNCBEHIND_BYTES ((long long)2 << 20)

typedef struct {
    pthread_t thread;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    int fd, started, stop; /* stop: under mu */
    /* fdatasyncs done; written by the thread alone, read by anyone (a
     * count: relaxed, pairs with nothing; after syncbehind_stop the join
     * orders it) */
    atomic_uint flushes;
} syncbehind;

/* The thread started on fd (which must stay open until syncbehind_stop);
 * when it cannot be, nothing happens: the commit's fsync does it all. */
void syncbehind_start(syncbehind *s, int fd);
/* The thread stopped (an fdatasync under way finished) and joined; a
 * syncbehind never started, or stopped already, is left as it is. */
void syncbehind_stop(syncbehind *s);

#endif

/* The engine's shared-memory segment: sizing, creation, layout, futexes. */
#include "shm.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/futex.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/statvfs.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#define PAGE 4096u
#define MIB ((size_t)1 << 20)

static size_t round_up(size_t v, size_t a) { return (v + a - 1) / a * a; }

/* Room for the LIFO work stack: the implicit kind leaves at most 7
 * octants behind per level per octant in flight; this is several times
 * that for any worker count. */
static uint64_t stack_cap_for(uint32_t workers)
{
    return 4096u + 256u * ((uint64_t)workers + 1u);
}

/* Offsets of the fixed part; returns where the data area starts. */
static size_t layout(shm_header *h, uint32_t workers)
{
    size_t off = round_up(sizeof(shm_header), PAGE);
    size_t slot = round_up(sizeof(shm_slot), PAGE);
    uint64_t cap = stack_cap_for(workers);
    if (h) {
        h->slots_off = off;
        h->slot_bytes = slot;
    }
    off += slot * workers;
    if (h) {
        h->stack_off = off;
        h->stack_cap = cap;
    }
    off += round_up(cap * sizeof(shm_task), PAGE);
    if (h) h->data_off = off;
    return off;
}

size_t shm_min_bytes(uint32_t workers)
{
    return layout(NULL, workers) + SHM_MIN_DATA;
}

/* Free bytes in /dev/shm (where POSIX shared memory lives), or SIZE_MAX
 * when that cannot be told. */
static size_t shm_free_bytes(void)
{
    struct statvfs v;
    if (statvfs("/dev/shm", &v) != 0) return SIZE_MAX;
    unsigned long long b = (unsigned long long)v.f_bavail * v.f_frsize;
    return b > SIZE_MAX ? SIZE_MAX : (size_t)b;
}

size_t shm_default_bytes(uint32_t workers)
{
    /* Sparse, but what is touched must fit: take at most half the free
     * space so other users of /dev/shm keep some (a container's 64 MiB
     * gives 32), yet never less than the fixed part needs while that fits
     * at all. */
    size_t min = shm_min_bytes(workers), avail = shm_free_bytes();
    size_t bytes = SHM_DEFAULT_BYTES;
    if (avail != SIZE_MAX && bytes > avail / 2) bytes = avail / 2 / MIB * MIB;
    if (bytes < min && (avail == SIZE_MAX || min <= avail)) bytes = (min + MIB - 1) / MIB * MIB;
    return bytes;
}

static int choose_size(size_t *bytes, uint32_t workers, err_info *err)
{
    size_t min = shm_min_bytes(workers), avail = shm_free_bytes();
    if (*bytes == 0) *bytes = shm_default_bytes(workers);
    if (*bytes < min) {
        err_set(err, -ENOSPC,
                 "shared memory of %zu KiB is too small: %u worker(s) need at "
                 "least %zu KiB (/dev/shm has %zu MiB free)",
                 *bytes >> 10, workers, (min + 1023) >> 10,
                 avail == SIZE_MAX ? 0 : avail / MIB);
        return -ENOSPC;
    }
    if (avail != SIZE_MAX && *bytes > avail) {
        err_set(err, -ENOSPC,
                 "shared memory of %zu MiB asked for, but /dev/shm has only "
                 "%zu MiB free",
                 *bytes / MIB, avail / MIB);
        return -ENOSPC;
    }
    return 0;
}

/* shm_open(O_EXCL) under the given name, or a fresh private one. */
static int open_segment(shm_seg *s, const char *name, err_info *err)
{
    static atomic_uint counter; /* relaxed: only uniqueness matters */
    if (name) {
        if (name[0] != '/' || strchr(name + 1, '/') ||
            strlen(name) >= sizeof s->name || strlen(name) < 2) {
            err_set(err, -EINVAL,
                     "bad shared memory name '%s': want \"/name\" (no other "
                     "slash, under %zu bytes)",
                     name, sizeof s->name);
            return -EINVAL;
        }
        snprintf(s->name, sizeof s->name, "%s", name);
        s->fd = shm_open(s->name, O_RDWR | O_CREAT | O_EXCL, 0600);
    } else {
        for (int tries = 0; tries < 16; tries++) {
            struct timespec ts;
            clock_gettime(CLOCK_MONOTONIC, &ts);
            snprintf(s->name, sizeof s->name, "/voxd.%d.%u.%lx", (int)getpid(),
                     atomic_fetch_add_explicit(&counter, 1,
                                               memory_order_relaxed),
                     (unsigned long)ts.tv_nsec);
            s->fd = shm_open(s->name, O_RDWR | O_CREAT | O_EXCL, 0600);
            if (s->fd >= 0 || errno != EEXIST) break;
        }
    }
    if (s->fd < 0) {
        int e = errno;
        err_set(err, -e, "cannot create shared memory %s: %s%s", s->name,
                 strerror(e),
                 e == EEXIST ? " (another voxd runs, or a stale one left it: "
                               "remove it from /dev/shm)"
                             : "");
        return -e;
    }
    return 0;
}

int shm_create(shm_seg *s, const char *name, size_t bytes, uint32_t workers,
               err_info *err)
{
    memset(s, 0, sizeof *s);
    s->fd = -1;
    int rc = choose_size(&bytes, workers, err);
    if (rc) return rc;
    if ((rc = open_segment(s, name, err))) return rc;
    if (ftruncate(s->fd, (off_t)bytes) != 0) {
        rc = -errno;
        err_set(err, rc, "cannot size shared memory to %zu MiB: %s",
                 bytes / MIB, strerror(-rc));
        goto fail;
    }
    void *p = mmap(NULL, bytes, PROT_READ | PROT_WRITE, MAP_SHARED, s->fd, 0);
    if (p == MAP_FAILED) {
        rc = -errno;
        err_set(err, rc, "cannot map %zu MiB of shared memory: %s",
                 bytes / MIB, strerror(-rc));
        goto fail;
    }
    close(s->fd);
    s->fd = -1;
    s->base = p;
    s->bytes = bytes;
    s->named = name != NULL;
    if (!s->named) shm_unlink(s->name);
    /* A fresh (O_EXCL) object reads as zeros: only the header is set. */
    shm_header *h = shm_hdr(s->base);
    h->magic = SHM_MAGIC;
    h->version = SHM_VERSION;
    h->master_pid = (int32_t)getpid();
    h->workers = workers;
    h->bytes = bytes;
    layout(h, workers);
    h->data_bytes = bytes - h->data_off;
    return 0;
fail:
    close(s->fd);
    shm_unlink(s->name);
    s->fd = -1;
    return rc;
}

void shm_destroy(shm_seg *s)
{
    if (s->base) munmap(s->base, s->bytes);
    if (s->named) shm_unlink(s->name);
    s->base = NULL;
}

void shm_futex_wait(atomic_uint *w, unsigned val, long timeout_ns)
{
    struct timespec ts = {timeout_ns / 1000000000L, timeout_ns % 1000000000L};
    /* EAGAIN (value changed), EINTR and ETIMEDOUT all mean: look again. */
    syscall(SYS_futex, (unsigned *)w, FUTEX_WAIT, val,
            timeout_ns > 0 ? &ts : NULL, NULL, 0);
}

void shm_futex_wake(atomic_uint *w, int n)
{
    syscall(SYS_futex, (unsigned *)w, FUTEX_WAKE, n, NULL, NULL, 0);
}

void shm_wake_if_sleeping(atomic_uint *w, atomic_int *sleeping)
{
    /* seq_cst fence: the Dekker pair of the sleeper's fence between setting
     * its flag and re-checking the condition this side just changed. */
    atomic_thread_fence(memory_order_seq_cst);
    if (atomic_load_explicit(sleeping, memory_order_relaxed)) {
        /* release (in the seq_cst RMW): the sleeper's acquire load of w
         * then sees the changed condition too. */
        atomic_fetch_add(w, 1);
        shm_futex_wake(w, INT_MAX);
    }
}

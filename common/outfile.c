#include "outfile.h"

#include <errno.h>
#include <fcntl.h>
#include <stdatomic.h>
#include <stdio.h>
#include <time.h>
#include <unistd.h>

int outfile_create(const char *path, char *tmp, size_t cap)
{
    /* relaxed: only makes names differ between threads; O_EXCL decides */
    static atomic_uint counter;
    for (int tries = 0; tries < 100; tries++) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        unsigned n = atomic_fetch_add_explicit(&counter, 1, memory_order_relaxed);
        unsigned salt = (unsigned)ts.tv_nsec ^ (unsigned)getpid() << 8 ^ n * 2654435761u;
        int len = snprintf(tmp, cap, "%s.tmp.%06x", path, salt & 0xffffff);
        if (len < 0 || (size_t)len >= cap) return -ENAMETOOLONG;
        int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (fd >= 0 || errno != EEXIST) return fd >= 0 ? fd : -errno;
    }
    return -EEXIST;
}

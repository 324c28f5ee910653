#include "outfile.h"

#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

/* A fresh name beside path into tmp: 0, or -ENAMETOOLONG. */
static int temp_name(const char *path, char *tmp, size_t cap)
{
    /* relaxed: only makes names differ between threads; O_EXCL decides */
    static atomic_uint counter;
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    unsigned n = atomic_fetch_add_explicit(&counter, 1, memory_order_relaxed);
    unsigned salt = (unsigned)ts.tv_nsec ^ (unsigned)getpid() << 8 ^ n * 2654435761u;
    int len = snprintf(tmp, cap, "%s.tmp.%06x", path, salt & 0xffffff);
    return len < 0 || (size_t)len >= cap ? -ENAMETOOLONG : 0;
}

static int open_named(outfile *f, const char *path)
{
    for (int tries = 0; tries < 100; tries++) {
        int rc = temp_name(path, f->tmp, sizeof f->tmp);
        if (rc) return rc;
        f->fd = open(f->tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
        if (f->fd >= 0) {
            f->named = 1;
            return 0;
        }
        if (errno != EEXIST) return -errno;
    }
    return -EEXIST;
}

/* The unnamed file in path's directory; -EOPNOTSUPP where the file system
 * (or the kernel) has none. */
static int open_unnamed(outfile *f, const char *path)
{
    const char *off = getenv("VOXD_OUTFILE_NAMED");
    if (off && off[0] == '1') return -EOPNOTSUPP;
    if (strlen(path) + 16 > sizeof f->tmp) return -ENAMETOOLONG;
    char dir[sizeof f->tmp];
    snprintf(dir, sizeof dir, "%s", path);
    f->fd = open(dirname(dir), O_TMPFILE | O_WRONLY | O_CLOEXEC, 0666);
    if (f->fd < 0)
        return errno == EISDIR || errno == EINVAL || errno == EOPNOTSUPP ? -EOPNOTSUPP : -errno;
    snprintf(f->tmp, sizeof f->tmp, "/proc/self/fd/%d", f->fd);
    return 0;
}

int outfile_open(outfile *f, const char *path)
{
    f->fd = -1;
    f->written = f->kicked = 0;
    f->named = 0;
    f->tmp[0] = '\0';
    int rc = open_unnamed(f, path);
    return rc == -EOPNOTSUPP ? open_named(f, path) : rc;
}

const char *outfile_name(const outfile *f)
{
    return f->tmp;
}

int outfile_write(void *ud, const void *buf, size_t n)
{
    outfile *f = ud;
    const uint8_t *p = buf;
    for (size_t left = n; left;) {
        ssize_t k = write(f->fd, p, left);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return k < 0 ? -errno : -EIO;
        p += k;
        left -= (size_t)k;
    }
    f->written += n;
    if (f->written - f->kicked >= OUTFILE_KICK) {
        /* a hint: where it fails (not a file), the commit's fsync decides */
        sync_file_range(f->fd, (off64_t)f->kicked, (off64_t)(f->written - f->kicked),
                        SYNC_FILE_RANGE_WRITE);
        f->kicked = f->written;
    }
    return 0;
}

/* The unnamed file under a fresh name beside path (linkat cannot replace
 * a file, rename can): by its /proc link, or AT_EMPTY_PATH without /proc. */
static int link_unnamed(outfile *f, const char *path)
{
    char tmp[sizeof f->tmp];
    for (int tries = 0; tries < 100; tries++) {
        int rc = temp_name(path, tmp, sizeof tmp);
        if (rc) return rc;
        rc = linkat(AT_FDCWD, f->tmp, AT_FDCWD, tmp, AT_SYMLINK_FOLLOW);
        if (rc && errno == ENOENT) rc = linkat(f->fd, "", AT_FDCWD, tmp, AT_EMPTY_PATH);
        if (rc == 0) {
            memcpy(f->tmp, tmp, sizeof tmp);
            f->named = 1;
            return 0;
        }
        if (errno != EEXIST) return -errno;
    }
    return -EEXIST;
}

int outfile_commit(outfile *f, const char *path)
{
    int rc = fsync(f->fd) ? -errno : 0;
    if (!rc && !f->named) rc = link_unnamed(f, path);
    if (close(f->fd) && !rc) rc = -errno;
    f->fd = -1;
    if (!rc && rename(f->tmp, path)) rc = -errno;
    if (rc) outfile_abort(f);
    f->named = 0;
    return rc;
}

void outfile_abort(outfile *f)
{
    if (f->fd >= 0) close(f->fd);
    f->fd = -1;
    if (f->named) unlink(f->tmp);
    f->named = 0;
}

int outfile_put(const char *path, const void *buf, size_t n)
{
    outfile f;
    int rc = outfile_open(&f, path);
    if (rc) return rc;
    if ((rc = outfile_write(&f, buf, n))) {
        outfile_abort(&f);
        return rc;
    }
    return outfile_commit(&f, path);
}

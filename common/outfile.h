/* outfile — a result file that appears whole or not at all, and leaves
 * nothing behind when its writer dies.
 *
 * outfile_open() makes the file in PATH's directory as an unnamed file
 * (O_TMPFILE): until outfile_commit() links it into place nothing names
 * it, so a writer killed by any signal, SIGKILL included, leaves no
 * litter.  Where the file system refuses O_TMPFILE (an older overlayfs,
 * NFS) it falls back to a name beside PATH (PATH.tmp.XXXXXX, created
 * exclusively); outfile_abort() removes that one, and the callers catch
 * SIGINT and SIGTERM so that it is removed on an interrupt too (only
 * SIGKILL leaves it then).  Either way the file gets mode 0666 less the
 * umask, like any file the user writes, and replaces PATH by a rename: a
 * reader sees the old file or the new one, never a part.  vox's commands,
 * vox_mpi and libvox write their results this way.
 *
 * VOXD_OUTFILE_NAMED=1 in the environment skips O_TMPFILE (the tests run
 * the fallback with it).
 */
#ifndef VOXD_OUTFILE_H
#define VOXD_OUTFILE_H

#include <limits.h>
#include <stddef.h>

#include <stdint.h>

typedef struct {
    int fd;                   /* O_WRONLY, O_CLOEXEC; -1 once closed */
    int named;                /* the fallback: the file has the name tmp */
    char tmp[PATH_MAX + 32];  /* the fallback's name; else the /proc path */
    uint64_t written;         /* outfile_write's bytes */
    uint64_t kicked;          /* ... whose write-back has been started */
} outfile;

/* Create the file for PATH: 0, or a negative errno (-ENAMETOOLONG when
 * PATH is too long for the temporary name). */
int outfile_open(outfile *f, const char *path);
/* A name that opens the file for writing while it is open (the temporary
 * name, or /proc/self/fd/N): for a library that writes by name. */
const char *outfile_name(const outfile *f);
/* n bytes appended (a vod_sink's write, f as its ud: 0 or a negative
 * errno).  Every OUTFILE_KICK bytes the kernel is asked to start writing
 * them back (sync_file_range), so that the commit's fsync waits for the
 * last few MiB only, not for the whole file after the last byte. */
#define OUTFILE_KICK ((uint64_t)8 << 20)
int outfile_write(void *f, const void *buf, size_t n);
/* fsync, close, then link the file into place as PATH (replacing any
 * file there): 0, or a negative errno after which nothing is left. */
int outfile_commit(outfile *f, const char *path);
/* Close and remove it: nothing is left.  Async-signal-safe. */
void outfile_abort(outfile *f);
/* A whole file of n bytes made in memory, written as PATH the same way
 * (open, write, commit): 0, or a negative errno with nothing left. */
int outfile_put(const char *path, const void *buf, size_t n);

#endif

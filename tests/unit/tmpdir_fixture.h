/* A scratch directory of a suite's own under /tmp: tmpdir_make() in the
 * suite's .init (named after the suite), tmpdir_remove() in its .fini
 * (the files in it removed, then the directory).  One per test binary. */
#ifndef VOXD_TMPDIR_FIXTURE_H
#define VOXD_TMPDIR_FIXTURE_H

#include <criterion/criterion.h>
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

static char dir[64];

static inline void tmpdir_make(const char *suite)
{
    snprintf(dir, sizeof dir, "/tmp/test_%s.XXXXXX", suite);
    cr_assert_not_null(mkdtemp(dir));
}

static inline void tmpdir_remove(void)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    char p[sizeof dir + 256 + 2];
    while (d && (e = readdir(d)))
        if (e->d_name[0] != '.') snprintf(p, sizeof p, "%s/%s", dir, e->d_name), unlink(p);
    if (d) closedir(d);
    rmdir(dir);
}

#endif

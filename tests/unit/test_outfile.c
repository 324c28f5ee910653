/* outfile: a result file that appears whole or not at all, unnamed
 * (O_TMPFILE) until committed, or under a temporary name as the fallback
 * (VOXD_OUTFILE_NAMED=1), and nothing left after an abort either way. */
#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "outfile.h"
#include "tmpdir_fixture.h"

static void make_dir(void)
{
    tmpdir_make("outfile");
    unsetenv("VOXD_OUTFILE_NAMED");
}

TestSuite(outfile, .init = make_dir, .fini = tmpdir_remove);

/* The directory's entries, sorted by nothing: "a b " */
static void entries(char *out, size_t cap)
{
    out[0] = '\0';
    DIR *d = opendir(dir);
    cr_assert_not_null(d);
    struct dirent *e;
    while ((e = readdir(d)))
        if (e->d_name[0] != '.') {
            strncat(out, e->d_name, cap - strlen(out) - 2);
            strcat(out, " ");
        }
    closedir(d);
}

static void path_of(const char *name, char *p, size_t cap)
{
    snprintf(p, cap, "%s/%s", dir, name);
}

static void write_str(int fd, const char *s)
{
    cr_assert_eq(write(fd, s, strlen(s)), (ssize_t)strlen(s));
}

static void check_content(const char *path, const char *want)
{
    char buf[64] = "";
    FILE *f = fopen(path, "r");
    cr_assert_not_null(f, "%s: %s", path, strerror(errno));
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    cr_assert_str_eq(buf, want);
}

Test(outfile, unnamed_until_committed)
{
    char p[128], ls[256];
    path_of("out.vod", p, sizeof p);
    outfile f;
    cr_assert_eq(outfile_open(&f, p), 0);
    cr_assert_eq(f.named, 0, "O_TMPFILE works on /tmp here");
    write_str(f.fd, "hello");
    entries(ls, sizeof ls);
    cr_assert_str_eq(ls, "", "nothing named while it is written");
    cr_assert_eq(outfile_commit(&f, p), 0);
    entries(ls, sizeof ls);
    cr_assert_str_eq(ls, "out.vod ");
    check_content(p, "hello");
}

Test(outfile, the_umask_decides_the_mode)
{
    char p[128];
    path_of("m.vod", p, sizeof p);
    mode_t old = umask(027);
    outfile f;
    cr_assert_eq(outfile_open(&f, p), 0);
    cr_assert_eq(outfile_commit(&f, p), 0);
    umask(old);
    struct stat st;
    cr_assert_eq(stat(p, &st), 0);
    cr_assert_eq(st.st_mode & 0777, 0640, "mode %o", st.st_mode & 0777);
}

Test(outfile, abort_leaves_nothing_both_ways)
{
    char p[128], ls[256];
    path_of("gone.vod", p, sizeof p);
    for (int named = 0; named < 2; named++) {
        if (named) setenv("VOXD_OUTFILE_NAMED", "1", 1);
        outfile f;
        cr_assert_eq(outfile_open(&f, p), 0);
        cr_assert_eq(f.named, named);
        write_str(f.fd, "partial");
        entries(ls, sizeof ls);
        if (named) cr_assert(strncmp(ls, "gone.vod.tmp.", 13) == 0, "'%s'", ls);
        outfile_abort(&f);
        entries(ls, sizeof ls);
        cr_assert_str_eq(ls, "", "named %d: '%s' left", named, ls);
    }
}

Test(outfile, commit_replaces_the_old_file)
{
    char p[128], ls[256];
    path_of("r.vod", p, sizeof p);
    for (int named = 0; named < 2; named++) {
        if (named) setenv("VOXD_OUTFILE_NAMED", "1", 1);
        outfile f;
        cr_assert_eq(outfile_open(&f, p), 0);
        write_str(f.fd, named ? "second" : "first");
        cr_assert_eq(outfile_commit(&f, p), 0);
        check_content(p, named ? "second" : "first");
        entries(ls, sizeof ls);
        cr_assert_str_eq(ls, "r.vod ");
    }
}

Test(outfile, its_name_opens_it_for_a_writer_by_name)
{
    char p[128];
    path_of("byname.vdb", p, sizeof p);
    for (int named = 0; named < 2; named++) {
        if (named) setenv("VOXD_OUTFILE_NAMED", "1", 1);
        outfile f;
        cr_assert_eq(outfile_open(&f, p), 0);
        int fd = open(outfile_name(&f), O_WRONLY | O_TRUNC);
        cr_assert_geq(fd, 0, "%s: %s", outfile_name(&f), strerror(errno));
        write_str(fd, "grid");
        close(fd);
        cr_assert_eq(outfile_commit(&f, p), 0);
        check_content(p, "grid");
    }
}

Test(outfile, errors_are_the_directorys)
{
    char p[160];
    snprintf(p, sizeof p, "%s/no/such/dir/x.vod", dir);
    outfile f;
    cr_assert_eq(outfile_open(&f, p), -ENOENT);
    setenv("VOXD_OUTFILE_NAMED", "1", 1);
    cr_assert_eq(outfile_open(&f, p), -ENOENT);
}

/* outfile_write appends whatever the sizes of the writes, across the
 * write-back kicks (every OUTFILE_KICK bytes), counts what it wrote, and a
 * write to a closed descriptor is an error, not a short file. */
Test(outfile, outfile_write_appends_across_the_kicks)
{
    char p[128];
    path_of("w.vod", p, sizeof p);
    size_t total = (size_t)(2 * OUTFILE_KICK + 12345);
    uint8_t *src = malloc(total), *back = malloc(total);
    cr_assert(src && back);
    for (size_t i = 0; i < total; i++) src[i] = (uint8_t)(i * 2654435761u >> 13);
    outfile f;
    cr_assert_eq(outfile_open(&f, p), 0);
    for (size_t at = 0, k = 1; at < total; k = k * 3 % 1000003) {
        size_t n = k < total - at ? k : total - at;
        cr_assert_eq(outfile_write(&f, src + at, n), 0);
        at += n;
    }
    cr_assert_eq(f.written, total);
    /* started for all but the last OUTFILE_KICK bytes at most */
    cr_assert(f.kicked >= OUTFILE_KICK && f.kicked <= total && total - f.kicked < OUTFILE_KICK,
              "the write-back started up to %llu of %zu bytes",
              (unsigned long long)f.kicked, total);
    cr_assert_eq(outfile_commit(&f, p), 0);
    FILE *in = fopen(p, "rb");
    cr_assert_not_null(in);
    cr_assert_eq(fread(back, 1, total, in), total);
    cr_assert_eq(fgetc(in), EOF);
    fclose(in);
    cr_assert_eq(memcmp(src, back, total), 0);
    outfile g = {.fd = -1};
    cr_assert_eq(outfile_write(&g, src, 1), -EBADF);
    free(src);
    free(back);
}

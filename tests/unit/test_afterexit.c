/* afterexit: the helper that outlives a command shares its memory (kcmp
 * says so, an independent oracle of the kernel's), holds the file the
 * command replaced (its /proc fd link), lets the command exit, and exits
 * itself once the command is gone; afterexit_hold takes only a regular
 * file of one name.  The test is a subreaper, so the helper is reaped
 * here and a helper that never left would be seen. */
#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <linux/kcmp.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "afterexit.h"
#include "tmpdir_fixture.h"

static void make_dir(void)
{
    tmpdir_make("afterexit");
}

TestSuite(afterexit, .init = make_dir, .fini = tmpdir_remove);

static void put(const char *path, const char *text)
{
    FILE *f = fopen(path, "w");
    cr_assert_not_null(f, "%s: %s", path, strerror(errno));
    fputs(text, f);
    cr_assert_eq(fclose(f), 0);
}

Test(afterexit, holds_only_a_regular_file_of_one_name)
{
    char a[128], b[128];
    snprintf(a, sizeof a, "%s/a", dir);
    snprintf(b, sizeof b, "%s/b", dir);
    cr_assert_eq(afterexit_hold(a), -1, "a missing file is held");
    put(a, "old");
    int fd = afterexit_hold(a);
    cr_assert_geq(fd, 0, "a regular file is not held");
    close(fd);
    cr_assert_eq(link(a, b), 0);
    cr_assert_eq(afterexit_hold(a), -1, "a file of two names is held (the rename frees nothing)");
    cr_assert_eq(afterexit_hold(dir), -1, "a directory is held");
}

/* The one child of pid (the helper), or 0 after a few seconds. */
static pid_t child_of(pid_t pid)
{
    for (int tries = 0; tries < 500; tries++) {
        DIR *d = opendir("/proc");
        struct dirent *e;
        pid_t found = 0;
        while (d && !found && (e = readdir(d))) {
            char p[300], buf[512];
            snprintf(p, sizeof p, "/proc/%s/stat", e->d_name);
            FILE *f = e->d_name[0] >= '1' && e->d_name[0] <= '9' ? fopen(p, "r") : NULL;
            if (!f) continue;
            size_t n = fread(buf, 1, sizeof buf - 1, f);
            fclose(f);
            buf[n] = '\0';
            const char *rp = strrchr(buf, ')');
            int ppid;
            if (rp && sscanf(rp + 2, "%*c %d", &ppid) == 1 && ppid == pid) found = atoi(e->d_name);
        }
        if (d) closedir(d);
        if (found) return found;
        nanosleep(&(struct timespec){0, 10000000}, NULL);
    }
    return 0;
}

/* The command: old replaced by new, the helper started, then "ready" on
 * up and an exit when down closes. */
static _Noreturn void command(const char *old, const char *fresh, int up, int down)
{
    int fd = afterexit_hold(old);
    if (fd < 0 || rename(fresh, old)) _exit(2);
    afterexit_leave(fd);
    char c = 'r';
    if (write(up, &c, 1) != 1) _exit(3);
    while (read(down, &c, 1) > 0) {
    }
    /* as a command ends, but by _exit: under ASan, LSan's check at exit()
     * in a child forked from Criterion's runner tries to suspend the
     * runner's thread (the parent's id, not ours) and reports that it
     * could not; vox itself, under ASan in the integration suites, exits
     * through exit() with its helper alive, and reports nothing. */
    fflush(NULL);
    _exit(0);
}

/* Whether pid has a descriptor on a deleted file whose name ends in tail. */
static int holds_deleted(pid_t pid, const char *tail)
{
    char p[64], link[512];
    snprintf(p, sizeof p, "/proc/%d/fd", (int)pid);
    DIR *d = opendir(p);
    struct dirent *e;
    int found = 0;
    while (d && !found && (e = readdir(d))) {
        char fp[64 + 256 + 2];
        snprintf(fp, sizeof fp, "%s/%s", p, e->d_name);
        ssize_t n = readlink(fp, link, sizeof link - 1);
        if (n <= 0) continue;
        link[n] = '\0';
        found = strstr(link, tail) && strstr(link, "(deleted)");
    }
    if (d) closedir(d);
    return found;
}

Test(afterexit, the_helper_shares_the_memory_holds_the_file_and_leaves_after_the_command)
{
    char old[128], fresh[128];
    snprintf(old, sizeof old, "%s/out.vod", dir);
    snprintf(fresh, sizeof fresh, "%s/out.vod.tmp", dir);
    put(old, "the old file");
    put(fresh, "the new file");
    cr_assert_eq(prctl(PR_SET_CHILD_SUBREAPER, 1), 0);
    int up[2], down[2];
    cr_assert_eq(pipe(up), 0);
    cr_assert_eq(pipe(down), 0);
    pid_t cmd = fork();
    cr_assert_geq(cmd, 0);
    if (cmd == 0) {
        close(up[0]), close(down[1]);
        command(old, fresh, up[1], down[0]);
    }
    close(up[1]), close(down[0]);
    char c;
    cr_assert_eq(read(up[0], &c, 1), 1, "the command did not get as far as its helper");
    pid_t helper = child_of(cmd);
    cr_assert_gt(helper, 0, "no helper under the command");
    long same = syscall(SYS_kcmp, cmd, helper, KCMP_VM, 0, 0);
    cr_assert_eq(same, 0, "the helper does not share the command's memory (kcmp: %ld, %s)", same,
                 same < 0 ? strerror(errno) : "differs");
    cr_assert(holds_deleted(helper, "/out.vod"), "the helper does not hold the replaced file");
    cr_assert_not(holds_deleted(cmd, "/out.vod"), "the command still holds the replaced file");
    close(down[1]); /* the command exits */
    int st;
    cr_assert_eq(waitpid(cmd, &st, 0), cmd);
    cr_assert(WIFEXITED(st) && WEXITSTATUS(st) == 0, "the command ended with status %#x", st);
    alarm(10); /* a helper that never leaves fails the test here */
    cr_assert_eq(waitpid(helper, &st, 0), helper, "the helper was not reaped here: %s",
                 strerror(errno));
    alarm(0);
    cr_assert(WIFEXITED(st) && WEXITSTATUS(st) == 0, "the helper ended with status %#x", st);
    char buf[32] = "";
    FILE *f = fopen(old, "r");
    cr_assert_not_null(f);
    cr_assert_not_null(fgets(buf, sizeof buf, f));
    fclose(f);
    cr_assert_str_eq(buf, "the new file");
    close(up[0]);
}

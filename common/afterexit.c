#include "afterexit.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

/* Valgrind runs no clone but a thread's or a fork's (it stops the program
 * at any other): under it there is no helper.  Without its header (a
 * build machine without valgrind) nothing can run under it either. */
#if defined(__has_include)
#if __has_include(<valgrind/valgrind.h>)
#include <valgrind/valgrind.h>
#endif
#endif
#ifndef RUNNING_ON_VALGRIND
#define RUNNING_ON_VALGRIND 0
#endif

int afterexit_hold(const char *path)
{
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_NOFOLLOW | O_CLOEXEC);
    struct stat st;
    if (fd >= 0 && (fstat(fd, &st) || !S_ISREG(st.st_mode) || st.st_nlink != 1)) {
        close(fd);
        fd = -1;
    }
    return fd;
}

#define HELPER_STACK (64 << 10)

typedef struct {
    int pipe[2]; /* [0]: the helper's end; [1]: ours, open until we exit */
    int fd;      /* the replaced file, or -1 */
} helper_args;

/* The helper, in our memory but a process of its own, every signal
 * blocked (so no handler of ours runs on it): raw system calls only, no
 * library state (it shares our main thread's, errno included).  The
 * arguments live on its stack, copied before we return. */
static int helper_run(void *arg)
{
    helper_args a = *(const helper_args *)arg;
    char c;
    syscall(SYS_close, 0);
    syscall(SYS_close, 1);
    syscall(SYS_close, 2);
    syscall(SYS_close, a.pipe[1]);
    while (syscall(SYS_read, a.pipe[0], &c, 1) > 0) {
    }
    if (a.fd >= 0) syscall(SYS_close, a.fd);
    syscall(SYS_exit, 0);
    return 0;
}

/* The helper started on a stack of its own, never unmapped (our memory
 * is the helper's until it exits), its arguments copied to the stack's
 * low end, which it does not reach, since we do not wait for it to read
 * them: 0, or -1 when it cannot be made. */
static int start_helper(const helper_args *a)
{
    uint8_t *stack = mmap(NULL, HELPER_STACK, PROT_READ | PROT_WRITE,
                          MAP_PRIVATE | MAP_ANONYMOUS | MAP_STACK, -1, 0);
    if (stack == MAP_FAILED) return -1;
    helper_args *arg = (helper_args *)stack; /* the stack's low end, unused by it */
    *arg = *a;
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    pid_t pid = clone(helper_run, stack + HELPER_STACK, CLONE_VM | SIGCHLD, arg);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (pid < 0) munmap(stack, HELPER_STACK);
    return pid < 0 ? -1 : 0;
}

void afterexit_leave(int fd)
{
    helper_args a = {{-1, -1}, fd};
    if (!RUNNING_ON_VALGRIND && pipe2(a.pipe, O_CLOEXEC) == 0) {
        if (start_helper(&a)) close(a.pipe[1]);
        close(a.pipe[0]);
    }
    /* a.pipe[1] stays open: its close at our exit wakes the helper */
    if (fd >= 0) close(fd); /* the helper's own descriptor holds it */
}

/* failmalloc — an LD_PRELOAD shim for daemon_oom.sh: while armed, every
 * Nth allocation that the main program's own code makes (the caller's
 * return address lies in its executable segment) fails with ENOMEM, in the
 * daemon and in the workers it forks.  Allocations by libc, libuv and the
 * other libraries never fail: their own handling of memory running out
 * (libuv aborts in places) is not what is tested.
 *
 *   FAILMALLOC_ARM    a path: armed while that file exists (looked at on
 *                     the first call and every 8 calls of the program's)
 *   FAILMALLOC_EVERY  N (default 7): the program's Nth, 2Nth, ... call fails
 *
 * Built without sanitizers (it is preloaded into the release voxd).  The
 * real functions come from dlsym(RTLD_NEXT); malloc and calloc answer from
 * a static buffer while dlsym itself needs memory. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <link.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static void *(*real_malloc)(size_t);
static void *(*real_calloc)(size_t, size_t);
static void (*real_free)(void *);
static void *(*real_realloc)(void *, size_t);
static void *(*real_aligned_alloc)(size_t, size_t);
static int (*real_posix_memalign)(void **, size_t, size_t);

static uintptr_t text_lo, text_hi; /* the main program's executable segment */
static unsigned long every = 7;
static const char *arm_path;
/* relaxed, all: a count and a flag that only decide which calls fail */
static atomic_ulong calls;
static atomic_int armed;

static int first_object(struct dl_phdr_info *info, size_t size, void *ud)
{
    (void)size, (void)ud;
    for (int i = 0; i < info->dlpi_phnum; i++) {
        const ElfW(Phdr) *ph = &info->dlpi_phdr[i];
        if (ph->p_type != PT_LOAD || !(ph->p_flags & PF_X)) continue;
        text_lo = info->dlpi_addr + ph->p_vaddr;
        text_hi = text_lo + ph->p_memsz;
    }
    return 1; /* the first object is the program */
}

static char boot[4096]; /* the answers while dlsym looks the functions up */
static size_t boot_used;
static int resolving;       /* the first calls are the main thread's alone */

static void *boot_alloc(size_t n)
{
    size_t want = (n + 15) & ~(size_t)15;
    if (want > sizeof boot - boot_used) return NULL;
    void *p = boot + boot_used;
    boot_used += want;
    return p; /* zeroed: static */
}

static void init(void)
{
    if (real_malloc || resolving) return;
    resolving = 1;
    real_calloc = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "calloc");
    real_realloc = (void *(*)(void *, size_t))dlsym(RTLD_NEXT, "realloc");
    real_aligned_alloc = (void *(*)(size_t, size_t))dlsym(RTLD_NEXT, "aligned_alloc");
    real_posix_memalign = (int (*)(void **, size_t, size_t))dlsym(RTLD_NEXT, "posix_memalign");
    real_free = (void (*)(void *))dlsym(RTLD_NEXT, "free");
    void *m = dlsym(RTLD_NEXT, "malloc");
    const char *e = getenv("FAILMALLOC_EVERY");
    if (e && atol(e) > 0) every = (unsigned long)atol(e);
    arm_path = getenv("FAILMALLOC_ARM");
    dl_iterate_phdr(first_object, NULL);
    real_malloc = (void *(*)(size_t))m; /* last: it says the rest is set */
    resolving = 0;
}

/* Whether this call, made from return address ra, fails. */
static int fails(void *ra)
{
    uintptr_t a = (uintptr_t)ra;
    if (!arm_path || a < text_lo || a >= text_hi) return 0;
    unsigned long n = atomic_fetch_add_explicit(&calls, 1, memory_order_relaxed) + 1;
    if (n % 8 == 1) atomic_store_explicit(&armed, access(arm_path, F_OK) == 0, memory_order_relaxed);
    if (!atomic_load_explicit(&armed, memory_order_relaxed) || n % every) return 0;
    errno = ENOMEM;
    return 1;
}

void *malloc(size_t n)
{
    init();
    if (!real_malloc) return boot_alloc(n);
    return fails(__builtin_return_address(0)) ? NULL : real_malloc(n);
}

void *calloc(size_t n, size_t size)
{
    init();
    if (!real_malloc) return size && n > SIZE_MAX / size ? NULL : boot_alloc(n * size);
    return fails(__builtin_return_address(0)) ? NULL : real_calloc(n, size);
}

void *realloc(void *p, size_t n)
{
    init();
    return fails(__builtin_return_address(0)) ? NULL : real_realloc(p, n);
}

void *aligned_alloc(size_t align, size_t n)
{
    init();
    return fails(__builtin_return_address(0)) ? NULL : real_aligned_alloc(align, n);
}

int posix_memalign(void **out, size_t align, size_t n)
{
    init();
    return fails(__builtin_return_address(0)) ? ENOMEM : real_posix_memalign(out, align, n);
}

void free(void *p)
{
    if ((char *)p >= boot && (char *)p < boot + sizeof boot) return;
    init();
    if (real_free) real_free(p);
}

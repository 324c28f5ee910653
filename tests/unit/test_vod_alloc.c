/* The reader when memory runs out: every allocation that vod_read and
 * vod_scan make fails in turn, the first, then the second, and so on until
 * a read makes no more, with one thread and with three.  Each read either
 * gives what it gives with its memory (a scan whose thread lacks its brick
 * of room has another thread do its chunks; a shared brick that cannot be
 * kept is visited where it was inflated) or fails with -ENOMEM, says "out
 * of memory", and hands back no file; nothing leaks (counted
 * here: every block allocated during a read is freed by its end).
 *
 * The failure: this binary alone is linked with
 * -Wl,--wrap=malloc,--wrap=calloc,--wrap=aligned_alloc,--wrap=free (the
 * Makefile says so), so the library's allocations pass through the
 * wrappers below, which count them while armed, fail the one whose turn it
 * is and keep the others in a table until they are freed.  The table, not
 * LeakSanitizer: LSan scans the stacks conservatively, and a pointer left
 * in a dead frame that a later deeper call did not overwrite keeps its
 * block "reachable" (a leak on make_refs' error path went unreported).
 * The library's own threads allocate too: the count is atomic, and which
 * allocation is the n-th may differ between runs with three threads; each
 * run's answer is checked whichever it was. */
#include "vod_fixture.h"

#include <pthread.h>
#include <stdatomic.h>

#include "par.h"

void *__real_malloc(size_t size);
void *__real_calloc(size_t n, size_t size);
void *__real_aligned_alloc(size_t align, size_t size);
void __real_free(void *p);
void *__wrap_malloc(size_t size);
void *__wrap_calloc(size_t n, size_t size);
void *__wrap_aligned_alloc(size_t align, size_t size);
void __wrap_free(void *p);

/* Armed: allocations counted, and the one numbered fail_at (1-based)
 * fails.  Relaxed: the count only numbers the allocations; the test reads
 * it after the read has joined its threads. */
static atomic_bool armed;
static atomic_ulong made, fail_at;

/* The blocks allocated while armed and not freed yet (a read's few dozen;
 * LIVE_MAX bounds them, the test fails past it). */
#define LIVE_MAX 4096
static pthread_mutex_t live_lock = PTHREAD_MUTEX_INITIALIZER;
static void *live[LIVE_MAX];
static size_t nlive;
static bool live_overflow;

static int fail_now(void)
{
    if (!atomic_load_explicit(&armed, memory_order_relaxed)) return 0;
    unsigned long n = atomic_fetch_add_explicit(&made, 1, memory_order_relaxed) + 1;
    return n == atomic_load_explicit(&fail_at, memory_order_relaxed);
}

static void *track(void *p)
{
    if (!p || !atomic_load_explicit(&armed, memory_order_relaxed)) return p;
    pthread_mutex_lock(&live_lock);
    if (nlive < LIVE_MAX) live[nlive++] = p;
    else live_overflow = true;
    pthread_mutex_unlock(&live_lock);
    return p;
}

void *__wrap_malloc(size_t size)
{
    return fail_now() ? NULL : track(__real_malloc(size));
}

void *__wrap_calloc(size_t n, size_t size)
{
    return fail_now() ? NULL : track(__real_calloc(n, size));
}

void *__wrap_aligned_alloc(size_t align, size_t size)
{
    return fail_now() ? NULL : track(__real_aligned_alloc(align, size));
}

void __wrap_free(void *p)
{
    pthread_mutex_lock(&live_lock);
    for (size_t i = 0; p && i < nlive; i++)
        if (live[i] == p) {
            live[i] = live[--nlive];
            break;
        }
    pthread_mutex_unlock(&live_lock);
    __real_free(p);
}

static void arm(unsigned long at)
{
    atomic_store(&made, 0);
    atomic_store(&fail_at, at);
    atomic_store(&armed, true);
}

/* Disarms; whether the armed allocation was made (and failed).  Every
 * block allocated while armed must be free by then. */
static bool disarm(void)
{
    atomic_store(&armed, false);
    pthread_mutex_lock(&live_lock);
    size_t left = nlive;
    bool overflow = live_overflow;
    nlive = 0;
    live_overflow = false;
    pthread_mutex_unlock(&live_lock);
    cr_assert(!overflow, "more than %d blocks allocated at once", LIVE_MAX);
    cr_assert_eq(left, 0, "%zu blocks allocated while armed (allocation %lu failing) were "
                 "never freed", left, atomic_load(&fail_at));
    return atomic_load(&made) >= atomic_load(&fail_at);
}

/* ---- what a read gives: every node's brick summed, order-free ---- */

typedef struct {
    uint32_t sum;
    uint64_t n;
} brick_sum;

static void sum_add(brick_sum *s, const vod_info *in, int level, const uint32_t b[3],
                    const uint8_t *raw)
{
    uint32_t key[4] = {(uint32_t)level, b[0], b[1], b[2]};
    size_t raw_bytes = (size_t)in->brick * in->brick * in->brick * in->voxel_bits / 8;
    uLong c = crc32(0, (const Bytef *)key, sizeof key);
    s->sum += (uint32_t)crc32(c, raw, (uInt)raw_bytes);
    s->n++;
}

static void scan_add(void *ud, unsigned thread, const vod_info *in, int level,
                     const uint32_t b[3], const uint8_t *raw)
{
    brick_sum *per_thread = ud;
    cr_assert_lt(thread, (unsigned)PAR_MAX, "thread %u", thread);
    sum_add(&per_thread[thread], in, level, b, raw);
}

typedef struct {
    const vod_info *in;
    int level;
    brick_sum s;
} walk_sum;

static int walk_add(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    walk_sum *w = ud;
    sum_add(&w->s, w->in, w->level, b, raw);
    return 0;
}

static brick_sum sum_file(const vod_file *v)
{
    walk_sum w = {vod_get_info(v), 0, {0, 0}};
    for (w.level = 0; w.level < (int)w.in->height; w.level++)
        cr_assert_eq(vod_foreach_brick(v, w.level, walk_add, &w), 0);
    return w.s;
}

/* ---- the reads ---- */

typedef struct {
    const membuf *m;
    const char *path; /* the same bytes in a file, for vod_scan */
    int threads;
    bool scan;
} read_case;

/* One read of c: its return code, its sum when it opened, its message. */
static int read_once(const read_case *c, brick_sum *got, err_info *err)
{
    vod_file *v = (vod_file *)1;
    int rc;
    *got = (brick_sum){0, 0};
    if (c->scan) {
        brick_sum per[PAR_MAX] = {{0, 0}};
        vod_scan_opts o = {c->threads, VOD_SCAN_KEEP, scan_add, per};
        rc = vod_scan(c->path, &o, &v, err);
        for (int i = 0; !rc && i < PAR_MAX; i++) got->sum += per[i].sum, got->n += per[i].n;
    } else {
        rc = vod_read_threads(c->m->p, c->m->n, c->threads, &v, err);
        if (!rc) *got = sum_file(v);
    }
    if (rc) cr_assert_null(v, "a failed read handed back a file");
    else vod_close(v);
    return rc;
}

/* Every allocation of c failing in turn: each read gives the whole answer
 * (want) or fails with -ENOMEM and says so.  Returns the allocations a
 * read made (the last run's, which failed none). */
static unsigned long each_allocation_fails(const read_case *c, const brick_sum *want)
{
    for (unsigned long at = 1;; at++) {
        brick_sum got;
        err_info err = {0};
        arm(at);
        int rc = read_once(c, &got, &err);
        bool failed_one = disarm();
        const char *what = c->scan ? "scan" : "read";
        if (!failed_one) {
            cr_assert_eq(rc, 0, "%s, %d threads, nothing failed: %s", what, c->threads, err.msg);
            cr_assert(got.n == want->n && got.sum == want->sum);
            return at - 1;
        }
        if (rc == 0) {
            cr_assert(got.n == want->n && got.sum == want->sum,
                      "%s, %d threads, allocation %lu failed: %llu bricks %08x, want %llu %08x",
                      what, c->threads, at, (unsigned long long)got.n, got.sum,
                      (unsigned long long)want->n, want->sum);
            continue;
        }
        cr_assert_eq(rc, -ENOMEM, "%s, %d threads, allocation %lu failed: %d (%s)", what,
                     c->threads, at, rc, err.msg);
        cr_assert(strstr(err.msg, "out of memory"), "%s, %d threads, allocation %lu: \"%s\"",
                  what, c->threads, at, err.msg);
    }
}

/* m read and scanned by one thread and by three, each allocation failing
 * in turn; at least min_allocs allocations in a read (so that the test
 * reaches the paths it means to). */
static void reads_survive(const membuf *m, unsigned long min_allocs)
{
    char path[] = "/tmp/test_vod_alloc_XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    cr_assert_eq(write(fd, m->p, m->n), (ssize_t)m->n);
    close(fd);
    vod_file *v = read_ok(m);
    brick_sum want = sum_file(v);
    vod_close(v);
    for (int scan = 0; scan < 2; scan++)
        for (int threads = 1; threads <= 3; threads += 2) {
            read_case c = {m, path, threads, scan};
            unsigned long n = each_allocation_fails(&c, &want);
            cr_assert_geq(n, min_allocs, "%s, %d threads: only %lu allocations",
                          scan ? "scan" : "read", threads, n);
        }
    unlink(path);
}

/* Small bricks, many of them shared by more than 16 nodes (a block of one
 * value): the scan keeps those, one allocation each. */
Test(vod_alloc, a_file_of_shared_bricks_reads_or_fails_cleanly)
{
    fixture f;
    fx_init(&f, 6, 64, 48, 40);
    uint32_t v = voxel_surface((const double[3]){0, 0, 1});
    for (uint32_t z = 0; z < 32; z++)
        for (uint32_t y = 0; y < 32; y++)
            for (uint32_t x = 0; x < 40; x++) fx_store(&f, x, y, z, v);
    fx_sphere(&f, 40, 30, 20, 15);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    reads_survive(&m, 6);
    free(m.p);
}

/* Bricks of 1 MiB (64^3, 32 bits), two to a reader's chunk: its slabs are
 * aligned_alloc'd huge-page-sized blocks. */
Test(vod_alloc, a_file_of_large_bricks_reads_or_fails_cleanly)
{
    fixture f;
    fx_init(&f, 8, 192, 128, 128);
    fx_sphere(&f, 96, 64, 64, 60);
    fx_sphere(&f, 30, 30, 30, 20);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 64);
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    reads_survive(&m, 6);
    free(m.p);
}

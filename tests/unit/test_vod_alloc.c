/* The reader when memory runs out: every allocation that vod_read and
 * vod_scan make fails in turn (alloc_fail.h), with one thread and with
 * three.  Each read either gives the whole answer (a scan whose thread
 * lacks its brick of room has another thread do its chunks; a shared
 * brick that cannot be kept is visited where it was inflated) or fails
 * with -ENOMEM, says "out of memory", and hands back no file; every block
 * of the read is freed by its end. */
#include "vod_fixture.h"

#include "alloc_fail.h"
#include "par.h"

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
    brick_sum want; /* the whole file's */
} read_case;

/* One read of c (an alloc_fail_run): its return code; when it opened, the
 * sum of its bricks is the whole file's. */
static int read_once(void *ctx, char *msg)
{
    const read_case *c = ctx;
    vod_file *v = (vod_file *)1;
    err_info err = {0};
    brick_sum got = {0, 0};
    int rc;
    if (c->scan) {
        brick_sum per[PAR_MAX] = {{0, 0}};
        vod_scan_opts o = {c->threads, VOD_SCAN_KEEP, scan_add, per};
        rc = vod_scan(c->path, &o, &v, &err);
        for (int i = 0; !rc && i < PAR_MAX; i++) got.sum += per[i].sum, got.n += per[i].n;
    } else {
        rc = vod_read_threads(c->m->p, c->m->n, c->threads, &v, &err);
        if (!rc) got = sum_file(v);
    }
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) {
        cr_assert_null(v, "a failed read handed back a file");
        return rc;
    }
    vod_close(v);
    cr_assert(got.n == c->want.n && got.sum == c->want.sum,
              "%s, %d threads: %llu bricks %08x, want %llu %08x", c->scan ? "scan" : "read",
              c->threads, (unsigned long long)got.n, got.sum, (unsigned long long)c->want.n,
              c->want.sum);
    return 0;
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
            read_case c = {m, path, threads, scan, want};
            char what[32];
            snprintf(what, sizeof what, "%s, %d threads", scan ? "scan" : "read", threads);
            unsigned long n = alloc_fail_each(read_once, &c, what);
            cr_assert_geq(n, min_allocs, "%s: only %lu allocations", what, n);
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

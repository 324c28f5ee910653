/* The reader and the serial writer when memory runs out: every allocation
 * that vod_read and vod_scan make fails in turn (alloc_fail.h), with one
 * thread and with three (and vod_open_levels of level 0 alone), and every
 * allocation of vod_write_octree with each compression and hash.  Each read either gives the whole answer (a scan whose thread
 * lacks its brick of room has another thread do its chunks; a shared
 * brick that cannot be kept is visited where it was inflated, its bytes
 * left to the budget of the next) or fails with -ENOMEM, says "out of
 * memory", and hands back no file; every block of the read is freed by its
 * end. */
#include "vod_fixture.h"

#include "alloc_fail.h"

/* ---- the reads ---- */

/* How a case reads: vod_read_threads, vod_scan, vod_open_levels of level 0. */
typedef enum { BY_READ, BY_SCAN, BY_LEVEL0 } read_by;

typedef struct {
    const membuf *m;
    const char *path; /* the same bytes in a file, for vod_scan and vod_open_levels */
    int threads;
    read_by by;
    brick_sum want; /* the bricks it reads: the whole file's, or level 0's */
} read_case;

static const char *const read_names[] = {"read", "scan", "level 0"};

/* One read of c (an alloc_fail_run): its return code; when it opened, the
 * sum of its bricks is the whole file's. */
static int read_once(void *ctx, char *msg)
{
    const read_case *c = ctx;
    vod_file *v = (vod_file *)1;
    err_info err = {0};
    brick_sum got = {0, 0};
    int rc;
    if (c->by == BY_SCAN) {
        brick_sum per[PAR_MAX] = {{0, 0}};
        vod_scan_opts o = {c->threads, VOD_SCAN_KEEP, scan_add, per};
        rc = vod_scan(c->path, &o, &v, &err);
        for (int i = 0; !rc && i < PAR_MAX; i++) got.sum += per[i].sum, got.n += per[i].n;
    } else if (c->by == BY_LEVEL0) {
        rc = vod_open_levels(c->path, c->threads, 1, &v, &err);
        if (!rc) got = sum_levels(v, 1);
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
              "%s, %d threads: %llu bricks %08x, want %llu %08x", read_names[c->by],
              c->threads, (unsigned long long)got.n, got.sum, (unsigned long long)c->want.n,
              c->want.sum);
    return 0;
}

/* m read, scanned and opened for level 0 by one thread and by three, each
 * allocation failing in turn; at least min_allocs allocations in a read
 * (so that the test reaches the paths it means to). */
static void reads_survive(const membuf *m, unsigned long min_allocs)
{
    char path[] = "/tmp/test_vod_alloc_XXXXXX";
    fx_temp_file(m, path);
    vod_file *v = read_ok(m);
    brick_sum whole = sum_file(v), level0 = sum_levels(v, 1);
    vod_close(v);
    for (read_by by = BY_READ; by <= BY_LEVEL0; by++)
        for (int threads = 1; threads <= 3; threads += 2) {
            read_case c = {m, path, threads, by, by == BY_LEVEL0 ? level0 : whole};
            char what[32];
            snprintf(what, sizeof what, "%s, %d threads", read_names[by], threads);
            unsigned long n = alloc_fail_each(read_once, &c, what);
            cr_assert_geq(n, min_allocs, "%s: only %lu allocations", what, n);
        }
    unlink(path);
}

/* Small bricks, many of them shared by more than 16 nodes (a block of one
 * value): the scan keeps those, one allocation each. */
Test(vod_alloc, a_file_of_shared_bricks_reads_or_fails_cleanly)
{
    membuf m = fx_file_shared_bricks();
    reads_survive(&m, 6);
    free(m.p);
}

/* A scan of the file at path by one thread, keeping at most keep bytes of
 * shared bricks, armed to fail allocation at (0: none): the bricks' sum,
 * and how many allocations of raw bytes it made. */
static unsigned long scan_watching(const char *path, uint64_t keep, unsigned long at,
                                   size_t raw, brick_sum *got)
{
    brick_sum per[PAR_MAX] = {{0, 0}};
    vod_scan_opts o = {1, keep, scan_add, per};
    vod_file *v = NULL;
    err_info err = {0};
    atomic_store(&af_watch, raw);
    af_arm(at);
    int rc = vod_scan(path, &o, &v, &err);
    if (!rc) vod_close(v);
    af_disarm("scan");
    atomic_store(&af_watch, 0);
    cr_assert_eq(rc, 0, "%s", err.msg);
    *got = (brick_sum){0, 0};
    for (int i = 0; i < PAR_MAX; i++) got->sum += per[i].sum, got->n += per[i].n;
    return atomic_load(&af_watched);
}

/* Two blocks of one value each, each brick shared by 40 nodes: within a
 * budget of one brick the scan keeps the first it meets.  When that copy
 * cannot be made, its bytes go back to the budget and the other block's
 * copy is made instead (one more allocation of a brick's bytes), the
 * answer whole either way. */
Test(vod_alloc, a_copy_that_fails_leaves_the_budget_to_the_next_shared_brick)
{
    fixture f;
    fx_init(&f, 6, 64, 48, 40);
    uint32_t up = voxel_surface((const double[3]){0, 0, 1});
    uint32_t side = voxel_surface((const double[3]){1, 0, 0});
    for (uint32_t z = 0; z < 32; z++)
        for (uint32_t y = 0; y < 32; y++)
            for (uint32_t x = 0; x < 40; x++) fx_store(&f, x, y, z, z < 16 ? up : side);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    char path[] = "/tmp/test_vod_alloc_XXXXXX";
    fx_temp_file(&m, path);
    vod_file *v = read_ok(&m);
    brick_sum want = sum_file(v), got;
    vod_close(v);
    size_t raw = (size_t)8 * 8 * 8 * 4;
    unsigned long whole = scan_watching(path, raw, 0, raw, &got);
    cr_assert(got.n == want.n && got.sum == want.sum);
    unsigned long copy = atomic_load(&af_watched_last); /* the kept copy's malloc */
    unsigned long after = scan_watching(path, raw, copy, raw, &got);
    cr_assert(got.n == want.n && got.sum == want.sum);
    cr_assert_eq(after, whole + 1, "a refused copy kept its bytes from the budget: "
                 "%lu brick-sized allocations, %lu without the failure", after, whole);
    unlink(path);
    free(m.p);
}

/* Bricks of 1 MiB, two to a reader's chunk: its slabs are aligned_alloc'd
 * huge-page-sized blocks. */
Test(vod_alloc, a_file_of_large_bricks_reads_or_fails_cleanly)
{
    membuf m = fx_file_large_bricks(VOD_COMP_ZLIB);
    reads_survive(&m, 6);
    free(m.p);
}

/* ---- the serial writer (vod_write_octree), every compression and hash ---- */

typedef struct {
    fixture *f;
    vod_params p;
    membuf want;
} write_case;

/* mem_write into the test's own memory (the writer's sink is not the
 * writer's allocation). */
static int test_mem_write(void *ud, const void *buf, size_t n)
{
    membuf *m = ud;
    uint8_t *p = af_test_realloc(m->p, m->n + n);
    cr_assert(p);
    memcpy(p + m->n, buf, n);
    m->p = p, m->n += n;
    return 0;
}

static int write_once(void *ctx, char *msg)
{
    write_case *c = ctx;
    membuf m = {0};
    vod_sink sink = {test_mem_write, &m};
    vod_stats st;
    err_info err = {0};
    int rc = vod_write_octree(&c->f->t, &c->p, &sink, &st, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    cr_assert_null(c->f->t.agg, "the writer's aggregates kept");
    if (!rc) cr_assert(m.n == c->want.n && !memcmp(m.p, c->want.p, m.n), "other bytes");
    free(m.p);
    return rc;
}

Test(vod_alloc, the_serial_writer_writes_or_fails_cleanly)
{
    fixture f;
    fx_init(&f, 6, 64, 48, 40);
    fx_sphere(&f, 30, 24, 20, 15);
    fx_random(&f, 300);
    const uint32_t comps[] = {VOD_COMP_ZLIB, VOD_COMP_NONE, VOD_COMP_RUNL};
    const uint32_t hashes[] = {VOD_HASH_SFHS, VOD_HASH_XX32, VOD_HASH_SFHS};
    const char *const names[] = {"write, ZLIB SFHS", "write, NONE XX32", "write, RUNL SFHS"};
    for (int k = 0; k < 3; k++) {
        write_case c = {.f = &f};
        params(&c.p, &f, VOXEL_CH_SURFACE, comps[k], hashes[k], 8);
        c.want = write_file(&f, &c.p, NULL);
        cr_assert_geq(alloc_fail_runs(write_once, &c, names[k], false), 3, "%s", names[k]);
        free(c.want.p);
    }
    fx_free(&f);
}

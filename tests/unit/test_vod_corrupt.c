/* VOD files that do not check: every truncation and every bit flip of a small
 * file, a file without its trailer, a hand-made bad file for each case of spec
 * section 8 with its message, tiny and empty inputs; and the reader on several
 * threads gives one thread's answer and message (its CRC in parts too). */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zlib.h>
#include <libdeflate.h>

#include "octree.h"
#include "par.h"
#include "vod.h"
#include "vod_downsample.h"
#include "vod_volume.h"
#include "voxel.h"
#include "unit_util.h"

#include "vod_fixture.h"

static void fix_crc(uint8_t *b, size_t n)
{
    uint32_t c = (uint32_t)crc32(0, b, (uInt)(n - 4));
    vod_put32(b + n - 4, c);
}

/* --------------------------------------------------------- corruption */

static membuf small_file(void)
{
    fixture f;
    fx_init(&f, 4, 10, 9, 7);
    fx_random(&f, 60);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    p.metadata = "source=test\n";
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    return m;
}

static int try_read(const uint8_t *b, size_t n, err_info *err)
{
    vod_file *v = (vod_file *)1;
    *err = (err_info){.code = 1, .msg = "stale"};
    int rc = vod_read(b, n, &v, err);
    if (rc == 0) {
        vod_close(v);
        cr_assert_str_eq(err->msg, "", "success with a message left");
        cr_assert_eq(err->code, 0, "success with a code left");
    } else {
        cr_assert_null(v);
        cr_assert(err->msg[0], "failure without a message");
        cr_assert_eq(err->code, rc, "returned %d, err says %d", rc, err->code);
    }
    return rc;
}

Test(vod_corrupt, every_truncation_fails_with_a_message)
{
    membuf m = small_file();
    err_info err = {0};
    for (size_t n = 0; n < m.n; n++) {
        uint8_t *cut = malloc(n + 1); /* exact size, so ASan sees any overread */
        memcpy(cut, m.p, n);
        cr_assert_neq(try_read(cut, n, &err), 0, "truncated to %zu read fine", n);
        if (n >= 64) cr_assert(strstr(err.msg, "truncated") || strstr(err.msg, "CRC"), "%zu: %s", n, err.msg);
        free(cut);
    }
    cr_assert_eq(try_read(m.p, m.n, &err), 0);
    free(m.p);
}

Test(vod_corrupt, every_bit_flip_fails)
{
    membuf m = small_file();
    err_info err = {0};
    size_t crc_reports = 0, bits = m.n * 8;
    for (size_t bit = 0; bit < bits; bit++) {
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        cr_assert_neq(try_read(m.p, m.n, &err), 0, "bit %zu flipped read fine", bit);
        crc_reports += strstr(err.msg, "CRC") != NULL;
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
    cr_assert(crc_reports > bits * 9 / 10, "%zu of %zu flips reported as CRC", crc_reports, bits);
    free(m.p);
}

/* The same file as Figure 24 alone describes it: no trailer, bit 16 clear. */
static size_t strip_trailer(membuf *m)
{
    uint32_t at = vod_get32(m->p + m->n - 12);
    vod_put32(m->p + 60, vod_get32(m->p + 60) & ~VOD_FLAG_TRAILER);
    m->n = at;
    return at;
}

Test(vod_corrupt, file_without_trailer_reads_and_refuses_truncation)
{
    membuf m = small_file(), full = small_file();
    strip_trailer(&m);
    err_info err = {0};
    vod_file *v = read_ok(&m), *w = read_ok(&full);
    cr_assert_eq(vod_get_info(v)->has_trailer, 0);
    cr_assert_str_eq(vod_get_info(v)->metadata, "");
    for (uint32_t i = 0; i < 16 * 16 * 16; i++)
        cr_assert_eq(vod_voxel(v, 0, i % 16, i / 16 % 16, i / 256),
                     vod_voxel(w, 0, i % 16, i / 16 % 16, i / 256));
    vod_close(v);
    vod_close(w);
    for (size_t n = 0; n < m.n; n++) {
        uint8_t *cut = malloc(n + 1);
        memcpy(cut, m.p, n);
        cr_assert_neq(try_read(cut, n, &err), 0, "truncated to %zu read fine", n);
        free(cut);
    }
    /* bit flips without a CRC: some are harmless (a voxelScale bit), none may crash */
    for (size_t bit = 0; bit < m.n * 8; bit += 3) {
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        try_read(m.p, m.n, &err);
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
    /* trailing garbage is refused when bit 16 says there is no trailer */
    uint8_t *more = malloc(m.n + 3);
    memcpy(more, m.p, m.n);
    memset(more + m.n, 0, 3);
    cr_assert_neq(try_read(more, m.n + 3, &err), 0);
    cr_assert(strstr(err.msg, "3 unexpected bytes after the last brick record"), "%s", err.msg);
    free(more);
    free(m.p);
    free(full.p);
}

/* Where things are in a file, found with the spec's arithmetic. */
typedef struct {
    uint64_t nodes, count_at, table_at;
    uint32_t count;
} where;

static where locate(const uint8_t *b)
{
    where w;
    w.nodes = ((1ull << (3 * vod_get32(b + 44))) - 1) / 7;
    w.count_at = 64 + 4 * w.nodes;
    w.count = vod_get32(b + w.count_at);
    w.table_at = w.count_at + 4;
    return w;
}

typedef void (*patch_fn)(uint8_t *b, size_t *n, const where *w);

static void expect_refusal(patch_fn patch, int keep_crc, const char *want)
{
    membuf m = small_file();
    where w = locate(m.p);
    patch(m.p, &m.n, &w);
    if (!keep_crc) fix_crc(m.p, m.n);
    err_info err = {0};
    cr_assert_neq(try_read(m.p, m.n, &err), 0, "patched file for '%s' read fine", want);
    cr_assert(strstr(err.msg, want), "message '%s' lacks '%s'", err.msg, want);
    free(m.p);
}

static void p_sig(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; b[1] = 'X'; }

static void p_version(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 4, 2); }

static void p_brick3(uint8_t *b, size_t *n, const where *w)
{
    (void)n, (void)w;
    for (int a = 0; a < 3; a++) vod_put32(b + 20 + 4 * a, 3);
}

static void p_brick_shape(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 28, 8); }

static void p_volume0(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 12, 0); }

static void p_scale(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 36, 0x7fc00000); }

static void p_height(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 44, 5); }

static void p_bits(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 48, 7); }

static void p_hash(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; memcpy(b + 52, "ABCD", 4); }

static void p_comp(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; memcpy(b + 56, "FTLZ", 4); }

static void p_flag0(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; b[60] &= (uint8_t)~1u; }

static void p_flag1(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; b[60] &= (uint8_t)~2u; }

static void p_flag5(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; b[60] |= 32; }

/* volumeSize 4000 with a matching treeHeight 11: the table cannot fit */
static void p_huge(uint8_t *b, size_t *n, const where *w)
{
    (void)n, (void)w;
    vod_put32(b + 8, 4000);
    vod_put32(b + 44, 11);
}

static void p_id(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + 64 + 4 * 3, w->count + 5); }

static void p_root0(uint8_t *b, size_t *n, const where *w) { (void)n, (void)w; vod_put32(b + 64, 0); }

static void p_count(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + w->count_at, 1000000); }

static void p_dup(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + w->table_at + 12, vod_get32(b + w->table_at)); }

static void p_id0(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + w->table_at + 12, 0); }

static void p_offset(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + w->table_at + 4, 12345678); }

static void p_offset_low(uint8_t *b, size_t *n, const where *w) { (void)n; vod_put32(b + w->table_at + 4, 64); }

static void p_datasize(uint8_t *b, size_t *n, const where *w)
{
    (void)n;
    vod_put32(b + vod_get32(b + w->table_at + 4), 1u << 30);
}

static void p_overlap(uint8_t *b, size_t *n, const where *w)
{
    (void)n;
    vod_put32(b + w->table_at + 12 + 4, vod_get32(b + w->table_at + 4));
}

static void p_zlib(uint8_t *b, size_t *n, const where *w)
{
    (void)n;
    b[vod_get32(b + w->table_at + 4) + 4] = 0x00; /* zlib header 0x78 -> 0x00 */
}

static void p_zlib_tail(uint8_t *b, size_t *n, const where *w)
{
    (void)n; /* corrupt the stream's end (its Adler-32) */
    uint32_t off = vod_get32(b + w->table_at + 4);
    b[off + 4 + vod_get32(b + off) - 1] ^= 0x55;
}

static void p_hashval(uint8_t *b, size_t *n, const where *w) { (void)n; b[w->table_at + 8] ^= 1; }

static void p_crc_only(uint8_t *b, size_t *n, const where *w) { (void)w; b[*n / 2] ^= 4; }

static void p_no_trailer(uint8_t *b, size_t *n, const where *w) { (void)b, (void)w; *n = vod_get32(b + *n - 12); }

static void p_bad_offset(uint8_t *b, size_t *n, const where *w) { (void)w; vod_put32(b + *n - 12, 70); }

static void p_channel(uint8_t *b, size_t *n, const where *w)
{
    (void)w;
    vod_put32(b + vod_get32(b + *n - 12) + 20, 1);
}

static void p_meta(uint8_t *b, size_t *n, const where *w)
{
    (void)w;
    vod_put32(b + vod_get32(b + *n - 12) + 24, 1000);
}

static void p_garbage(uint8_t *b, size_t *n, const where *w)
{
    (void)n; /* the last record is followed by 4 bytes no one points at */
    uint32_t off = vod_get32(b + w->table_at + 12 * (w->count - 1) + 4);
    vod_put32(b + off, vod_get32(b + off) - 4);
}

Test(vod_corrupt, each_section8_case_has_its_message)
{
    expect_refusal(p_sig, 0, "bad signature");
    expect_refusal(p_version, 0, "unsupported fileVersion 2");
    expect_refusal(p_brick3, 0, "brickSize 3 is not a power of two in 2..256");
    expect_refusal(p_brick_shape, 0, "brickSize 4x4x8 is not cubic");
    expect_refusal(p_volume0, 0, "volumeSize 10x0x7");
    expect_refusal(p_scale, 0, "voxelScale");
    expect_refusal(p_height, 0, "treeHeight 5 does not fit");
    expect_refusal(p_bits, 0, "voxelSize 7");
    expect_refusal(p_hash, 0, "unsupported hashAlgorithm 'ABCD'");
    expect_refusal(p_comp, 0, "unsupported compAlgorithm 'FTLZ'");
    expect_refusal(p_flag0, 0, "flags bit 0");
    expect_refusal(p_flag1, 0, "flags bit 1");
    expect_refusal(p_flag5, 0, "reserved");
    expect_refusal(p_huge, 0, "file is truncated: octree table");
    expect_refusal(p_id, 0, "is not in the brick table");
    expect_refusal(p_root0, 0, "node 0 has brickID 0");
    expect_refusal(p_count, 0, "numberOfBricks 1000000");
    expect_refusal(p_dup, 0, "duplicate brick ID 1 in table");
    expect_refusal(p_id0, 0, "brickID 0, outside");
    expect_refusal(p_offset, 0, "brick 1: offset 12345678 outside the file");
    expect_refusal(p_offset_low, 0, "brick 1: offset 64 outside the file");
    expect_refusal(p_datasize, 0, "brick 1: dataSize 1073741824");
    expect_refusal(p_overlap, 0, "overlaps");
    expect_refusal(p_zlib, 0, "brick 1 does not decompress to 256 bytes");
    expect_refusal(p_zlib_tail, 0, "brick 1 does not decompress");
    expect_refusal(p_hashval, 0, "brick 1: hash mismatch");
    expect_refusal(p_crc_only, 1, "trailer CRC mismatch (file corrupted)");
    expect_refusal(p_no_trailer, 1, "'XDOV' is not at offset");
    expect_refusal(p_bad_offset, 0, "trailerOffset 70");
    expect_refusal(p_channel, 0, "trailer channel 1 needs voxelSize 1");
    expect_refusal(p_meta, 0, "metadataSize 1000");
    expect_refusal(p_garbage, 0, "4 unexpected bytes after the last brick record");
}

/* ------------------------------------------- reading with several threads */

static membuf chunked_file_as(uint32_t comp)
{
    return fx_file_large_bricks(comp);
}

static membuf chunked_file(void)
{
    return fx_file_large_bricks(VOD_COMP_ZLIB);
}

/* The brick records' (offset, ID) in file order. */
typedef struct {
    uint32_t off, id;
} brick_rec;

static int brick_rec_cmp(const void *a, const void *b)
{
    const brick_rec *x = a, *y = b;
    return (x->off > y->off) - (x->off < y->off);
}

static brick_rec *records(const membuf *m, uint32_t *n)
{
    where w = locate(m->p);
    brick_rec *r = malloc(w.count * sizeof *r);
    cr_assert(r);
    for (uint32_t i = 0; i < w.count; i++)
        r[i] = (brick_rec){vod_get32(m->p + w.table_at + 12 * i + 4),
                     vod_get32(m->p + w.table_at + 12 * i)};
    qsort(r, w.count, sizeof *r, brick_rec_cmp);
    *n = w.count;
    return r;
}

static const int thread_counts[] = {2, 3, 4, 16};

/* ---- vod_scan against the bricks vod_read keeps ---- */

/* m scanned by each thread count, keeping the shared bricks (the default
 * budget) and keeping none: the same code and message as one thread's
 * vod_read (rc, err), and for a file that opens (one), every node's brick
 * handed once, as one keeps them; the scanned file's info is one's and its
 * voxels are not there. */
static void scan_agrees(const membuf *m, int rc, const err_info *err, const vod_file *one)
{
    char path[] = "/tmp/test_vod_scan_XXXXXX";
    fx_temp_file(m, path);
    kept_sum k = {one ? vod_get_info(one) : NULL, 0, one ? sum_file(one) : (brick_sum){0, 0}};
    size_t runs = 2 * (1 + sizeof thread_counts / sizeof *thread_counts);
    for (size_t t = 0; t < runs; t++) {
        int threads = t / 2 ? thread_counts[t / 2 - 1] : 1;
        brick_sum per[PAR_MAX] = {{0, 0}}, all = {0, 0};
        vod_file *v = (vod_file *)1;
        err_info e2 = {0};
        vod_scan_opts o = {threads, t % 2 ? 0 : VOD_SCAN_KEEP, scan_add, per};
        int r2 = vod_scan(path, &o, &v, &e2);
        cr_assert_eq(r2, rc, "scan, %d threads (keep %llu): %d (%s), read: %d (%s)", threads,
                     (unsigned long long)o.keep_bytes, r2, e2.msg, rc, err->msg);
        cr_assert_str_eq(e2.msg, rc ? err->msg : "", "scan, %d threads", threads);
        if (rc) {
            cr_assert_null(v);
            continue;
        }
        for (int i = 0; i < PAR_MAX; i++) all.sum += per[i].sum, all.n += per[i].n;
        cr_assert(all.n == k.s.n && all.sum == k.s.sum, "scan, %d threads (keep %llu): %llu "
                  "bricks %08x, kept %llu %08x", threads, (unsigned long long)o.keep_bytes,
                  (unsigned long long)all.n, all.sum, (unsigned long long)k.s.n, k.s.sum);
        const vod_info *a = vod_get_info(v), *b = k.in;
        cr_assert(a->bricks == b->bricks && a->nodes == b->nodes && a->crc32 == b->crc32 &&
                  a->brick_data_bytes == b->brick_data_bytes && !strcmp(a->metadata, b->metadata));
        uint32_t origin[3] = {0, 0, 0};
        cr_assert_eq(vod_voxel(v, 0, 0, 0, 0), 0);
        cr_assert_null(vod_brick(v, (int)a->height - 1, origin));
        cr_assert_eq(vod_foreach_brick(v, 0, kept_add, &k), -EINVAL);
        vod_close(v);
    }
    unlink(path);
}

/* ---------------------------------------------------- some levels only */

/* The levels whose nodes hold each brick ID (bit l of held[id]), walked
 * here in the file's octree table (preorder; a level-l node's children
 * are subtrees of (8^l - 1) / 7 nodes each). */
static void held_walk(const uint8_t *tree, uint64_t p, int l, uint32_t count, uint32_t *held)
{
    uint32_t id = vod_get32(tree + 4 * p);
    if (!id) return;
    if (id <= count) held[id] |= 1u << l;
    uint64_t sub = ((1ull << (3 * l)) - 1) / 7;
    for (unsigned i = 0; l > 0 && i < 8; i++) held_walk(tree, p + 1 + i * sub, l - 1, count, held);
}

static void rewrite(const char *path, const membuf *m)
{
    FILE *fp = fopen(path, "wb");
    cr_assert(fp && fwrite(m->p, 1, m->n, fp) == m->n && !fclose(fp), "%s", path);
}

/* v opened with the levels in mask `levels`: those levels' bricks are the
 * whole read's, every other level reads as absent. */
static void levels_agree(const vod_file *v, const vod_file *whole, uint32_t levels)
{
    const vod_info *in = vod_get_info(whole);
    for (int l = 0; l < (int)in->height; l++) {
        brick_sum a = sum_levels(whole, 1u << l);
        uint32_t origin[3] = {0, 0, 0};
        if (levels >> l & 1u) {
            brick_sum b = sum_levels(v, 1u << l);
            cr_assert(a.n == b.n && a.sum == b.sum, "level %d: other bricks", l);
            continue;
        }
        kept_sum k = {in, l, {0, 0}};
        cr_assert_eq(vod_foreach_brick(v, l, kept_add, &k), -EINVAL, "level %d walked", l);
        cr_assert_null(vod_brick(v, l, origin), "level %d has a brick", l);
        cr_assert_eq(vod_foreach(v, l, NULL, NULL), -EINVAL, "level %d walked", l);
    }
}

/* Each level alone, two of them, none and every one: the levels asked for
 * read as the whole read's, the others as absent. */
Test(vod_levels, the_levels_asked_for_are_read_and_only_they)
{
    membuf m = small_file();
    char path[] = "/tmp/test_vod_levels_XXXXXX";
    fx_temp_file(&m, path);
    vod_file *whole = read_ok(&m);
    int height = (int)vod_get_info(whole)->height;
    cr_assert_geq(height, 3);
    const uint32_t masks[] = {1, 2, 4, 5, 0, 1u << height, VOD_LEVELS_ALL};
    for (size_t i = 0; i < sizeof masks / sizeof *masks; i++) {
        vod_file *v;
        err_info err = {0};
        cr_assert_eq(vod_open_levels(path, 2, masks[i], &v, &err), 0, "%s", err.msg);
        levels_agree(v, whole, masks[i]);
        vod_close(v);
    }
    /* a voxel of level 0 reads 0 when level 0 was not asked for */
    vod_file *v;
    err_info err = {0};
    cr_assert_eq(vod_open_levels(path, 1, 2, &v, &err), 0, "%s", err.msg);
    unsigned differ = 0, n = vod_level_size(whole, 0);
    for (uint32_t z = 0; z < n; z++)
        for (uint32_t y = 0; y < n; y++)
            for (uint32_t x = 0; x < n; x++) {
                cr_assert_eq(vod_voxel(v, 0, x, y, z), 0);
                differ += vod_voxel(whole, 0, x, y, z) != 0;
            }
    cr_assert_gt(differ, 0, "a file without a voxel at level 0");
    vod_close(v);
    vod_close(whole);
    unlink(path);
    free(m.p);
}

/* Each brick's hash damaged in turn (the CRC made right again): opened
 * with one level, the file is refused, naming that brick, exactly when a
 * node of that level holds it (the table walked here), and read whole
 * otherwise; vod_open refuses it always. */
Test(vod_levels, a_damaged_brick_is_found_by_the_levels_that_hold_it)
{
    membuf m = small_file();
    where w = locate(m.p);
    int height = (int)vod_get32(m.p + 44);
    uint32_t *held = calloc(w.count + 1, sizeof *held);
    cr_assert(held);
    held_walk(m.p + 64, 0, height - 1, w.count, held);
    char path[] = "/tmp/test_vod_levels_XXXXXX";
    fx_temp_file(&m, path);
    vod_file *whole = read_ok(&m);
    unsigned found = 0, passed = 0;
    for (uint32_t i = 0; i < w.count; i++) {
        uint32_t id = vod_get32(m.p + w.table_at + 12 * i);
        char want[48];
        snprintf(want, sizeof want, "brick %u: hash mismatch", id);
        m.p[w.table_at + 12 * i + 8] ^= 1;
        fix_crc(m.p, m.n);
        rewrite(path, &m);
        vod_file *v = (vod_file *)1;
        err_info err = {0};
        cr_assert_eq(vod_open_threads(path, 2, &v, &err), -EBADMSG, "brick %u", id);
        for (int l = 0; l < height; l++) {
            v = (vod_file *)1;
            int rc = vod_open_levels(path, 2, 1u << l, &v, &err);
            if (held[id] >> l & 1u) {
                cr_assert_eq(rc, -EBADMSG, "brick %u, level %d: %d", id, l, rc);
                cr_assert(strstr(err.msg, want), "'%s' lacks '%s'", err.msg, want);
                cr_assert_null(v);
                found++;
            } else {
                cr_assert_eq(rc, 0, "brick %u, level %d: %s", id, l, err.msg);
                levels_agree(v, whole, 1u << l);
                vod_close(v);
                passed++;
            }
        }
        m.p[w.table_at + 12 * i + 8] ^= 1;
    }
    cr_assert(found > 0 && passed > 0, "found %u, passed %u", found, passed);
    vod_close(whole);
    unlink(path);
    free(held);
    free(m.p);
}

/* m read by 1 thread and by each of thread_counts: the same return code and
 * message, and when it opens, the same bricks at every level; and scanned
 * alike (scan_agrees).  Returns the return code; err holds the message. */
static int read_threads_agree(const membuf *m, err_info *err)
{
    vod_file *one = (vod_file *)1;
    int rc = vod_read_threads(m->p, m->n, 1, &one, err);
    scan_agrees(m, rc, err, rc ? NULL : one);
    for (size_t k = 0; k < sizeof thread_counts / sizeof *thread_counts; k++) {
        vod_file *v = (vod_file *)1;
        err_info e2 = {0};
        int r2 = vod_read_threads(m->p, m->n, thread_counts[k], &v, &e2);
        cr_assert_eq(r2, rc, "%d threads: %d (%s), 1 thread: %d (%s)", thread_counts[k], r2,
                     e2.msg, rc, err->msg);
        cr_assert_str_eq(e2.msg, rc ? err->msg : "", "%d threads", thread_counts[k]);
        if (rc) {
            cr_assert_null(v);
            continue;
        }
        const vod_info *in = vod_get_info(one);
        size_t raw = (size_t)in->brick * in->brick * in->brick * in->voxel_bits / 8;
        for (int l = 0; l < (int)in->height; l++) {
            uint32_t side = 1u << (in->height - 1 - (uint32_t)l), b[3];
            for (b[2] = 0; b[2] < side; b[2]++)
                for (b[1] = 0; b[1] < side; b[1]++)
                    for (b[0] = 0; b[0] < side; b[0]++) {
                        const uint8_t *x = vod_brick(one, l, b), *y = vod_brick(v, l, b);
                        cr_assert_eq(!x, !y);
                        if (x) cr_assert_eq(memcmp(x, y, raw), 0, "level %d brick %u %u %u",
                                            l, b[0], b[1], b[2]);
                    }
        }
        vod_close(v);
    }
    if (!rc) vod_close(one);
    return rc;
}

Test(vod_threads, several_threads_read_what_one_reads)
{
    membuf m = chunked_file();
    err_info err = {0};
    uint32_t n;
    free(records(&m, &n));
    cr_assert_geq(n, 12, "only %u bricks", n);
    cr_assert_eq(read_threads_agree(&m, &err), 0, "%s", err.msg);
    /* and through a file */
    char path[] = "/tmp/test_vod_threads_XXXXXX";
    fx_temp_file(&m, path);
    vod_file *v;
    cr_assert_eq(vod_open_threads(path, 4, &v, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_get_info(v)->bricks, n);
    vod_close(v);
    unlink(path);
    free(m.p);
}

/* Damage in records anywhere in the file (the first, one in the middle, the
 * last, and two at once): every thread count reports the first damaged
 * record in file order, with one thread's words. */
Test(vod_threads, the_first_bad_record_is_reported_whatever_the_threads)
{
    membuf m = chunked_file();
    uint32_t n;
    brick_rec *r = records(&m, &n);
    const uint32_t at[][2] = {{0, 0}, {n / 2, n / 2}, {n - 1, n - 1}, {n / 2, n - 1},
                              {1, n - 2}, {n - 2, 1}};
    for (size_t t = 0; t < sizeof at / sizeof *at; t++) {
        for (int k = 0; k < 2; k++)
            cr_assert_gt(vod_get32(m.p + r[at[t][k]].off), 30, "a record too small to damage");
        uint8_t *p[2] = {m.p + r[at[t][0]].off + 20, m.p + r[at[t][1]].off + 30};
        p[0][0] ^= 0x5a;
        p[1][0] ^= 0x21;
        fix_crc(m.p, m.n);
        err_info err = {0};
        char want[32];
        cr_assert_neq(read_threads_agree(&m, &err), 0);
        uint32_t first = at[t][0] < at[t][1] ? at[t][0] : at[t][1];
        snprintf(want, sizeof want, "brick %u", r[first].id);
        cr_assert(strstr(err.msg, want), "case %zu: '%s' does not name %s", t, err.msg, want);
        p[1][0] ^= 0x21;
        p[0][0] ^= 0x5a;
    }
    /* a hash in the table that does not match: the last record's */
    where w = locate(m.p);
    for (uint32_t i = 0; i < n; i++)
        if (vod_get32(m.p + w.table_at + 12 * i) == r[n - 1].id)
            vod_put32(m.p + w.table_at + 12 * i + 8, vod_get32(m.p + w.table_at + 12 * i + 8) ^ 1);
    fix_crc(m.p, m.n);
    err_info err = {0};
    char want[48];
    cr_assert_neq(read_threads_agree(&m, &err), 0);
    snprintf(want, sizeof want, "brick %u: hash mismatch", r[n - 1].id);
    cr_assert(strstr(err.msg, want), "'%s' lacks '%s'", err.msg, want);
    free(r);
    free(m.p);
}

static int count_brick(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    (void)b, (void)raw;
    ++*(uint64_t *)ud;
    return 0;
}

/* A block of one value, so that many nodes share its bricks (the file
 * stores one): vod_scan hands a shared brick to every node that holds it,
 * as vod_read's walks see it. */
Test(vod_threads, a_shared_brick_is_scanned_for_every_node)
{
    membuf m = fx_file_shared_bricks();
    vod_file *one = read_ok(&m);
    uint64_t nodes = 0;
    for (int l = 0; l < (int)vod_get_info(one)->height; l++)
        vod_foreach_brick(one, l, count_brick, &nodes);
    cr_assert_gt(nodes, (uint64_t)vod_get_info(one)->bricks + 40, "%llu nodes, %u bricks: "
                 "too few shared", (unsigned long long)nodes, vod_get_info(one)->bricks);
    vod_close(one);
    err_info err = {0};
    cr_assert_eq(read_threads_agree(&m, &err), 0, "%s", err.msg);
    free(m.p);
}

/* The file's CRC checked in parts, one a thread (1 MiB or more each): an
 * uncompressed file of 1 MiB bricks, a byte changed in the first part, in
 * a middle one, in the last and in the trailer's offset: every thread
 * count reports the mismatch with one thread's computed CRC, and the whole
 * file checks (the parts' CRCs joined are the file's). */
Test(vod_threads, the_crc_in_parts_is_the_crc_of_the_whole)
{
    membuf m = chunked_file_as(VOD_COMP_NONE);
    cr_assert_gt(m.n, (size_t)8 << 20, "%zu bytes: 2 to 4 threads would not each take a part", m.n);
    err_info err = {0};
    cr_assert_eq(read_threads_agree(&m, &err), 0, "%s", err.msg);
    const size_t at[] = {100, m.n / 3, m.n / 2 + 12345, m.n - 200, m.n - 9};
    for (size_t k = 0; k < sizeof at / sizeof *at; k++) {
        m.p[at[k]] ^= 0x40;
        cr_assert_neq(read_threads_agree(&m, &err), 0, "byte %zu changed", at[k]);
        cr_assert(strstr(err.msg, "trailer CRC mismatch"), "byte %zu: %s", at[k], err.msg);
        m.p[at[k]] ^= 0x40;
    }
    free(m.p);
}

Test(vod_corrupt, tiny_and_empty_inputs)
{
    err_info err = {0};
    cr_assert_neq(try_read(NULL, 0, &err), 0);
    cr_assert(strstr(err.msg, "file is truncated: the header needs 64 bytes, file has 0"), "%s", err.msg);
    uint8_t hdr[64] = {0x2E, 0x56, 0x4F, 0x44};
    vod_put32(hdr + 60, VOD_FLAG_TRAILER);
    cr_assert_neq(try_read(hdr, sizeof hdr, &err), 0);
    cr_assert(strstr(err.msg, "truncated"), "%s", err.msg);
}

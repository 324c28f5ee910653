/* VOD writer and reader against independent oracles: hash test vectors and
 * a reference SuperFastHash, dense arrays of the voxels written, a
 * downsampling oracle per level, a second minimal reader that follows
 * Figure 24 alone, the header's bytes, and every truncation and bit flip of
 * a small file plus a hand-made bad file for each case of spec section 8.
 * The two brick sources, octree and volume, give the same bytes for the
 * same voxels (the volume's own tests: test_vod_volume.c). */
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
#include "vod.h"
#include "vod_downsample.h"
#include "vod_volume.h"
#include "voxel.h"

#include "unit_util.h"

/* ---------------------------------------------------------------- helpers */

static uint64_t rng_state = 88172645463325252ull;
static uint32_t rnd(void) { return xorshift32(&rng_state); }

/* An octree and a dense copy of its voxels over the octree's 2^depth cube. */
typedef struct {
    octree t;
    octree_cell *arena;
    uint32_t side;
    uint32_t *dense;
    uint32_t vol[3];
    uint64_t count;
} fixture;

static void fx_init(fixture *f, int depth, uint32_t vx, uint32_t vy, uint32_t vz)
{
    uint32_t cap = 1u << 18;
    f->arena = malloc(octree_arena_bytes(cap));
    cr_assert(f->arena);
    octree_init(&f->t, f->arena, cap, depth);
    f->side = 1u << depth;
    f->dense = calloc((size_t)f->side * f->side * f->side, sizeof *f->dense);
    cr_assert(f->dense);
    f->vol[0] = vx;
    f->vol[1] = vy;
    f->vol[2] = vz;
    f->count = 0;
}

static void fx_free(fixture *f)
{
    free(f->arena);
    free(f->dense);
}

static void fx_store(fixture *f, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    cr_assert_eq(octree_store(&f->t, x, y, z, v), 0);
    uint32_t *d = &f->dense[((size_t)z * f->side + y) * f->side + x];
    f->count += *d == 0;
    *d = v;
}

static uint32_t fx_get(const fixture *f, uint32_t x, uint32_t y, uint32_t z)
{
    if (x >= f->side || y >= f->side || z >= f->side) return 0;
    return f->dense[((size_t)z * f->side + y) * f->side + x];
}

/* A surface value: random normal bits, occupancy mostly 1..255, sometimes
 * 0 (a non-zero voxel whose occupancy byte is 0 must still round-trip). */
static uint32_t random_surface(void)
{
    uint32_t occ = rnd() % 16 == 0 ? 0 : 1 + rnd() % 255;
    uint32_t v = (rnd() << 8) | occ;
    return v ? v : 0x100;
}

static void fx_random(fixture *f, int count)
{
    for (int i = 0; i < count; i++)
        fx_store(f, rnd() % f->vol[0], rnd() % f->vol[1], rnd() % f->vol[2],
                 random_surface());
    /* and one solid block, so that some bricks are full and repeat */
    uint32_t hi[3];
    for (int a = 0; a < 3; a++) hi[a] = f->vol[a] < 12 ? f->vol[a] : 12;
    for (uint32_t z = 0; z < hi[2]; z++)
        for (uint32_t y = 0; y < hi[1]; y++)
            for (uint32_t x = 0; x < hi[0]; x++) fx_store(f, x, y, z, 0x8007ff);
}

/* A voxelized sphere shell with outward normals, as the engine makes them. */
static void fx_sphere(fixture *f, double cx, double cy, double cz, double r)
{
    for (uint32_t z = 0; z < f->vol[2]; z++)
        for (uint32_t y = 0; y < f->vol[1]; y++)
            for (uint32_t x = 0; x < f->vol[0]; x++) {
                double n[3] = {x + 0.5 - cx, y + 0.5 - cy, z + 0.5 - cz};
                double d = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                if (fabs(d - r) > 0.87 || d == 0) continue;
                for (int a = 0; a < 3; a++) n[a] /= d;
                fx_store(f, x, y, z, voxel_surface(n));
            }
}

static void params(vod_params *p, const fixture *f, int channel, uint32_t comp,
                   uint32_t hash, uint32_t brick)
{
    vod_params_default(p);
    memcpy(p->volume, f->vol, sizeof f->vol);
    p->channel = channel;
    p->comp = comp;
    p->hash = hash;
    p->brick = brick;
    p->voxel_scale[0] = 0.5f;
    p->voxel_scale[1] = 0.25f;
    p->voxel_scale[2] = 2.0f;
    p->origin[0] = -1.5f;
    p->origin[1] = 3.0f;
    p->origin[2] = 0.0f;
}

static membuf write_file(fixture *f, const vod_params *p, vod_stats *st)
{
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    char err[256] = "";
    vod_stats local;
    int rc = vod_write_octree(&f->t, p, &sink, st ? st : &local, err, sizeof err);
    cr_assert_eq(rc, 0, "write: %s", err);
    cr_assert_null(f->t.agg, "agg allocated by the writer is freed again");
    return m;
}

static vod_file *read_ok(const membuf *m)
{
    vod_file *v;
    char err[256] = "";
    int rc = vod_read(m->p, m->n, &v, err, sizeof err);
    cr_assert_eq(rc, 0, "read: %s", err);
    return v;
}

/* The spec's treeHeight and padded side, computed here independently. */
static uint32_t expect_height(const uint32_t vol[3], uint32_t brick, uint32_t *padded)
{
    uint32_t m = vol[0] > vol[1] ? vol[0] : vol[1];
    if (vol[2] > m) m = vol[2];
    double per = ceil((double)m / brick);
    uint32_t h = 1 + (uint32_t)ceil(log2(per));
    *padded = brick << (h - 1);
    return h;
}

static void fix_crc(uint8_t *b, size_t n)
{
    uint32_t c = (uint32_t)crc32(0, b, (uInt)(n - 4));
    vod_put32(b + n - 4, c);
}

/* -------------------------------------------------------------- hashes */

Test(vod_hash, xxhash32_test_vectors)
{
    cr_assert_eq(vod_hash_xx32("", 0), 0x02CC5D05u);
    cr_assert_eq(vod_hash_xx32("a", 1), 0x550D7456u);
    cr_assert_eq(vod_hash_xx32("abc", 3), 0x32D153FFu);
    cr_assert_eq(vod_hash_xx32("Nobody inspects the spammish repetition", 39), 0xE2293B2Fu);
    cr_assert_eq(vod_hash(VOD_HASH_XX32, "abc", 3), 0x32D153FFu);
}

/* Hsieh's SuperFastHash as published (portable get16bits), written out
 * again here; the only change is the u32 conversion before the shift of the
 * sign-extended tail byte, which the spec asks for. */
#define get16bits(d) ((((uint32_t)(((const uint8_t *)(d))[1])) << 8) + \
                      (uint32_t)(((const uint8_t *)(d))[0]))
static uint32_t ref_sfhs(const char *data, int len)
{
    uint32_t hash = (uint32_t)len, tmp;
    int rem;
    if (len <= 0 || data == NULL) return 0;
    rem = len & 3;
    len >>= 2;
    for (; len > 0; len--) {
        hash += get16bits(data);
        tmp = (get16bits(data + 2) << 11) ^ hash;
        hash = (hash << 16) ^ tmp;
        data += 2 * sizeof(uint16_t);
        hash += hash >> 11;
    }
    switch (rem) {
    case 3:
        hash += get16bits(data);
        hash ^= hash << 16;
        hash ^= (uint32_t)(signed char)data[sizeof(uint16_t)] << 18;
        hash += hash >> 11;
        break;
    case 2:
        hash += get16bits(data);
        hash ^= hash << 11;
        hash += hash >> 17;
        break;
    case 1:
        hash += (uint32_t)(signed char)*data;
        hash ^= hash << 10;
        hash += hash >> 1;
    }
    hash ^= hash << 3;
    hash += hash >> 5;
    hash ^= hash << 4;
    hash += hash >> 17;
    hash ^= hash << 25;
    hash += hash >> 6;
    return hash;
}

Test(vod_hash, superfasthash_matches_the_reference_code)
{
    char buf[64];
    for (int round = 0; round < 50; round++)
        for (int len = 0; len <= 64; len++) {
            for (int i = 0; i < len; i++) buf[i] = (char)rnd();
            if (round == 0) memset(buf, 0xff, sizeof buf); /* all tails negative */
            cr_assert_eq(vod_hash_sfhs(buf, (size_t)len), ref_sfhs(buf, len),
                         "length %d", len);
        }
    cr_assert_eq(vod_hash_sfhs("", 0), 0u, "the reference returns 0 for length 0");
    cr_assert_neq(vod_hash_sfhs("\x80", 1), vod_hash_sfhs("\x00", 1));
}

/* The four-lane SuperFastHash gives each buffer's reference hash, at
 * every length around the vector loop's steps and tails. */
Test(vod_hash, four_lanes_match_the_reference_code)
{
    static char buf[4][1100];
    const int lens[] = {256, 257, 258, 259, 1023, 1024, 1027, 1100};
    for (int round = 0; round < 4; round++)
        for (int li = 0; li < 70 + 8; li++) {
            int len = li < 70 ? li : lens[li - 70];
            for (int b = 0; b < 4; b++)
                for (int i = 0; i < len; i++)
                    buf[b][i] = round == 0 ? (char)0xff : (char)rnd();
            const void *d[4] = {buf[0], buf[1], buf[2], buf[3]};
            if (round == 3) d[2] = d[1] = d[0]; /* one buffer in several lanes */
            uint32_t h[4];
            vod_hash_sfhs4(d, (size_t)len, h);
            for (int b = 0; b < 4; b++)
                cr_assert_eq(h[b], ref_sfhs(d[b], len), "length %d lane %d", len, b);
        }
}

/* --------------------------------------------------------------- RUNL */

Test(vod_runl, round_trip_every_width_and_run_boundaries)
{
    static uint8_t raw[4096], back[4096], enc[8192];
    uint32_t widths[] = {1, 8, 16, 32};
    for (int w = 0; w < 4; w++)
        for (int round = 0; round < 20; round++) {
            size_t n = 4096;
            for (size_t i = 0; i < n;) { /* runs of 1..600 bytes of one value */
                size_t run = 1 + rnd() % (round < 10 ? 4 : 600);
                uint8_t v = (uint8_t)(rnd() % 3);
                for (size_t k = 0; k < run && i < n; k++) raw[i++] = v;
            }
            size_t e = vod_runl_encode(widths[w], raw, n, enc, sizeof enc);
            cr_assert(e > 0 && e <= vod_runl_bound(widths[w], n));
            cr_assert_eq(vod_runl_decode(widths[w], enc, e, back, n), 0);
            cr_assert_arr_eq(raw, back, n);
        }
    memset(raw, 7, 1024); /* 1024 equal bytes = 4 runs of 256 */
    cr_assert_eq(vod_runl_encode(8, raw, 1024, enc, sizeof enc), 8);
    cr_assert_eq(enc[0], 255);
    cr_assert_eq(vod_runl_encode(32, raw, 1024, enc, sizeof enc), 5, "256 u32 voxels");
    cr_assert_eq(vod_runl_encode(8, raw, 1024, enc, 7), 0, "too small a buffer");
}

Test(vod_runl, decoder_refuses_bad_runs)
{
    uint8_t raw[8];
    const uint8_t over[] = {8, 1};            /* 9 bytes into 8 */
    const uint8_t half[] = {3, 1, 3};         /* ends inside a pair */
    const uint8_t extra[] = {7, 1, 0};        /* a byte left over */
    const uint8_t short_[] = {3, 1};          /* only 4 of 8 bytes */
    const uint8_t ok[] = {3, 1, 3, 2};
    cr_assert_eq(vod_runl_decode(8, over, 2, raw, 8), -EBADMSG);
    cr_assert_eq(vod_runl_decode(8, half, 3, raw, 8), -EBADMSG);
    cr_assert_eq(vod_runl_decode(8, extra, 3, raw, 8), -EBADMSG);
    cr_assert_eq(vod_runl_decode(8, short_, 2, raw, 8), -EBADMSG);
    cr_assert_eq(vod_runl_decode(8, ok, 4, raw, 8), 0);
    cr_assert_eq(raw[3], 1);
    cr_assert_eq(raw[4], 2);
    const uint8_t w32[] = {1, 1, 2, 3, 4}; /* 2 x u32 = 8 bytes */
    cr_assert_eq(vod_runl_decode(32, w32, 5, raw, 8), 0);
    cr_assert_eq(vod_get32(raw + 4), 0x04030201u);
}

/* -------------------------------------------------------------- layout */

static int layout_rc(vod_params *p, int depth, const char *want)
{
    vod_layout L;
    char err[256] = "";
    int rc = vod_layout_make(p, depth, &L, err, sizeof err);
    if (want) cr_assert(strstr(err, want), "message '%s' lacks '%s'", err, want);
    return rc;
}

Test(vod_layout, validates_params_per_spec)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 100;
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, 7, &L, err, sizeof err), 0, "%s", err);
    cr_assert_eq(L.height, 4); /* ceil(100/16) = 7 -> 1 + 3 */
    cr_assert_eq(L.padded, 128);
    cr_assert_eq(L.raw_bytes, 16 * 16 * 16 * 4);
    cr_assert_eq(L.nodes, 585);
    cr_assert_eq(vod_layout_make(&p, 9, &L, err, sizeof err), 0, "deeper octree");
    cr_assert_eq(L.padded, 128, "N < 2^depth: %u", L.padded);
    p.volume[0] = p.volume[1] = p.volume[2] = 5;
    cr_assert_eq(vod_layout_make(&p, 3, &L, err, sizeof err), 0);
    cr_assert_eq(L.height, 1);
    cr_assert_eq(L.padded, 16, "one root brick bigger than the octree");
    p.channel = VOXEL_CH_OCCUPANCY;
    cr_assert_eq(vod_layout_make(&p, 3, &L, err, sizeof err), 0);
    cr_assert_eq(L.raw_bytes, 512);

    vod_params q = p;
    q.brick = 3;
    cr_assert_eq(layout_rc(&q, 3, "brickSize 3 is not a power of two in 2..256"), -EINVAL);
    q.brick = 512;
    cr_assert_eq(layout_rc(&q, 3, "brickSize 512"), -EINVAL);
    q.brick = 1;
    cr_assert_eq(layout_rc(&q, 3, "brickSize 1"), -EINVAL);
    q = p, q.volume[1] = 0;
    cr_assert_eq(layout_rc(&q, 3, "at least 1"), -EINVAL);
    q = p, q.channel = VOXEL_CH_DENSITY;
    cr_assert_eq(layout_rc(&q, 3, NULL), 0, "channel 2: 8-bit voxels");
    cr_assert_eq(vod_layout_make(&q, 3, &L, err, sizeof err), 0);
    cr_assert_eq(L.voxel_bits, 8);
    cr_assert_eq(L.raw_bytes, 16 * 16 * 16);
    q = p, q.channel = VOXEL_CH_DISTANCE;
    cr_assert_eq(layout_rc(&q, 3, NULL), 0, "channel 4: f32 voxels");
    cr_assert_eq(vod_layout_make(&q, 3, &L, err, sizeof err), 0);
    cr_assert_eq(L.voxel_bits, 32);
    q = p, q.channel = 5;
    cr_assert_eq(layout_rc(&q, 3, "channel 5 cannot be written"), -EINVAL);
    q = p, q.channel = VOXEL_CH_UNSPECIFIED;
    cr_assert_eq(layout_rc(&q, 3, "channel 0 cannot be written"), -EINVAL);
    q = p, q.comp = VOD_FOURCC('F', 'T', 'L', 'Z');
    cr_assert_eq(layout_rc(&q, 3, "'FTLZ'"), -EINVAL);
    q = p, q.hash = VOD_FOURCC('M', 'D', '5', ' ');
    cr_assert_eq(layout_rc(&q, 3, "'MD5 '"), -EINVAL);
    q = p, q.zlib_level = 13;
    cr_assert_eq(layout_rc(&q, 3, "zlib level 13 outside 1..12"), -EINVAL);
    q = p, q.zlib_level = 0;
    cr_assert_eq(layout_rc(&q, 3, "zlib level 0"), -EINVAL);
    q = p, q.zlib_level = 12; /* libdeflate's highest */
    cr_assert_eq(layout_rc(&q, 3, NULL), 0);
    q = p, q.voxel_scale[2] = 0;
    cr_assert_eq(layout_rc(&q, 3, "voxelScale"), -EINVAL);
    q = p, q.voxel_scale[0] = NAN;
    cr_assert_eq(layout_rc(&q, 3, "voxelScale"), -EINVAL);
    q = p, q.volume[0] = 9;
    cr_assert_eq(layout_rc(&q, 3, "exceeds the octree's 8"), -EINVAL);
    static char big[VOD_MAX_METADATA + 2];
    memset(big, 'a', sizeof big - 1);
    q = p, q.metadata = big;
    cr_assert_eq(layout_rc(&q, 3, "metadata"), -EINVAL);
    q = p, q.brick = 2, q.volume[0] = 65536;
    cr_assert_eq(layout_rc(&q, 16, "4 GiB"), -EFBIG);
}

/* ------------------------------------------------- round trip, level 0 */

typedef struct {
    const fixture *f;
    int occupancy;
    uint32_t dims[3];
    uint64_t seen;
    uint8_t *mark;
} visit_ctx;

static int visit_l0(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    visit_ctx *c = ud;
    cr_assert(x < c->f->vol[0] && y < c->f->vol[1] && z < c->f->vol[2]);
    uint32_t want = fx_get(c->f, x, y, z);
    cr_assert(want != 0, "visited an empty voxel %u %u %u", x, y, z);
    cr_assert_eq(v, c->occupancy ? 1u : want, "voxel %u %u %u", x, y, z);
    uint8_t *m = &c->mark[((size_t)z * c->f->side + y) * c->f->side + x];
    cr_assert_eq(*m, 0, "visited twice");
    *m = 1;
    c->seen++;
    return 0;
}

static void check_level0(const fixture *f, const vod_file *v, int occupancy)
{
    uint32_t n = vod_level_size(v, 0);
    visit_ctx c = {f, occupancy, {0}, 0, calloc((size_t)f->side * f->side * f->side, 1)};
    cr_assert_eq(vod_foreach(v, 0, visit_l0, &c), 0);
    cr_assert_eq(c.seen, f->count, "foreach saw %llu of %llu voxels",
                 (unsigned long long)c.seen, (unsigned long long)f->count);
    free(c.mark);
    /* every voxel of the padded cube, or a sample of a large one */
    uint64_t all = (uint64_t)n * n * n, step = all > (1u << 16) ? 7919 : 1;
    for (uint64_t i = 0; i < all; i += step) {
        uint32_t x = (uint32_t)(i % n), y = (uint32_t)(i / n % n), z = (uint32_t)(i / n / n);
        uint32_t want = fx_get(f, x, y, z);
        if (occupancy) want = want != 0;
        cr_assert_eq(vod_voxel(v, 0, x, y, z), want, "voxel %u %u %u", x, y, z);
    }
    cr_assert_eq(vod_voxel(v, 0, n, 0, 0), 0, "outside the padded cube");
}

static void check_info(const vod_file *v, const vod_params *p, const vod_stats *st,
                       const membuf *m)
{
    const vod_info *in = vod_get_info(v);
    uint32_t padded, h = expect_height(p->volume, p->brick, &padded);
    cr_assert_eq(in->height, h);
    cr_assert_eq(vod_level_size(v, 0), padded);
    cr_assert_eq(vod_level_size(v, (int)h), 0);
    cr_assert_eq(in->brick, p->brick);
    cr_assert_arr_eq(in->volume, p->volume, sizeof p->volume);
    cr_assert_eq(in->voxel_bits, p->channel == VOXEL_CH_OCCUPANCY ? 1u : 32u);
    cr_assert_eq(in->channel, (uint32_t)p->channel);
    cr_assert_eq(in->comp, p->comp);
    cr_assert_eq(in->hash, p->hash);
    cr_assert_eq(in->has_trailer, 1);
    cr_assert_float_eq(in->voxel_scale[1], 0.25f, 0);
    cr_assert_float_eq(in->origin[0], -1.5f, 0);
    cr_assert_eq(in->bricks, st->bricks);
    cr_assert_eq(in->file_bytes, m->n);
    cr_assert_eq(st->file_bytes, m->n);
    cr_assert_eq(in->crc32, st->crc32);
    cr_assert_eq(in->brick_data_bytes, st->brick_data_bytes);
    cr_assert_eq(in->nodes, st->nodes);
    cr_assert_eq(st->raw_bytes, (uint64_t)padded * padded * padded * in->voxel_bits / 8);
}

static void round_trip(fixture *f, int channel, uint32_t comp, uint32_t hash,
                       uint32_t brick)
{
    vod_params p;
    params(&p, f, channel, comp, hash, brick);
    vod_stats st;
    membuf m = write_file(f, &p, &st);
    vod_file *v = read_ok(&m);
    check_info(v, &p, &st, &m);
    check_level0(f, v, channel == VOXEL_CH_OCCUPANCY);
    vod_close(v);
    free(m.p);
}

static void matrix(int depth, uint32_t vx, uint32_t vy, uint32_t vz, int count)
{
    static const uint32_t comps[] = {VOD_COMP_NONE, VOD_COMP_ZLIB, VOD_COMP_RUNL};
    static const uint32_t hashes[] = {VOD_HASH_SFHS, VOD_HASH_XX32};
    static const uint32_t bricks[] = {2, 8, 16, 32};
    fixture f;
    fx_init(&f, depth, vx, vy, vz);
    fx_random(&f, count);
    for (int ch = 0; ch < 2; ch++)
        for (int c = 0; c < 3; c++)
            for (int h = 0; h < 2; h++)
                for (int b = 0; b < 4; b++)
                    round_trip(&f, ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE,
                               comps[c], hashes[h], bricks[b]);
    fx_free(&f);
}

Test(vod_roundtrip, odd_volume_not_a_multiple_of_the_brick) { matrix(5, 20, 13, 7, 400); }
Test(vod_roundtrip, power_of_two_volume) { matrix(5, 32, 32, 32, 2000); }
Test(vod_roundtrip, volume_smaller_than_the_brick) { matrix(3, 5, 3, 6, 40); }
Test(vod_roundtrip, octree_deeper_than_the_volume_needs) { matrix(7, 20, 17, 24, 500); }

Test(vod_roundtrip, empty_tree)
{
    fixture f;
    fx_init(&f, 4, 16, 16, 16);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    vod_stats st;
    membuf m = write_file(&f, &p, &st);
    cr_assert_eq(st.bricks, 0);
    cr_assert_eq(st.nonempty_nodes, 0);
    vod_file *v = read_ok(&m);
    cr_assert_eq(vod_get_info(v)->bricks, 0);
    check_level0(&f, v, 0);
    vod_close(v);
    free(m.p);
    fx_free(&f);
}

/* ------------------------------------------------------- downsampling */

/* Spec section 3, written out here: channel 3 occupancy is the mean rounded
 * half up; the normal the normalized sum over occupied children. */
static void check_parent(uint32_t got, const uint32_t c[8], int occupancy,
                         int l, uint32_t x, uint32_t y, uint32_t z)
{
    if (occupancy) {
        uint32_t any = 0;
        for (int i = 0; i < 8; i++) any |= c[i] != 0;
        cr_assert_eq(got, any, "level %d voxel %u %u %u", l, x, y, z);
        return;
    }
    double sum = 0, n[3] = {0, 0, 0};
    for (int i = 0; i < 8; i++) {
        if (!(c[i] & 0xff)) continue;
        double m[3];
        voxel_unpack_normal(c[i], m);
        sum += c[i] & 0xff;
        for (int a = 0; a < 3; a++) n[a] += m[a];
    }
    uint32_t occ = (uint32_t)floor(sum / 8.0 + 0.5);
    cr_assert_eq(got & 0xff, occ, "level %d voxel %u %u %u occupancy", l, x, y, z);
    if (occ == 0) {
        cr_assert_eq(got, 0, "no voxel where the occupancy rounds to 0");
        return;
    }
    double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), g[3];
    if (len < 1e-9) return;
    voxel_unpack_normal(got, g);
    double dot = (g[0] * n[0] + g[1] * n[1] + g[2] * n[2]) / len;
    cr_assert(dot > cos(2e-3), "level %d voxel %u %u %u normal off by %g rad", l,
              x, y, z, acos(dot < 1 ? dot : 1));
}

/* Every voxel of every level >= 1 against its 8 children one level down. */
static void check_levels(const vod_file *v, int occupancy)
{
    int levels = (int)vod_get_info(v)->height;
    for (int l = 1; l < levels; l++) {
        uint32_t n = vod_level_size(v, l);
        cr_assert_eq(n * 2, vod_level_size(v, l - 1));
        for (uint32_t z = 0; z < n; z++)
            for (uint32_t y = 0; y < n; y++)
                for (uint32_t x = 0; x < n; x++) {
                    uint32_t c[8];
                    for (unsigned i = 0; i < 8; i++)
                        c[i] = vod_voxel(v, l - 1, 2 * x + (i & 1), 2 * y + (i >> 1 & 1),
                                         2 * z + (i >> 2 & 1));
                    check_parent(vod_voxel(v, l, x, y, z), c, occupancy, l, x, y, z);
                }
    }
}

static int count_nonzero(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    (void)x, (void)y, (void)z;
    cr_assert_neq(v, 0);
    ++*(uint64_t *)ud;
    return 0;
}

/* foreach on level l visits exactly the non-zero voxels inside the level's dims. */
static void check_foreach_levels(const vod_file *v)
{
    for (int l = 0; l < (int)vod_get_info(v)->height; l++) {
        uint32_t d[3];
        cr_assert_eq(vod_level_dims(v, l, d), 0);
        uint64_t want = 0, got = 0;
        for (uint32_t z = 0; z < d[2]; z++)
            for (uint32_t y = 0; y < d[1]; y++)
                for (uint32_t x = 0; x < d[0]; x++) want += vod_voxel(v, l, x, y, z) != 0;
        cr_assert_eq(vod_foreach(v, l, count_nonzero, &got), 0);
        cr_assert_eq(got, want, "level %d", l);
    }
    cr_assert_eq(vod_foreach(v, (int)vod_get_info(v)->height, count_nonzero, NULL), -EINVAL);
}

static void downsample_case(int channel, uint32_t brick, uint32_t comp)
{
    fixture f;
    fx_init(&f, 6, 61, 64, 50);
    fx_sphere(&f, 30.2, 31.7, 24.9, 22.3);
    fx_sphere(&f, 10.0, 12.0, 9.0, 4.0);
    vod_params p;
    params(&p, &f, channel, comp, VOD_HASH_XX32, brick);
    membuf m = write_file(&f, &p, NULL);
    vod_file *v = read_ok(&m);
    check_level0(&f, v, channel == VOXEL_CH_OCCUPANCY);
    check_levels(v, channel == VOXEL_CH_OCCUPANCY);
    check_foreach_levels(v);
    vod_close(v);
    free(m.p);
    fx_free(&f);
}

Test(vod_levels, sphere_shell_surface_brick_8) { downsample_case(VOXEL_CH_SURFACE, 8, VOD_COMP_ZLIB); }
Test(vod_levels, sphere_shell_surface_brick_2) { downsample_case(VOXEL_CH_SURFACE, 2, VOD_COMP_RUNL); }
Test(vod_levels, sphere_shell_occupancy_or) { downsample_case(VOXEL_CH_OCCUPANCY, 4, VOD_COMP_NONE); }

Test(vod_levels, random_values_surface)
{
    fixture f;
    fx_init(&f, 5, 32, 29, 31);
    fx_random(&f, 3000);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    membuf m = write_file(&f, &p, NULL);
    vod_file *v = read_ok(&m);
    check_levels(v, 0);
    check_foreach_levels(v);
    vod_close(v);
    free(m.p);
    fx_free(&f);
}

/* ---------------------------------------- the second reader (Figure 24) */

/* Reads one voxel following Figure 24 and the spec's settled points only:
 * header fields, the preorder table, the brick table through offsets. */
static uint32_t fig24_voxel(const uint8_t *b, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t B = vod_get32(b + 20), H = vod_get32(b + 44), bits = vod_get32(b + 48);
    uint32_t comp = vod_get32(b + 56), k = 0;
    while ((1u << k) < B) k++;
    uint64_t nodes = ((1ull << (3 * H)) - 1) / 7, p = 0;
    for (uint32_t l = H - 1; l > 0; l--) { /* node at level l spans B << l */
        uint32_t s = k + l - 1;
        uint32_t c = (x >> s & 1) | (y >> s & 1) << 1 | (z >> s & 1) << 2;
        p += 1 + c * (((1ull << (3 * l)) - 1) / 7);
    }
    uint32_t id = vod_get32(b + 64 + 4 * p);
    if (id == 0) return 0;
    const uint8_t *tab = b + 64 + 4 * nodes;
    uint32_t count = vod_get32(tab), off = 0;
    for (uint32_t i = 0; i < count; i++)
        if (vod_get32(tab + 4 + 12 * i) == id) off = vod_get32(tab + 8 + 12 * i);
    cr_assert_neq(off, 0);
    uint32_t size = vod_get32(b + off);
    const uint8_t *d = b + off + 4;
    static uint8_t raw[32 * 32 * 32 * 4];
    uLongf rawn = (uLongf)B * B * B * bits / 8;
    if (comp == VOD_COMP_ZLIB) {
        uLongf got = rawn;
        cr_assert_eq(uncompress(raw, &got, d, size), Z_OK);
        cr_assert_eq(got, rawn);
    } else if (comp == VOD_COMP_RUNL) {
        uint32_t w = bits == 1 ? 1 : bits / 8, o = 0;
        for (uint32_t i = 0; i < size; i += 1 + w)
            for (uint32_t r = 0; r <= d[i]; r++, o += w) memcpy(raw + o, d + i + 1, w);
        cr_assert_eq(o, rawn);
    } else {
        cr_assert_eq(size, rawn);
        memcpy(raw, d, size);
    }
    uint32_t m = B - 1, v = ((z & m) * B + (y & m)) * B + (x & m);
    return bits == 1 ? (raw[v >> 3] >> (v & 7)) & 1 : vod_get32(raw + 4 * v);
}

Test(vod_oracle, figure24_reader_agrees)
{
    static const uint32_t comps[] = {VOD_COMP_NONE, VOD_COMP_ZLIB, VOD_COMP_RUNL};
    fixture f;
    fx_init(&f, 5, 30, 32, 17);
    fx_random(&f, 600);
    for (int c = 0; c < 3; c++)
        for (int ch = 0; ch < 2; ch++)
            for (uint32_t brick = 2; brick <= 32; brick *= 4) {
                vod_params p;
                params(&p, &f, ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE, comps[c],
                       VOD_HASH_SFHS, brick);
                membuf m = write_file(&f, &p, NULL);
                vod_file *v = read_ok(&m);
                for (int i = 0; i < 400; i++) {
                    uint32_t x = rnd() % 32, y = rnd() % 32, z = rnd() % 32;
                    uint32_t want = fx_get(&f, x, y, z);
                    if (ch) want = want != 0;
                    cr_assert_eq(fig24_voxel(m.p, x, y, z), want);
                    cr_assert_eq(vod_voxel(v, 0, x, y, z), want);
                }
                vod_close(v);
                free(m.p);
            }
    fx_free(&f);
}

/* ------------------------------------------------------ bytes on disk */

Test(vod_bytes, header_fields_at_documented_offsets)
{
    fixture f;
    fx_init(&f, 5, 20, 13, 7);
    fx_random(&f, 100);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    p.metadata = "generator=test\nsource=random\n";
    vod_stats st;
    membuf m = write_file(&f, &p, &st);
    const uint8_t *b = m.p;
    const uint8_t sig[] = {0x2E, 0x56, 0x4F, 0x44, 1, 0, 0, 0, 20, 0, 0, 0, 13, 0, 0, 0,
                           7, 0, 0, 0, 8, 0, 0, 0, 8, 0, 0, 0, 8, 0, 0, 0};
    cr_assert_arr_eq(b, sig, sizeof sig);
    float s;
    memcpy(&s, (uint32_t[]){vod_get32(b + 36)}, 4);
    cr_assert_float_eq(s, 0.25f, 0);
    cr_assert_eq(vod_get32(b + 32), 0x3F000000u, "0.5f little-endian");
    cr_assert_eq(vod_get32(b + 44), 3, "ceil(20/8) = 3 -> 1 + 2");
    cr_assert_eq(vod_get32(b + 48), 32);
    cr_assert_arr_eq(b + 52, "SFHSZLIB", 8);
    cr_assert_eq(vod_get32(b + 60), VOD_FLAG_COMPRESSED | VOD_FLAG_PADDED | VOD_FLAG_TRAILER);
    /* octree, count, table, records, trailer: each where the offsets say */
    uint64_t nodes = 73;
    cr_assert_neq(vod_get32(b + 64), 0, "the root is not empty");
    uint32_t count = vod_get32(b + 64 + 4 * nodes);
    cr_assert_eq(count, st.bricks);
    uint64_t rec = 64 + 4 * nodes + 4 + 12 * count;
    cr_assert_eq(vod_get32(b + 64 + 4 * nodes + 8), rec, "first record after the table");
    size_t n = m.n, meta = strlen(p.metadata);
    uint32_t at = vod_get32(b + n - 12);
    cr_assert_arr_eq(b + at, "VODX", 4);
    cr_assert_eq(vod_get32(b + at + 4), n - at);
    cr_assert_eq(vod_get32(b + at + 4), 40 + meta);
    cr_assert_eq(vod_get32(b + at + 8), 0xBFC00000u, "origin x -1.5f");
    cr_assert_eq(vod_get32(b + at + 20), 3, "channel");
    cr_assert_eq(vod_get32(b + at + 24), meta);
    cr_assert_arr_eq(b + at + 28, p.metadata, meta);
    cr_assert_arr_eq(b + n - 8, "XDOV", 4);
    cr_assert_eq(vod_get32(b + n - 4), (uint32_t)crc32(0, b, (uInt)(n - 4)));
    vod_file *v = read_ok(&m);
    cr_assert_str_eq(vod_get_info(v)->metadata, p.metadata);
    vod_close(v);
    /* no padding, no compression: flags bits 0 and 1 clear */
    fixture g;
    fx_init(&g, 4, 16, 16, 16);
    fx_store(&g, 3, 4, 5, 0x1234ff);
    params(&p, &g, VOXEL_CH_OCCUPANCY, VOD_COMP_NONE, VOD_HASH_XX32, 4);
    membuf m2 = write_file(&g, &p, NULL);
    cr_assert_eq(vod_get32(m2.p + 60), VOD_FLAG_TRAILER);
    cr_assert_eq(vod_get32(m2.p + 48), 1);
    cr_assert_arr_eq(m2.p + 52, "XX32NONE", 8);
    free(m2.p);
    free(m.p);
    fx_free(&f);
    fx_free(&g);
}

/* -------------------------------------------------------------- dedup */

/* Enumerates the table's non-empty nodes (as the second reader would) and
 * reads each node's brick through vod_voxel: two nodes must share an ID iff
 * their bricks are equal. */
static void check_dedup_exact(const membuf *m, const vod_file *v)
{
    const vod_info *in = vod_get_info(v);
    uint32_t B = in->brick, H = in->height, vox = B * B * B;
    size_t cap = 4096, n = 0;
    uint32_t *ids = malloc(cap * sizeof *ids), *bricks = malloc(cap * vox * 4);
    uint64_t p = 0;
    /* preorder walk of the complete tree by explicit arithmetic */
    struct { uint32_t l, b[3]; } stack[64];
    int top = 0;
    stack[0].l = H - 1;
    memset(stack[0].b, 0, sizeof stack[0].b);
    while (top >= 0) {
        uint32_t l = stack[top].l, b[3];
        memcpy(b, stack[top].b, sizeof b);
        top--;
        uint32_t id = vod_get32(m->p + 64 + 4 * p);
        uint64_t size = ((1ull << (3 * (l + 1))) - 1) / 7;
        if (id == 0) { p += size; continue; }
        cr_assert(n < cap);
        ids[n] = id;
        for (uint32_t i = 0; i < vox; i++)
            bricks[n * vox + i] = vod_voxel(v, (int)l, b[0] * B + i % B,
                                            b[1] * B + i / B % B, b[2] * B + i / B / B);
        n++;
        p++;
        for (int c = 7; l > 0 && c >= 0; c--) {
            top++;
            stack[top].l = l - 1;
            for (int a = 0; a < 3; a++) stack[top].b[a] = b[a] * 2 + ((c >> a) & 1);
        }
    }
    cr_assert_eq(p, in->nodes);
    for (size_t i = 0; i < n; i++)
        for (size_t j = 0; j < i; j++) {
            int same = !memcmp(&bricks[i * vox], &bricks[j * vox], vox * 4);
            cr_assert_eq(same, ids[i] == ids[j], "nodes %zu and %zu", i, j);
        }
    free(ids);
    free(bricks);
}

Test(vod_dedup, repeated_pattern_stores_each_brick_once)
{
    fixture f;
    fx_init(&f, 6, 64, 64, 64);
    for (uint32_t z = 0; z < 64; z++)
        for (uint32_t y = 0; y < 64; y++)
            for (uint32_t x = 0; x < 64; x++) {
                uint32_t a = x % 8, b = y % 8, c = z % 8;
                if ((a * 7 + b * 3 + c * 5) % 11 < 3) fx_store(&f, x, y, z, 0xabc0ff + a);
            }
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    vod_stats st;
    membuf m = write_file(&f, &p, &st);
    cr_assert_eq(st.nonempty_nodes, 585, "every node non-empty");
    cr_assert(st.bricks <= 4, "one brick per level at most, got %llu",
              (unsigned long long)st.bricks);
    cr_assert_eq(st.brick_raw_bytes, st.bricks * 8 * 8 * 8 * 4);
    vod_file *v = read_ok(&m);
    check_dedup_exact(&m, v);
    check_level0(&f, v, 0);
    vod_close(v);
    free(m.p);
    fx_free(&f);
}

Test(vod_dedup, random_tree_shares_ids_exactly_for_equal_bricks)
{
    fixture f;
    fx_init(&f, 5, 32, 32, 32);
    fx_random(&f, 300);
    for (int ch = 0; ch < 2; ch++) {
        vod_params p;
        params(&p, &f, ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE, VOD_COMP_RUNL,
               VOD_HASH_XX32, 4);
        membuf m = write_file(&f, &p, NULL);
        vod_file *v = read_ok(&m);
        check_dedup_exact(&m, v);
        vod_close(v);
        free(m.p);
    }
    fx_free(&f);
}

/* Two different 8-byte raw bricks with the same SuperFastHash (found by a
 * birthday search), checked against the reference code here. */
static const uint8_t coll_a[8] = {0x77, 0xcc, 0x03, 0x8b, 0xad, 0x4f, 0x4c, 0xbb};
static const uint8_t coll_b[8] = {0x42, 0x11, 0x55, 0x54, 0xc5, 0xba, 0x17, 0xce};

Test(vod_dedup, sfhs_collision_is_not_merged)
{
    cr_assert(memcmp(coll_a, coll_b, 8) != 0);
    cr_assert_eq(ref_sfhs((const char *)coll_a, 8), ref_sfhs((const char *)coll_b, 8));
    cr_assert_eq(vod_hash_sfhs(coll_a, 8), vod_hash_sfhs(coll_b, 8));
    /* 1-bit bricks of 4^3 voxels are 8 raw bytes: brick (0,0,0) holds a,
     * brick (1,0,0) holds b, bit v of the brick is voxel v (x fastest). */
    fixture f;
    fx_init(&f, 3, 8, 4, 4);
    for (uint32_t i = 0; i < 64; i++) {
        uint32_t x = i % 4, y = i / 4 % 4, z = i / 16;
        if (coll_a[i >> 3] >> (i & 7) & 1) fx_store(&f, x, y, z, 1);
        if (coll_b[i >> 3] >> (i & 7) & 1) fx_store(&f, x + 4, y, z, 1);
    }
    for (int c = 0; c < 3; c++) {
        vod_params p;
        params(&p, &f, VOXEL_CH_OCCUPANCY,
               c == 0 ? VOD_COMP_NONE : c == 1 ? VOD_COMP_ZLIB : VOD_COMP_RUNL,
               VOD_HASH_SFHS, 4);
        vod_stats st;
        membuf m = write_file(&f, &p, &st);
        cr_assert_eq(st.bricks, 3, "a, b and the root: got %llu", (unsigned long long)st.bricks);
        /* both level-0 bricks are in the table with the same hash */
        uint32_t h1 = vod_get32(m.p + 64 + 36 + 4 + 12 + 8);
        uint32_t h2 = vod_get32(m.p + 64 + 36 + 4 + 24 + 8);
        cr_assert_eq(h1, h2);
        cr_assert_eq(h1, vod_hash_sfhs(coll_a, 8));
        vod_file *v = read_ok(&m);
        check_level0(&f, v, 1);
        vod_close(v);
        free(m.p);
    }
    fx_free(&f);
}

/* The byte comparison, driven directly: equal forged hashes, different
 * bytes, must stay two bricks; equal bytes are merged. */
Test(vod_dedup, assemble_merges_only_equal_bytes)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 8;
    p.comp = VOD_COMP_NONE;
    p.brick = 4;
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, 3, &L, err, sizeof err), 0);
    static uint8_t d1[256], d2[256], d3[256];
    memset(d1, 1, sizeof d1);
    memset(d2, 2, sizeof d2);
    memset(d3, 1, sizeof d3);
    vod_node nodes[4] = {{.preorder = 0, .level = 1},
                         {.preorder = 1},
                         {.preorder = 2, .bx = 1},
                         {.preorder = 3, .by = 1}};
    vod_encoded recs[4] = {{7, 256}, {7, 256}, {7, 256}, {9, 256}};
    const uint8_t *data[4] = {d1, d2, d3, d1};
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = 4, .nodes = nodes,
                                              .recs = recs, .data = data,
                                              .sink = &sink, .st = &st,
                                              .err = err, .errlen = sizeof err}), 0);
    cr_assert_eq(st.bricks, 3, "d1 == d3 merged, d2 (same hash) and d1 (other hash) not");
    cr_assert_eq(vod_get32(m.p + 64), 1);
    cr_assert_eq(vod_get32(m.p + 68), 2);
    cr_assert_eq(vod_get32(m.p + 72), 1);
    cr_assert_eq(vod_get32(m.p + 76), 3);
    free(m.p);
    /* nodes out of preorder or oversize records are refused */
    vod_node bad[2] = {{.preorder = 2, .bx = 1}, {.preorder = 1}};
    m = (membuf){0};
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = 2, .nodes = bad,
                                              .recs = recs, .data = data,
                                              .sink = &sink, .st = &st,
                                              .err = err, .errlen = sizeof err}), -EINVAL);
    vod_encoded big[1] = {{7, 257}};
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = 1, .nodes = nodes + 1,
                                              .recs = big, .data = data,
                                              .sink = &sink, .st = &st,
                                              .err = err, .errlen = sizeof err}), -EINVAL);
    cr_assert_eq(m.calls, 0);
}

/* Enough bricks for the duplicates to be searched by several threads
 * (vod_assemble cuts the hashes into parts): the IDs must be those of
 * the first use, as an oracle here finds them class by class.  Forged
 * hashes shared by different bytes, and equal bytes at different
 * addresses (compared, not merged by pointer). */
Test(vod_dedup, many_bricks_get_the_ids_of_their_first_use)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 128;
    p.comp = VOD_COMP_NONE;
    p.brick = 4;
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, 7, &L, err, sizeof err), 0);
    enum { N = 30000, CLASSES = 1500, BYTES = 256 };
    cr_assert_geq(L.nodes, N);
    static uint8_t pool[2][CLASSES][BYTES];
    for (int c = 0; c < CLASSES; c++)
        for (int k = 0; k < 2; k++) vod_put32(pool[k][c], (uint32_t)c + 1);
    vod_node *nodes = calloc(N, sizeof *nodes);
    vod_encoded *recs = calloc(N, sizeof *recs);
    const uint8_t **data = calloc(N, sizeof *data);
    uint32_t id_of[CLASSES] = {0}, u = 0, *want = calloc(N, sizeof *want);
    cr_assert(nodes && recs && data && want);
    for (uint32_t i = 0; i < N; i++) {
        uint32_t c = (uint32_t)(((uint64_t)i * 7919 + i / 3) % CLASSES);
        nodes[i].preorder = i;
        recs[i] = (vod_encoded){.hash = c % 300, .size = BYTES};
        data[i] = pool[i & 1][c];
        want[i] = id_of[c] ? id_of[c] : (id_of[c] = ++u);
    }
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = N, .nodes = nodes,
                                              .recs = recs, .data = data,
                                              .sink = &sink, .st = &st, .err = err,
                                              .errlen = sizeof err}), 0, "%s", err);
    cr_assert_eq(st.bricks, u);
    for (uint32_t i = 0; i < N; i++)
        cr_assert_eq(vod_get32(m.p + VOD_HEADER_BYTES + 4 * i), want[i], "node %u", i);
    free(m.p);
    free(nodes);
    free(recs);
    free(data);
    free(want);
}

/* ------------------------------------------- parallel writer reference */

Test(vod_write, phases_by_hand_give_the_same_bytes)
{
    fixture f;
    fx_init(&f, 5, 32, 30, 25);
    fx_random(&f, 1500);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    p.metadata = "k=v\n";
    membuf ref = write_file(&f, &p, NULL);

    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, f.t.depth, &L, err, sizeof err), 0);
    f.t.agg = malloc(f.t.used * sizeof *f.t.agg);
    vod_aggregate(&f.t, p.channel); /* as the engine does, into its own agg */
    vod_source src = vod_octree_source(&f.t);
    size_t n = vod_collect(&src, &L, NULL, 0);
    vod_node *nodes = malloc(n * sizeof *nodes);
    cr_assert_eq(vod_collect(&src, &L, nodes, n), n);
    vod_encoded *recs = malloc(n * sizeof *recs);
    uint8_t **data = malloc(n * sizeof *data);
    size_t bound = vod_encode_bound(&L, &p);
    uint8_t *scratch = malloc(L.raw_bytes);
    for (size_t i = n; i-- > 0;) { /* any order, separate buffers, as workers would */
        data[i] = malloc(bound);
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, data[i], bound, &recs[i]), 0);
    }
    cr_assert_eq(vod_encode(&src, &L, &p, &nodes[0], scratch, data[0], 4, &recs[0]), -ENOBUFS);
    cr_assert_eq(vod_encode(&src, &L, &p, &nodes[0], scratch, data[0], bound, &recs[0]), 0);
    vod_node outside = {.level = L.height};
    cr_assert_eq(vod_encode(&src, &L, &p, &outside, scratch, data[0], bound, &recs[0]), -EINVAL);
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = n, .nodes = nodes,
                                              .recs = recs, .data = (const uint8_t *const *)data,
                                              .sink = &sink, .st = &st,
                                              .err = err, .errlen = sizeof err}), 0);
    cr_assert_eq(m.n, ref.n);
    cr_assert_arr_eq(m.p, ref.p, m.n);
    cr_assert_eq(st.nonempty_nodes, n);
    for (size_t i = 0; i < n; i++) {
        free(data[i]);
        cr_assert(i == 0 || nodes[i].preorder > nodes[i - 1].preorder);
    }
    free(data), free(recs), free(nodes), free(scratch), free(f.t.agg);
    f.t.agg = NULL;
    free(m.p), free(ref.p);
    fx_free(&f);
}

/* ------------------------------------------------------------ encoder */

/* A raw brick of brick^3 32-bit voxels of one kind: 0 sparse surface, 1
 * dense random, 2 uniform, 3 few values, 4 all zero, 5 runs. */
/* n bytes of a brick of the kind: 4-byte words, then what is left. */
static void make_brick(uint8_t *raw, size_t n, int kind)
{
    uint32_t run = 0, rv = 0;
    for (size_t i = 0; i < (n + 3) / 4; i++) {
        uint32_t v = 0;
        switch (kind) {
        case 0: v = rnd() % 9 == 0 ? 0xff | rnd() << 8 : 0; break;
        case 1: v = rnd() ^ rnd() << 16; break;
        case 2: v = 0x5a5a5aff; break;
        case 3: v = rnd() % 3 ? 0 : 0xff | (rnd() % 4) << 8; break;
        case 4: v = 0; break;
        case 5: /* occupancy of a solid: runs of 0 and 1 bits, a cut between */
            if (!run) run = 1 + rnd() % 12, rv = rnd() % 2 ? 0 : 0xffffffffu;
            v = run-- == 1 ? rv ^ (0xffffffffu << (rnd() % 32)) : rv;
            break;
        default:
            if (!run) run = 1 + rnd() % 40, rv = rnd() % 2 ? 0 : rnd();
            v = rv, run--;
        }
        uint8_t w[4];
        vod_put32(w, v);
        memcpy(raw + 4 * i, w, n - 4 * i < 4 ? n - 4 * i : 4);
    }
}

/* The aggregate in parts, as the engine's processes share it: the
 * subtrees of every split height in reverse order, some twice (a worker
 * that died after writing part of one, done again by the master), then
 * the cells above: vod_aggregate's values for every cell. */
Test(vod_encoder, aggregate_in_parts_is_the_whole)
{
    fixture f;
    fx_init(&f, 6, 64, 60, 50);
    fx_random(&f, 3000);
    fx_sphere(&f, 30, 31, 24, 20);
    for (int ch = 0; ch < 2; ch++) {
        int channel = ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE;
        uint32_t *whole = calloc(f.t.used, sizeof *whole);
        uint32_t *parts = calloc(f.t.used, sizeof *parts);
        f.t.agg = whole;
        vod_aggregate(&f.t, channel);
        for (int h = 0; h < f.t.depth; h++) {
            size_t n = vod_aggregate_roots(&f.t, h, NULL, 0);
            cr_assert_gt(n, 0);
            uint32_t *roots = malloc(n * sizeof *roots);
            cr_assert_eq(vod_aggregate_roots(&f.t, h, roots, n), n);
            memset(parts, 0xab, f.t.used * sizeof *parts);
            f.t.agg = parts;
            for (size_t i = n; i-- > 0;) {
                vod_aggregate_subtree(&f.t, roots[i], h, channel);
                if (i % 3 == 0) vod_aggregate_subtree(&f.t, roots[i], h, channel);
            }
            vod_aggregate_top(&f.t, h, channel);
            cr_assert_arr_eq(parts + 1, whole + 1, (f.t.used - 1) * sizeof *parts,
                             "split at height %d, channel %d", h, channel);
            free(roots);
        }
        cr_assert_eq(vod_aggregate_roots(&f.t, f.t.depth, NULL, 0), 0);
        cr_assert_eq(vod_aggregate_roots(&f.t, f.t.depth - 1, NULL, 0), 1, "the root");
        f.t.agg = NULL;
        free(whole), free(parts);
    }
    fx_free(&f);
}

/* The mip levels' own unpacking of a normal is voxel_unpack_normal's, bit
 * for bit: every u code with every 7th v code, and every v with every 7th
 * u (both signs of z, the folds, the edges). */
Test(vod_encoder, mip_unpack_is_voxel_unpack)
{
    for (uint32_t a = 0; a < 4096; a++)
        for (uint32_t b = a % 7; b < 4096; b += 7)
            for (int k = 0; k < 2; k++) {
                uint32_t u = k ? b : a, v = k ? a : b;
                uint32_t packed = u << 8 | v << 20 | 0xffu;
                double x[3], y[3];
                voxel_unpack_normal(packed, x);
                vod_unpack_normal(packed, y);
                cr_assert(!memcmp(x, y, sizeof x), "u %u v %u", u, v);
            }
}

/* Every voxel size, every brick side: the stream inflates (zlib) to the
 * brick, and is small where the brick is mostly runs. */
Test(vod_encoder, one_pass_streams_inflate_to_the_brick)
{
    static const uint32_t bits[3] = {1, 8, 32};
    for (int b = 0; b < 3; b++)
        for (uint32_t brick = 2; brick <= 32; brick *= 2) {
            vod_sparse *z;
            size_t n = (size_t)brick * brick * brick * bits[b] / 8, cap = 2 * n + 64;
            cr_assert_eq(vod_sparse_new(brick, bits[b], &z), 0);
            uint8_t *raw = malloc(n), *out = malloc(cap), *back = malloc(n);
            for (int it = 0; it < 70; it++) {
                int kind = it % 7;
                make_brick(raw, n, kind);
                size_t k = vod_sparse_compress(z, raw, n, out, cap);
                cr_assert_gt(k, 6, "brick %u bits %u kind %d", brick, bits[b], kind);
                uLongf got = n;
                cr_assert_eq(uncompress(back, &got, out, k), Z_OK, "brick %u bits %u kind %d",
                             brick, bits[b], kind);
                cr_assert_eq(got, n);
                cr_assert_arr_eq(back, raw, n, "brick %u bits %u kind %d", brick, bits[b], kind);
                if (n >= 2048 && (kind == 0 || kind == 2 || kind == 4))
                    cr_assert_lt(k, n / 3, "brick %u kind %d: %zu of %zu bytes", brick, kind, k, n);
                cr_assert_eq(vod_sparse_compress(z, raw, n, out, k - 1), 0, "no room");
            }
            cr_assert_eq(vod_sparse_compress(z, raw, n + 4, out, cap), 0, "larger than made for");
            if (bits[b] == 32)
                cr_assert_eq(vod_sparse_compress(z, raw, n - 2, out, cap), 0, "part of a voxel");
            vod_sparse_free(z);
            free(raw), free(out), free(back);
        }
    vod_sparse *z;
    cr_assert_eq(vod_sparse_new(VOD_SPARSE_MAX_BRICK * 2, 32, &z), -EINVAL);
    cr_assert_eq(vod_sparse_new(16, 16, &z), -EINVAL);
}

/* A brick of few tokens goes with the fixed codes (no table to send), a
 * brick of many literals of few values with its own. */
Test(vod_encoder, one_pass_picks_the_smaller_code)
{
    vod_sparse *z;
    cr_assert_eq(vod_sparse_new(16, 1, &z), 0);
    uint8_t raw[512] = {0}, out[1200];
    memset(raw + 256, 0xff, 256);
    size_t k = vod_sparse_compress(z, raw, sizeof raw, out, sizeof out);
    cr_assert_gt(k, 6);
    cr_assert_eq((out[2] >> 1) & 3, 1, "fixed codes for a half-full brick");
    cr_assert_leq(k, 20, "%zu bytes", k);
    for (size_t i = 0; i < sizeof raw; i++) raw[i] = (uint8_t)('a' + rnd() % 3);
    k = vod_sparse_compress(z, raw, sizeof raw, out, sizeof out);
    cr_assert_gt(k, 6);
    cr_assert_eq((out[2] >> 1) & 3, 2, "dynamic codes for a brick of three letters");
    vod_sparse_free(z);
}

Test(vod_encoder, bound_holds_any_zlib_stream)
{
    struct libdeflate_compressor *c = libdeflate_alloc_compressor(12);
    for (uint32_t brick = 2; brick <= 64; brick *= 2)
        for (int ch = 0; ch < 2; ch++) {
            vod_params p;
            vod_params_default(&p);
            p.volume[0] = p.volume[1] = p.volume[2] = brick;
            p.brick = brick;
            p.channel = ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE;
            vod_layout L;
            char err[256];
            cr_assert_eq(vod_layout_make(&p, 6, &L, err, sizeof err), 0, "%s", err);
            cr_assert_geq(vod_encode_bound(&L, &p), libdeflate_zlib_compress_bound(c, L.raw_bytes));
        }
    libdeflate_free_compressor(c);
}

/* A 128 x 128 x 256 volume of 32^3 bricks: the 64 bricks of the lower
 * half all different, the upper half a copy of the lower, so that every
 * brick of it, at each level below the root, repeats one of the lower
 * half.  At 128 KiB a raw brick, the lower half's 74 bricks pass the 8 MiB
 * the encoder keeps: duplicates are compared both ways (with the kept
 * bytes, and by filling the first again). */
static void fx_copies(fixture *f)
{
    for (uint32_t b = 0; b < 64; b++)
        for (uint32_t i = 0; i < 40 + b; i++)
            fx_store(f, b % 4 * 32 + rnd() % 32, b / 4 % 4 * 32 + rnd() % 32,
                     b / 16 * 32 + rnd() % 32, random_surface());
    for (uint32_t z = 0; z < 128; z++)
        for (uint32_t y = 0; y < 128; y++)
            for (uint32_t x = 0; x < 128; x++) {
                uint32_t v = fx_get(f, x, y, z);
                if (v) fx_store(f, x, y, z + 128, v);
            }
}

/* fx_copies' fixture as surface bricks of the given size (zlib, SFHS):
 * the file the writer makes of it into *ref when ref is not NULL (before
 * the aggregates: the writer makes its own), then the layout, the
 * aggregates, the source and its n non-empty nodes (malloc'ed). */
static vod_node *copies_nodes(fixture *f, vod_params *p, uint32_t brick, membuf *ref,
                              vod_stats *st, vod_layout *L, vod_source *src, size_t *n)
{
    char err[256];
    fx_init(f, 8, 128, 128, 256);
    fx_copies(f);
    params(p, f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, brick);
    if (ref) *ref = write_file(f, p, st);
    cr_assert_eq(vod_layout_make(p, f->t.depth, L, err, sizeof err), 0);
    f->t.agg = malloc(f->t.used * sizeof *f->t.agg);
    vod_aggregate(&f->t, p->channel);
    *src = vod_octree_source(&f->t);
    *n = vod_collect(src, L, NULL, 0);
    vod_node *nodes = malloc(*n * sizeof *nodes);
    vod_collect(src, L, nodes, *n);
    return nodes;
}

Test(vod_encoder, duplicates_found_before_compression_change_nothing)
{
    fixture f;
    vod_params p;
    vod_stats st;
    membuf ref;
    vod_layout L;
    vod_source src;
    size_t n;
    char err[256];
    vod_node *nodes = copies_nodes(&f, &p, 32, &ref, &st, &L, &src, &n);
    size_t bound = vod_encode_bound(&L, &p);
    /* every brick compressed on its own, no duplicate looked for */
    vod_encoded *recs = malloc(n * sizeof *recs);
    uint8_t **data = malloc(n * sizeof *data), *scratch = malloc(L.raw_bytes);
    for (size_t i = 0; i < n; i++) {
        data[i] = malloc(bound);
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, data[i], bound, &recs[i]), 0);
    }
    vod_encode_cleanup();
    /* the encoder: a duplicate's first has the same bytes, and the firsts
     * are as many as the file's unique bricks */
    vod_encoder *e;
    cr_assert_eq(vod_encoder_new(&L, &p, &e), 0);
    uint8_t *out = malloc(bound);
    size_t firsts = 0, dups = 0;
    for (size_t i = 0; i < n; i++) {
        vod_encoded rec;
        uint64_t same;
        cr_assert_eq(vod_encoder_put(e, &src, &nodes[i], i, out, bound, &rec, &same), 0);
        cr_assert_eq(rec.hash, recs[i].hash);
        cr_assert_eq(rec.size, recs[i].size);
        if (same == i) {
            firsts++;
            cr_assert_arr_eq(out, data[i], rec.size);
        } else {
            dups++;
            cr_assert_lt(same, i);
            cr_assert_arr_eq(data[same], data[i], rec.size, "node %zu is not %llu", i,
                             (unsigned long long)same);
        }
    }
    cr_assert_eq(firsts, st.bricks);
    cr_assert_gt(firsts, 64, "more firsts than the encoder keeps the bytes of");
    cr_assert_geq(dups, 64 + 8, "the copies were found");
    vod_times t;
    vod_encoder_times(e, &t);
    cr_assert(t.fill > 0 && t.hash > 0 && t.compress > 0);
    vod_encoder_free(e);
    /* and the file is the one of bricks compressed one by one */
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = n, .nodes = nodes,
                                              .recs = recs, .data = (const uint8_t *const *)data,
                                              .sink = &sink, .err = err, .errlen = sizeof err}), 0);
    cr_assert_eq(m.n, ref.n);
    cr_assert_arr_eq(m.p, ref.p, m.n);
    for (size_t i = 0; i < n; i++) free(data[i]);
    free(data), free(recs), free(nodes), free(scratch), free(out), free(f.t.agg);
    f.t.agg = NULL;
    free(m.p), free(ref.p);
    fx_free(&f);
}

/* Node picks of the fixture's first few bricks, encoded in batches of 1
 * to 4, so that a brick repeats inside a batch and across batches: each
 * record is vod_encode's, a duplicate names an earlier equal brick, and
 * each distinct brick is compressed once. */
Test(vod_encoder, batches_find_duplicates_inside_and_across)
{
    fixture f;
    vod_params p;
    vod_layout L;
    vod_source src;
    size_t n;
    vod_node *nodes = copies_nodes(&f, &p, 16, NULL, NULL, &L, &src, &n);
    size_t bound = vod_encode_bound(&L, &p);
    cr_assert_gt(n, 24);
    enum { DISTINCT = 24, PICKS = 400 };
    vod_encoded ref[DISTINCT];
    uint8_t *data[DISTINCT], *scratch = malloc(L.raw_bytes);
    for (size_t i = 0; i < DISTINCT; i++) {
        data[i] = malloc(bound);
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, data[i], bound, &ref[i]), 0);
    }
    vod_encode_cleanup();
    size_t pick[PICKS], firsts = 0;
    vod_node picked[PICKS];
    for (size_t j = 0; j < PICKS; j++) {
        pick[j] = j < DISTINCT ? DISTINCT - 1 - j : rnd() % DISTINCT;
        if (j % 5 == 1) pick[j] = pick[j - 1]; /* often the brick just before */
        picked[j] = nodes[pick[j]];
    }
    vod_encoder *e;
    cr_assert_eq(vod_encoder_new(&L, &p, &e), 0);
    uint8_t *outs = malloc(VOD_ENCODE_BATCH * bound);
    for (size_t j = 0; j < PICKS;) {
        size_t k = 1 + rnd() % VOD_ENCODE_BATCH;
        if (k > PICKS - j) k = PICKS - j;
        uint8_t *out[VOD_ENCODE_BATCH];
        uint64_t tag[VOD_ENCODE_BATCH], same[VOD_ENCODE_BATCH];
        vod_encoded rec[VOD_ENCODE_BATCH];
        for (size_t t = 0; t < k; t++) out[t] = outs + t * bound, tag[t] = j + t;
        cr_assert_eq(vod_encoder_put_batch(e, &src, &picked[j], tag, k, out, bound, rec,
                                           same), 0);
        for (size_t t = 0; t < k; t++) {
            const vod_encoded *r = &ref[pick[j + t]];
            cr_assert_eq(rec[t].hash, r->hash, "pick %zu", j + t);
            cr_assert_eq(rec[t].size, r->size, "pick %zu", j + t);
            if (same[t] == j + t) {
                firsts++;
                cr_assert_arr_eq(out[t], data[pick[j + t]], r->size);
                continue;
            }
            cr_assert_lt(same[t], j + t);
            cr_assert_arr_eq(data[pick[same[t]]], data[pick[j + t]], r->size,
                             "pick %zu is not %llu", j + t, (unsigned long long)same[t]);
        }
        j += k;
    }
    size_t distinct = 0; /* equal raw bricks <=> equal streams */
    for (size_t i = 0; i < DISTINCT; i++) {
        bool seen = false;
        for (size_t h = 0; h < i && !seen; h++)
            seen = ref[h].size == ref[i].size && !memcmp(data[h], data[i], ref[i].size);
        distinct += !seen;
    }
    cr_assert_eq(firsts, distinct);
    uint64_t tag[VOD_ENCODE_BATCH + 1] = {0}, same[VOD_ENCODE_BATCH + 1];
    uint8_t *out[VOD_ENCODE_BATCH + 1] = {0};
    vod_encoded rec[VOD_ENCODE_BATCH + 1];
    cr_assert_eq(vod_encoder_put_batch(e, &src, nodes, tag, VOD_ENCODE_BATCH + 1, out,
                                       bound, rec, same), -EINVAL);
    vod_encoder_free(e);
    for (size_t i = 0; i < DISTINCT; i++) free(data[i]);
    free(outs), free(scratch), free(nodes), free(f.t.agg);
    f.t.agg = NULL;
    fx_free(&f);
}

Test(vod_encoder, every_level_gives_the_same_voxels)
{
    fixture f;
    fx_init(&f, 6, 64, 64, 64);
    fx_sphere(&f, 30.5, 33, 31, 25);
    membuf files[4];
    static const int levels[4] = {1, 6, 9, 12};
    for (int k = 0; k < 4; k++) {
        vod_params p;
        params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 16);
        p.zlib_level = levels[k];
        vod_stats st;
        files[k] = write_file(&f, &p, &st);
        cr_assert(st.t.fill > 0 && st.t.hash > 0 && st.t.compress > 0 && st.t.assemble > 0 &&
                  st.t.write > 0, "every stage timed");
        vod_file *v = read_ok(&files[k]);
        for (uint32_t z = 0; z < 64; z += 3)
            for (uint32_t y = 0; y < 64; y++)
                for (uint32_t x = 0; x < 64; x++)
                    cr_assert_eq(vod_voxel(v, 0, x, y, z), fx_get(&f, x, y, z));
        vod_close(v);
    }
    /* 1 and 6 use the one-pass encoder for 32-bit voxels, 9 and 12 libdeflate */
    cr_assert_eq(files[0].n, files[1].n);
    cr_assert_arr_eq(files[0].p, files[1].p, files[0].n);
    cr_assert(files[1].n != files[2].n || memcmp(files[1].p, files[2].p, files[1].n));
    for (int k = 0; k < 4; k++) free(files[k].p);
    fx_free(&f);
}

Test(vod_write, voxel_outside_the_volume_is_refused)
{
    fixture f;
    fx_init(&f, 5, 20, 20, 20);
    fx_store(&f, 3, 3, 3, 0xff);
    fx_store(&f, 4, 25, 6, 0xff);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    char err[256] = "";
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, &st, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "4,25,6") && strstr(err, "outside volumeSize"), "%s", err);
    cr_assert_eq(m.calls, 0);
    fx_free(&f);
}

Test(vod_write, file_past_4_gib_is_refused_before_writing)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 1024;
    p.brick = 256;
    p.comp = VOD_COMP_NONE;
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, 10, &L, err, sizeof err), 0);
    cr_assert_eq(L.nodes, 73);
    enum { N = 65 }; /* 65 distinct 64 MiB bricks: 4.06 GiB */
    uint8_t *raw = calloc(1, L.raw_bytes);
    vod_node nodes[N];
    vod_encoded recs[N];
    const uint8_t *data[N];
    for (int i = 0; i < N; i++) {
        nodes[i] = (vod_node){.preorder = (uint64_t)i};
        recs[i] = (vod_encoded){(uint32_t)i, (uint32_t)L.raw_bytes};
        data[i] = raw;
    }
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = N, .nodes = nodes,
                                              .recs = recs, .data = data,
                                              .sink = &sink, .st = &st,
                                              .err = err, .errlen = sizeof err}), -EFBIG);
    cr_assert_eq(m.calls, 0);
    cr_assert(strstr(err, "would pass 4 GiB") && strstr(err, "65 unique bricks"), "%s", err);
    free(raw);
}

Test(vod_write, fd_sink_and_vod_open)
{
    fixture f;
    fx_init(&f, 4, 16, 16, 16);
    fx_random(&f, 100);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    char path[] = "/tmp/test_vod_XXXXXX";
    int fd = mkstemp(path);
    cr_assert(fd >= 0);
    vod_sink sink = {vod_fd_write, (void *)(intptr_t)fd};
    vod_stats st;
    char err[256] = "";
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, &st, err, sizeof err), 0, "%s", err);
    close(fd);
    vod_file *v;
    cr_assert_eq(vod_open(path, &v, err, sizeof err), 0, "%s", err);
    cr_assert_eq(vod_get_info(v)->file_bytes, st.file_bytes);
    check_level0(&f, v, 0);
    vod_close(v);
    unlink(path);
    cr_assert_neq(vod_open(path, &v, err, sizeof err), 0);
    cr_assert(strstr(err, "cannot open"), "%s", err);
    cr_assert_null(v);
    fx_free(&f);
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

static int try_read(const uint8_t *b, size_t n, char *err, size_t errlen)
{
    vod_file *v = (vod_file *)1;
    err[0] = '\0';
    int rc = vod_read(b, n, &v, err, errlen);
    if (rc == 0) {
        vod_close(v);
    } else {
        cr_assert_null(v);
        cr_assert(err[0], "failure without a message");
    }
    return rc;
}

Test(vod_corrupt, every_truncation_fails_with_a_message)
{
    membuf m = small_file();
    char err[256];
    for (size_t n = 0; n < m.n; n++) {
        uint8_t *cut = malloc(n + 1); /* exact size, so ASan sees any overread */
        memcpy(cut, m.p, n);
        cr_assert_neq(try_read(cut, n, err, sizeof err), 0, "truncated to %zu read fine", n);
        if (n >= 64) cr_assert(strstr(err, "truncated") || strstr(err, "CRC"), "%zu: %s", n, err);
        free(cut);
    }
    cr_assert_eq(try_read(m.p, m.n, err, sizeof err), 0);
    free(m.p);
}

Test(vod_corrupt, every_bit_flip_fails)
{
    membuf m = small_file();
    char err[256];
    size_t crc_reports = 0, bits = m.n * 8;
    for (size_t bit = 0; bit < bits; bit++) {
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        cr_assert_neq(try_read(m.p, m.n, err, sizeof err), 0, "bit %zu flipped read fine", bit);
        crc_reports += strstr(err, "CRC") != NULL;
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
    char err[256];
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
        cr_assert_neq(try_read(cut, n, err, sizeof err), 0, "truncated to %zu read fine", n);
        free(cut);
    }
    /* bit flips without a CRC: some are harmless (a voxelScale bit), none may crash */
    for (size_t bit = 0; bit < m.n * 8; bit += 3) {
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
        try_read(m.p, m.n, err, sizeof err);
        m.p[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    }
    /* trailing garbage is refused when bit 16 says there is no trailer */
    uint8_t *more = malloc(m.n + 3);
    memcpy(more, m.p, m.n);
    memset(more + m.n, 0, 3);
    cr_assert_neq(try_read(more, m.n + 3, err, sizeof err), 0);
    cr_assert(strstr(err, "3 unexpected bytes after the last brick record"), "%s", err);
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
    char err[512];
    cr_assert_neq(try_read(m.p, m.n, err, sizeof err), 0, "patched file for '%s' read fine", want);
    cr_assert(strstr(err, want), "message '%s' lacks '%s'", err, want);
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

/* A file of 1 MiB bricks (64^3, 32 bits): two to a chunk of the reader's
 * (2 MiB of raw bricks), so that threads share its bricks (a dozen or more). */
static membuf chunked_file(void)
{
    fixture f;
    fx_init(&f, 8, 192, 128, 128);
    fx_sphere(&f, 96, 64, 64, 60);
    fx_sphere(&f, 30, 30, 30, 20);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 64);
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    return m;
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

/* m read by 1 thread and by each of thread_counts: the same return code and
 * message, and when it opens, the same bricks at every level.  Returns the
 * return code; err holds the message. */
static int read_threads_agree(const membuf *m, char *err, size_t errlen)
{
    vod_file *one = (vod_file *)1;
    int rc = vod_read_threads(m->p, m->n, 1, &one, err, errlen);
    for (size_t k = 0; k < sizeof thread_counts / sizeof *thread_counts; k++) {
        vod_file *v = (vod_file *)1;
        char e2[512] = "";
        int r2 = vod_read_threads(m->p, m->n, thread_counts[k], &v, e2, sizeof e2);
        cr_assert_eq(r2, rc, "%d threads: %d (%s), 1 thread: %d (%s)", thread_counts[k], r2,
                     e2, rc, err);
        cr_assert_str_eq(e2, rc ? err : "", "%d threads", thread_counts[k]);
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
    char err[512] = "";
    uint32_t n;
    free(records(&m, &n));
    cr_assert_geq(n, 12, "only %u bricks", n);
    cr_assert_eq(read_threads_agree(&m, err, sizeof err), 0, "%s", err);
    /* and through a file */
    char path[] = "/tmp/test_vod_threads_XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    cr_assert_eq(write(fd, m.p, m.n), (ssize_t)m.n);
    close(fd);
    vod_file *v;
    cr_assert_eq(vod_open_threads(path, 4, &v, err, sizeof err), 0, "%s", err);
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
        char err[512] = "", want[32];
        cr_assert_neq(read_threads_agree(&m, err, sizeof err), 0);
        uint32_t first = at[t][0] < at[t][1] ? at[t][0] : at[t][1];
        snprintf(want, sizeof want, "brick %u", r[first].id);
        cr_assert(strstr(err, want), "case %zu: '%s' does not name %s", t, err, want);
        p[1][0] ^= 0x21;
        p[0][0] ^= 0x5a;
    }
    /* a hash in the table that does not match: the last record's */
    where w = locate(m.p);
    for (uint32_t i = 0; i < n; i++)
        if (vod_get32(m.p + w.table_at + 12 * i) == r[n - 1].id)
            vod_put32(m.p + w.table_at + 12 * i + 8, vod_get32(m.p + w.table_at + 12 * i + 8) ^ 1);
    fix_crc(m.p, m.n);
    char err[512] = "", want[48];
    cr_assert_neq(read_threads_agree(&m, err, sizeof err), 0);
    snprintf(want, sizeof want, "brick %u: hash mismatch", r[n - 1].id);
    cr_assert(strstr(err, want), "'%s' lacks '%s'", err, want);
    free(r);
    free(m.p);
}

Test(vod_corrupt, tiny_and_empty_inputs)
{
    char err[256];
    cr_assert_neq(try_read(NULL, 0, err, sizeof err), 0);
    cr_assert(strstr(err, "file is truncated: the header needs 64 bytes, file has 0"), "%s", err);
    uint8_t hdr[64] = {0x2E, 0x56, 0x4F, 0x44};
    vod_put32(hdr + 60, VOD_FLAG_TRAILER);
    cr_assert_neq(try_read(hdr, sizeof hdr, err, sizeof err), 0);
    cr_assert(strstr(err, "truncated"), "%s", err);
}

/* The library's memory sink keeps every byte in order across its growth. */
Test(vod, mem_sink_grows_and_keeps_order)
{
    vod_membuf m = {0};
    uint8_t chunk[1000];
    for (int i = 0; i < 300; i++) {
        memset(chunk, i & 0xff, sizeof chunk);
        cr_assert_eq(vod_mem_write(&m, chunk, (size_t)(i % 7) * 100 + 1), 0);
    }
    size_t at = 0;
    for (int i = 0; i < 300; i++) {
        size_t len = (size_t)(i % 7) * 100 + 1;
        for (size_t k = 0; k < len; k++)
            cr_assert_eq(m.p[at + k], (uint8_t)i, "byte %zu", at + k);
        at += len;
    }
    cr_assert_eq(m.n, at);
    cr_assert_geq(m.cap, m.n);
    free(m.p);
}

static int efbig_write(void *ud, const void *buf, size_t n)
{
    (void)ud, (void)buf, (void)n;
    return -EFBIG;
}

/* A sink's own -EFBIG (a caller's size limit) is the sink's failure, not
 * the format's 4 GiB limit. */
Test(vod, sink_errors_are_not_the_4_GiB_limit)
{
    fixture f;
    fx_init(&f, 4, 16, 16, 16);
    fx_random(&f, 50);
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) p.volume[a] = 16;
    vod_sink sink = {efbig_write, NULL};
    char err[256];
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, NULL, err, sizeof err), -EFBIG);
    cr_assert_str_eq(err, "cannot write the VOD file: File too large");
    fx_free(&f);
}


/* ------------------------------------ brick sources: octree and volume */

/* The fixture's voxels as a volume of storage bricks of side sb, the way a
 * producer would store them: a brick whose voxels inside the volume are all
 * one non-zero value (and that lies wholly inside) by vod_volume_fill, so
 * that it is uniform, every other voxel by vod_volume_set. */
static vod_volume *fx_volume(const fixture *f, uint32_t sb, void **arena)
{
    size_t bytes = vod_volume_bytes(f->vol, 32, sb, UINT32_MAX);
    cr_assert_gt(bytes, 0);
    *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, *arena, bytes, f->vol, 32, sb), 0);
    uint32_t b[3], g[3];
    for (int a = 0; a < 3; a++) g[a] = (f->vol[a] + sb - 1) / sb;
    for (b[2] = 0; b[2] < g[2]; b[2]++)
        for (b[1] = 0; b[1] < g[1]; b[1]++)
            for (b[0] = 0; b[0] < g[0]; b[0]++) {
                uint32_t lo[3], hi[3], first = fx_get(f, b[0] * sb, b[1] * sb, b[2] * sb);
                bool same = first != 0;
                for (int a = 0; a < 3; a++) {
                    lo[a] = b[a] * sb;
                    hi[a] = lo[a] + sb;
                    same = same && hi[a] <= f->vol[a];
                }
                for (uint32_t z = lo[2]; z < hi[2] && same; z++)
                    for (uint32_t y = lo[1]; y < hi[1] && same; y++)
                        for (uint32_t x = lo[0]; x < hi[0] && same; x++)
                            same = fx_get(f, x, y, z) == first;
                if (same) {
                    cr_assert_eq(vod_volume_fill(v, lo, hi, first), 0);
                    continue;
                }
                for (uint32_t z = lo[2]; z < hi[2] && z < f->vol[2]; z++)
                    for (uint32_t y = lo[1]; y < hi[1] && y < f->vol[1]; y++)
                        for (uint32_t x = lo[0]; x < hi[0] && x < f->vol[0]; x++)
                            cr_assert_eq(vod_volume_set(v, x, y, z, fx_get(f, x, y, z)), 0);
            }
    return v;
}

static membuf write_source(vod_source *s, const vod_params *p, vod_stats *st)
{
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    char err[256] = "";
    cr_assert_eq(vod_write(s, p, &sink, st, err, sizeof err), 0, "%s", err);
    return m;
}

/* Nodes the volume calls uniform, for this layout (after a write). */
static size_t uniform_nodes(vod_source *s, const vod_params *p)
{
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(p, s->depth, &L, err, sizeof err), 0, "%s", err);
    size_t n = vod_collect(s, &L, NULL, 0), u = 0;
    vod_node *nodes = malloc((n + 1) * sizeof *nodes);
    cr_assert_eq(vod_collect(s, &L, nodes, n), n);
    for (size_t i = 0; i < n; i++) u += nodes[i].uniform;
    free(nodes);
    return u;
}

/* Every channel the octree gives, through the octree and through volumes
 * of several storage brick sizes: the same file, byte for byte.  Returns
 * how many nodes the volumes called uniform. */
static size_t same_bytes(fixture *f, const uint32_t *bricks, int nb,
                         const uint32_t *sbs, int ns)
{
    static const uint32_t comps[] = {VOD_COMP_ZLIB, VOD_COMP_RUNL, VOD_COMP_NONE};
    size_t uniform = 0;
    for (int si = 0; si < ns; si++) {
        void *arena;
        vod_volume *v = fx_volume(f, sbs[si], &arena);
        vod_source vs = vod_volume_source(v);
        for (int ch = 0; ch < 2; ch++)
            for (int bi = 0; bi < nb; bi++) {
                vod_params p;
                params(&p, f, ch ? VOXEL_CH_OCCUPANCY : VOXEL_CH_SURFACE,
                       comps[(bi + ch) % 3], bi % 2 ? VOD_HASH_XX32 : VOD_HASH_SFHS,
                       bricks[bi]);
                vod_stats so, sv;
                membuf a = write_file(f, &p, &so), b = write_source(&vs, &p, &sv);
                cr_assert_eq(a.n, b.n, "channel %d brick %u storage %u: %zu vs %zu bytes",
                             p.channel, p.brick, sbs[si], a.n, b.n);
                cr_assert_arr_eq(a.p, b.p, a.n, "channel %d brick %u storage %u",
                                 p.channel, p.brick, sbs[si]);
                cr_assert_eq(so.bricks, sv.bricks);
                uniform += uniform_nodes(&vs, &p);
                free(a.p), free(b.p);
            }
        free(arena);
    }
    return uniform;
}

Test(vod_source, random_voxels_same_bytes_from_octree_and_volume)
{
    static const uint32_t bricks[] = {2, 4, 8, 16, 32}, sbs[] = {2, 4, 8, 16};
    fixture f;
    fx_init(&f, 5, 20, 13, 7);
    fx_random(&f, 400);
    same_bytes(&f, bricks, 5, sbs, 4);
    fx_free(&f);
}

Test(vod_source, octree_deeper_than_the_volume_same_bytes)
{
    static const uint32_t bricks[] = {4, 8, 64}, sbs[] = {8, 32};
    fixture f;
    fx_init(&f, 7, 20, 17, 24);
    fx_random(&f, 500);
    same_bytes(&f, bricks, 3, sbs, 2);
    fx_free(&f);
}

/* A solid ball of one value inside a shell with normals, and a block of
 * another value: whole uniform bricks at level 0 and uniform mip bricks
 * above them, next to mixed ones; the uniform path (and its per-thread
 * cache) must give the same bytes. */
Test(vod_source, solid_ball_uniform_bricks_same_bytes)
{
    static const uint32_t bricks[] = {2, 4, 8, 16}, sbs[] = {2, 4, 8};
    fixture f;
    fx_init(&f, 6, 61, 64, 50);
    fx_sphere(&f, 30.2, 31.7, 24.9, 22.3);
    for (uint32_t z = 0; z < f.vol[2]; z++)
        for (uint32_t y = 0; y < f.vol[1]; y++)
            for (uint32_t x = 0; x < f.vol[0]; x++) {
                double d = hypot(hypot(x + 0.5 - 30.2, y + 0.5 - 31.7), z + 0.5 - 24.9);
                if (d < 21.4) fx_store(&f, x, y, z, 0x800cff);
                /* a block of another value, so uniform bricks of two values
                 * alternate in preorder */
                if (x >= 48 && y >= 48 && z >= 32) fx_store(&f, x, y, z, 0x4123ff);
            }
    size_t uniform = same_bytes(&f, bricks, 4, sbs, 3);
    cr_assert_gt(uniform, 100, "the ball's inside is uniform bricks (%zu)", uniform);
    fx_free(&f);
}

/* A file brick larger than the whole volume (treeHeight 1): one node whose
 * cube covers more than the volume's top level. */
Test(vod_source, volume_smaller_than_the_brick_same_bytes)
{
    static const uint32_t bricks[] = {8, 16, 32}, sbs[] = {2, 4};
    fixture f;
    fx_init(&f, 3, 5, 3, 6);
    fx_random(&f, 40);
    same_bytes(&f, bricks, 3, sbs, 2);
    fx_free(&f);
}

Test(vod_source, empty_sources_same_bytes)
{
    static const uint32_t bricks[] = {4, 16}, sbs[] = {4};
    fixture f;
    fx_init(&f, 4, 16, 9, 16);
    same_bytes(&f, bricks, 2, sbs, 1);
    fx_free(&f);
}

/* Channel 4 from a float volume (VOD_VOLUME_F32): negative and positive
 * uniform bricks, mixed ones, and the padding: every voxel reads back with
 * its float's bits, the float flag set, the mip levels the means.  The
 * octree, which gives no distance, refuses it. */
static float dist_at(uint32_t x, uint32_t y, uint32_t z)
{
    return x < 8 ? -3.5f : x >= 16 ? 3.5f : (float)x * 0.25f - (float)y * 0.125f + (float)z;
}

Test(vod_source, channel_4_from_a_float_volume_reads_back)
{
    uint32_t dims[3] = {20, 16, 16};
    size_t bytes = vod_volume_bytes(dims, VOD_VOLUME_F32, 8, UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, arena, bytes, dims, VOD_VOLUME_F32, 8), 0);
    uint32_t b[3];
    float brick[8 * 8 * 8];
    for (b[2] = 0; b[2] < 2; b[2]++)
        for (b[1] = 0; b[1] < 2; b[1]++)
            for (b[0] = 0; b[0] < 3; b[0]++) {
                for (uint32_t i = 0; i < 512; i++) {
                    uint32_t x = b[0] * 8 + i % 8, y = b[1] * 8 + i / 8 % 8, z = b[2] * 8 + i / 64;
                    brick[i] = x < dims[0] ? dist_at(x, y, z) : 0.0f;
                }
                cr_assert_eq(vod_volume_put_brick(v, b, brick), 0);
            }
    vod_volume_info in;
    vod_volume_get_info(v, &in);
    cr_assert_eq(in.bits, VOD_VOLUME_F32);
    cr_assert_eq(in.level0_bricks, 8, "the -3.5 bricks are uniform: %u", in.level0_bricks);
    vod_source vs = vod_volume_source(v);
    vod_params p;
    vod_params_default(&p);
    memcpy(p.volume, dims, sizeof dims);
    p.channel = VOXEL_CH_DISTANCE;
    p.brick = 4;
    vod_stats vst;
    membuf m = write_source(&vs, &p, &vst);
    vod_file *f;
    char err[256] = "";
    cr_assert_eq(vod_read(m.p, m.n, &f, err, sizeof err), 0, "%s", err);
    const vod_info *fi = vod_get_info(f);
    cr_assert_eq(fi->channel, 4);
    cr_assert_eq(fi->voxel_bits, 32);
    cr_assert(fi->flags & VOD_FLAG_FLOAT);
    for (uint32_t z = 0; z < dims[2]; z++)
        for (uint32_t y = 0; y < dims[1]; y++)
            for (uint32_t x = 0; x < dims[0]; x++) {
                float want = dist_at(x, y, z), got;
                uint32_t u = vod_voxel(f, 0, x, y, z);
                memcpy(&got, &u, 4);
                cr_assert_eq(memcmp(&want, &got, 4), 0, "(%u %u %u): %g, not %g", x, y, z,
                             (double)got, (double)want);
            }
    /* level 1: the mean of the 8 children (padding counts as 0) */
    for (uint32_t z = 0; z < 8; z++)
        for (uint32_t y = 0; y < 8; y++)
            for (uint32_t x = 0; x < 10; x++) {
                double sum = 0;
                for (int i = 0; i < 8; i++) {
                    uint32_t cx = 2 * x + (i & 1), cy = 2 * y + (i >> 1 & 1), cz = 2 * z + (i >> 2);
                    sum += cx < dims[0] ? dist_at(cx, cy, cz) : 0.0f;
                }
                float want = (float)(sum / 8), got;
                uint32_t u = vod_voxel(f, 1, x, y, z);
                memcpy(&got, &u, 4);
                cr_assert_eq(memcmp(&want, &got, 4), 0, "level 1 (%u %u %u)", x, y, z);
            }
    vod_close(f);
    free(m.p);
    free(arena);
    /* the octree gives no distance */
    fixture fx;
    fx_init(&fx, 4, 16, 16, 16);
    fx_random(&fx, 20);
    params(&p, &fx, VOXEL_CH_DISTANCE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    membuf m2 = {0};
    vod_sink sink = {mem_write, &m2};
    cr_assert_eq(vod_write_octree(&fx.t, &p, &sink, NULL, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "channel 4 cannot be written from the octree"), "%s", err);
    cr_assert_eq(m2.calls, 0, "nothing written");
    fx_free(&fx);
}

Test(vod_source, a_channel_the_source_lacks_is_refused)
{
    fixture f;
    fx_init(&f, 4, 16, 16, 16);
    fx_random(&f, 20);
    vod_params p;
    params(&p, &f, VOXEL_CH_DENSITY, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    char err[256] = "";
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, NULL, err, sizeof err), -EINVAL);
    cr_assert_str_eq(err, "channel 2 cannot be written from the octree (it gives "
                          "channels 1 and 3)");
    cr_assert_null(f.t.agg);
    /* and the octree's fill refuses a layout it cannot give even if asked */
    vod_source s = vod_octree_source(&f.t);
    vod_layout L;
    cr_assert_eq(vod_layout_make(&p, 4, &L, err, sizeof err), 0, "%s", err);
    cr_assert_eq(L.voxel_bits, 8);
    vod_node n = {.level = 0};
    uint8_t *scratch = malloc(L.raw_bytes), *out = malloc(vod_encode_bound(&L, &p));
    vod_encoded rec;
    cr_assert_eq(vod_encode(&s, &L, &p, &n, scratch, out, vod_encode_bound(&L, &p), &rec),
                 -EINVAL);
    cr_assert_eq(m.calls, 0);
    free(scratch), free(out);
    fx_free(&f);
}

/* A source that breaks region()'s contract (it renumbers the nodes): the
 * nodes reach vod_assemble out of preorder, and vod_write must return
 * assemble's refusal with its message, not succeed with nothing written. */
static int renumbering_region(const vod_source *s, const vod_layout *L, vod_node *n)
{
    vod_source o = vod_octree_source(s->ctx);
    int r = o.ops->region(&o, L, n);
    n->preorder = 0;
    return r;
}

Test(vod_source, assemble_refusals_reach_the_caller)
{
    fixture f;
    fx_init(&f, 5, 32, 32, 32);
    fx_random(&f, 300);
    vod_source s = vod_octree_source(&f.t);
    vod_source_ops ops = *s.ops;
    ops.region = renumbering_region;
    s.ops = &ops;
    f.t.agg = malloc(f.t.used * sizeof *f.t.agg);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 8);
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    char err[256] = "";
    cr_assert_eq(vod_write(&s, &p, &sink, NULL, err, sizeof err), -EINVAL);
    cr_assert_str_eq(err, "bricks out of preorder or over their bound");
    cr_assert_eq(m.calls, 0);
    free(f.t.agg);
    fx_free(&f);
}

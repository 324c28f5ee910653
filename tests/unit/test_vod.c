/* VOD writer and reader against independent oracles: hash test vectors and a
 * reference SuperFastHash, run-length bricks, the layout's rules, dense arrays
 * of the voxels written, a downsampling oracle per level, a second minimal
 * reader that follows Figure 24 alone, the header's bytes, the writer's refusals
 * and its sinks.  The encoder and duplicates: test_vod_encoder.c; corrupt files:
 * test_vod_corrupt.c; the two brick sources: test_vod_source.c; the volume's own
 * tests: test_vod_volume.c. */
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

#include "vod_fixture.h"

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

/* -------------------------------------------------------------- hashes */

Test(vod_hash, xxhash32_test_vectors)
{
    cr_assert_eq(vod_hash_xx32("", 0), 0x02CC5D05u);
    cr_assert_eq(vod_hash_xx32("a", 1), 0x550D7456u);
    cr_assert_eq(vod_hash_xx32("abc", 3), 0x32D153FFu);
    cr_assert_eq(vod_hash_xx32("Nobody inspects the spammish repetition", 39), 0xE2293B2Fu);
    cr_assert_eq(vod_hash(VOD_HASH_XX32, "abc", 3), 0x32D153FFu);
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
    err_info err = {0};
    int rc = vod_layout_make(p, depth, &L, &err);
    if (want) cr_assert(strstr(err.msg, want), "message '%s' lacks '%s'", err.msg, want);
    return rc;
}

Test(vod_layout, validates_params_per_spec)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 100;
    vod_layout L;
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, 7, &L, &err), 0, "%s", err.msg);
    cr_assert_eq(L.height, 4); /* ceil(100/16) = 7 -> 1 + 3 */
    cr_assert_eq(L.padded, 128);
    cr_assert_eq(L.raw_bytes, 16 * 16 * 16 * 4);
    cr_assert_eq(L.nodes, 585);
    cr_assert_eq(vod_layout_make(&p, 9, &L, &err), 0, "deeper octree");
    cr_assert_eq(L.padded, 128, "N < 2^depth: %u", L.padded);
    p.volume[0] = p.volume[1] = p.volume[2] = 5;
    cr_assert_eq(vod_layout_make(&p, 3, &L, &err), 0);
    cr_assert_eq(L.height, 1);
    cr_assert_eq(L.padded, 16, "one root brick bigger than the octree");
    p.channel = VOXEL_CH_OCCUPANCY;
    cr_assert_eq(vod_layout_make(&p, 3, &L, &err), 0);
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
    cr_assert_eq(vod_layout_make(&q, 3, &L, &err), 0);
    cr_assert_eq(L.voxel_bits, 8);
    cr_assert_eq(L.raw_bytes, 16 * 16 * 16);
    q = p, q.channel = VOXEL_CH_DISTANCE;
    cr_assert_eq(layout_rc(&q, 3, NULL), 0, "channel 4: f32 voxels");
    cr_assert_eq(vod_layout_make(&q, 3, &L, &err), 0);
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

/* The plan reads only the root's cell to tell an empty node (every other
 * cell exists because a voxel lies below it): a childless cell below the
 * root, which only a broken writer leaves, is a node of zeros, written and
 * read back like any brick. */
Test(vod_roundtrip, a_childless_cell_below_the_root_is_a_brick_of_zeros)
{
    fixture f;
    fx_init(&f, 5, 32, 32, 32);
    fx_store(&f, 1, 1, 1, random_surface() | 1u);
    fx_store(&f, 17, 1, 1, random_surface() | 1u);
    uint32_t c = octree_find(&f.t, 3, 16, 0, 0); /* brick (1, 0, 0)'s cell */
    cr_assert_neq(c, 0);
    memset(f.t.cells[c].child, 0, sizeof f.t.cells[c].child);
    f.dense[(1 * f.side + 1) * f.side + 17] = 0, f.count--;
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 16);
    vod_stats st;
    membuf m = write_file(&f, &p, &st);
    cr_assert_eq(st.nonempty_nodes, 3, "the root and two level-0 nodes: %llu",
                 (unsigned long long)st.nonempty_nodes);
    vod_file *v = read_ok(&m);
    check_level0(&f, v, 0);
    vod_close(v);
    free(m.p);
    fx_free(&f);
}

/* ------------------------------------------------------- downsampling */

/* A voxel of a level, for the messages. */
typedef struct {
    int l;
    uint32_t x, y, z;
} voxel_at;

/* Spec section 3, written out here: channel 3 occupancy is the mean rounded
 * half up; the normal the normalized sum over occupied children. */
static void check_parent(uint32_t got, const uint32_t c[8], int occupancy, voxel_at at)
{
    int l = at.l;
    uint32_t x = at.x, y = at.y, z = at.z;
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
                    check_parent(vod_voxel(v, l, x, y, z), c, occupancy,
                                 (voxel_at){l, x, y, z});
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
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, f.t.depth, &L, &err), 0);
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
        vod_brick_out o = {data[i], bound, &recs[i]};
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, &o), 0);
    }
    vod_brick_out small = {data[0], 4, &recs[0]}, first = {data[0], bound, &recs[0]};
    cr_assert_eq(vod_encode(&src, &L, &p, &nodes[0], scratch, &small), -ENOBUFS);
    cr_assert_eq(vod_encode(&src, &L, &p, &nodes[0], scratch, &first), 0);
    vod_node outside = {.level = L.height};
    cr_assert_eq(vod_encode(&src, &L, &p, &outside, scratch, &first), -EINVAL);
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    vod_stats st;
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = n, .nodes = nodes,
                                              .recs = recs, .data = (const uint8_t *const *)data,
                                              .sink = &sink, .st = &st,
                                              .err = &err}), 0);
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
    err_info err = {0};
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, &st, &err), -EINVAL);
    cr_assert(strstr(err.msg, "4,25,6") && strstr(err.msg, "outside volumeSize"), "%s", err.msg);
    cr_assert_eq(err.code, -EINVAL);
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
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, 10, &L, &err), 0);
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
                                              .err = &err}), -EFBIG);
    cr_assert_eq(m.calls, 0);
    cr_assert(strstr(err.msg, "would pass 4 GiB") && strstr(err.msg, "65 unique bricks"), "%s", err.msg);
    cr_assert_eq(err.code, -EFBIG);
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
    err_info err = {0};
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, &st, &err), 0, "%s", err.msg);
    close(fd);
    vod_file *v;
    cr_assert_eq(vod_open(path, &v, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_get_info(v)->file_bytes, st.file_bytes);
    check_level0(&f, v, 0);
    vod_close(v);
    unlink(path);
    cr_assert_eq(vod_open(path, &v, &err), -ENOENT);
    cr_assert(strstr(err.msg, "cannot open"), "%s", err.msg);
    cr_assert_eq(err.code, -ENOENT);
    cr_assert_null(v);
    fx_free(&f);
}

/* vod_open maps the file (vod_read's copy of it is not made): the same
 * file as vod_read of its bytes; an empty file and one cut short are
 * refused with vod_read's own errors, not read past their end. */
Test(vod_write, vod_open_of_a_mapped_file_is_vod_read_of_its_bytes)
{
    fixture f;
    fx_init(&f, 4, 16, 16, 16);
    fx_random(&f, 100);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, 4);
    membuf m = write_file(&f, &p, NULL);
    err_info err = {0}, err2 = {0};
    char path[] = "/tmp/test_vod_map_XXXXXX";
    int fd = mkstemp(path);
    cr_assert(fd >= 0);
    cr_assert_eq(write(fd, m.p, m.n), (ssize_t)m.n);
    vod_file *a, *b;
    cr_assert_eq(vod_open_threads(path, 2, &a, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_read(m.p, m.n, &b, &err), 0, "%s", err.msg);
    const vod_info *ia = vod_get_info(a), *ib = vod_get_info(b);
    cr_assert_eq(ia->file_bytes, m.n);
    cr_assert_eq(ia->bricks, ib->bricks);
    cr_assert_eq(ia->nodes, ib->nodes);
    cr_assert_eq(ia->crc32, ib->crc32);
    cr_assert_str_eq(ia->metadata, ib->metadata);
    size_t raw = (size_t)ia->brick * ia->brick * ia->brick * ia->voxel_bits / 8;
    uint32_t side = vod_level_size(a, 0) / ia->brick, c[3], n = 0;
    for (c[2] = 0; c[2] < side; c[2]++)
        for (c[1] = 0; c[1] < side; c[1]++)
            for (c[0] = 0; c[0] < side; c[0]++) {
                const uint8_t *x = vod_brick(a, 0, c), *y = vod_brick(b, 0, c);
                cr_assert_eq(!x, !y);
                if (x) {
                    cr_assert_eq(memcmp(x, y, raw), 0);
                    n++;
                }
            }
    cr_assert_gt(n, 0, "no brick compared");
    check_level0(&f, a, 0);
    vod_close(a);
    vod_close(b);
    /* cut short: the mapping ends at the file's end, as the bytes do */
    cr_assert_eq(ftruncate(fd, (off_t)(m.n - 7)), 0);
    cr_assert_neq(vod_open(path, &a, &err), 0);
    cr_assert_neq(vod_read(m.p, m.n - 7, &b, &err2), 0);
    cr_assert_str_eq(err.msg, err2.msg);
    cr_assert_eq(err.code, err2.code);
    cr_assert_null(a);
    cr_assert_eq(ftruncate(fd, 0), 0); /* nothing to map */
    cr_assert_neq(vod_open(path, &a, &err), 0);
    cr_assert_neq(vod_read(m.p, 0, &b, &err2), 0);
    cr_assert_str_eq(err.msg, err2.msg);
    cr_assert_eq(err.code, err2.code);
    close(fd);
    unlink(path);
    free(m.p);
    fx_free(&f);
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
    err_info err = {0};
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, NULL, &err), -EFBIG);
    cr_assert_str_eq(err.msg, "cannot write the VOD file: File too large");
    cr_assert_eq(err.code, -EFBIG);
    fx_free(&f);
}

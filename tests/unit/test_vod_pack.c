/* The packed bricks of a float volume (vod_volume_pack.c): every voxel
 * reads back with the bits it was given, whatever the mix of literals and
 * +-bg voxels (zeros, -0.0, NaN bits, values above the band's width), by
 * every writer (put_brick, put_uniform, set, fill); the file's voxels and
 * mip levels are a dense oracle's; a record costs what its literals do;
 * vod_volume_check refuses a record that disagrees with itself. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "unit_util.h"
#include "vod.h"
#include "vod_volume.h"
#include "vod_volume_int.h"
#include "voxel.h"

static uint32_t fb(float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    return u;
}

static uint64_t rng = 88172645463325252ull;
static uint32_t rnd(void)
{
    rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
    return (uint32_t)(rng >> 11);
}

/* A distance-like voxel: mostly +-w, some band values, a few odd bits. */
static uint32_t sample(float w)
{
    uint32_t r = rnd() % 100;
    if (r < 40) return fb(w);
    if (r < 75) return fb(-w);
    if (r < 95) return fb(((float)(rnd() % 2000) - 1000.0f) / 1000.0f * w);
    uint32_t odd[5] = {0, 0x80000000u, 0x7fc00001u, fb(2 * w), fb(-3 * w)};
    return odd[r - 95];
}

typedef struct {
    uint32_t dims[3], S;
    void *arena;
    size_t bytes;
    vod_volume *v;
    uint32_t *dense; /* the oracle */
} fx;

static void fx_make(fx *f, uint32_t dx, uint32_t dy, uint32_t dz, uint32_t S)
{
    memset(f, 0, sizeof *f);
    f->dims[0] = dx, f->dims[1] = dy, f->dims[2] = dz, f->S = S;
    f->bytes = vod_volume_bytes(f->dims, VOD_VOLUME_F32, S, UINT32_MAX);
    cr_assert(f->bytes > 0);
    f->arena = malloc(f->bytes);
    cr_assert_eq(vod_volume_init(&f->v, f->arena, f->bytes, f->dims, VOD_VOLUME_F32, S), 0);
    f->dense = calloc((size_t)dx * dy * dz, 4);
}

static void fx_free(fx *f)
{
    free(f->arena);
    free(f->dense);
}

static uint32_t *at(fx *f, uint32_t x, uint32_t y, uint32_t z)
{
    return &f->dense[((size_t)z * f->dims[1] + y) * f->dims[0] + x];
}

/* Every brick by put_brick (a few by put_uniform), then some sets and a
 * fill over them, all mirrored in the oracle. */
static void fx_fill(fx *f, float w)
{
    uint32_t S = f->S, g[3], b[3];
    for (int a = 0; a < 3; a++) g[a] = (f->dims[a] + S - 1) / S;
    uint32_t *brick = malloc((size_t)S * S * S * 4);
    for (b[2] = 0; b[2] < g[2]; b[2]++)
        for (b[1] = 0; b[1] < g[1]; b[1]++)
            for (b[0] = 0; b[0] < g[0]; b[0]++) {
                bool whole = true, uni = rnd() % 4 == 0;
                for (int a = 0; a < 3; a++) whole = whole && (b[a] + 1) * S <= f->dims[a];
                uint32_t u = rnd() & 1 ? fb(w) : fb(-w);
                for (uint32_t i = 0; i < S * S * S; i++) {
                    uint32_t x = b[0] * S + i % S, y = b[1] * S + i / S % S, z = b[2] * S + i / (S * S);
                    bool in = x < f->dims[0] && y < f->dims[1] && z < f->dims[2];
                    brick[i] = !in ? 0 : uni && whole ? u : sample(w);
                    if (in) *at(f, x, y, z) = brick[i];
                }
                if (uni && whole) cr_assert_eq(vod_volume_put_uniform(f->v, b, u), 0);
                else cr_assert_eq(vod_volume_put_brick(f->v, b, brick), 0);
            }
    free(brick);
    for (int k = 0; k < 200; k++) {
        uint32_t x = rnd() % f->dims[0], y = rnd() % f->dims[1], z = rnd() % f->dims[2];
        uint32_t val = sample(w);
        cr_assert_eq(vod_volume_set(f->v, x, y, z, val), 0);
        *at(f, x, y, z) = val;
    }
    uint32_t lo[3] = {1, 2, 3}, hi[3] = {f->dims[0] - 1, f->dims[1] / 2 + 1, f->dims[2] - 2};
    cr_assert_eq(vod_volume_fill(f->v, lo, hi, fb(0.25f)), 0);
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++)
            for (uint32_t x = lo[0]; x < hi[0]; x++) *at(f, x, y, z) = fb(0.25f);
}

static void same_as_oracle(fx *f)
{
    for (uint32_t z = 0; z < f->dims[2]; z++)
        for (uint32_t y = 0; y < f->dims[1]; y++)
            for (uint32_t x = 0; x < f->dims[0]; x++)
                cr_assert_eq(vod_volume_get(f->v, x, y, z), *at(f, x, y, z),
                             "S %u (%u %u %u): %08x, not %08x", f->S, x, y, z,
                             vod_volume_get(f->v, x, y, z), *at(f, x, y, z));
}

Test(vod_pack, every_writer_reads_back_bit_for_bit)
{
    uint32_t sides[] = {2, 4, 8, 16, 64};
    for (size_t i = 0; i < sizeof sides / sizeof *sides; i++) {
        fx f;
        fx_make(&f, 37, 29, 21, sides[i]);
        fx_fill(&f, 0.375f);
        same_as_oracle(&f);
        cr_assert_eq(vod_volume_check(f.v, f.bytes), 0, "S %u", sides[i]);
        fx_free(&f);
    }
}

/* A record takes its head, two masks and its literals, rounded to units. */
Test(vod_pack, a_record_costs_its_literals)
{
    fx f;
    fx_make(&f, 16, 16, 16, 16);
    uint32_t brick[4096], b[3] = {0, 0, 0};
    for (int i = 0; i < 4096; i++) brick[i] = i % 3 ? fb(1.5f) : fb(-1.5f);
    for (int i = 0; i < 100; i++) brick[i * 7] = fb((float)i / 100.0f);
    cr_assert_eq(vod_volume_put_brick(f.v, b, brick), 0);
    vod_volume_info in;
    vod_volume_get_info(f.v, &in);
    cr_assert_eq(in.pool_used, (16 + 2 * 512 + 4 * 100 + 15) / 16);
    cr_assert_lt(in.pool_used * 16, 4096 * 4 / 10, "a tenth of the dense brick");
    for (uint32_t i = 0; i < 4096; i++)
        cr_assert_eq(vod_volume_get(f.v, i % 16, i / 16 % 16, i / 256), brick[i]);
    /* written again with fewer literals: the same units */
    for (int i = 50; i < 100; i++) brick[i * 7] = fb(1.5f);
    cr_assert_eq(vod_volume_put_brick(f.v, b, brick), 0);
    vod_volume_info again;
    vod_volume_get_info(f.v, &again);
    cr_assert_eq(again.pool_used, in.pool_used);
    cr_assert_eq(vod_volume_get(f.v, 7 * 60 % 16, 7 * 60 / 16 % 16, 7 * 60 / 256), fb(1.5f));
    fx_free(&f);
}

Test(vod_pack, check_refuses_a_record_that_disagrees_with_itself)
{
    fx f;
    fx_make(&f, 16, 8, 8, 8);
    uint32_t brick[512], b[3] = {1, 0, 0};
    for (int i = 0; i < 512; i++) brick[i] = i % 5 ? fb(2.0f) : fb((float)i);
    cr_assert_eq(vod_volume_put_brick(f.v, b, brick), 0);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    uint32_t e = table(f.v, 0)[1];
    pack_head *h = (pack_head *)(void *)brick_data(f.v, e);
    h->n++;
    cr_assert_eq(vod_volume_check(f.v, f.bytes), -EINVAL, "a count the mask does not have");
    h->n--;
    h->cap = 1000;
    cr_assert_eq(vod_volume_check(f.v, f.bytes), -EINVAL, "units past the pool's used");
    h->cap = 1;
    cr_assert_eq(vod_volume_check(f.v, f.bytes), -EINVAL, "fewer units than its size");
    fx_free(&f);
}

/* The check on every CPU (a pool of 16,384 units or more): level 0's
 * table of 8192 entries is read in chunks of 4096, alternately by the
 * parts, so a bad record in either chunk (the bricks at z 0 and z 15)
 * fails the check, and the volume checks again once it is mended. */
Test(vod_pack, the_check_on_every_cpu_finds_a_bad_record_in_any_part)
{
    fx f;
    fx_make(&f, 256, 128, 128, 8); /* 32 x 16 x 16 bricks */
    uint32_t brick[512];
    for (uint32_t z = 0; z < 16; z += 15)
        for (uint32_t y = 0; y < 16; y++)
            for (uint32_t x = 0; x < 32; x++) {
                uint32_t b[3] = {x, y, z};
                for (int i = 0; i < 512; i++) brick[i] = fb((float)(i + 7 * x + 13 * y + z));
                cr_assert_eq(vod_volume_put_brick(f.v, b, brick), 0);
            }
    vod_volume_info in;
    vod_volume_get_info(f.v, &in);
    cr_assert_geq(in.pool_used, 16384, "the pool takes the parallel check");
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    const uint64_t bad[] = {5 + 3 * 32, 31 + 15 * 32 + 15 * 512}; /* one in each chunk */
    for (size_t k = 0; k < 2; k++) {
        pack_head *h = (pack_head *)(void *)brick_data(f.v, table(f.v, 0)[bad[k]]);
        h->n++;
        cr_assert_eq(vod_volume_check(f.v, f.bytes), -EINVAL, "entry %llu",
                     (unsigned long long)bad[k]);
        h->n--;
        cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    }
    fx_free(&f);
}

/* Channel 4 of a packed volume, written and read back: level 0 the
 * oracle's bits, level 1 the mean of 8 (spec section 3, padding 0), for a
 * file brick smaller and larger than the storage brick. */
static void file_case(uint32_t S, uint32_t brick)
{
    fx f;
    fx_make(&f, 37, 29, 21, S);
    fx_fill(&f, 0.375f);
    vod_source src = vod_volume_source(f.v);
    vod_params p;
    vod_params_default(&p);
    memcpy(p.volume, f.dims, sizeof f.dims);
    p.channel = VOXEL_CH_DISTANCE;
    p.brick = brick;
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    err_info err = {0};
    cr_assert_eq(vod_write(&src, &p, &sink, NULL, &err), 0, "%s", err.msg);
    vod_file *file;
    cr_assert_eq(vod_read(m.p, m.n, &file, &err), 0, "%s", err.msg);
    for (uint32_t z = 0; z < f.dims[2]; z++)
        for (uint32_t y = 0; y < f.dims[1]; y++)
            for (uint32_t x = 0; x < f.dims[0]; x++)
                cr_assert_eq(vod_voxel(file, 0, x, y, z), *at(&f, x, y, z));
    for (uint32_t z = 0; z < (f.dims[2] + 1) / 2; z++)
        for (uint32_t y = 0; y < (f.dims[1] + 1) / 2; y++)
            for (uint32_t x = 0; x < (f.dims[0] + 1) / 2; x++) {
                uint32_t c[8];
                for (int i = 0; i < 8; i++) {
                    uint32_t cx = 2 * x + (i & 1), cy = 2 * y + (i >> 1 & 1), cz = 2 * z + (i >> 2);
                    bool in = cx < f.dims[0] && cy < f.dims[1] && cz < f.dims[2];
                    c[i] = in ? *at(&f, cx, cy, cz) : 0;
                }
                double sum = 0;
                for (int i = 0; i < 8; i++) {
                    float v;
                    memcpy(&v, &c[i], 4);
                    sum += v;
                }
                float want = (float)(sum / 8);
                uint32_t got = vod_voxel(file, 1, x, y, z);
                cr_assert(got == fb(want) || (isnan(want) && (got & 0x7f800000u) == 0x7f800000u),
                          "S %u brick %u level 1 (%u %u %u)", S, brick, x, y, z);
            }
    vod_close(file);
    free(m.p);
    fx_free(&f);
}

Test(vod_pack, the_file_is_the_oracles)
{
    file_case(8, 4);
    file_case(4, 16);
    file_case(16, 8);
}

/* The writer refuses a voxel outside the file's volume (VOD padding must
 * be 0) in a packed record as in any other brick: a band value, and -0.0
 * (non-zero bits); the record is read whole for it (vol_outside). */
Test(vod_pack, a_voxel_outside_the_file_volume_is_refused)
{
    fx f;
    fx_make(&f, 20, 20, 20, 8);
    cr_assert_eq(vod_volume_set(f.v, 3, 3, 3, fb(0.5f)), 0);
    vod_source src = vod_volume_source(f.v);
    vod_params p;
    vod_params_default(&p);
    memcpy(p.volume, f.dims, sizeof f.dims);
    p.volume[0] = 16;
    p.channel = VOXEL_CH_DISTANCE;
    const uint32_t bad[] = {fb(0.25f), 0x80000000u};
    for (int k = 0; k < 2; k++) {
        cr_assert_eq(vod_volume_set(f.v, 17, 5, 6, bad[k]), 0);
        membuf m = {0};
        vod_sink sink = {mem_write, &m};
        err_info err = {0};
        cr_assert_eq(vod_write(&src, &p, &sink, NULL, &err), -EINVAL, "value %08x", bad[k]);
        cr_assert_str_eq(err.msg, "the volume holds a voxel at 17,5,6, outside volumeSize "
                                  "16x20x20 (VOD padding must be 0)");
        free(m.p);
    }
    cr_assert_eq(vod_volume_set(f.v, 17, 5, 6, 0), 0);
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    err_info err = {0};
    cr_assert_eq(vod_write(&src, &p, &sink, NULL, &err), 0, "%s", err.msg);
    free(m.p);
    fx_free(&f);
}

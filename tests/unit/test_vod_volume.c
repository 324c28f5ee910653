/* The brick-sparse volume (vod_volume.h) and its VOD brick source: its
 * voxels against a dense copy, its pool and argument errors, channel 2
 * (8-bit density) and channel 1 against a brute-force oracle of spec
 * section 3 computed here from the dense copy (every voxel of every level,
 * and which nodes hold a brick), position independence of the arena, the
 * volume precondition and the mip levels' memory.  That octree and volume
 * give the same bytes for channels 1 and 3 is in test_vod.c. */
#include <criterion/criterion.h>
#include <pthread.h>
#include <errno.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

#include "unit_util.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static uint32_t rnd(void) { return xorshift32(&rng_state); }

/* A volume and a dense copy of its voxels. */
typedef struct {
    void *arena;
    size_t bytes;
    vod_volume *v;
    uint32_t dims[3], bits;
    uint32_t *dense;
} vfx;

static void vfx_init(vfx *f, uint32_t x, uint32_t y, uint32_t z, uint32_t bits,
                     uint32_t sb)
{
    f->dims[0] = x, f->dims[1] = y, f->dims[2] = z;
    f->bits = bits;
    f->bytes = vod_volume_bytes(f->dims, bits, sb, UINT32_MAX);
    cr_assert_gt(f->bytes, 0);
    f->arena = malloc(f->bytes);
    cr_assert_eq(vod_volume_init(&f->v, f->arena, f->bytes, f->dims, bits, sb), 0);
    f->dense = calloc((size_t)x * y * z, sizeof *f->dense);
}

static void vfx_free(vfx *f)
{
    free(f->arena);
    free(f->dense);
}

static uint32_t *vfx_at(const vfx *f, uint32_t x, uint32_t y, uint32_t z)
{
    return &f->dense[((size_t)z * f->dims[1] + y) * f->dims[0] + x];
}

static uint32_t vfx_get(const vfx *f, uint32_t x, uint32_t y, uint32_t z)
{
    if (x >= f->dims[0] || y >= f->dims[1] || z >= f->dims[2]) return 0;
    return *vfx_at(f, x, y, z);
}

static void vfx_set(vfx *f, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    cr_assert_eq(vod_volume_set(f->v, x, y, z, v), 0, "set %u %u %u", x, y, z);
    *vfx_at(f, x, y, z) = v;
}

/* The voxels [lo, hi) (x, y, z) := v, in the volume and the oracle. */
typedef struct {
    uint32_t lo[3], hi[3];
} vbox;

static void vfx_fill(vfx *f, vbox b, uint32_t v)
{
    cr_assert_eq(vod_volume_fill(f->v, b.lo, b.hi, v), 0);
    for (uint32_t z = b.lo[2]; z < b.hi[2]; z++)
        for (uint32_t y = b.lo[1]; y < b.hi[1]; y++)
            for (uint32_t x = b.lo[0]; x < b.hi[0]; x++) *vfx_at(f, x, y, z) = v;
}

static void vfx_check(const vfx *f)
{
    for (uint32_t z = 0; z < f->dims[2]; z++)
        for (uint32_t y = 0; y < f->dims[1]; y++)
            for (uint32_t x = 0; x < f->dims[0]; x++)
                cr_assert_eq(vod_volume_get(f->v, x, y, z), vfx_get(f, x, y, z),
                             "voxel %u %u %u", x, y, z);
}

static void params(vod_params *p, const uint32_t dims[3], int channel, uint32_t brick,
                   uint32_t comp)
{
    vod_params_default(p);
    memcpy(p->volume, dims, sizeof p->volume);
    p->channel = channel;
    p->brick = brick;
    p->comp = comp;
}

static vod_membuf write_ok(vod_volume *v, const vod_params *p)
{
    vod_source s = vod_volume_source(v);
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    err_info err = {0};
    cr_assert_eq(vod_write(&s, p, &sink, NULL, &err), 0, "%s", err.msg);
    return m;
}

static int write_rc(vod_volume *v, const vod_params *p, err_info *err)
{
    vod_source s = vod_volume_source(v);
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    *err = (err_info){0};
    int rc = vod_write(&s, p, &sink, NULL, err);
    free(m.p);
    return rc;
}

/* ------------------------------------------------------- the volume */

Test(vod_volume, arguments_and_arena_are_validated)
{
    const uint32_t ok[3] = {5, 3, 6};
    static const uint32_t bad_dims[][3] = {{0, 3, 6}, {5, 65537, 6}};
    for (int i = 0; i < 2; i++)
        cr_assert_eq(vod_volume_bytes(bad_dims[i], 8, 4, 10), 0);
    cr_assert_eq(vod_volume_bytes(ok, 16, 4, 10), 0, "bits 8 or 32 only");
    cr_assert_eq(vod_volume_bytes(ok, 8, 3, 10), 0, "brick not a power of two");
    cr_assert_eq(vod_volume_bytes(ok, 8, 1, 10), 0);
    cr_assert_eq(vod_volume_bytes(ok, 8, 128, 10), 0);
    size_t bytes = vod_volume_bytes(ok, 32, 4, 10);
    cr_assert_gt(bytes, 0);
    uint64_t *arena = malloc(bytes + 8);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, (uint8_t *)arena + 4, bytes, ok, 32, 4), -EINVAL,
                 "misaligned arena");
    cr_assert_eq(vod_volume_init(&v, arena, 64, ok, 32, 4), -ENOSPC, "no room for tables");
    cr_assert_eq(vod_volume_init(&v, arena, bytes, bad_dims[0], 32, 4), -EINVAL);
    cr_assert_eq(vod_volume_init(&v, arena, bytes, ok, 32, 4), 0);
    vod_volume_info in;
    vod_volume_get_info(v, &in);
    cr_assert_eq(in.depth, 3, "2^3 >= 6");
    cr_assert_eq(in.sbrick, 4);
    cr_assert_eq(in.pool_used, 0);
    cr_assert_eq(in.pool_cap, 7, "2x1x2 level-0 bricks, one at each of levels 1..3");
    cr_assert_eq(vod_volume_source(v).depth, 3);
    cr_assert_eq(vod_volume_view(arena), v);
    uint64_t junk[64] = {0};
    cr_assert_null(vod_volume_view(junk));
    free(arena);
}

Test(vod_volume, voxels_against_a_dense_copy)
{
    vfx f;
    vfx_init(&f, 23, 17, 30, 32, 8);
    vfx_fill(&f, (vbox){{0, 0, 0}, {16, 16, 16}}, 0x777); /* 8 whole bricks: uniform */
    vod_volume_info in;
    vod_volume_get_info(f.v, &in);
    cr_assert_eq(in.level0_bricks, 0, "whole bricks take no memory");
    for (int i = 0; i < 3000; i++) {
        uint32_t x = rnd() % 23, y = rnd() % 17, z = rnd() % 30;
        vfx_set(&f, x, y, z, rnd() % 4 == 0 ? 0 : rnd());
    }
    vfx_fill(&f, (vbox){{3, 5, 7}, {21, 9, 29}}, 0xabcdef);   /* parts of bricks */
    vfx_fill(&f, (vbox){{8, 8, 8}, {16, 16, 24}}, 0);         /* a whole brick emptied */
    vfx_fill(&f, (vbox){{0, 0, 16}, {8, 8, 24}}, 0x80000001); /* too wide for a uniform entry */
    vfx_fill(&f, (vbox){{16, 0, 0}, {23, 8, 8}}, 5);          /* past dims on x: not uniform */
    vfx_check(&f);
    cr_assert_eq(vod_volume_get(f.v, 23, 0, 0), 0, "outside dims");
    cr_assert_eq(vod_volume_set(f.v, 23, 0, 0, 1), -EINVAL);
    cr_assert_eq(vod_volume_set(f.v, 0, 17, 0, 1), -EINVAL);
    uint32_t lo[3] = {0, 0, 0}, hi[3] = {24, 1, 1}, empty[3] = {2, 1, 1};
    cr_assert_eq(vod_volume_fill(f.v, lo, hi, 1), -EINVAL, "box past dims");
    cr_assert_eq(vod_volume_fill(f.v, empty, empty, 1), -EINVAL, "empty box");
    vfx_free(&f);

    vfx_init(&f, 9, 9, 9, 8, 4);
    cr_assert_eq(vod_volume_set(f.v, 1, 1, 1, 256), -EINVAL, "8-bit voxels");
    uint32_t h9[3] = {9, 9, 9};
    cr_assert_eq(vod_volume_fill(f.v, lo, h9, 300), -EINVAL);
    vfx_set(&f, 1, 1, 1, 255);
    vfx_check(&f);
    vfx_free(&f);
}

Test(vod_volume, a_full_pool_is_enomem_and_changes_nothing)
{
    const uint32_t dims[3] = {16, 16, 16};
    size_t bytes = vod_volume_bytes(dims, 8, 8, 0) + 512; /* one 8^3 brick */
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, arena, bytes, dims, 8, 8), 0);
    cr_assert_eq(vod_volume_set(v, 1, 2, 3, 9), 0);
    cr_assert_eq(vod_volume_set(v, 7, 7, 7, 10), 0, "same brick");
    cr_assert_eq(vod_volume_set(v, 9, 2, 3, 9), -ENOMEM);
    cr_assert_eq(vod_volume_get(v, 9, 2, 3), 0);
    cr_assert_eq(vod_volume_set(v, 9, 2, 3, 0), 0, "writing 0 to an empty brick takes nothing");
    uint32_t lo[3] = {8, 0, 0}, hi[3] = {16, 8, 8}, part[3] = {12, 16, 8};
    cr_assert_eq(vod_volume_fill(v, lo, hi, 200), 0, "a whole brick needs no memory");
    cr_assert_eq(vod_volume_get(v, 15, 7, 0), 200);
    cr_assert_eq(vod_volume_set(v, 15, 7, 0, 200), 0, "same as the uniform value");
    cr_assert_eq(vod_volume_set(v, 15, 7, 0, 201), -ENOMEM, "a uniform brick needs memory to differ");
    cr_assert_eq(vod_volume_get(v, 15, 7, 0), 200);
    lo[1] = 8, hi[1] = 16;
    cr_assert_eq(vod_volume_fill(v, lo, part, 3), -ENOMEM);
    cr_assert_eq(vod_volume_get(v, 1, 2, 3), 9);
    free(arena);
}

/* Whole bricks put at once: uniform ones take no memory, others are copied,
 * and writers of different bricks may run at the same time. */
typedef struct {
    vfx *f;
    uint32_t first, step; /* this thread's bricks: first, first+step, ... */
} put_job;

static void brick_pattern(uint32_t *vox, uint32_t S, const uint32_t b[3], uint32_t dims[3])
{
    uint32_t kind = (b[0] * 7 + b[1] * 3 + b[2]) % 4;
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                uint32_t X = b[0] * S + x, Y = b[1] * S + y, Z = b[2] * S + z;
                uint32_t v = kind == 0 ? 0 : kind == 1 ? 42 : (X ^ Y ^ Z) & 0xff;
                if (kind == 3 && (X + Y + Z) % 5) v = 0;
                if (X >= dims[0] || Y >= dims[1] || Z >= dims[2]) v = 0;
                vox[(z * S + y) * S + x] = v;
            }
}

static void *put_thread(void *arg)
{
    put_job *j = arg;
    uint32_t S = 8, g[3] = {(j->f->dims[0] + 7) / 8, (j->f->dims[1] + 7) / 8,
                            (j->f->dims[2] + 7) / 8};
    uint32_t *vox = malloc(S * S * S * 4);
    for (uint32_t i = j->first; i < g[0] * g[1] * g[2]; i += j->step) {
        uint32_t b[3] = {i % g[0], i / g[0] % g[1], i / (g[0] * g[1])};
        brick_pattern(vox, S, b, j->f->dims);
        if (vod_volume_put_brick(j->f->v, b, vox) != 0) abort();
    }
    free(vox);
    return NULL;
}

Test(vod_volume, bricks_put_whole_from_several_threads)
{
    vfx f;
    vfx_init(&f, 61, 40, 35, 32, 8);
    put_job jobs[4];
    pthread_t th[4];
    for (uint32_t t = 0; t < 4; t++) {
        jobs[t] = (put_job){&f, t, 4};
        cr_assert_eq(pthread_create(&th[t], NULL, put_thread, &jobs[t]), 0);
    }
    for (int t = 0; t < 4; t++) pthread_join(th[t], NULL);
    uint32_t S = 8, g[3] = {8, 5, 5}, uniform = 0, vox[512];
    for (uint32_t i = 0; i < g[0] * g[1] * g[2]; i++) {
        uint32_t b[3] = {i % g[0], i / g[0] % g[1], i / (g[0] * g[1])};
        brick_pattern(vox, S, b, f.dims);
        uniform += (b[0] * 7 + b[1] * 3 + b[2]) % 4 < 2 &&
                   (b[0] + 1) * S <= f.dims[0] && (b[1] + 1) * S <= f.dims[1] &&
                   (b[2] + 1) * S <= f.dims[2];
        for (uint32_t z = 0; z < S; z++)
            for (uint32_t y = 0; y < S; y++)
                for (uint32_t x = 0; x < S; x++) {
                    uint32_t X = b[0] * S + x, Y = b[1] * S + y, Z = b[2] * S + z;
                    if (X < f.dims[0] && Y < f.dims[1] && Z < f.dims[2])
                        vfx_set(&f, X, Y, Z, vox[(z * S + y) * S + x]);
                }
    }
    vod_volume_info in;
    vod_volume_get_info(f.v, &in);
    /* vfx_set wrote the same values again: no brick changes, and the
     * uniform ones stayed without memory */
    cr_assert_leq(in.level0_bricks, g[0] * g[1] * g[2] - uniform);
    vfx_check(&f);
    uint32_t outside[3] = {8, 0, 0};
    cr_assert_eq(vod_volume_put_brick(f.v, outside, vox), -EINVAL);
    vfx_free(&f);
}

/* The dense copy's brick b (side 8) := v. */
static void dense_brick(vfx *f, const uint32_t b[3], uint32_t v)
{
    for (uint32_t z = 0; z < 8; z++)
        for (uint32_t y = 0; y < 8; y++)
            for (uint32_t x = 0; x < 8; x++) *vfx_at(f, b[0] * 8 + x, b[1] * 8 + y, b[2] * 8 + z) = v;
}

/* A whole brick of one value: an entry without memory, or the voxels of a
 * brick that has memory already. */
Test(vod_volume, uniform_bricks_put_without_a_buffer)
{
    vfx f;
    vfx_init(&f, 32, 16, 16, 8, 8);
    uint32_t a[3] = {1, 0, 1}, b[3] = {2, 1, 0}, outside[3] = {4, 0, 0};
    cr_assert_eq(vod_volume_put_uniform(f.v, a, 77), 0);
    dense_brick(&f, a, 77);
    vfx_set(&f, 17, 9, 3, 5); /* brick b gets memory */
    cr_assert_eq(vod_volume_put_uniform(f.v, b, 200), 0);
    dense_brick(&f, b, 200);
    vod_volume_info in;
    vod_volume_get_info(f.v, &in);
    cr_assert_eq(in.level0_bricks, 1, "only the brick that had memory has some");
    vfx_check(&f);
    cr_assert_eq(vod_volume_put_uniform(f.v, a, 0), 0);
    dense_brick(&f, a, 0);
    vfx_check(&f);
    cr_assert_eq(vod_volume_put_uniform(f.v, outside, 1), -EINVAL);
    cr_assert_eq(vod_volume_put_uniform(f.v, a, 256), -EINVAL, "8-bit voxels");
    vfx_free(&f);
}

/* The arena moved to another address (a worker maps the segment anywhere)
 * gives the same file: the volume holds offsets, never pointers. */
Test(vod_volume, a_view_at_another_address_gives_the_same_bytes)
{
    vfx f;
    vfx_init(&f, 30, 20, 25, 32, 4);
    vfx_fill(&f, (vbox){{4, 4, 4}, {20, 16, 20}}, 0x5000ff);
    for (int i = 0; i < 500; i++) vfx_set(&f, rnd() % 30, rnd() % 20, rnd() % 25, rnd() | 1);
    vod_params p;
    params(&p, f.dims, VOXEL_CH_SURFACE, 8, VOD_COMP_ZLIB);
    vod_membuf a = write_ok(f.v, &p);
    /* the copy carries the mip levels prepare() built: the view writes from
     * them, as a worker encodes from what the master prepared */
    uint8_t *copy = malloc(f.bytes + 64);
    memcpy(copy + 64, f.arena, f.bytes);
    memset(f.arena, 0xa5, f.bytes);
    vod_volume *w = vod_volume_view(copy + 64);
    cr_assert_not_null(w);
    vod_volume_info in;
    vod_volume_get_info(w, &in);
    cr_assert_eq(in.mip_channel, VOXEL_CH_SURFACE);
    vod_membuf b = write_ok(w, &p);
    cr_assert_eq(a.n, b.n);
    cr_assert_arr_eq(a.p, b.p, a.n);
    free(a.p), free(b.p), free(copy);
    vfx_free(&f);
}

/* ------------------------------------------- channels 2 and 1: oracle */

/* Spec section 3 by brute force over the padded cube of side n: level 0 is
 * the dense copy (0 outside dims; channel 1: 1 where non-zero), a level-l
 * voxel the mean of its 8 level-(l-1) children rounded half up (channel 2)
 * or their OR (channel 1). */
typedef struct {
    uint32_t n, levels;
    uint32_t *lv[17];
} oracle;

static void oracle_make(oracle *o, const vfx *f, int channel, uint32_t n, uint32_t levels)
{
    o->n = n, o->levels = levels;
    o->lv[0] = malloc((size_t)n * n * n * sizeof(uint32_t));
    for (uint32_t z = 0; z < n; z++)
        for (uint32_t y = 0; y < n; y++)
            for (uint32_t x = 0; x < n; x++) {
                uint32_t v = vfx_get(f, x, y, z);
                o->lv[0][((size_t)z * n + y) * n + x] = channel == 1 ? v != 0 : v;
            }
    for (uint32_t l = 1; l < levels; l++) {
        uint32_t s = n >> l, c = n >> (l - 1);
        o->lv[l] = malloc((size_t)s * s * s * sizeof(uint32_t));
        for (uint32_t z = 0; z < s; z++)
            for (uint32_t y = 0; y < s; y++)
                for (uint32_t x = 0; x < s; x++) {
                    uint32_t sum = 0, any = 0;
                    for (uint32_t i = 0; i < 8; i++) {
                        uint32_t v = o->lv[l - 1][((size_t)(2 * z + (i >> 2)) * c +
                                                   2 * y + (i >> 1 & 1)) * c +
                                                  2 * x + (i & 1)];
                        sum += v;
                        any |= v;
                    }
                    o->lv[l][((size_t)z * s + y) * s + x] =
                        channel == 1 ? any != 0 : (sum + 4) / 8;
                }
    }
}

static void oracle_free(oracle *o)
{
    for (uint32_t l = 0; l < o->levels; l++) free(o->lv[l]);
}

/* Some voxel of the dense copy in the cube [lo, lo + side) is non-zero. */
static bool footprint_has_voxel(const vfx *f, const uint32_t lo[3], uint32_t side)
{
    for (uint32_t z = lo[2]; z < lo[2] + side && z < f->dims[2]; z++)
        for (uint32_t y = lo[1]; y < lo[1] + side && y < f->dims[1]; y++)
            for (uint32_t x = lo[0]; x < lo[0] + side && x < f->dims[0]; x++)
                if (*vfx_at(f, x, y, z)) return true;
    return false;
}

/* check_nodes' walk over the file of volume f (bricks of side brick):
 * the nodes seen so far, and those with a brick. */
typedef struct {
    const vfx *f;
    const uint8_t *file;
    uint32_t brick;
    uint64_t pre, bricks;
} node_walk;

/* Every node of the complete tree in preorder: its brickID is non-zero
 * exactly when its full-resolution footprint holds a voxel. */
static void check_nodes(node_walk *w, uint32_t level, const uint32_t b[3])
{
    uint32_t side = w->brick << level, lo[3] = {b[0] * side, b[1] * side, b[2] * side};
    uint32_t id = vod_get32(w->file + 64 + 4 * w->pre);
    bool want = footprint_has_voxel(w->f, lo, side);
    cr_assert_eq(id != 0, want, "node %llu (level %u, brick %u %u %u): id %u",
                 (unsigned long long)w->pre, level, b[0], b[1], b[2], id);
    w->bricks += id != 0;
    w->pre++;
    if (level == 0) return;
    for (uint32_t i = 0; i < 8; i++) {
        uint32_t c[3] = {2 * b[0] + (i & 1), 2 * b[1] + (i >> 1 & 1), 2 * b[2] + (i >> 2)};
        check_nodes(w, level - 1, c);
    }
}

static void check_against_oracle(const vfx *f, int channel, uint32_t brick, uint32_t comp)
{
    vod_params p;
    params(&p, f->dims, channel, brick, comp);
    vod_membuf m = write_ok(f->v, &p);
    vod_file *r;
    err_info err = {0};
    cr_assert_eq(vod_read(m.p, m.n, &r, &err), 0, "%s", err.msg);
    const vod_info *in = vod_get_info(r);
    cr_assert_eq(in->voxel_bits, channel == 1 ? 1u : 8u);
    cr_assert_eq(in->channel, (uint32_t)channel);
    oracle o;
    oracle_make(&o, f, channel, vod_level_size(r, 0), in->height);
    for (uint32_t l = 0; l < in->height; l++) {
        uint32_t s = o.n >> l;
        for (uint32_t z = 0; z < s; z++)
            for (uint32_t y = 0; y < s; y++)
                for (uint32_t x = 0; x < s; x++)
                    cr_assert_eq(vod_voxel(r, (int)l, x, y, z),
                                 o.lv[l][((size_t)z * s + y) * s + x],
                                 "channel %d brick %u level %u voxel %u %u %u", channel,
                                 brick, l, x, y, z);
    }
    node_walk w = {.f = f, .file = m.p, .brick = brick};
    uint32_t root[3] = {0, 0, 0};
    check_nodes(&w, in->height - 1, root);
    cr_assert_eq(w.pre, in->nodes);
    cr_assert_geq(w.bricks, in->bricks, "duplicates share a brick");
    oracle_free(&o);
    vod_close(r);
    free(m.p);
}

/* Densities of every kind: scattered values, small ones whose means round
 * to 0 above level 0 (their nodes keep a brick of zeros), two solid blocks
 * of different values (uniform bricks and uniform mips), a hole cleared in
 * one, and a brick written and then cleared (memory, but empty). */
static void density_fixture(vfx *f, uint32_t sb)
{
    vfx_init(f, 37, 21, 30, 8, sb);
    vfx_fill(f, (vbox){{0, 0, 0}, {17, 9, 13}}, 255);
    vfx_fill(f, (vbox){{20, 12, 16}, {37, 21, 30}}, 128);
    vfx_fill(f, (vbox){{2, 2, 2}, {5, 5, 5}}, 0);
    for (int i = 0; i < 600; i++)
        vfx_set(f, rnd() % 37, rnd() % 21, rnd() % 30, 1 + rnd() % 255);
    for (int i = 0; i < 60; i++) vfx_set(f, rnd() % 37, rnd() % 21, rnd() % 30, 1 + rnd() % 3);
    vfx_set(f, 33, 2, 25, 7);
    vfx_set(f, 33, 2, 25, 0);
    vfx_set(f, 36, 20, 29, 1); /* alone in the far corner */
    vfx_check(f);
}

static void oracle_case(int channel, uint32_t sb)
{
    static const uint32_t bricks[] = {2, 4, 8, 16, 32, 64};
    static const uint32_t comps[] = {VOD_COMP_ZLIB, VOD_COMP_RUNL, VOD_COMP_NONE};
    vfx f;
    density_fixture(&f, sb);
    for (int i = 0; i < 6; i++) check_against_oracle(&f, channel, bricks[i], comps[i % 3]);
    vfx_free(&f);
}

Test(vod_volume_oracle, density_storage_brick_2) { oracle_case(VOXEL_CH_DENSITY, 2); }
Test(vod_volume_oracle, density_storage_brick_4) { oracle_case(VOXEL_CH_DENSITY, 4); }
Test(vod_volume_oracle, density_storage_brick_16) { oracle_case(VOXEL_CH_DENSITY, 16); }
Test(vod_volume_oracle, density_storage_brick_64) { oracle_case(VOXEL_CH_DENSITY, 64); }
Test(vod_volume_oracle, occupancy_of_densities) { oracle_case(VOXEL_CH_OCCUPANCY, 8); }
/* storage bricks of 16 and 64: rows of 16 voxels and more, which the
 * fill and the mip levels take 16 at a time (SSE2) */
Test(vod_volume_oracle, occupancy_storage_brick_16) { oracle_case(VOXEL_CH_OCCUPANCY, 16); }
Test(vod_volume_oracle, occupancy_storage_brick_64) { oracle_case(VOXEL_CH_OCCUPANCY, 64); }

/* A brick that held a voxel and was cleared has memory but no voxel: the
 * file is the one of a volume that never had it, at every brick size
 * (smaller than, equal to and larger than the storage brick). */
Test(vod_volume_oracle, a_cleared_brick_is_empty)
{
    vfx a, b;
    vfx_init(&a, 40, 40, 40, 8, 8);
    vfx_init(&b, 40, 40, 40, 8, 8);
    vfx_set(&a, 3, 3, 3, 90);
    vfx_set(&a, 3, 3, 3, 0);
    vfx_set(&a, 30, 31, 32, 90);
    vfx_set(&b, 30, 31, 32, 90);
    static const uint32_t bricks[] = {2, 8, 16, 32};
    for (int i = 0; i < 4; i++)
        for (int ch = 1; ch <= 2; ch++) {
            vod_params p;
            params(&p, a.dims, ch, bricks[i], VOD_COMP_ZLIB);
            vod_membuf ma = write_ok(a.v, &p), mb = write_ok(b.v, &p);
            cr_assert_eq(ma.n, mb.n, "brick %u channel %d", bricks[i], ch);
            cr_assert_arr_eq(ma.p, mb.p, ma.n, "brick %u channel %d", bricks[i], ch);
            free(ma.p), free(mb.p);
        }
    vfx_free(&a), vfx_free(&b);
}

/* ------------------------------------------------- writer and volume */

Test(vod_volume_write, channels_the_volume_lacks_are_refused)
{
    vfx f;
    vfx_init(&f, 8, 8, 8, 8, 4);
    vfx_set(&f, 1, 1, 1, 1);
    vod_params p;
    err_info err = {0};
    params(&p, f.dims, VOXEL_CH_SURFACE, 4, VOD_COMP_ZLIB);
    cr_assert_eq(write_rc(f.v, &p, &err), -EINVAL);
    cr_assert_str_eq(err.msg, "channel 3 cannot be written from the volume (it gives "
                          "channels 1 and 2)");
    params(&p, f.dims, VOXEL_CH_DISTANCE, 4, VOD_COMP_ZLIB);
    cr_assert_eq(write_rc(f.v, &p, &err), -EINVAL);
    cr_assert(strstr(err.msg, "channel 4"), "%s", err.msg);
    vfx_free(&f);
    vfx_init(&f, 8, 8, 8, 32, 4);
    params(&p, f.dims, VOXEL_CH_DENSITY, 4, VOD_COMP_ZLIB);
    cr_assert_eq(write_rc(f.v, &p, &err), -EINVAL);
    cr_assert_str_eq(err.msg, "channel 2 cannot be written from the volume (it gives "
                          "channels 1 and 3)"); /* channel 4: a VOD_VOLUME_F32 volume's */
    vfx_free(&f);
}

Test(vod_volume_write, voxel_outside_the_file_volume_is_refused)
{
    vfx f;
    vfx_init(&f, 20, 20, 20, 8, 4);
    vfx_set(&f, 3, 3, 3, 1);
    vfx_set(&f, 17, 5, 6, 1);
    vod_params p;
    err_info err = {0};
    params(&p, f.dims, VOXEL_CH_DENSITY, 8, VOD_COMP_ZLIB);
    p.volume[0] = 16;
    cr_assert_eq(write_rc(f.v, &p, &err), -EINVAL);
    cr_assert_str_eq(err.msg, "the volume holds a voxel at 17,5,6, outside volumeSize "
                          "16x20x20 (VOD padding must be 0)");
    vfx_set(&f, 17, 5, 6, 0);
    cr_assert_eq(write_rc(f.v, &p, &err), 0, "%s", err.msg);
    vfx_fill(&f, (vbox){{0, 16, 8}, {4, 20, 12}}, 9); /* a uniform brick past y = 16 */
    p.volume[0] = 20, p.volume[1] = 16;
    cr_assert_eq(write_rc(f.v, &p, &err), -EINVAL);
    cr_assert(strstr(err.msg, "at 0,16,8,"), "%s", err.msg);
    vfx_free(&f);
}

/* A volume with many bricks past the file's volume is scanned on several
 * threads, rows of bricks dealt round robin: the voxel named is still the
 * first in the one-thread scan's order (z, then y, then x), whichever
 * part finds it and whatever later voxels the other parts find first. */
static void expect_outside_at(vfx *f, const vod_params *p, const char *at)
{
    err_info err = {0};
    cr_assert_eq(write_rc(f->v, p, &err), -EINVAL);
    char want[96];
    snprintf(want, sizeof want, "the volume holds a voxel at %s, outside volumeSize 250x250x60", at);
    cr_assert(strstr(err.msg, want), "%s", err.msg);
}

Test(vod_volume_write, the_first_voxel_outside_is_named_when_many_threads_look)
{
    vfx f;
    vfx_init(&f, 256, 256, 64, 8, 2); /* 128 x 128 x 32 bricks: enough for threads */
    vod_params p;
    params(&p, f.dims, VOXEL_CH_DENSITY, 8, VOD_COMP_ZLIB);
    p.volume[0] = 250, p.volume[1] = 250, p.volume[2] = 60;
    vfx_set(&f, 100, 100, 63, 1); /* the last row of bricks (z 62-63, y 100-101) */
    expect_outside_at(&f, &p, "100,100,63");
    vfx_set(&f, 9, 8, 40, 2); /* inside the file's volume: no matter */
    vfx_set(&f, 252, 8, 40, 3); /* row z 40-41, y 8-9: even (20 * 128 + 4) */
    expect_outside_at(&f, &p, "252,8,40");
    vfx_set(&f, 3, 251, 10, 4); /* row z 10-11, y 250-251: odd (5 * 128 + 125), earlier */
    expect_outside_at(&f, &p, "3,251,10");
    vfx_set(&f, 255, 0, 10, 5); /* row z 10-11, y 0-1: even (5 * 128), earlier still */
    expect_outside_at(&f, &p, "255,0,10");
    vfx_set(&f, 254, 1, 11, 6); /* the same brick, later in it (z 11) */
    expect_outside_at(&f, &p, "255,0,10");
    vfx_set(&f, 250, 1, 11, 7); /* the same row, an earlier brick (x 250-251) */
    expect_outside_at(&f, &p, "250,1,11");
    vfx_free(&f);
}

/* vod_volume_bytes is enough for the mip levels of the worst case, bricks
 * scattered so that none shares a parent; without that room prepare()
 * fails with a message and nothing is written. */
Test(vod_volume_write, mip_levels_need_pool_room)
{
    const uint32_t dims[3] = {64, 64, 64};
    uint32_t count = 0;
    size_t exact = vod_volume_bytes(dims, 8, 4, 0);
    for (int pass = 0; pass < 2; pass++) {
        size_t bytes = pass ? vod_volume_bytes(dims, 8, 4, count) : exact + 64 * 64;
        void *arena = malloc(bytes);
        vod_volume *v;
        cr_assert_eq(vod_volume_init(&v, arena, bytes, dims, 8, 4), 0);
        count = 0;
        for (uint32_t z = 0; z < 64; z += 16)
            for (uint32_t y = 0; y < 64; y += 16)
                for (uint32_t x = 0; x < 64; x += 16, count++)
                    cr_assert_eq(vod_volume_set(v, x + 1, y + 2, z + 3, 200), 0);
        vod_params p;
        params(&p, dims, VOXEL_CH_DENSITY, 4, VOD_COMP_ZLIB);
        err_info err = {0};
        vod_source s = vod_volume_source(v);
        vod_membuf m = {0};
        vod_sink sink = {vod_mem_write, &m};
        int rc = vod_write(&s, &p, &sink, NULL, &err);
        vod_volume_info in;
        vod_volume_get_info(v, &in);
        if (pass == 0) {
            cr_assert_eq(rc, -ENOMEM);
            cr_assert_str_eq(err.msg, "cannot prepare the mip levels of the volume: Cannot "
                                  "allocate memory");
            cr_assert_eq(m.n, 0);
            cr_assert_eq(in.mip_channel, 0);
            cr_assert_eq(in.pool_used, in.level0_bricks, "the partial mips are given back");
        } else {
            cr_assert_eq(rc, 0, "%s", err.msg);
            cr_assert_leq(in.pool_used, in.pool_cap);
            cr_assert_gt(in.pool_used, count, "mip bricks in the pool");
        }
        free(m.p);
        free(arena);
    }
}

/* Voxels written after a file drop the mip levels; the next file has the
 * new voxel at every level, and a second channel rebuilds them. */
Test(vod_volume_write, later_voxels_reach_the_next_file)
{
    vfx f;
    vfx_init(&f, 16, 16, 16, 8, 4);
    vfx_set(&f, 1, 1, 1, 80);
    vod_params p;
    params(&p, f.dims, VOXEL_CH_DENSITY, 4, VOD_COMP_NONE);
    vod_membuf a = write_ok(f.v, &p);
    vfx_set(&f, 14, 14, 14, 240);
    vod_membuf b = write_ok(f.v, &p);
    vod_file *r;
    err_info err = {0};
    cr_assert_eq(vod_read(b.p, b.n, &r, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_voxel(r, 0, 14, 14, 14), 240);
    cr_assert_eq(vod_voxel(r, 1, 7, 7, 7), 30, "240 / 8");
    cr_assert_eq(vod_voxel(r, 2, 3, 3, 3), 4, "(30 + 4) / 8");
    cr_assert_eq(vod_voxel(r, 1, 0, 0, 0), 10, "80 / 8");
    vod_close(r);
    params(&p, f.dims, VOXEL_CH_OCCUPANCY, 4, VOD_COMP_NONE);
    vod_membuf c = write_ok(f.v, &p);
    cr_assert_eq(vod_read(c.p, c.n, &r, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_voxel(r, 2, 3, 3, 3), 1);
    cr_assert_eq(vod_voxel(r, 2, 0, 0, 0), 1);
    cr_assert_eq(vod_voxel(r, 2, 1, 1, 1), 0);
    vod_close(r);
    free(a.p), free(b.p), free(c.p);
    vfx_free(&f);
}

/* ------------------------------------------- mip levels built by column */

/* b := a copy of a's volume and voxels (the arena is position independent). */
static void vfx_copy(vfx *b, const vfx *a, uint32_t sb)
{
    vfx_init(b, a->dims[0], a->dims[1], a->dims[2], a->bits, sb);
    memcpy(b->arena, a->arena, a->bytes);
    b->v = vod_volume_view(b->arena);
    cr_assert_not_null(b->v);
    memcpy(b->dense, a->dense, (size_t)a->dims[0] * a->dims[1] * a->dims[2] * sizeof *a->dense);
}

/* Levels 1..levels of channel built column by column at that level (one
 * column twice, as a tile run again after a worker's death), declared. */
static void build_by_columns(vfx *f, int channel, int levels, uint32_t sb)
{
    uint32_t g[2];
    for (int a = 0; a < 2; a++) {
        uint32_t side = (f->dims[a] + (1u << levels) - 1) >> levels;
        g[a] = (side + sb - 1) / sb;
    }
    for (uint32_t y = 0; y < g[1]; y++)
        for (uint32_t x = 0; x < g[0]; x++) {
            uint32_t lo[2] = {x, y}, hi[2] = {x + 1, y + 1 + (y == g[1] - 1)}; /* clipped */
            cr_assert_eq(vod_volume_mip_columns(f->v, channel, levels, lo, hi), 0);
        }
    uint32_t lo[2] = {0, 0}, hi[2] = {1, 1};
    cr_assert_eq(vod_volume_mip_columns(f->v, channel, levels, lo, hi), 0, "again");
    cr_assert_eq(vod_volume_check(f->v, f->bytes), 0, "built, not declared: checkable");
    cr_assert_eq(vod_volume_mips_low(f->v, channel, levels), 0);
    cr_assert_eq(vod_volume_check(f->v, f->bytes), -EINVAL, "declared: not level 0 alone");
}

static void same_files(vfx *a, vfx *b, int channel, const char *what)
{
    static const uint32_t bricks[] = {2, 4, 16, 32};
    for (int i = 0; i < 4; i++) {
        vod_params p;
        params(&p, a->dims, channel, bricks[i], VOD_COMP_ZLIB);
        vod_membuf ma = write_ok(a->v, &p), mb = write_ok(b->v, &p);
        cr_assert_eq(ma.n, mb.n, "%s: brick %u channel %d", what, bricks[i], channel);
        cr_assert_arr_eq(ma.p, mb.p, ma.n, "%s: brick %u channel %d", what, bricks[i], channel);
        free(ma.p), free(mb.p);
    }
}

/* The low mip levels built by column (as the mesh kind's tiles do), then
 * the rest by prepare(), give the files of a volume prepared whole: for
 * the channel they were built for, for another one (built over), and
 * after a voxel written later (dropped). */
Test(vod_volume_columns, give_the_files_of_a_whole_prepare)
{
    for (int levels = 1; levels <= 2; levels++)
        for (int channel = VOXEL_CH_OCCUPANCY; channel <= VOXEL_CH_DENSITY; channel++) {
            vfx a, b;
            density_fixture(&a, 4);
            vfx_copy(&b, &a, 4);
            build_by_columns(&b, channel, levels, 4);
            same_files(&a, &b, channel, "the columns' channel");
            same_files(&a, &b, VOXEL_CH_OCCUPANCY + VOXEL_CH_DENSITY - channel,
                       "the other channel");
            vfx_set(&a, 36, 0, 0, 99);
            vfx_set(&b, 36, 0, 0, 99);
            vfx_check(&b);
            same_files(&a, &b, channel, "a voxel written later");
            vfx_free(&a), vfx_free(&b);
        }
}

Test(vod_volume_columns, arguments_are_validated)
{
    vfx f;
    vfx_init(&f, 20, 20, 20, 8, 4);
    vfx_set(&f, 1, 2, 3, 40);
    uint32_t lo[2] = {0, 0}, hi[2] = {1, 1}, far[2] = {9, 0}, far1[2] = {10, 1};
    cr_assert_eq(vod_volume_mip_columns(f.v, VOXEL_CH_SURFACE, 1, lo, hi), -EINVAL,
                 "a channel 8-bit voxels do not give");
    cr_assert_eq(vod_volume_mip_columns(f.v, VOXEL_CH_DENSITY, 0, lo, hi), -EINVAL);
    cr_assert_eq(vod_volume_mip_columns(f.v, VOXEL_CH_DENSITY, 6, lo, hi), -EINVAL,
                 "past the depth (5)");
    cr_assert_eq(vod_volume_mip_columns(f.v, VOXEL_CH_DENSITY, 1, hi, lo), -EINVAL);
    cr_assert_eq(vod_volume_mip_columns(f.v, VOXEL_CH_DENSITY, 1, far, far1), -EINVAL,
                 "a column past the level's grid (3 bricks)");
    cr_assert_eq(vod_volume_mips_low(f.v, VOXEL_CH_SURFACE, 1), -EINVAL);
    vod_params p;
    params(&p, f.dims, VOXEL_CH_DENSITY, 4, VOD_COMP_NONE);
    vod_membuf m = write_ok(f.v, &p);
    cr_assert_eq(vod_volume_mips_low(f.v, VOXEL_CH_DENSITY, 1), -EINVAL, "prepared already");
    free(m.p);
    vfx_free(&f);
}

/* A brick put with voxels, then put again all zero, keeps its memory but
 * holds no voxel: the file is that of a volume without it (the writer may
 * not take a brick with memory for a non-empty one once a zero went into
 * one), at brick sizes equal to and larger than the storage brick. */
Test(vod_volume_oracle, a_brick_put_again_all_zero_is_empty)
{
    vfx a, b;
    vfx_init(&a, 32, 32, 32, 8, 8);
    vfx_init(&b, 32, 32, 32, 8, 8);
    uint8_t vox[8 * 8 * 8] = {0};
    vox[5] = 77;
    uint32_t at[3] = {1, 2, 3};
    cr_assert_eq(vod_volume_put_brick(a.v, at, vox), 0);
    vod_volume_info in;
    vod_volume_get_info(a.v, &in);
    cr_assert_eq(in.level0_bricks, 1);
    vox[5] = 0;
    cr_assert_eq(vod_volume_put_brick(a.v, at, vox), 0);
    vfx_set(&a, 30, 1, 2, 9);
    vfx_set(&b, 30, 1, 2, 9);
    vfx_set(&a, 0, 16, 16, 9); /* its level-1 parent holds a voxel: the writer */
    vfx_set(&b, 0, 16, 16, 9); /* asks about the brick itself */
    static const uint32_t bricks[] = {8, 16};
    for (int i = 0; i < 2; i++)
        for (int ch = 1; ch <= 2; ch++) {
            vod_params p;
            params(&p, a.dims, ch, bricks[i], VOD_COMP_ZLIB);
            vod_membuf ma = write_ok(a.v, &p), mb = write_ok(b.v, &p);
            cr_assert_eq(ma.n, mb.n, "brick %u channel %d", bricks[i], ch);
            cr_assert_arr_eq(ma.p, mb.p, ma.n, "brick %u channel %d", bricks[i], ch);
            free(ma.p), free(mb.p);
        }
    vfx_free(&a), vfx_free(&b);
}

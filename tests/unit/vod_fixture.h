/* vod_fixture — what the VOD suites (test_vod*.c) share: a small octree with a
 * dense array of the voxels it holds (random surfaces, a sphere shell), the
 * writer's parameters, and writing a file and reading it back. */
#ifndef VOXD_TEST_VOD_FIXTURE_H
#define VOXD_TEST_VOD_FIXTURE_H

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

/* ---------------------------------------------------------------- helpers */

static uint64_t rng_state = 88172645463325252ull;

static inline uint32_t rnd(void) { return xorshift32(&rng_state); }

/* An octree and a dense copy of its voxels over the octree's 2^depth cube. */
typedef struct {
    octree t;
    octree_cell *arena;
    uint32_t side;
    uint32_t *dense;
    uint32_t vol[3];
    uint64_t count;
} fixture;

static inline void fx_init(fixture *f, int depth, uint32_t vx, uint32_t vy, uint32_t vz)
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

static inline void fx_free(fixture *f)
{
    free(f->arena);
    free(f->dense);
}

static inline void fx_store(fixture *f, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    cr_assert_eq(octree_store(&f->t, x, y, z, v), 0);
    uint32_t *d = &f->dense[((size_t)z * f->side + y) * f->side + x];
    f->count += *d == 0;
    *d = v;
}

static inline uint32_t fx_get(const fixture *f, uint32_t x, uint32_t y, uint32_t z)
{
    if (x >= f->side || y >= f->side || z >= f->side) return 0;
    return f->dense[((size_t)z * f->side + y) * f->side + x];
}

/* A surface value: random normal bits, occupancy mostly 1..255, sometimes
 * 0 (a non-zero voxel whose occupancy byte is 0 must still round-trip). */
static inline uint32_t random_surface(void)
{
    uint32_t occ = rnd() % 16 == 0 ? 0 : 1 + rnd() % 255;
    uint32_t v = (rnd() << 8) | occ;
    return v ? v : 0x100;
}

static inline void fx_random(fixture *f, int count)
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
static inline void fx_sphere(fixture *f, double cx, double cy, double cz, double r)
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

static inline void params(vod_params *p, const fixture *f, int channel, uint32_t comp,
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

static inline membuf write_file(fixture *f, const vod_params *p, vod_stats *st)
{
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    err_info err = {0};
    vod_stats local;
    int rc = vod_write_octree(&f->t, p, &sink, st ? st : &local, &err);
    cr_assert_eq(rc, 0, "write: %s", err.msg);
    cr_assert_null(f->t.agg, "agg allocated by the writer is freed again");
    return m;
}

static inline vod_file *read_ok(const membuf *m)
{
    vod_file *v;
    err_info err = {0};
    int rc = vod_read(m->p, m->n, &v, &err);
    cr_assert_eq(rc, 0, "read: %s", err.msg);
    return v;
}

/* Hsieh's SuperFastHash as published (portable get16bits), written out
 * again here; the only change is the u32 conversion before the shift of the
 * sign-extended tail byte, which the spec asks for. */
#define get16bits(d) ((((uint32_t)(((const uint8_t *)(d))[1])) << 8) + \
                      (uint32_t)(((const uint8_t *)(d))[0]))

static inline uint32_t ref_sfhs(const char *data, int len)
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

/* ------------------------------------------------- round trip, level 0 */

typedef struct {
    const fixture *f;
    int occupancy;
    uint32_t dims[3];
    uint64_t seen;
    uint8_t *mark;
} visit_ctx;

static inline int visit_l0(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
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

static inline void check_level0(const fixture *f, const vod_file *v, int occupancy)
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

/* ------------------------------------- files and sums the readers' suites share */

/* A file of 1 MiB bricks (64^3, 32 bits): two to a chunk of the reader's
 * (2 MiB of raw bricks, a slab allocated aligned to a huge page), so that
 * threads share its bricks (a dozen or more); comp: their compression. */
static inline membuf fx_file_large_bricks(uint32_t comp)
{
    fixture f;
    fx_init(&f, 8, 192, 128, 128);
    fx_sphere(&f, 96, 64, 64, 60);
    fx_sphere(&f, 30, 30, 30, 20);
    vod_params p;
    params(&p, &f, VOXEL_CH_SURFACE, comp, VOD_HASH_SFHS, 64);
    membuf m = write_file(&f, &p, NULL);
    fx_free(&f);
    return m;
}

/* A block of one value beside a sphere, in 8^3 bricks: many nodes (more
 * than vod_scan's 16) share the block's bricks, which the file stores
 * once. */
static inline membuf fx_file_shared_bricks(void)
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
    return m;
}

/* m's bytes into a new file named from template path (its XXXXXX
 * replaced); the caller unlinks it. */
static inline void fx_temp_file(const membuf *m, char *path)
{
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0, "%s", path);
    cr_assert_eq(write(fd, m->p, m->n), (ssize_t)m->n);
    cr_assert_eq(close(fd), 0);
}

/* A sum over (level, b, raw bytes) of every node's brick, order-free: a
 * read's bricks as vod_scan hands them (a thread's own sum each, scan_add
 * its fn, ud an array of PAR_MAX) or as vod_read keeps them (sum_file). */
typedef struct {
    uint32_t sum;
    uint64_t n;
} brick_sum;

static inline void sum_brick(brick_sum *s, const vod_info *in, int level, const uint32_t b[3],
                             const uint8_t *raw)
{
    uint32_t key[4] = {(uint32_t)level, b[0], b[1], b[2]};
    size_t raw_bytes = (size_t)in->brick * in->brick * in->brick * in->voxel_bits / 8;
    uLong c = crc32(0, (const Bytef *)key, sizeof key);
    s->sum += (uint32_t)crc32(c, raw, (uInt)raw_bytes);
    s->n++;
}

static inline void scan_add(void *ud, unsigned thread, const vod_info *in, int level,
                            const uint32_t b[3], const uint8_t *raw)
{
    brick_sum *per_thread = ud;
    cr_assert_lt(thread, (unsigned)PAR_MAX, "thread %u", thread);
    sum_brick(&per_thread[thread], in, level, b, raw);
}

typedef struct {
    const vod_info *in;
    int level;
    brick_sum s;
} kept_sum;

static inline int kept_add(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    kept_sum *k = ud;
    sum_brick(&k->s, k->in, k->level, b, raw);
    return 0;
}

/* The bricks of v's levels in mask levels (bit l: level l), kept by
 * vod_read or vod_open_levels, summed. */
static inline brick_sum sum_levels(const vod_file *v, uint32_t levels)
{
    kept_sum k = {vod_get_info(v), 0, {0, 0}};
    for (k.level = 0; k.level < (int)k.in->height; k.level++)
        if (levels >> k.level & 1u)
            cr_assert_eq(vod_foreach_brick(v, k.level, kept_add, &k), 0);
    return k.s;
}

/* Every level's bricks of v, kept by vod_read, summed. */
static inline brick_sum sum_file(const vod_file *v)
{
    return sum_levels(v, VOD_LEVELS_ALL);
}

#endif

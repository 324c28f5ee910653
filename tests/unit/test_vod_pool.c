/* The volume's pool taken a chunk at a time (vod_volume_pool.c): a
 * thread's records come out of its own chunk while the pool has room to
 * spare, two threads' records never share a unit (every voxel reads back,
 * the volume's check passes), a small pool is taken a record at a time as
 * before, and a chunk is never given out of a volume it was not taken
 * from: a new volume made at the same address, or the pool given back
 * below it (the mip levels dropped), nor by a forked child; near its
 * end the pool is taken a record at a time, so a pool filled to its last
 * record loses no more than a record's units per chunk. */
#include <criterion/criterion.h>
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

#include "vod_volume.h"
#include "vod_volume_int.h"
#include "voxel.h"

#define CHUNK_UNITS ((1u << 20) / PACK_UNIT) /* vod_volume_pool.c's chunk */

typedef struct {
    uint32_t dims[3];
    void *arena;
    size_t bytes;
    vod_volume *v;
} pool_fx;

/* A float volume (packed records) of 8^3 bricks, its pool for every brick. */
static void fx_make(pool_fx *f, uint32_t dx, uint32_t dy, uint32_t dz)
{
    f->dims[0] = dx, f->dims[1] = dy, f->dims[2] = dz;
    f->bytes = vod_volume_bytes(f->dims, VOD_VOLUME_F32, 8, UINT32_MAX);
    cr_assert(f->bytes > 0);
    f->arena = malloc(f->bytes);
    cr_assert(f->arena);
    cr_assert_eq(vod_volume_init(&f->v, f->arena, f->bytes, f->dims, VOD_VOLUME_F32, 8), 0);
}

static uint32_t used(const pool_fx *f)
{
    vod_volume_info in;
    vod_volume_get_info(f->v, &in);
    return in.pool_used;
}

/* Voxel i of brick b: a band value a brick's own, or beyond the band. */
static uint32_t voxel_of(const uint32_t b[3], uint32_t i)
{
    float x = (i % 3) ? 0.5f : (float)(b[0] + 7 * b[1] + 31 * b[2]) / 1000.0f + (float)i / 4096.0f;
    uint32_t u;
    memcpy(&u, &x, 4);
    return u;
}

static void put(pool_fx *f, const uint32_t b[3])
{
    uint32_t vox[512];
    for (uint32_t i = 0; i < 512; i++) vox[i] = voxel_of(b, i);
    cr_assert_eq(vod_volume_put_brick(f->v, b, vox), 0);
}

static void read_back(pool_fx *f, const uint32_t b[3])
{
    for (uint32_t i = 0; i < 512; i += 37) {
        uint32_t x = b[0] * 8 + i % 8, y = b[1] * 8 + i / 8 % 8, z = b[2] * 8 + i / 64;
        cr_assert_eq(vod_volume_get(f->v, x, y, z), voxel_of(b, i), "brick %u %u %u voxel %u",
                     b[0], b[1], b[2], i);
    }
}

/* 64 x 32 x 16 bricks: a pool of some 170 MB, far more than 64 chunks. */
#define BIG 512, 256, 128

Test(vod_pool, a_large_pool_gives_a_thread_a_chunk)
{
    pool_fx f;
    fx_make(&f, BIG);
    put(&f, (const uint32_t[3]){0, 0, 0});
    cr_assert_eq(used(&f), CHUNK_UNITS, "the first record took a chunk");
    uint32_t e0 = table(f.v, 0)[0];
    put(&f, (const uint32_t[3]){1, 0, 0});
    cr_assert_eq(used(&f), CHUNK_UNITS, "the second came out of it");
    cr_assert_eq(e0, 1);
    cr_assert_gt(table(f.v, 0)[1], e0);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    free(f.arena);
}

Test(vod_pool, a_small_pool_is_taken_a_record_at_a_time)
{
    pool_fx f;
    fx_make(&f, 64, 64, 64); /* 512 bricks: some 2.6 MB */
    put(&f, (const uint32_t[3]){0, 0, 0});
    cr_assert_lt(used(&f), 200, "one record's units, not a chunk");
    free(f.arena);
}

typedef struct {
    pool_fx *f;
    uint32_t z0, z1;
} slab_job;

static void *put_slab(void *ud)
{
    slab_job *j = ud;
    uint32_t b[3];
    for (b[2] = j->z0; b[2] < j->z1; b[2]++)
        for (b[1] = 0; b[1] < 32; b[1]++)
            for (b[0] = 0; b[0] < 64; b[0]++) put(j->f, b);
    return NULL;
}

Test(vod_pool, two_threads_never_share_a_unit)
{
    pool_fx f;
    fx_make(&f, BIG);
    slab_job a = {&f, 0, 8}, c = {&f, 8, 16};
    pthread_t ta, tc;
    cr_assert_eq(pthread_create(&ta, NULL, put_slab, &a), 0);
    cr_assert_eq(pthread_create(&tc, NULL, put_slab, &c), 0);
    pthread_join(ta, NULL);
    pthread_join(tc, NULL);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    uint32_t b[3];
    for (b[2] = 0; b[2] < 16; b[2]++)
        for (b[1] = 0; b[1] < 32; b[1] += 3)
            for (b[0] = 0; b[0] < 64; b[0] += 5) read_back(&f, b);
    /* the threads' records in chunks of their own: the first brick of
     * each slab is in another chunk than the other slab's */
    uint32_t ea = table(f.v, 0)[0], ec = table(f.v, 0)[8 * 32 * 64];
    cr_assert_neq((ea - 1) / CHUNK_UNITS, (ec - 1) / CHUNK_UNITS);
    free(f.arena);
}

Test(vod_pool, a_new_volume_at_the_same_address_starts_its_pool_afresh)
{
    pool_fx f;
    fx_make(&f, BIG);
    put(&f, (const uint32_t[3]){0, 0, 0});
    put(&f, (const uint32_t[3]){1, 0, 0});
    cr_assert_eq(vod_volume_init(&f.v, f.arena, f.bytes, f.dims, VOD_VOLUME_F32, 8), 0);
    put(&f, (const uint32_t[3]){2, 0, 0});
    cr_assert_eq(table(f.v, 0)[2], 1, "the new volume's first record at the pool's start");
    cr_assert_eq(used(&f), CHUNK_UNITS);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    read_back(&f, (const uint32_t[3]){2, 0, 0});
    free(f.arena);
}

Test(vod_pool, the_pool_given_back_is_not_given_out_from_an_old_chunk)
{
    pool_fx f;
    fx_make(&f, BIG);
    /* a mip level's record taken on this thread (its chunk from the pool's
     * start), then the mip levels dropped: the pool goes back below it */
    f.v->mip_base = 0;
    f.v->mip_channel = VOXEL_CH_DISTANCE;
    cr_assert_eq(vod_vol_pool_units(f.v, 10), 1);
    vod_vol_drop_mips(f.v);
    cr_assert_eq(used(&f), 0);
    put(&f, (const uint32_t[3]){3, 0, 0});
    cr_assert_eq(table(f.v, 0)[3], 1, "taken anew from where the pool went back to");
    cr_assert_eq(used(&f), CHUNK_UNITS);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    read_back(&f, (const uint32_t[3]){3, 0, 0});
    free(f.arena);
}

/* A process forked from a thread that holds a chunk (a worker's
 * replacement, forked by the master mid-job) takes a chunk of its own: its
 * records and its parent's, in one shared volume, never share a unit. */
Test(vod_pool, a_forked_child_does_not_give_out_its_parents_chunk)
{
    pool_fx f;
    f.dims[0] = 512, f.dims[1] = 256, f.dims[2] = 128;
    f.bytes = vod_volume_bytes(f.dims, VOD_VOLUME_F32, 8, UINT32_MAX);
    f.arena = mmap(NULL, f.bytes, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    cr_assert_neq(f.arena, MAP_FAILED);
    cr_assert_eq(vod_volume_init(&f.v, f.arena, f.bytes, f.dims, VOD_VOLUME_F32, 8), 0);
    put(&f, (const uint32_t[3]){0, 0, 0}); /* this thread's chunk */
    pid_t pid = fork();
    cr_assert_geq(pid, 0);
    if (pid == 0) {
        uint32_t vox[512];
        for (uint32_t i = 0; i < 512; i++) vox[i] = voxel_of((const uint32_t[3]){1, 0, 0}, i);
        _exit(vod_volume_put_brick(f.v, (const uint32_t[3]){1, 0, 0}, vox) ? 1 : 0);
    }
    int status;
    cr_assert_eq(waitpid(pid, &status, 0), pid);
    cr_assert(WIFEXITED(status) && WEXITSTATUS(status) == 0);
    put(&f, (const uint32_t[3]){2, 0, 0});
    uint32_t child = table(f.v, 0)[1], parent = table(f.v, 0)[2];
    cr_assert_geq(child, CHUNK_UNITS + 1, "the child's record in a chunk of its own");
    cr_assert_lt(parent, CHUNK_UNITS + 1, "the parent's in its chunk");
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    for (uint32_t x = 0; x < 3; x++) read_back(&f, (const uint32_t[3]){x, 0, 0});
    munmap(f.arena, f.bytes);
}

/* A pool of exactly as many units as BIG's bricks take as full records
 * (every voxel a literal), filled by this thread, and when 2 MiB are left
 * a record put by a thread that has no chunk: near its end the pool is
 * taken a record at a time, so that record takes its own units, not a
 * chunk that no one would fill (taken a chunk at a time to the end, the
 * last puts would fail with 1 MiB free).  A put fails only when less than
 * a record's units are left, and the failure leaves the volume sound. */
typedef struct {
    pool_fx *f;
    uint32_t k;
    int rc;
} late_put;

static void brick_of(uint32_t k, uint32_t b[3])
{
    b[0] = k % 64, b[1] = k / 64 % 32, b[2] = k / 2048;
}

/* Full record k: none of its voxels alike. */
static uint32_t full_voxel(uint32_t k, uint32_t i)
{
    return 0x3c000000u + k * 512 + i;
}

static int put_full(pool_fx *f, uint32_t k)
{
    uint32_t vox[512], b[3];
    brick_of(k, b);
    for (uint32_t i = 0; i < 512; i++) vox[i] = full_voxel(k, i);
    return vod_volume_put_brick(f->v, b, vox);
}

static void *put_late(void *ud)
{
    late_put *l = ud;
    l->rc = put_full(l->f, l->k);
    return NULL;
}

Test(vod_pool, a_pool_is_taken_to_its_last_record)
{
    pool_fx f;
    f.dims[0] = 512, f.dims[1] = 256, f.dims[2] = 128;
    uint32_t max_u = (uint32_t)vod_pack_max_units(8), bricks = 64 * 32 * 16;
    size_t head = vod_volume_bytes(f.dims, VOD_VOLUME_F32, 8, 0);
    cr_assert_gt(head, 0);
    f.bytes = head + (size_t)bricks * max_u * PACK_UNIT - 1; /* a unit short of them all */
    f.arena = malloc(f.bytes);
    cr_assert_not_null(f.arena);
    cr_assert_eq(vod_volume_init(&f.v, f.arena, f.bytes, f.dims, VOD_VOLUME_F32, 8), 0);
    uint32_t cap = f.v->pool_cap, k = 0;
    cr_assert_gt((uint64_t)cap * PACK_UNIT, (64u + 2u) << 20, "chunks first, then records");
    late_put late = {&f, UINT32_MAX, 0};
    int rc = 0;
    for (; k < bricks && !rc; k++) {
        if (late.k == UINT32_MAX && (uint64_t)(cap - used(&f)) * PACK_UNIT < (2u << 20)) {
            pthread_t t;
            late.k = k;
            cr_assert_eq(pthread_create(&t, NULL, put_late, &late), 0);
            pthread_join(t, NULL);
            cr_assert_eq(late.rc, 0);
            continue;
        }
        rc = put_full(&f, k);
    }
    cr_assert_neq(late.k, UINT32_MAX, "the late thread put its record");
    cr_assert_eq(rc, -ENOMEM, "the pool ran out");
    cr_assert_lt(cap - used(&f), max_u, "with less than a record left: %u units", cap - used(&f));
    /* units taken but holding no record: a record's at most at the end of
     * each of the few chunks (the pool's first 8 MiB), none elsewhere */
    uint32_t rec_u = table(f.v, 0)[1] - table(f.v, 0)[0], stored = k - 1;
    cr_assert_lt(used(&f) - stored * rec_u, 16 * rec_u, "%u units wasted",
                 used(&f) - stored * rec_u);
    cr_assert_eq(vod_volume_check(f.v, f.bytes), 0);
    for (uint32_t j = 0; j < stored; j += 97) {
        uint32_t b[3], i = 5 + j % 500;
        brick_of(j, b);
        cr_assert_eq(vod_volume_get(f.v, b[0] * 8 + i % 8, b[1] * 8 + i / 8 % 8, b[2] * 8 + i / 64),
                     full_voxel(j, i), "record %u", j);
    }
    free(f.arena);
}

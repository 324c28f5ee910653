/* The writer's phases that run on threads in one process.  vod_assemble,
 * which renders the file in chunks on several threads and combines their
 * CRCs, against a plain sequential assembler written here from
 * docs/vod-format.md (the writer's code before the chunks): the same bytes
 * for files of one chunk and of many (bricks, the octree table and the
 * brick table straddling the chunks' boundaries), on every CPU and on one;
 * a sink's failure stops the writes.  vod_collect, whose subtrees are
 * walked by several threads: the nodes of the one-thread walk, in order,
 * whatever the room given. */
#include <criterion/criterion.h>
#include <errno.h>
#include <sched.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

#include "unit_util.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static uint32_t rnd(void) { return xorshift32(&rng_state); }

/* ------------------------------------------- the reference, sequential */

static void put(membuf *m, const void *p, size_t n) { mem_write(m, p, n); }

static void put32(membuf *m, uint32_t v)
{
    uint8_t b[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
    put(m, b, 4);
}

static uint32_t bits_of(float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    return u;
}

/* Section 2's header, the octree table (IDs by first use of equal bytes),
 * the brick table, the bricks, the trailer with its CRC. */
static membuf ref_assemble(const vod_layout *L, const vod_params *p, size_t n,
                           const vod_node *nodes, const vod_encoded *recs,
                           const uint8_t *const *data)
{
    membuf m = {0};
    uint32_t flags = VOD_FLAG_TRAILER | (p->comp != VOD_COMP_NONE ? VOD_FLAG_COMPRESSED : 0);
    for (int a = 0; a < 3; a++)
        if (L->padded > p->volume[a]) flags |= VOD_FLAG_PADDED;
    put(&m, ".VOD", 4);
    put32(&m, 1);
    for (int a = 0; a < 3; a++) put32(&m, p->volume[a]);
    for (int a = 0; a < 3; a++) put32(&m, L->brick);
    for (int a = 0; a < 3; a++) put32(&m, bits_of(p->voxel_scale[a]));
    put32(&m, L->height), put32(&m, L->voxel_bits), put32(&m, p->hash);
    put32(&m, p->comp), put32(&m, flags);
    uint32_t *id = calloc(n + 1, 4), *first = calloc(n + 1, 4), u = 0;
    for (size_t i = 0; i < n; i++) {
        for (uint32_t j = 0; j < u && !id[i]; j++) {
            const vod_encoded *a = &recs[first[j]];
            if (a->hash == recs[i].hash && a->size == recs[i].size &&
                memcmp(data[first[j]], data[i], a->size) == 0)
                id[i] = j + 1;
        }
        if (!id[i]) first[u] = (uint32_t)i, id[i] = ++u;
    }
    for (uint64_t k = 0, i = 0; k < L->nodes; k++)
        put32(&m, i < n && nodes[i].preorder == k ? id[i++] : 0);
    put32(&m, u);
    uint64_t off = m.n + 12ull * u;
    for (uint32_t j = 0; j < u; j++) {
        put32(&m, j + 1), put32(&m, (uint32_t)off), put32(&m, recs[first[j]].hash);
        off += 4 + recs[first[j]].size;
    }
    for (uint32_t j = 0; j < u; j++) {
        put32(&m, recs[first[j]].size);
        put(&m, data[first[j]], recs[first[j]].size);
    }
    uint32_t at = (uint32_t)m.n, meta = p->metadata ? (uint32_t)strlen(p->metadata) : 0;
    put(&m, "VODX", 4);
    put32(&m, 40 + meta);
    for (int a = 0; a < 3; a++) put32(&m, bits_of(p->origin[a]));
    put32(&m, (uint32_t)p->channel), put32(&m, meta);
    put(&m, p->metadata, meta);
    put32(&m, at);
    put(&m, "XDOV", 4);
    put32(&m, (uint32_t)crc32(0, m.p, (uInt)m.n));
    free(id), free(first);
    return m;
}

/* ------------------------------------------------------------ the cases */

typedef struct {
    vod_layout L;
    vod_params p;
    size_t n;
    vod_node *nodes;
    vod_encoded *recs;
    const uint8_t **data;
    uint8_t *pool;
} forged;

/* n records on nodes in preorder, of random sizes up to max_size bytes of
 * random data, with repeats: the same bytes again (one in 8), a forged
 * equal hash on other bytes (one in 16). */
static void forge(forged *f, uint32_t side, size_t n, uint32_t max_size)
{
    vod_params_default(&f->p);
    for (int a = 0; a < 3; a++) f->p.volume[a] = side - 3;
    f->p.comp = VOD_COMP_NONE;
    f->p.metadata = "k=v\nsource=forged\n";
    err_info err = {0};
    int depth = 0; /* the octree's: 2^depth voxels a side */
    while ((1u << depth) < side) depth++;
    cr_assert_eq(vod_layout_make(&f->p, depth, &f->L, &err), 0, "%s", err.msg);
    cr_assert_leq(max_size, vod_encode_bound(&f->L, &f->p));
    cr_assert_leq(n, f->L.nodes);
    f->n = n;
    f->nodes = calloc(n + 1, sizeof *f->nodes);
    f->recs = calloc(n + 1, sizeof *f->recs);
    f->data = calloc(n + 1, sizeof *f->data);
    f->pool = malloc(n * (size_t)max_size + 1);
    for (size_t i = 0, k = 0; i < n; k++) /* a random subset, in preorder */
        if (rnd() % (uint32_t)(f->L.nodes - k) < n - i) f->nodes[i++].preorder = k;
    for (size_t i = 0; i < n; i++) {
        uint8_t *d = f->pool + i * (size_t)max_size;
        uint32_t size = 1 + rnd() % max_size, r = rnd() % 16;
        if (i && r < 2) { /* the bytes of an earlier one */
            size_t j = rnd() % i;
            size = f->recs[j].size;
            memcpy(d, f->data[j], size);
            f->recs[i].hash = f->recs[j].hash;
        } else {
            for (uint32_t b = 0; b < size; b++) d[b] = (uint8_t)rnd();
            f->recs[i].hash = i && r == 2 ? f->recs[i - 1].hash : rnd();
        }
        f->recs[i].size = size;
        f->data[i] = d;
    }
}

static void forged_free(forged *f)
{
    free(f->nodes), free(f->recs), free(f->data), free(f->pool);
}

static membuf assemble(const forged *f, vod_stats *st, int fail_at, int *rc)
{
    membuf m = {.fail_at = fail_at};
    vod_sink sink = {mem_write, &m};
    err_info err = {0};
    vod_assembly a = {.L = &f->L, .p = &f->p, .n = f->n, .nodes = f->nodes,
                      .recs = f->recs, .data = f->data, .sink = &sink, .st = st,
                      .err = &err};
    *rc = vod_assemble(&a);
    return m;
}

static void same_as_reference(uint32_t side, size_t n, uint32_t max_size)
{
    forged f;
    forge(&f, side, n, max_size);
    membuf ref = ref_assemble(&f.L, &f.p, f.n, f.nodes, f.recs, f.data);
    vod_stats st;
    int rc;
    membuf m = assemble(&f, &st, 0, &rc);
    cr_assert_eq(rc, 0);
    cr_assert_eq(m.n, ref.n, "%zu bytes, want %zu", m.n, ref.n);
    for (size_t i = 0; i < m.n; i++)
        cr_assert_eq(m.p[i], ref.p[i], "byte %zu of %zu", i, m.n);
    cr_assert_eq(st.file_bytes, ref.n);
    cr_assert_eq(st.crc32, vod_get32(ref.p + ref.n - 4));
    cr_assert_eq(st.nonempty_nodes, n);
    free(m.p), free(ref.p);
    forged_free(&f);
}

Test(vod_assemble, one_chunk_same_as_the_sequential_writer)
{
    same_as_reference(64, 40, 300);
    same_as_reference(16, 0, 1); /* no brick at all */
}

Test(vod_assemble, many_chunks_same_as_the_sequential_writer)
{
    /* 4681 nodes (an 18 KiB table), about 10 MiB of bricks: every part
     * crosses a chunk's boundary somewhere */
    same_as_reference(256, 1200, 16384);
    /* a table of 2.4 MB of which most is zeros, bricks of a few bytes */
    same_as_reference(2048, 3000, 9);
}

/* This thread on one CPU of its affinity (on = 1), or back on all. */
static void one_cpu(int on)
{
    static cpu_set_t all;
    if (!on) {
        cr_assert_eq(sched_setaffinity(0, sizeof all, &all), 0);
        return;
    }
    cpu_set_t one;
    cr_assert_eq(sched_getaffinity(0, sizeof all, &all), 0);
    CPU_ZERO(&one);
    for (int c = 0; c < CPU_SETSIZE; c++)
        if (CPU_ISSET(c, &all)) {
            CPU_SET(c, &one);
            break;
        }
    cr_assert_eq(sched_setaffinity(0, sizeof one, &one), 0);
}

Test(vod_assemble, one_cpu_same_bytes)
{
    one_cpu(1);
    same_as_reference(256, 600, 16384);
    one_cpu(0);
}

Test(vod_assemble, a_sink_failure_stops_the_writes)
{
    forged f;
    forge(&f, 256, 800, 16384);
    for (int at = 1; at <= 4; at++) {
        int rc;
        membuf m = assemble(&f, NULL, at, &rc);
        cr_assert_eq(rc, -EIO);
        cr_assert_eq(m.calls, at, "no write after the failing one");
        free(m.p);
    }
    forged_free(&f);
}

/* ------------------------------------------------------------ vod_collect */

/* A 8-bit volume of side^3 voxels in bricks of sb: random voxels, and a
 * solid block (uniform bricks), its mip levels made. */
static vod_volume *random_volume(uint32_t side, uint32_t sb, void **arena,
                                 vod_layout *L)
{
    uint32_t dims[3] = {side, side, side};
    size_t bytes = vod_volume_bytes(dims, 8, sb, UINT32_MAX);
    cr_assert_gt(bytes, 0);
    *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, *arena, bytes, dims, 8, sb), 0);
    for (int i = 0; i < 3000; i++)
        cr_assert_eq(vod_volume_set(v, rnd() % side, rnd() % side, rnd() % side,
                                    1 + rnd() % 255), 0);
    for (uint32_t z = 0; z < side / 4; z++)
        for (uint32_t y = side / 2; y < side; y++)
            for (uint32_t x = 0; x < side / 2; x++)
                cr_assert_eq(vod_volume_set(v, x, y, z, 200), 0);
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) p.volume[a] = side;
    p.brick = sb;
    p.channel = VOXEL_CH_DENSITY;
    err_info err = {0};
    vod_source src = vod_volume_source(v);
    cr_assert_eq(vod_layout_make(&p, src.depth, L, &err), 0, "%s", err.msg);
    cr_assert_eq(vod_prepare(&src, L, p.channel, &err), 0, "%s", err.msg);
    return v;
}

Test(vod_collect, threads_give_the_nodes_of_one_walk)
{
    void *arena;
    vod_layout L;
    vod_volume *v = random_volume(128, 4, &arena, &L);
    cr_assert_geq(L.height, 6, "tall enough for the subtrees' walk");
    vod_source src = vod_volume_source(v);
    one_cpu(1); /* one CPU: one walk, the reference */
    size_t n = vod_collect(&src, &L, NULL, 0);
    vod_node *ref = malloc(n * sizeof *ref);
    cr_assert_eq(vod_collect(&src, &L, ref, n), n);
    one_cpu(0);
    cr_assert_gt(n, 1000);
    vod_node *got = malloc((n + 1) * sizeof *got);
    cr_assert_eq(vod_collect(&src, &L, NULL, 0), n);
    size_t uniform = 0;
    for (size_t cap = n + 1;; cap /= 3) { /* less room: the first cap nodes */
        memset(got, 0xa5, (n + 1) * sizeof *got);
        cr_assert_eq(vod_collect(&src, &L, got, cap), n, "room for %zu", cap);
        size_t k = cap < n ? cap : n;
        cr_assert_eq(memcmp(got, ref, k * sizeof *got), 0, "room for %zu", cap);
        for (size_t i = k; i <= n && cap <= n; i++)
            cr_assert_eq(((uint8_t *)&got[i])[0], 0xa5, "node %zu past the room", i);
        if (!cap) break;
    }
    for (size_t i = 0; i < n; i++) {
        cr_assert(i == 0 || ref[i].preorder > ref[i - 1].preorder);
        uniform += ref[i].uniform;
    }
    cr_assert_gt(uniform, 0, "the block's uniform bricks are among them");
    free(ref), free(got), free(arena);
}

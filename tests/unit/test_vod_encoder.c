/* The VOD encoder and duplicates: aggregates in parts are the whole, the
 * one-pass deflate's streams inflate to the brick and it picks the smaller code,
 * the compress bound, duplicates found before compression and in batches change
 * no byte, every level gives the same voxels; a brick stored once, an SFHS
 * collision not merged, the assembly merging only equal bytes. */
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
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, 3, &L, &err), 0);
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
                                              .err = &err}), 0);
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
                                              .err = &err}), -EINVAL);
    vod_encoded big[1] = {{7, 257}};
    cr_assert_eq(vod_assemble(&(vod_assembly){.L = &L, .p = &p, .n = 1, .nodes = nodes + 1,
                                              .recs = big, .data = data,
                                              .sink = &sink, .st = &st,
                                              .err = &err}), -EINVAL);
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
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, 7, &L, &err), 0);
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
                                              .sink = &sink, .st = &st, .err = &err}), 0, "%s", err.msg);
    cr_assert_eq(st.bricks, u);
    for (uint32_t i = 0; i < N; i++)
        cr_assert_eq(vod_get32(m.p + VOD_HEADER_BYTES + 4 * i), want[i], "node %u", i);
    free(m.p);
    free(nodes);
    free(recs);
    free(data);
    free(want);
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
            err_info err = {0};
            cr_assert_eq(vod_layout_make(&p, 6, &L, &err), 0, "%s", err.msg);
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

/* fx_copies' fixture ready for the encoder: the layout, the source and its
 * n non-empty nodes (malloc'ed). */
typedef struct {
    vod_layout L;
    vod_source src;
    size_t n;
    vod_node *nodes;
} copies_tree;

/* fx_copies' fixture as surface bricks of the given size (zlib, SFHS):
 * the file the writer makes of it into *ref when ref is not NULL (before
 * the aggregates: the writer makes its own), then the aggregates and the
 * tree to encode. */
static copies_tree copies_nodes(fixture *f, vod_params *p, uint32_t brick, membuf *ref,
                                vod_stats *st)
{
    err_info err = {0};
    copies_tree c;
    fx_init(f, 8, 128, 128, 256);
    fx_copies(f);
    params(p, f, VOXEL_CH_SURFACE, VOD_COMP_ZLIB, VOD_HASH_SFHS, brick);
    if (ref) *ref = write_file(f, p, st);
    cr_assert_eq(vod_layout_make(p, f->t.depth, &c.L, &err), 0);
    f->t.agg = malloc(f->t.used * sizeof *f->t.agg);
    vod_aggregate(&f->t, p->channel);
    c.src = vod_octree_source(&f->t);
    c.n = vod_collect(&c.src, &c.L, NULL, 0);
    c.nodes = malloc(c.n * sizeof *c.nodes);
    vod_collect(&c.src, &c.L, c.nodes, c.n);
    return c;
}

Test(vod_encoder, duplicates_found_before_compression_change_nothing)
{
    fixture f;
    vod_params p;
    vod_stats st;
    membuf ref;
    err_info err = {0};
    copies_tree c = copies_nodes(&f, &p, 32, &ref, &st);
    vod_layout L = c.L;
    vod_source src = c.src;
    size_t n = c.n;
    vod_node *nodes = c.nodes;
    size_t bound = vod_encode_bound(&L, &p);
    /* every brick compressed on its own, no duplicate looked for */
    vod_encoded *recs = malloc(n * sizeof *recs);
    uint8_t **data = malloc(n * sizeof *data), *scratch = malloc(L.raw_bytes);
    for (size_t i = 0; i < n; i++) {
        data[i] = malloc(bound);
        vod_brick_out o = {data[i], bound, &recs[i]};
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, &o), 0);
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
        cr_assert_eq(vod_encoder_put(e, &src, &nodes[i], i, &(vod_brick_out){out, bound, &rec},
                                     &same), 0);
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
                                              .sink = &sink,
                                              .err = &err}), 0);
    cr_assert_eq(m.n, ref.n);
    cr_assert_arr_eq(m.p, ref.p, m.n);
    for (size_t i = 0; i < n; i++) free(data[i]);
    free(data), free(recs), free(nodes), free(scratch), free(out), free(f.t.agg);
    f.t.agg = NULL;
    free(m.p), free(ref.p);
    fx_free(&f);
}

/* One batch of 1 to VOD_ENCODE_BATCH nodes (at random, at most picks - j)
 * from picked[j] on, tagged j, j + 1, ..., encoded into r (outs: room for
 * a batch, bound bytes a brick); how many. */
typedef struct {
    uint8_t *out[VOD_ENCODE_BATCH];
    uint64_t tag[VOD_ENCODE_BATCH], same[VOD_ENCODE_BATCH];
    vod_encoded rec[VOD_ENCODE_BATCH];
} batch_out;

static size_t put_random_batch(vod_encoder *e, const vod_source *src, const vod_node *picked,
                               size_t j, size_t picks, uint8_t *outs, size_t bound,
                               batch_out *r)
{
    size_t k = 1 + rnd() % VOD_ENCODE_BATCH;
    if (k > picks - j) k = picks - j;
    for (size_t t = 0; t < k; t++) r->out[t] = outs + t * bound, r->tag[t] = j + t;
    vod_brick_batch b = {&picked[j], r->tag, k, r->out, bound, r->rec, r->same};
    cr_assert_eq(vod_encoder_put_batch(e, src, &b), 0);
    return k;
}

/* Node picks of the fixture's first few bricks, encoded in batches of 1
 * to 4, so that a brick repeats inside a batch and across batches: each
 * record is vod_encode's, a duplicate names an earlier equal brick, and
 * each distinct brick is compressed once. */
Test(vod_encoder, batches_find_duplicates_inside_and_across)
{
    fixture f;
    vod_params p;
    copies_tree c = copies_nodes(&f, &p, 16, NULL, NULL);
    vod_layout L = c.L;
    vod_source src = c.src;
    size_t n = c.n;
    vod_node *nodes = c.nodes;
    size_t bound = vod_encode_bound(&L, &p);
    cr_assert_gt(n, 24);
    enum { DISTINCT = 24, PICKS = 400 };
    vod_encoded ref[DISTINCT];
    uint8_t *data[DISTINCT], *scratch = malloc(L.raw_bytes);
    for (size_t i = 0; i < DISTINCT; i++) {
        data[i] = malloc(bound);
        vod_brick_out o = {data[i], bound, &ref[i]};
        cr_assert_eq(vod_encode(&src, &L, &p, &nodes[i], scratch, &o), 0);
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
        batch_out got;
        size_t k = put_random_batch(e, &src, picked, j, PICKS, outs, bound, &got);
        uint8_t **out = got.out;
        const uint64_t *same = got.same;
        const vod_encoded *rec = got.rec;
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
    vod_brick_batch too_many = {nodes, tag, VOD_ENCODE_BATCH + 1, out, bound, rec, same};
    cr_assert_eq(vod_encoder_put_batch(e, &src, &too_many), -EINVAL);
    vod_encoder_free(e);
    for (size_t i = 0; i < DISTINCT; i++) free(data[i]);
    free(outs), free(scratch), free(nodes), free(f.t.agg);
    f.t.agg = NULL;
    fx_free(&f);
}

/* Uniform nodes of more values than the encoder keeps at hand (two a
 * distance field has, +w and -w), alternating, in batches, with a mixed
 * node whose brick is one of them: each record is vod_encode's, and a
 * repeat names the first node of its bytes, whichever way the encoder
 * found it (kept at hand, the table, or the batch). */
Test(vod_encoder, uniform_nodes_of_many_values_name_their_first)
{
    fixture f;
    vod_params p;
    copies_tree c = copies_nodes(&f, &p, 16, NULL, NULL);
    vod_layout L = c.L;
    size_t bound = vod_encode_bound(&L, &p);
    enum { VALUES = 7, PICKS = 600 };
    vod_node u[VALUES];
    vod_encoded ref[VALUES];
    uint8_t *data[VALUES], *scratch = malloc(L.raw_bytes);
    for (size_t v = 0; v < VALUES; v++) {
        u[v] = (vod_node){.level = 0, .bx = 8 + (uint32_t)v, .uniform = 1, /* past x 128 */
                          .value = v == VALUES - 1 ? 0 : 0x3f800000u + (uint32_t)v};
        data[v] = malloc(bound);
        vod_brick_out o = {data[v], bound, &ref[v]};
        cr_assert_eq(vod_encode(&c.src, &L, &p, &u[v], scratch, &o), 0);
    }
    vod_encode_cleanup();
    /* first a mixed node whose voxels are all 0 (past the volume): value 0's brick */
    vod_node zero = u[VALUES - 1];
    zero.uniform = 0;
    size_t pick[PICKS], first[VALUES];
    vod_node picked[PICKS];
    for (size_t v = 0; v < VALUES; v++) first[v] = SIZE_MAX;
    for (size_t j = 0; j < PICKS; j++) {
        pick[j] = j % 2 ? rnd() % VALUES : rnd() % 2; /* mostly two values */
        picked[j] = j == 0 ? zero : u[pick[j]];
        if (j == 0) pick[j] = VALUES - 1;
        if (first[pick[j]] == SIZE_MAX) first[pick[j]] = j;
    }
    vod_encoder *e;
    cr_assert_eq(vod_encoder_new(&L, &p, &e), 0);
    uint8_t *outs = malloc(VOD_ENCODE_BATCH * bound);
    for (size_t j = 0; j < PICKS;) {
        batch_out got;
        size_t k = put_random_batch(e, &c.src, picked, j, PICKS, outs, bound, &got);
        uint8_t **out = got.out;
        const uint64_t *same = got.same;
        const vod_encoded *rec = got.rec;
        for (size_t t = 0; t < k; t++) {
            size_t v = pick[j + t];
            cr_assert_eq(rec[t].hash, ref[v].hash, "pick %zu", j + t);
            cr_assert_eq(rec[t].size, ref[v].size, "pick %zu", j + t);
            cr_assert_eq(same[t], first[v], "pick %zu (value %zu) names %llu, not %zu", j + t,
                         v, (unsigned long long)same[t], first[v]);
            if (same[t] == j + t) cr_assert_arr_eq(out[t], data[v], ref[v].size);
        }
        j += k;
    }
    vod_encoder_free(e);
    for (size_t v = 0; v < VALUES; v++) free(data[v]);
    free(outs), free(scratch), free(c.nodes), free(f.t.agg);
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

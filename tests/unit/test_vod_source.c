/* The two brick sources, octree and volume (vod_source), give the same bytes for
 * the same voxels: random voxels, a deeper octree, a solid ball's uniform
 * bricks, a volume smaller than the brick, empty sources; channel 4 from a float
 * volume; a channel a source lacks and the assembly's refusals reach the caller. */
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
    err_info err = {0};
    cr_assert_eq(vod_write(s, p, &sink, st, &err), 0, "%s", err.msg);
    return m;
}

/* Nodes the volume calls uniform, for this layout (after a write). */
static size_t uniform_nodes(vod_source *s, const vod_params *p)
{
    vod_layout L;
    err_info err = {0};
    cr_assert_eq(vod_layout_make(p, s->depth, &L, &err), 0, "%s", err.msg);
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
    err_info err = {0};
    cr_assert_eq(vod_read(m.p, m.n, &f, &err), 0, "%s", err.msg);
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
    cr_assert_eq(vod_write_octree(&fx.t, &p, &sink, NULL, &err), -EINVAL);
    cr_assert(strstr(err.msg, "channel 4 cannot be written from the octree"), "%s", err.msg);
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
    err_info err = {0};
    membuf m = {0};
    vod_sink sink = {mem_write, &m};
    cr_assert_eq(vod_write_octree(&f.t, &p, &sink, NULL, &err), -EINVAL);
    cr_assert_str_eq(err.msg, "channel 2 cannot be written from the octree (it gives "
                          "channels 1 and 3)");
    cr_assert_null(f.t.agg);
    /* and the octree's fill refuses a layout it cannot give even if asked */
    vod_source s = vod_octree_source(&f.t);
    vod_layout L;
    cr_assert_eq(vod_layout_make(&p, 4, &L, &err), 0, "%s", err.msg);
    cr_assert_eq(L.voxel_bits, 8);
    vod_node n = {.level = 0};
    uint8_t *scratch = malloc(L.raw_bytes), *out = malloc(vod_encode_bound(&L, &p));
    vod_encoded rec;
    vod_brick_out o = {out, vod_encode_bound(&L, &p), &rec};
    cr_assert_eq(vod_encode(&s, &L, &p, &n, scratch, &o), -EINVAL);
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
    err_info err = {0};
    cr_assert_eq(vod_write(&s, &p, &sink, NULL, &err), -EINVAL);
    cr_assert_str_eq(err.msg, "bricks out of preorder or over their bound");
    cr_assert_eq(m.calls, 0);
    free(f.t.agg);
    fx_free(&f);
}

/* The octree against a dense array: random stores in random and in preorder,
 * lookups, Figure 6 iteration (every voxel once, in preorder), full arena. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "octree.h"
#include "voxel.h"

#define DEPTH 5
#define N (1u << DEPTH)

static uint32_t key(uint32_t x, uint32_t y, uint32_t z) { return (z * N + y) * N + x; }

/* Morton (preorder) key: interleave bits, highest level first. */
static uint64_t morton(uint32_t x, uint32_t y, uint32_t z)
{
    uint64_t m = 0;
    for (int b = DEPTH - 1; b >= 0; b--)
        m = m << 3 | ((z >> b) & 1) << 2 | ((y >> b) & 1) << 1 | ((x >> b) & 1);
    return m;
}

static void fill_random(octree *t, uint32_t *dense, unsigned seed, int count)
{
    srand(seed);
    for (int i = 0; i < count; i++) {
        uint32_t x = rand() % N, y = rand() % N, z = rand() % N;
        uint32_t v = 1 + (uint32_t)rand();
        cr_assert_eq(octree_store(t, x, y, z, v), 0);
        dense[key(x, y, z)] = v;
    }
}

Test(octree, random_stores_match_dense_array)
{
    static octree_cell arena[20000];
    static uint32_t dense[N * N * N];
    octree t;
    octree_init(&t, arena, 20000, DEPTH);
    fill_random(&t, dense, 7, 3000);
    uint64_t count = 0;
    for (uint32_t z = 0; z < N; z++)
        for (uint32_t y = 0; y < N; y++)
            for (uint32_t x = 0; x < N; x++) {
                cr_assert_eq(octree_get(&t, x, y, z), dense[key(x, y, z)],
                             "voxel %u %u %u", x, y, z);
                count += dense[key(x, y, z)] != 0;
            }
    cr_assert_eq(t.voxels, count);
}

Test(octree, iteration_visits_every_voxel_once_in_preorder)
{
    static octree_cell arena[20000];
    static uint32_t dense[N * N * N];
    octree t;
    octree_init(&t, arena, 20000, DEPTH);
    fill_random(&t, dense, 11, 2000);
    octree_iter it;
    octree_iter_init(&it, &t);
    uint32_t x, y, z, v;
    uint64_t seen = 0, prev = 0;
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        cr_assert_eq(v, dense[key(x, y, z)]);
        dense[key(x, y, z)] = 0; /* twice would now mismatch */
        uint64_t m = morton(x, y, z);
        cr_assert(seen == 0 || m > prev, "not in preorder");
        prev = m;
        seen++;
    }
    cr_assert_eq(seen, t.voxels);
    for (uint32_t i = 0; i < N * N * N; i++) cr_assert_eq(dense[i], 0);
}

Test(octree, preorder_insertion_builds_the_same_tree)
{
    static octree_cell a1[20000], a2[20000];
    static uint32_t dense[N * N * N];
    octree t1, t2;
    octree_init(&t1, a1, 20000, DEPTH);
    octree_init(&t2, a2, 20000, DEPTH);
    fill_random(&t1, dense, 3, 1500);
    octree_iter it;
    octree_iter_init(&it, &t1);
    uint32_t x, y, z, v;
    while (octree_iter_next(&it, &x, &y, &z, &v))
        cr_assert_eq(octree_store(&t2, x, y, z, v), 0);
    cr_assert_eq(t2.voxels, t1.voxels);
    cr_assert_eq(t2.used, t1.used, "same cells whatever the order");
    for (uint32_t i = 0; i < N * N * N; i++)
        if (dense[i])
            cr_assert_eq(octree_get(&t2, i % N, i / N % N, i / N / N), dense[i]);
}

Test(octree, full_arena_is_enomem_and_leaves_tree_intact)
{
    static octree_cell arena[8];
    octree t;
    octree_init(&t, arena, 8, DEPTH);
    cr_assert_eq(octree_store(&t, 0, 0, 0, 5), 0); /* root + 4 cells */
    cr_assert_eq(octree_store(&t, 31, 31, 31, 6), -ENOMEM);
    cr_assert_eq(octree_get(&t, 0, 0, 0), 5);
    cr_assert_eq(octree_get(&t, 31, 31, 31), 0);
    cr_assert_eq(t.voxels, 1);
    cr_assert_eq(octree_store(&t, 1, 1, 1, 7), 0, "same leaf cell needs no new cell");
}

Test(octree, depth_one_tree)
{
    static octree_cell arena[4];
    octree t;
    octree_init(&t, arena, 4, 1);
    cr_assert_eq(octree_store(&t, 1, 0, 1, 9), 0);
    cr_assert_eq(octree_get(&t, 1, 0, 1), 9);
    cr_assert_eq(t.used, 2);
}

Test(voxel, octahedral_normals_round_trip_within_a_milliradian)
{
    srand(5);
    for (int i = 0; i < 100000; i++) {
        double n[3], m[3];
        for (int k = 0; k < 3; k++) n[k] = rand() / (double)RAND_MAX * 2 - 1;
        double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (l < 1e-6) continue;
        for (int k = 0; k < 3; k++) n[k] /= l;
        uint32_t v = voxel_surface(n);
        cr_assert_eq(voxel_occupancy(v), 255);
        voxel_unpack_normal(v, m);
        double dot = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
        cr_assert(dot > cos(1.5e-3), "normal %g %g %g: error %g rad", n[0], n[1], n[2], acos(dot));
    }
}

/* The packing as first written (quantize with floor()), which the VOD files
 * already written encode: the faster packing must give the same bits. */
static uint32_t ref_quantize(double u)
{
    double q = floor((u * 0.5 + 0.5) * 4095.0 + 0.5);
    if (!(q >= 0.0)) q = 0.0;
    if (q > 4095.0) q = 4095.0;
    return (uint32_t)q;
}

static uint32_t ref_pack(const double n[3])
{
    double l1 = fabs(n[0]) + fabs(n[1]) + fabs(n[2]);
    if (!(l1 > 0.0) || !isfinite(l1)) return ref_quantize(0.0) << 8 | ref_quantize(0.0) << 20;
    double u = n[0] / l1, v = n[1] / l1;
    if (n[2] < 0.0) {
        double fu = (1.0 - fabs(v)) * (u < 0.0 ? -1.0 : 1.0);
        double fv = (1.0 - fabs(u)) * (v < 0.0 ? -1.0 : 1.0);
        u = fu;
        v = fv;
    }
    return ref_quantize(u) << 8 | ref_quantize(v) << 20;
}

Test(voxel, packing_matches_the_floor_reference)
{
    srand(6);
    for (int i = 0; i < 1000000; i++) {
        double n[3];
        for (int k = 0; k < 3; k++) {
            int c = rand() % 12;
            n[k] = c == 0 ? 0.0 : c == 1 ? -0.0 : c == 2 ? (double)(rand() % 3 - 1)
                 : c == 3 ? ldexp(rand() % 2 ? 1 : -1, rand() % 2100 - 1070)
                 : c == 4 ? (rand() % 2 ? INFINITY : NAN)
                 : rand() / (double)RAND_MAX * 2 - 1;
        }
        cr_assert_eq(voxel_pack_normal(n), ref_pack(n), "%a %a %a", n[0], n[1], n[2]);
    }
    /* u on both sides of every rounding boundary (k - 1/2 after scaling) */
    for (int k = 0; k <= 4096; k++)
        for (int d = -2; d <= 2; d++) {
            double u = ((k - 1.0) / 4095.0 - 0.5) * 2 + d * 0x1p-52;
            double n[3] = {u, 0, 1 - fabs(u)};
            cr_assert_eq(voxel_pack_normal(n), ref_pack(n), "u = %a", u);
        }
}

Test(voxel, batched_packing_is_the_one_vector_packing)
{
    srand(7);
    for (int i = 0; i < 200000; i++) {
        double x[8], y[8], z[8];
        uint32_t out[8];
        for (int l = 0; l < 8; l++) {
            double *p[3] = {&x[l], &y[l], &z[l]};
            for (int k = 0; k < 3; k++) {
                int c = rand() % 12;
                *p[k] = c == 0 ? 0.0 : c == 1 ? -0.0 : c == 2 ? (double)(rand() % 3 - 1)
                      : c == 3 ? ldexp(rand() % 2 ? 1 : -1, rand() % 2100 - 1070)
                      : c == 4 ? (rand() % 2 ? INFINITY : NAN)
                      : rand() / (double)RAND_MAX * 2 - 1;
            }
        }
        unsigned n = 1 + (unsigned)rand() % 8;
        voxel_surfaces(x, y, z, n, out);
        for (unsigned l = 0; l < n; l++) {
            double v[3] = {x[l], y[l], z[l]};
            cr_assert_eq(out[l], voxel_surface(v), "%a %a %a", x[l], y[l], z[l]);
        }
    }
}

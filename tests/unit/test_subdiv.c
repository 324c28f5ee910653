/* The subdivision kernel: the grid contract, the one box formula, the
 * serial algorithm on a sphere against an exact geometric oracle (box–sphere
 * intersection computed here in plain C), normals, padding, and the
 * identity of the voxel set whatever order and kernel reach a box. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"
#include "octree.h"
#include "subdiv.h"
#include "voxel.h"

#define SPHERE "sqrt(x^2 + y^2 + z^2) - 0.8"
#define SPHERE_R 0.8

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    int rc = expr_compile(src, strlen(src), NULL, &t, &ee);
    cr_assert_eq(rc, 0, "compile %s: %s", src, ee.msg);
    return t;
}

static grid_spec cube_grid(double h, uint32_t res)
{
    double lo[3] = {-h, -h, -h}, hi[3] = {h, h, h};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    return g;
}

/* ---- the grid ---- */

Test(subdiv, grid_res_one_and_powers)
{
    grid_spec g = cube_grid(1, 1);
    cr_assert_eq(g.depth, 1);
    cr_assert(g.res[0] == 1 && g.res[1] == 1 && g.res[2] == 1);
    cr_assert_float_eq(g.vs, 2.0, 1e-15);
    g = cube_grid(1, 64);
    cr_assert_eq(g.depth, 6);
    g = cube_grid(1, 65);
    cr_assert_eq(g.depth, 7);
    g = cube_grid(1, 4096);
    cr_assert_eq(g.depth, 12);
    cr_assert_eq(grid_check(&g), 0);
}

Test(subdiv, grid_non_power_of_two_and_box_domains)
{
    grid_spec g = cube_grid(1, 100);
    cr_assert_eq(g.depth, 7);
    cr_assert(g.res[0] == 100 && g.res[1] == 100 && g.res[2] == 100);
    cr_assert_float_eq(g.vs, 0.02, 1e-15);
    double lo[3] = {0, 0, 0}, hi[3] = {2, 1, 0.5};
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 64, &g, &err), 0);
    cr_assert(g.res[0] == 64 && g.res[1] == 32 && g.res[2] == 16,
              "%u %u %u", g.res[0], g.res[1], g.res[2]);
    /* 0.3 / 0.1 is 2.9999999999999996 in doubles: still 3 voxels */
    double lo2[3] = {0, 0, 0}, hi2[3] = {1, 0.3, 1};
    cr_assert_eq(grid_make(lo2, hi2, 10, &g, &err), 0);
    cr_assert(g.res[0] == 10 && g.res[1] == 3 && g.res[2] == 10);
    /* a thin slab still gets one voxel; the longest axis may be y or z */
    double lo3[3] = {5, -3, 10}, hi3[3] = {5.001, 3, 11};
    cr_assert_eq(grid_make(lo3, hi3, 300, &g, &err), 0);
    cr_assert(g.res[0] == 1 && g.res[1] == 300 && g.res[2] == 50,
              "%u %u %u", g.res[0], g.res[1], g.res[2]);
    cr_assert_eq(g.depth, 9);
    /* the grid covers the domain on every axis */
    for (int a = 0; a < 3; a++)
        cr_assert(grid_coord(&g, a, g.res[a]) >= hi3[a]);
}

Test(subdiv, grid_errors_have_messages)
{
    grid_spec g;
    err_info err = {0};
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    err.msg[0] = 0;
    cr_assert_eq(grid_make(lo, hi, 0, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "resolution"), "%s", err.msg);
    cr_assert_eq(grid_make(lo, hi, 4097, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "4096"), "%s", err.msg);
    double hi_flat[3] = {1, -1, 1};
    cr_assert_eq(grid_make(lo, hi_flat, 64, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "empty on y"), "%s", err.msg);
    double hi_inv[3] = {1, 1, -2};
    cr_assert_eq(grid_make(lo, hi_inv, 64, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "on z"), "%s", err.msg);
    double hi_nan[3] = {NAN, 1, 1};
    cr_assert_eq(grid_make(lo, hi_nan, 64, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "not finite"), "%s", err.msg);
    double lo_inf[3] = {-INFINITY, -1, -1};
    cr_assert_eq(grid_make(lo_inf, hi, 64, &g, &err), -EINVAL);
    double lo_far[3] = {1e17, 0, 0}, hi_far[3] = {1e17 + 64, 100, 1};
    cr_assert_eq(grid_make(lo_far, hi_far, 64, &g, &err), -EINVAL);
    cr_assert(strstr(err.msg, "too small"), "%s", err.msg);
    g = cube_grid(1, 64);
    g.depth = 7; /* not the smallest depth */
    cr_assert_eq(grid_check(&g), -EINVAL);
}

/* ---- the one formula ---- */

Test(subdiv, neighbours_share_bounds_bit_for_bit)
{
    double lo[3] = {-0.37, 0.1, -3.3}, hi[3] = {0.91, 0.7, -2.0};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 333, &g, &err), 0);
    srand(5);
    for (int k = 0; k < 20000; k++) {
        uint16_t l = (uint16_t)(rand() % g.depth), n = (uint16_t)(1u << l);
        uint16_t m = (uint16_t)((1u << g.depth) / n - 1);
        grid_octant o = {(uint16_t)(rand() % m * n), (uint16_t)(rand() % m * n),
                           (uint16_t)(rand() % m * n), l};
        grid_octant nx = o, ny = o, nz = o;
        nx.x += n;
        ny.y += n;
        nz.z += n;
        ival a[3], b[3], c[3], d[3];
        subdiv_box(&g, o, &a[0], &a[1], &a[2]);
        subdiv_box(&g, nx, &b[0], &b[1], &b[2]);
        subdiv_box(&g, ny, &c[0], &c[1], &c[2]);
        subdiv_box(&g, nz, &d[0], &d[1], &d[2]);
        cr_assert(a[0].hi == b[0].lo && a[1].hi == c[1].lo && a[2].hi == d[2].lo);
        cr_assert(a[0].lo < a[0].hi && a[1].lo < a[1].hi && a[2].lo < a[2].hi);
        if (l == 0) continue;
        /* the children tile the parent exactly */
        grid_octant c0 = {o.x, o.y, o.z, (uint16_t)(l - 1)};
        grid_octant c7 = {(uint16_t)(o.x + n / 2), (uint16_t)(o.y + n / 2),
                            (uint16_t)(o.z + n / 2), (uint16_t)(l - 1)};
        ival p0[3], p7[3];
        subdiv_box(&g, c0, &p0[0], &p0[1], &p0[2]);
        subdiv_box(&g, c7, &p7[0], &p7[1], &p7[2]);
        for (int ax = 0; ax < 3; ax++) {
            cr_assert(p0[ax].lo == a[ax].lo && p7[ax].hi == a[ax].hi);
            cr_assert(p0[ax].hi == p7[ax].lo);
        }
    }
}

/* ---- the serial algorithm on a sphere ---- */

typedef struct {
    octree t;
    octree_cell *arena;
} tree;

static void tree_init(tree *t, int depth)
{
    uint32_t cap = 1u << 18;
    t->arena = malloc(octree_arena_bytes(cap));
    cr_assert(t->arena);
    octree_init(&t->t, t->arena, cap, depth);
}

static void serial(const char *src, const grid_spec *g, tree *t)
{
    expr_tape *tape = compile(src);
    tree_init(t, g->depth);
    cr_assert_eq(subdiv_serial(tape, g, &t->t), 0);
    expr_tape_free(tape);
}

/* Distance range from the origin over voxel (X, Y, Z)'s box. */
static void box_dist(const grid_spec *g, uint32_t X, uint32_t Y, uint32_t Z,
                     double *dmin, double *dmax)
{
    uint32_t v[3] = {X, Y, Z};
    double sn = 0, sx = 0;
    for (int a = 0; a < 3; a++) {
        double lo = grid_coord(g, a, v[a]), hi = grid_coord(g, a, v[a] + 1);
        double near = lo > 0 ? lo : hi < 0 ? -hi : 0;
        double far = fmax(fabs(lo), fabs(hi));
        sn += near * near;
        sx += far * far;
    }
    *dmin = sqrt(sn);
    *dmax = sqrt(sx);
}

/* Exact oracle: a box surely cut by the sphere must be there; a box surely
 * clear of it (beyond rounding) must not; the normal points outwards. */
static void check_sphere(const grid_spec *g, const tree *t, double R)
{
    const double eps = 1e-9;
    uint64_t must = 0;
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++) {
                double dn, dx;
                box_dist(g, x, y, z, &dn, &dx);
                uint32_t v = octree_get(&t->t, x, y, z);
                if (dn < R - eps && dx > R + eps) {
                    must++;
                    cr_assert(v, "voxel %u %u %u is cut but missing", x, y, z);
                }
                if (dn > R + eps || dx < R - eps)
                    cr_assert_eq(v, 0, "voxel %u %u %u is clear but present", x, y, z);
            }
    octree_iter it;
    octree_iter_init(&it, &t->t);
    uint32_t x, y, z, v;
    uint64_t n = 0;
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        n++;
        cr_assert(x < g->res[0] && y < g->res[1] && z < g->res[2]);
        cr_assert_eq(voxel_occupancy(v), VOXEL_FULL);
        double c[3] = {grid_coord(g, 0, x + 0.5), grid_coord(g, 1, y + 0.5),
                       grid_coord(g, 2, z + 0.5)};
        double r = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        cr_assert(fabs(r - R) <= sqrt(3.0) * g->vs, "voxel %u %u %u far", x, y, z);
        double nn[3];
        voxel_unpack_normal(v, nn);
        double dot = (nn[0] * c[0] + nn[1] * c[1] + nn[2] * c[2]) / r;
        cr_assert(dot > 0.99, "normal at %u %u %u: dot %f", x, y, z, dot);
    }
    cr_assert_eq(n, t->t.voxels);
    cr_assert(n >= must && must > 0);
}

Test(subdiv, serial_sphere_32_and_64_matches_exact_oracle)
{
    for (uint32_t res = 32; res <= 64; res *= 2) {
        grid_spec g = cube_grid(1, res);
        tree t;
        serial(SPHERE, &g, &t);
        check_sphere(&g, &t, SPHERE_R);
        free(t.arena);
    }
}

Test(subdiv, envelope_corners_with_sign_change_are_present)
{
    grid_spec g = cube_grid(1, 48);
    tree t;
    serial(SPHERE, &g, &t);
    for (uint32_t z = 0; z < 48; z++)
        for (uint32_t y = 0; y < 48; y++)
            for (uint32_t x = 0; x < 48; x++) {
                int neg = 0, pos = 0;
                for (int i = 0; i < 8; i++) {
                    double px = grid_coord(&g, 0, x + (i & 1));
                    double py = grid_coord(&g, 1, y + ((i >> 1) & 1));
                    double pz = grid_coord(&g, 2, z + ((i >> 2) & 1));
                    double f = sqrt(px * px + py * py + pz * pz) - SPHERE_R;
                    neg |= f < 0;
                    pos |= f > 0;
                }
                if (neg && pos) cr_assert(octree_get(&t.t, x, y, z), "%u %u %u", x, y, z);
            }
    free(t.arena);
}

Test(subdiv, padding_is_never_emitted)
{
    /* 100 voxels in a 128 tree, and a domain that cuts the sphere */
    double lo[3] = {-1, -1, -0.5}, hi[3] = {1, 1, 0.5};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 100, &g, &err), 0);
    cr_assert(g.res[2] == 50 && g.depth == 7);
    tree t;
    serial("sqrt(x^2 + y^2 + z^2) - 1.2", &g, &t);
    check_sphere(&g, &t, 1.2);
    octree_iter it;
    octree_iter_init(&it, &t.t);
    uint32_t x, y, z, v, maxc[3] = {0, 0, 0};
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        maxc[0] = x > maxc[0] ? x : maxc[0];
        maxc[1] = y > maxc[1] ? y : maxc[1];
        maxc[2] = z > maxc[2] ? z : maxc[2];
    }
    /* the sphere reaches past the domain's far side on every axis */
    cr_assert(maxc[0] == 99 && maxc[1] == 99 && maxc[2] == 49,
              "%u %u %u", maxc[0], maxc[1], maxc[2]);
    free(t.arena);
}

/* ---- the same voxels whatever the order ---- */

typedef struct {
    grid_octant *o;
    size_t n, cap;
    grid_voxel *v;
    size_t nv, capv;
} bag;

static int bag_octant(void *ud, const grid_octant *o)
{
    bag *b = ud;
    if (b->n == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 64;
        b->o = realloc(b->o, b->cap * sizeof *b->o);
    }
    b->o[b->n++] = *o;
    return 0;
}

static int bag_voxel(void *ud, const grid_voxel *v)
{
    bag *b = ud;
    if (b->nv == b->capv) {
        b->capv = b->capv ? 2 * b->capv : 1024;
        b->v = realloc(b->v, b->capv * sizeof *b->v);
    }
    b->v[b->nv++] = *v;
    return 0;
}

/* Every octant of the work list, taken in random order, expanded with
 * subdiv_children until level `stop`, then (if stop > 0) each remaining
 * octant as a subtree, again in random order: the Figure 3 schedules
 * emulated in one process with one kernel that jumps around the tree. */
static void shuffled(const char *src, const grid_spec *g, int stop,
                     unsigned seed, tree *out, uint64_t *tested)
{
    expr_tape *tape = compile(src);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(tape, g->depth, &vm), 0);
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    bag work = {0}, leaves = {0};
    subdiv_sink s = {.voxel = bag_voxel, .octant = bag_octant, .ud = &work};
    bag_octant(&work, &(grid_octant){0, 0, 0, (uint16_t)g->depth});
    srand(seed);
    while (work.n) {
        size_t i = (size_t)rand() % work.n;
        grid_octant o = work.o[i];
        work.o[i] = work.o[--work.n];
        if (o.level <= stop) {
            bag_octant(&leaves, &o);
            continue;
        }
        cr_assert_eq(subdiv_children(&k, o, &s), 0);
    }
    subdiv_sink s2 = {.voxel = bag_voxel, .ud = &work};
    while (leaves.n) {
        size_t i = (size_t)rand() % leaves.n;
        grid_octant o = leaves.o[i];
        leaves.o[i] = leaves.o[--leaves.n];
        cr_assert_eq(subdiv_subtree(&k, o, &s2), 0);
    }
    tree_init(out, g->depth);
    for (size_t i = 0; i < work.nv; i++) {
        grid_voxel v = work.v[i];
        cr_assert_eq(octree_get(&out->t, v.x, v.y, v.z), 0, "voxel twice");
        cr_assert_eq(octree_store(&out->t, v.x, v.y, v.z, v.value), 0);
    }
    *tested = k.tested;
    free(work.o);
    free(work.v);
    free(leaves.o);
    expr_vm_free(vm);
    expr_tape_free(tape);
}

static void assert_same(const tree *a, const tree *b)
{
    octree_iter ia, ib;
    octree_iter_init(&ia, &a->t);
    octree_iter_init(&ib, &b->t);
    uint32_t x, y, z, v, x2, y2, z2, v2;
    uint64_t n = 0;
    for (;;) {
        bool ma = octree_iter_next(&ia, &x, &y, &z, &v);
        bool mb = octree_iter_next(&ib, &x2, &y2, &z2, &v2);
        cr_assert_eq(ma, mb, "voxel counts differ after %llu", (unsigned long long)n);
        if (!ma) break;
        cr_assert(x == x2 && y == y2 && z == z2 && v == v2,
                  "voxel %llu: (%u %u %u %08x) vs (%u %u %u %08x)", (unsigned long long)n,
                  x, y, z, v, x2, y2, z2, v2);
        n++;
    }
    cr_assert(n > 0);
}

/* Seven spheres under min: pruning removes branches, and boxes reached by
 * different paths must still be decided alike. */
#define SPHERES                                                               \
    "min(sqrt((x-0.3)^2+y^2+z^2)-0.35, sqrt((x+0.3)^2+y^2+z^2)-0.3,"          \
    " sqrt(x^2+(y-0.4)^2+z^2)-0.25, sqrt(x^2+(y+0.45)^2+(z-0.1)^2)-0.3,"       \
    " sqrt((x-0.5)^2+(y-0.5)^2+(z-0.5)^2)-0.2, sqrt(x^2+y^2+(z+0.6)^2)-0.3,"  \
    " sqrt((x+0.6)^2+(y+0.6)^2+(z-0.4)^2)-0.15)"
#define SCENE2 "sin(4*theta)*sin(8*phi) - r"

Test(subdiv, any_order_and_kernel_gives_the_serial_voxels)
{
    /* CSG whose min/max choices change down to the last levels (thin slab,
     * close spheres): tapes are rewritten between neighbouring voxels, which
     * the serial walk's gradient batches must follow */
    const char *csg = "max(min(sqrt((x-0.1)^2+y^2+z^2)-0.3, sqrt((x+0.12)^2+y^2+z^2)-0.3,"
                      " abs(y)-0.05), -(sqrt(x^2+y^2+(z-0.2)^2)-0.2), z-0.45)";
    const char *src[] = {SPHERES, SCENE2, SPHERE, csg};
    const uint32_t res[] = {64, 64, 50, 64};
    for (int s = 0; s < 4; s++) {
        grid_spec g = cube_grid(1, res[s]);
        tree ref, got;
        serial(src[s], &g, &ref);
        for (int stop = 0; stop <= 3; stop += 3) {
            uint64_t tested;
            shuffled(src[s], &g, stop, 17u + (unsigned)stop, &got, &tested);
            assert_same(&ref, &got);
            free(got.arena);
        }
        free(ref.arena);
    }
}

/* In depth-first order the kernel rarely rebuilds a chain; in random order
 * it does, and the boxes tested stay the same. */
Test(subdiv, chain_rebuilds_are_cheap_in_dfs_order)
{
    grid_spec g = cube_grid(1, 64);
    expr_tape *tape = compile(SPHERES);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(tape, g.depth, &vm), 0);
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, &g);
    bag b = {0};
    subdiv_sink s = {.voxel = bag_voxel, .ud = &b};
    cr_assert_eq(subdiv_subtree(&k, grid_root(&g), &s), 0);
    cr_assert_eq(k.rebuilt, 0);
    uint64_t serial_tested = k.tested;
    tree got;
    uint64_t tested;
    shuffled(SPHERES, &g, 0, 3, &got, &tested);
    cr_assert_eq(tested, serial_tested);
    cr_assert_eq(got.t.voxels, b.nv);
    free(got.arena);
    free(b.v);
    expr_vm_free(vm);
    expr_tape_free(tape);
}

static int stop_after_10(void *ud, const grid_voxel *v)
{
    (void)v;
    return ++*(int *)ud == 10 ? -ECANCELED : 0;
}

Test(subdiv, a_sink_can_stop_the_kernel)
{
    grid_spec g = cube_grid(1, 32);
    expr_tape *tape = compile(SPHERE);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(tape, g.depth, &vm), 0);
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, &g);
    int n = 0;
    subdiv_sink s = {.voxel = stop_after_10, .ud = &n};
    cr_assert_eq(subdiv_subtree(&k, grid_root(&g), &s), -ECANCELED);
    cr_assert_eq(n, 10);
    expr_vm_free(vm);
    expr_tape_free(tape);
}

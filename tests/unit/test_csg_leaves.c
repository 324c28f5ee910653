/* CSG trees with implicit, mesh and VOD leaves against a slow dense
 * evaluator written here from the definitions (docs/csg.md), not from the
 * code: every voxel of the grid (and a margin for the dilation) computed
 * node by node into full arrays.  The mesh leaf is an axis-aligned box, so
 * its density (the mesh voxelizer's 4^3 samples a voxel, half coverage at
 * S) is a product of per-axis sample counts; the VOD leaf is a density
 * file on another grid, read back here voxel by voxel at each job voxel's
 * centre.  The serial path and 2 workers give the file the reference
 * holds; and bad leaves fail the job typed. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "engine.h"
#include "grid.h"
#include "pipeline.h"
#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

#define N 48          /* the job's voxels per axis over [-1, 1] */
#define MG 1          /* margin: the dilation's k */
#define M (N + 2 * MG)
#define IDX(x, y, z) ((size_t)((x) + MG) + M * ((size_t)((y) + MG) + M * (size_t)((z) + MG)))

static const float box_lo[3] = {-0.53f, -0.41f, -0.37f}, box_hi[3] = {0.47f, 0.59f, 0.63f};

/* The box as an OBJ text, outward faces. */
static char *box_obj(size_t *len)
{
    char *s = malloc(4096);
    int n = 0;
    for (int i = 0; i < 8; i++)
        n += sprintf(s + n, "v %.9g %.9g %.9g\n", (double)(i & 1 ? box_hi[0] : box_lo[0]),
                     (double)(i & 2 ? box_hi[1] : box_lo[1]),
                     (double)(i & 4 ? box_hi[2] : box_lo[2]));
    static const int f[12][3] = {{1, 3, 4}, {1, 4, 2}, {5, 6, 8}, {5, 8, 7}, {1, 2, 6},
                                 {1, 6, 5}, {3, 7, 8}, {3, 8, 4}, {1, 5, 7}, {1, 7, 3},
                                 {2, 4, 8}, {2, 8, 6}};
    for (int i = 0; i < 12; i++) n += sprintf(s + n, "f %d %d %d\n", f[i][0], f[i][1], f[i][2]);
    *len = (size_t)n;
    return s;
}

static engine_pipeline_job csg_job(const csg_tree *t, double lo, double hi, uint32_t res)
{
    engine_pipeline_job job = {.kind = &engine_kind_csg, .csg = {.tree = t, .source_bytes = 1},
                        .lo = {lo, lo, lo}, .hi = {hi, hi, hi}, .res = res};
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_DENSITY;
    return job;
}

static csg_tree *parse(const char *text)
{
    csg_tree *t;
    csg_error err;
    cr_assert_eq(csg_parse(text, strlen(text), &t, &err), 0, "%d:%d %s", err.line, err.col,
                 err.msg);
    return t;
}

static vod_membuf run(engine *e, const engine_pipeline_job *job)
{
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(e, job, &sink, &r), 0, "%s", r.err.msg);
    return m;
}

/* The node named name's index. */
static uint32_t node_of(const csg_tree *t, const char *name)
{
    for (uint32_t i = 0; i < t->n; i++)
        if (!strcmp(t->node[i].name, name)) return i;
    cr_assert_fail("no node %s", name);
    return 0;
}

static void attach(csg_tree *t, const char *name, const void *data, size_t len)
{
    uint32_t i = node_of(t, name);
    t->data[i] = malloc(len);
    memcpy(t->data[i], data, len);
    t->data_len[i] = len;
}

/* ---- the reference, from the definitions ---- */

static double centre(double vs, int x) { return -1.0 + (x + 0.5) * vs; }

/* implicit "z - 0.1" domain -0.8,0.8: S + 128 t, t = -F / |grad F| / vs. */
static uint8_t ref_plane(double vs, int x, int y, int z)
{
    double p[3] = {centre(vs, x), centre(vs, y), centre(vs, z)};
    for (int a = 0; a < 3; a++)
        if (!(p[a] >= -0.8 && p[a] <= 0.8)) return 0;
    double t = -(p[2] - 0.1) / 1.0 / vs;
    double v = 127 + t * 128 / 1.0;
    return !(v > 0) ? 0 : v >= 255 ? 255 : (uint8_t)floor(v);
}

/* Samples of voxel x along axis a (4 per voxel, at their centres) inside
 * the box's slab. */
static int samples_in(double vs, int a, int x)
{
    int c = 0;
    for (int j = 0; j < 4; j++) {
        double s = -1.0 + (4.0 * x + j + 0.5) * vs / 4;
        c += s > box_lo[a] && s < box_hi[a];
    }
    return c;
}

/* The box's density: floor((510 c + 63) / 128) of c samples in 64; 0 off
 * the grid (a leaf's volume covers the grid only). */
static uint8_t ref_box(double vs, int x, int y, int z)
{
    if (x < 0 || y < 0 || z < 0 || x >= N || y >= N || z >= N) return 0;
    int c = samples_in(vs, 0, x) * samples_in(vs, 1, y) * samples_in(vs, 2, z);
    return (uint8_t)((510 * c + 63) / 128);
}

/* The VOD file's voxel holding this voxel's centre; 0 off the job's grid
 * and off the file's. */
static uint8_t ref_vod(const vod_file *f, double vs, int x, int y, int z)
{
    if (x < 0 || y < 0 || z < 0 || x >= N || y >= N || z >= N) return 0;
    const vod_info *in = vod_get_info(f);
    int X[3] = {x, y, z};
    uint32_t i[3];
    for (int a = 0; a < 3; a++) {
        double k = floor((centre(vs, X[a]) - in->origin[a]) / in->voxel_scale[a]);
        if (k < 0 || k >= in->volume[a]) return 0;
        i[a] = (uint32_t)k;
    }
    return (uint8_t)vod_voxel(f, 0, i[0], i[1], i[2]);
}

static int mn(int a, int b) { return a < b ? a : b; }
static int mx(int a, int b) { return a > b ? a : b; }
static int difference(int a, int b)
{
    return a >= 127 && b < 127 ? mx(a - b, 127) : mx(a - b, 0);
}

Test(csg_leaves, implicit_mesh_and_vod_leaves_against_a_dense_evaluator, .timeout = 120)
{
    /* The VOD leaf's file: an ellipsoid's densities on a coarser grid. */
    csg_tree *pt = parse("e = ellipsoid center 0.1,0,0.2 radii 0.45,0.35,0.4\nresult e\n");
    engine_pipeline_job pj = csg_job(pt, -0.9, 0.9, 20);
    vod_membuf prev = run(NULL, &pj);
    csg_tree_free(pt);

    csg_tree *t = parse("plane = implicit \"z - 0.1\" domain -0.8,0.8\n"
                        "box = mesh \"box.obj\"\n"
                        "prev = vod \"prev.vod\"\n"
                        "cut = intersection(box, plane)\n"
                        "hole = difference(cut, prev)\n"
                        "out = union(hole, dilate(intersection(prev, plane), 1))\n"
                        "result out\n");
    size_t olen;
    char *obj = box_obj(&olen);
    attach(t, "box", obj, olen);
    attach(t, "prev", prev.p, prev.n);
    free(obj);

    vod_file *pf;
    err_info err = {0};
    cr_assert_eq(vod_read(prev.p, prev.n, &pf, &err), 0, "%s", err.msg);
    double vs = 2.0 / N;
    uint8_t *plane = malloc((size_t)M * M * M), *box = malloc((size_t)M * M * M),
            *pv = malloc((size_t)M * M * M), *ip = malloc((size_t)M * M * M);
    for (int z = -MG; z < N + MG; z++)
        for (int y = -MG; y < N + MG; y++)
            for (int x = -MG; x < N + MG; x++) {
                size_t k = IDX(x, y, z);
                plane[k] = ref_plane(vs, x, y, z);
                box[k] = ref_box(vs, x, y, z);
                pv[k] = ref_vod(pf, vs, x, y, z);
                ip[k] = (uint8_t)mn(pv[k], plane[k]);
            }

    engine_pipeline_job job = csg_job(t, -1, 1, N);
    vod_membuf serial = run(NULL, &job);
    engine_opts eo = {.workers = 2, .shm_bytes = (size_t)256 << 20};
    engine *e;
    err_info ee = {0};
    cr_assert_eq(engine_create(&eo, &e, &ee), 0, "%s", ee.msg);
    vod_membuf two = run(e, &job);
    engine_destroy(e);
    cr_assert(two.n == serial.n && !memcmp(two.p, serial.p, two.n), "2 workers: other bytes");

    vod_file *f;
    cr_assert_eq(vod_read(serial.p, serial.n, &f, &err), 0, "%s", err.msg);
    uint64_t in_box = 0, cut_by_prev = 0, from_dilation = 0;
    for (int z = 0; z < N; z++)
        for (int y = 0; y < N; y++)
            for (int x = 0; x < N; x++) {
                size_t k = IDX(x, y, z);
                int cut = mn(box[k], plane[k]);
                int hole = difference(cut, pv[k]);
                int dil = 0;
                for (int dz = -1; dz <= 1; dz++)
                    for (int dy = -1; dy <= 1; dy++)
                        for (int dx = -1; dx <= 1; dx++)
                            dil = mx(dil, ip[IDX(x + dx, y + dy, z + dz)]);
                int want = mx(hole, dil);
                in_box += box[k] >= 127;
                cut_by_prev += cut >= 127 && pv[k] >= 127;
                from_dilation += dil > hole;
                cr_assert_eq(vod_voxel(f, 0, (uint32_t)x, (uint32_t)y, (uint32_t)z),
                             (uint32_t)want, "voxel (%d,%d,%d): box %u plane %u vod %u",
                             x, y, z, box[k], plane[k], pv[k]);
            }
    /* every leaf matters somewhere */
    cr_assert_gt(in_box, 1000);
    cr_assert_gt(cut_by_prev, 100);
    cr_assert_gt(from_dilation, 100);
    vod_close(f);
    vod_close(pf);
    free(plane), free(box), free(pv), free(ip);
    free(serial.p), free(two.p), free(prev.p);
    csg_tree_free(t);
}

/* fit and scale place the mesh: the box fitted at a point with its
 * longest side made 0.5 is the cuboid of the same place and size, up to
 * the ramp (so the voxels at or above S agree but for the faces). */
/* The VOD leaf alone (csg_leaf_build): each job voxel the density of the
 * file's level-0 voxel that holds its centre, by the test's own lookup
 * (vod_voxel at the centre's floor'd index); occupancy and surface voxels
 * H where set.  Files of each channel (1, 8 and 32 bits) on a coarse and a
 * fine grid, job grids coarser and finer than them, over the domain and
 * shifted half out of it, by 1, 2 and 3 threads (the threads take rows of
 * bricks in turn, a brick under no file brick is skipped, a file voxel
 * read again by a finer grid is not looked up again: none may change a
 * voxel). */
static void leaf_matches(const vod_membuf *file, const grid_spec *g, unsigned threads)
{
    csg_tree *t = parse("v = vod \"v.vod\"\nresult v\n");
    attach(t, "v", file->p, file->n);
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(file->p, file->n, &f, &err), 0, "%s", err.msg);
    const vod_info *in = vod_get_info(f);
    size_t bytes = vod_volume_bytes(g->res, 8, CSG_VOLUME_BRICK, UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *vol;
    cr_assert_eq(vod_volume_init(&vol, arena, bytes, g->res, 8, CSG_VOLUME_BRICK), 0);
    cr_assert_eq(csg_leaf_build(t, 0, g, vol, threads, &err), 0, "%s", err.msg);
    uint64_t set = 0;
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++) {
                uint32_t v[3] = {x, y, z}, i[3], want = 0;
                int inside = 1;
                for (int a = 0; a < 3; a++) {
                    double k = floor((grid_coord(g, a, v[a] + 0.5) - in->origin[a]) /
                                     in->voxel_scale[a]);
                    inside &= k >= 0 && k < in->volume[a];
                    i[a] = inside ? (uint32_t)k : 0;
                }
                uint32_t fv = inside ? vod_voxel(f, 0, i[0], i[1], i[2]) : 0;
                want = in->channel == VOXEL_CH_DENSITY ? fv : fv ? 255 : 0;
                set += want != 0;
                cr_assert_eq(vod_volume_get(vol, x, y, z), want,
                             "channel %u, res %u: voxel %u %u %u", in->channel, g->res[0], x,
                             y, z);
            }
    cr_assert_gt(set, 0, "channel %u, res %u: an empty leaf", in->channel, g->res[0]);
    free(arena);
    vod_close(f);
    csg_tree_free(t);
}

Test(csg_leaves, a_vod_leaf_is_each_job_voxel_s_file_voxel, .timeout = 120)
{
    csg_tree *pt = parse("e = ellipsoid center 0.1,0,0.2 radii 0.45,0.35,0.4\nresult e\n");
    const uint32_t channels[] = {VOXEL_CH_OCCUPANCY, VOXEL_CH_DENSITY, VOXEL_CH_SURFACE};
    const uint32_t file_res[] = {20, 70}, job_res[] = {13, 48, 96};
    const double lo[][3] = {{-1, -1, -1}, {-0.2, -1.3, 0.1}};
    for (size_t c = 0; c < 3; c++)
        for (size_t fr = 0; fr < 2; fr++) {
            engine_pipeline_job pj = csg_job(pt, -0.9, 0.9, file_res[fr]);
            pj.vod.channel = (int)channels[c];
            vod_membuf file = run(NULL, &pj);
            for (size_t jr = 0; jr < 3; jr++)
                for (size_t d = 0; d < 2; d++) {
                    double hi[3] = {lo[d][0] + 2, lo[d][1] + 2, lo[d][2] + 2};
                    grid_spec g;
                    err_info err = {0};
                    cr_assert_eq(grid_make(lo[d], hi, job_res[jr], &g, &err), 0);
                    leaf_matches(&file, &g, 1 + (unsigned)(jr + d) % 3);
                }
            free(file.p);
        }
    csg_tree_free(pt);
}

Test(csg_leaves, a_fitted_mesh_lands_where_it_is_told)
{
    csg_tree *t = parse("m = mesh \"box.obj\" fit 0.2,-0.1,0.05 scale 0.5\nresult m\n");
    size_t olen;
    char *obj = box_obj(&olen);
    attach(t, "m", obj, olen);
    free(obj);
    engine_pipeline_job job = csg_job(t, -1, 1, 40);
    vod_membuf m = run(NULL, &job);
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(m.p, m.n, &f, &err), 0, "%s", err.msg);
    /* the box is 1 x 1 x 1 in the file: fitted, 0.5 on each side */
    double vs = 2.0 / 40, c[3] = {0.2, -0.1, 0.05};
    for (uint32_t z = 0; z < 40; z++)
        for (uint32_t y = 0; y < 40; y++)
            for (uint32_t x = 0; x < 40; x++) {
                double p[3] = {-1 + (x + 0.5) * vs, -1 + (y + 0.5) * vs, -1 + (z + 0.5) * vs};
                double d = 0; /* how far inside the fitted box, in voxels */
                for (int a = 0; a < 3; a++) {
                    double da = (0.25 - fabs(p[a] - c[a])) / vs;
                    d = a ? fmin(d, da) : da;
                }
                uint32_t v = vod_voxel(f, 0, x, y, z);
                if (d > 0.6) cr_assert_eq(v, 255, "(%u,%u,%u) inside", x, y, z);
                if (d < -0.6) cr_assert_eq(v, 0, "(%u,%u,%u) outside", x, y, z);
            }
    vod_close(f);
    free(m.p);
    csg_tree_free(t);
}

/* A leaf whose file does not load fails the job as a bad job, naming the
 * node, serially and on the engine. */
Test(csg_leaves, bad_leaf_files_fail_typed)
{
    csg_tree *t = parse("m = mesh \"x.obj\"\nv = vod \"x.vod\"\nu = union(m, v)\nresult u\n");
    size_t olen;
    char *obj = box_obj(&olen);
    attach(t, "m", obj, olen);
    free(obj);
    attach(t, "v", "not a vod file", 14);
    engine_pipeline_job job = csg_job(t, -1, 1, 16);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    cr_assert_lt(engine_pipeline_run(NULL, &job, &sink, &r), 0);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert(strstr(r.err.msg, "node 'v': vod:"), "%s", r.err.msg);
    engine_opts eo = {.workers = 1, .shm_bytes = (size_t)64 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&eo, &e, &err), 0, "%s", err.msg);
    cr_assert_lt(engine_pipeline_run(e, &job, &sink, &r), 0);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB, "%s", r.err.msg);
    cr_assert(strstr(r.err.msg, "node 'v': vod:"), "%s", r.err.msg);
    free(t->data[node_of(t, "m")]);
    t->data[node_of(t, "m")] = NULL; /* no data: refused too */
    cr_assert_lt(engine_pipeline_run(e, &job, &sink, &r), 0);
    cr_assert(strstr(r.err.msg, "node 'm': no file data"), "%s", r.err.msg);
    engine_destroy(e);
    free(out.p);
    csg_tree_free(t);
}

/* The signed distance of implicit surfaces (csg_dist.c) against closed
 * forms: spheres (F a distance, and F = r^2 - R^2 that is not one), a torus,
 * planes with a gradient of length other than 1.  Every band voxel is
 * within the documented bound: never below the distance (an upper bound,
 * but for the f32 rounding of the oracle), at most CSG_DIST_EPS voxel plus
 * DIST_SLACK above it, of its sign; beyond the band exactly +-W.  Then
 * through the pipeline: vox voxelize's job with channel 4 gives the same
 * bytes without an engine and with 1 and 2 workers, and the file holds the
 * values csg_dist computes, its metadata the band. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "engine.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

/* What the oracle's own rounding and the foot point's convergence may add
 * (in voxels) to CSG_DIST_EPS. */
#define DIST_SLACK 1e-4

typedef double (*oracle)(const double p[3]);

static double sphere(const double p[3]) { return sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) - 0.8; }

static double torus(const double p[3])
{
    double q = sqrt(p[0] * p[0] + p[1] * p[1]) - 0.6;
    return sqrt(q * q + p[2] * p[2]) - 0.25;
}

static double plane(const double p[3])
{
    return (0.3 * p[0] + 0.4 * p[1] - 0.5 * p[2] - 0.1) / sqrt(0.5);
}

static double off_sphere(const double p[3])
{
    return sqrt((p[0] - 0.1) * (p[0] - 0.1) + p[1] * p[1] + (p[2] + 0.05) * (p[2] + 0.05)) - 0.55;
}

static grid_spec grid64(uint32_t res)
{
    grid_spec g;
    err_info err = {0};
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    return g;
}

/* Every voxel of the grid against the oracle; returns the band voxels. */
static uint64_t check_shape(const char *src, oracle d_of, uint32_t res, uint32_t band)
{
    expr_tape *t;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    grid_spec g = grid64(res);
    csg_dist *d;
    cr_assert_eq(csg_dist_new(t, &g, band, &d), 0);
    const uint32_t n = 16;
    float *out = malloc(n * n * n * sizeof *out);
    double w = (float)(band * g.vs), worst = 0;
    uint64_t in_band = 0;
    uint32_t b[3];
    for (b[2] = 0; b[2] < res; b[2] += n)
        for (b[1] = 0; b[1] < res; b[1] += n)
            for (b[0] = 0; b[0] < res; b[0] += n) {
                cr_assert_eq(csg_dist_brick(d, b, n, out), 0);
                for (uint32_t k = 0; k < n * n * n; k++) {
                    double p[3] = {grid_coord(&g, 0, b[0] + k % n + 0.5),
                                   grid_coord(&g, 1, b[1] + k / n % n + 0.5),
                                   grid_coord(&g, 2, b[2] + k / n / n + 0.5)};
                    double want = d_of(p), got = out[k];
                    if (fabs(want) >= w) { /* beyond the band: +-W, the sign right */
                        cr_assert(fabs(got) <= w, "%s at (%g,%g,%g): %g past W %g", src, p[0],
                                  p[1], p[2], got, w);
                        cr_assert(got * want > 0, "%s at (%g,%g,%g): %g, distance %g", src,
                                  p[0], p[1], p[2], got, want);
                        if (fabs(want) > w + 2e-3 * g.vs)
                            cr_assert_eq(fabs(got), w, "%s: %g beyond the band", src, got);
                        continue;
                    }
                    in_band++;
                    cr_assert(got * want > 0 || got == 0, "%s at (%g,%g,%g): sign of %g, distance %g",
                              src, p[0], p[1], p[2], got, want);
                    double err = (fabs(got) - fabs(want)) / g.vs;
                    if (fabs(got) == w) continue; /* capped: want < W <= got */
                    cr_assert(err >= -DIST_SLACK && err <= CSG_DIST_EPS + DIST_SLACK,
                              "%s at (%g,%g,%g): %.9g, distance %.9g (%g voxel)", src, p[0],
                              p[1], p[2], got, want, err);
                    if (fabs(err) > worst) worst = fabs(err);
                }
            }
    cr_log_info("%s: %llu band voxels, worst %.3g voxel, %llu by projection, %llu marched",
                src, (unsigned long long)in_band, worst,
                (unsigned long long)csg_dist_get_stats(d)->projected,
                (unsigned long long)csg_dist_get_stats(d)->marched);
    free(out);
    csg_dist_free(d);
    expr_tape_free(t);
    return in_band;
}

Test(csg_dist, sphere_distance_function)
{
    cr_assert_gt(check_shape("sqrt(x^2 + y^2 + z^2) - 0.8", sphere, 64, 3), 10000);
}

Test(csg_dist, sphere_not_a_distance)
{
    /* |grad F| = 2r: F / |grad F| alone is off; the projection is not */
    cr_assert_gt(check_shape("x^2 + y^2 + z^2 - 0.64", sphere, 64, 3), 10000);
    cr_assert_gt(check_shape("5 * ((x-0.1)^2 + y^2 + (z+0.05)^2 - 0.3025)", off_sphere, 64, 2),
                 5000);
}

Test(csg_dist, torus)
{
    cr_assert_gt(check_shape("sqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25", torus, 64, 3), 10000);
    /* the quartic: not a distance, the same zero set */
    cr_assert_gt(check_shape("(x^2 + y^2 + z^2 + 0.6^2 - 0.25^2)^2 - 4 * 0.6^2 * (x^2 + y^2)",
                             torus, 64, 3),
                 10000);
}

Test(csg_dist, planes)
{
    cr_assert_gt(check_shape("0.3*x + 0.4*y - 0.5*z - 0.1", plane, 64, 3), 10000);
    cr_assert_gt(check_shape("3*x + 4*y - 5*z - 1", plane, 64, 1), 3000);
    cr_assert_gt(check_shape("0.3*x + 0.4*y - 0.5*z - 0.1", plane, 32, 5), 2000);
}

Test(csg_dist, bad_band)
{
    expr_tape *t;
    expr_error ee;
    cr_assert_eq(expr_compile("x", 1, NULL, &t, &ee), 0);
    grid_spec g = grid64(16);
    csg_dist *d;
    cr_assert_eq(csg_dist_new(t, &g, 0, &d), -EINVAL);
    cr_assert_eq(csg_dist_new(t, &g, CSG_DIST_MAX_BAND + 1, &d), -EINVAL);
    expr_tape_free(t);
}

/* The standard shapes: every voxel of the grid (band or not) has F's sign
 * at its centre, or is 0 where F there is within rounding of 0. */
Test(csg_dist, no_wrong_sign_on_the_examples)
{
    static const char *const names[] = {"sphere.vx", "torus.vx", "blend2.vx", "union64.vx",
                                        "scene1.vx", "scene2.vx", "scene3.vx"};
    for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
        char path[512], *src = malloc(65536);
        snprintf(path, sizeof path, "%s/examples/%s", getenv("VOXD_ROOT") ? getenv("VOXD_ROOT") : ".",
                 names[i]);
        FILE *fp = fopen(path, "rb");
        cr_assert(fp, "cannot open %s", path);
        size_t len = fread(src, 1, 65535, fp);
        fclose(fp);
        src[len] = 0;
        expr_tape *t;
        expr_error ee;
        cr_assert_eq(expr_compile(src, len, NULL, &t, &ee), 0, "%s: %s", names[i], ee.msg);
        grid_spec g = grid64(24);
        for (int a = 0; a < 3; a++) g.lo[a] = -1.05; /* the scenes' domain: the others' holds */
        g.vs = 2.1 / 24;
        csg_dist *d;
        cr_assert_eq(csg_dist_new(t, &g, 3, &d), 0);
        float out[8 * 8 * 8];
        uint64_t zeros = 0, negative = 0;
        uint32_t b[3];
        for (b[2] = 0; b[2] < 24; b[2] += 8)
            for (b[1] = 0; b[1] < 24; b[1] += 8)
                for (b[0] = 0; b[0] < 24; b[0] += 8) {
                    cr_assert_eq(csg_dist_brick(d, b, 8, out), 0);
                    for (uint32_t k = 0; k < 512; k++) {
                        double p[3] = {grid_coord(&g, 0, b[0] + k % 8 + 0.5),
                                       grid_coord(&g, 1, b[1] + k / 8 % 8 + 0.5),
                                       grid_coord(&g, 2, b[2] + k / 64 + 0.5)};
                        double f = expr_eval_point(t, p[0], p[1], p[2]);
                        if (isnan(f)) continue;
                        zeros += out[k] == 0;
                        negative += out[k] < 0;
                        cr_assert(out[k] * f > 0 || (out[k] == 0 && fabs(f) < 1e-9),
                                  "%s at (%g,%g,%g): %g where F = %g", names[i], p[0], p[1],
                                  p[2], out[k], f);
                    }
                }
        cr_assert_gt(negative, 20, "%s", names[i]);
        cr_log_info("%s: %llu inside, %llu zero", names[i], (unsigned long long)negative,
                    (unsigned long long)zeros);
        csg_dist_free(d);
        expr_tape_free(t);
        free(src);
    }
}

/* ---- through the pipeline ---- */

static engine *make_engine(int workers)
{
    engine_opts o = {.workers = workers, .shm_bytes = (size_t)256 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    return e;
}

static vod_membuf run(engine *e, const engine_pipeline_job *job)
{
    engine_pipeline_report r;
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    cr_assert_eq(engine_pipeline_run(e, job, &sink, &r), 0, "%s", r.err.msg);
    return m;
}

Test(csg_dist, pipeline_same_bytes_and_values)
{
    static const char src[] = "# a torus\nsqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25\n";
    expr_tape *t;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    engine_pipeline_job job = {.kind = &engine_kind_implicit,
                        .implicit = {.tape = t, .source = src, .source_len = strlen(src),
                                     .source_name = "torus.vx"},
                        .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = 48, .band = 2};
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_DISTANCE;
    vod_membuf m0 = run(NULL, &job);
    for (int w = 1; w <= 2; w++) {
        engine *e = make_engine(w);
        vod_membuf m = run(e, &job);
        cr_assert_eq(m.n, m0.n, "%d workers", w);
        cr_assert_eq(memcmp(m.p, m0.p, m.n), 0, "%d workers", w);
        free(m.p);
        engine_destroy(e);
    }
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(m0.p, m0.n, &f, &err), 0, "%s", err.msg);
    const vod_info *in = vod_get_info(f);
    cr_assert_eq(in->channel, VOXEL_CH_DISTANCE);
    cr_assert(in->flags & VOD_FLAG_FLOAT);
    cr_assert(strstr(in->metadata, "distance_band=2\ndistance_units=world\n"), "%s",
              in->metadata);
    grid_spec g = grid64(48);
    csg_dist *d;
    cr_assert_eq(csg_dist_new(t, &g, 2, &d), 0);
    float want[16 * 16 * 16];
    uint64_t negative = 0;
    uint32_t b[3];
    for (b[2] = 0; b[2] < 48; b[2] += 16)
        for (b[1] = 0; b[1] < 48; b[1] += 16)
            for (b[0] = 0; b[0] < 48; b[0] += 16) {
                cr_assert_eq(csg_dist_brick(d, b, 16, want), 0);
                for (uint32_t k = 0; k < 4096; k++) {
                    uint32_t got = vod_voxel(f, 0, b[0] + k % 16, b[1] + k / 16 % 16, b[2] + k / 256);
                    uint32_t bits;
                    memcpy(&bits, &want[k], 4);
                    cr_assert_eq(got, bits, "voxel %u of brick (%u,%u,%u)", k, b[0], b[1], b[2]);
                    negative += want[k] < 0;
                }
            }
    cr_assert_gt(negative, 1000);
    /* level 1: the f32 mean of the 8 children (spec section 3) */
    for (uint32_t z = 0; z < 24; z += 3)
        for (uint32_t y = 0; y < 24; y += 5)
            for (uint32_t x = 0; x < 24; x++) {
                /* summed in double in child order, rounded once */
                double sum = 0;
                float c, got;
                for (unsigned i = 0; i < 8; i++) {
                    uint32_t u = vod_voxel(f, 0, 2 * x + (i & 1u), 2 * y + (i >> 1 & 1u),
                                           2 * z + (i >> 2 & 1u));
                    memcpy(&c, &u, 4);
                    sum += c;
                }
                uint32_t u = vod_voxel(f, 1, x, y, z);
                memcpy(&got, &u, 4);
                cr_assert_eq(got, (float)(sum / 8), "level 1 (%u,%u,%u)", x, y, z);
            }
    csg_dist_free(d);
    vod_close(f);
    free(m0.p);
    expr_tape_free(t);
}

/* Mesh jobs through the pipeline: the serial reference (mesh_voxelize)
 * and the engine's mesh kind with 1 and 2 workers give the same bytes for
 * every channel, the file holds the voxels a box must have, the engine
 * runs mesh and implicit jobs one after the other, and bad mesh jobs fail
 * typed, at the right stage. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "engine.h"
#include "mesh.h"
#include "mesh_shapes.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

/* The axis-aligned box [lo, hi] (mesh_shapes.h), its mesh in *s. */
static mesh box_mesh(shape *s, const float lo[3], const float hi[3])
{
    double l[3] = {lo[0], lo[1], lo[2]}, h[3] = {hi[0], hi[1], hi[2]};
    shape_init(s);
    shape_box(s, l, h);
    return *shape_finish(s);
}

static engine_pipeline_job mesh_job(const mesh *m, uint32_t res, int channel)
{
    engine_pipeline_job job = {
        .kind = &engine_kind_mesh,
        .mesh = {.mesh = m, .opts = {.mode = MESH_SOLID, .channel = channel},
                 .pad = 1, .fit = 1, .source_name = "box.obj", .source_bytes = 999},
        .res = res,
    };
    vod_params_default(&job.vod);
    job.vod.channel = channel;
    return job;
}

static engine *make_engine(int workers)
{
    engine_opts o = {.workers = workers, .shm_bytes = (size_t)256 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    return e;
}

static vod_membuf run(engine *e, const engine_pipeline_job *job, engine_pipeline_report *r)
{
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    cr_assert_eq(engine_pipeline_run(e, job, &sink, r), 0, "%s job on %s: %s",
                 job->kind == &engine_kind_mesh ? "mesh" : "implicit",
                 e ? "an engine" : "no engine", r->err.msg);
    return m;
}

/* Voxel centres inside a box whose faces lie between voxel centres: the
 * file's level 0 must hold exactly those. */
Test(mesh_engine, a_box_serial_and_on_the_engine)
{
    float lo[3] = {0.1f, 0.2f, 0.3f}, hi[3] = {0.9f, 0.6f, 0.5f};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    static const int channels[] = {VOXEL_CH_OCCUPANCY, VOXEL_CH_DENSITY,
                                   VOXEL_CH_SURFACE};
    engine *e[2] = {make_engine(1), make_engine(2)};
    for (size_t c = 0; c < 3; c++) {
        engine_pipeline_job job = mesh_job(&m, 70, channels[c]);
        engine_pipeline_report r0, r;
        vod_membuf ref = run(NULL, &job, &r0);
        cr_assert_eq(r0.grid.res[0], 70);
        cr_assert_gt(r0.voxels, 0);
        for (int w = 0; w < 2; w++) {
            vod_membuf mb = run(e[w], &job, &r);
            cr_assert_eq(r.voxels, r0.voxels, "channel %d, %d workers", channels[c], w + 1);
            cr_assert(mb.n == ref.n && memcmp(mb.p, ref.p, mb.n) == 0,
                      "channel %d, %d workers: other bytes", channels[c], w + 1);
            cr_assert_gt(r.fig.mesh.vox.tiles, 0);
            free(mb.p);
        }
        if (channels[c] == VOXEL_CH_OCCUPANCY) {
            vod_file *f;
            err_info err = {0};
            cr_assert_eq(vod_read(ref.p, ref.n, &f, &err), 0, "%s", err.msg);
            const grid_spec *g = &r0.grid;
            uint64_t want = 0, got = 0;
            for (uint32_t z = 0; z < g->res[2]; z++)
                for (uint32_t y = 0; y < g->res[1]; y++)
                    for (uint32_t x = 0; x < g->res[0]; x++) {
                        double p[3] = {g->lo[0] + (x + 0.5) * g->vs,
                                       g->lo[1] + (y + 0.5) * g->vs,
                                       g->lo[2] + (z + 0.5) * g->vs};
                        int in = 1;
                        for (int a = 0; a < 3; a++) in &= p[a] > m.lo[a] && p[a] < m.hi[a];
                        want += in;
                        got += vod_voxel(f, 0, x, y, z) != 0;
                        cr_assert_eq(vod_voxel(f, 0, x, y, z) != 0, in,
                                     "voxel (%u,%u,%u)", x, y, z);
                    }
            cr_assert_eq(got, want);
            cr_assert_eq(r0.voxels, want);
            vod_close(f);
        }
        free(ref.p);
    }
    engine_destroy(e[0]);
    engine_destroy(e[1]);
    shape_free(&sh_m);
}

/* One engine, jobs of both kinds in turn: each one's result is its own. */
Test(mesh_engine, mesh_and_implicit_jobs_share_an_engine)
{
    float lo[3] = {-0.5f, -0.5f, -0.5f}, hi[3] = {0.5f, 0.5f, 0.5f};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    const char *src = "x^2 + y^2 + z^2 - 0.5";
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0);
    engine_pipeline_job mj = mesh_job(&m, 40, VOXEL_CH_OCCUPANCY);
    engine_pipeline_job ij = {.kind = &engine_kind_implicit,
                       .implicit = {.tape = t, .source = src, .source_len = strlen(src)},
                       .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = 40};
    vod_params_default(&ij.vod);
    engine_pipeline_report r;
    vod_membuf mref = run(NULL, &mj, &r);
    vod_membuf iref = run(NULL, &ij, &r);
    engine *e = make_engine(2);
    for (int round = 0; round < 2; round++) {
        vod_membuf a = run(e, &mj, &r), b = run(e, &ij, &r);
        cr_assert(a.n == mref.n && memcmp(a.p, mref.p, a.n) == 0, "mesh, round %d", round);
        cr_assert(b.n == iref.n && memcmp(b.p, iref.p, b.n) == 0, "implicit, round %d", round);
        free(a.p);
        free(b.p);
    }
    engine_destroy(e);
    free(mref.p);
    free(iref.p);
    expr_tape_free(t);
    shape_free(&sh_m);
}

Test(mesh_engine, bad_mesh_jobs_fail_typed)
{
    float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    engine_pipeline_job job = mesh_job(&m, 8, VOXEL_CH_OCCUPANCY);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    job.mesh.pad = 4;
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_GRID);
    cr_assert(strstr(r.err.msg, "padding"), "%s", r.err.msg);
    job.mesh.pad = 1;
    uint32_t n = m.n_triangles;
    m.n_triangles = 0;
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    m.n_triangles = n;
    float flat[3] = {1, 1, 1};
    shape sh_pt;
    mesh pt = box_mesh(&sh_pt, flat, flat);
    job.mesh.mesh = &pt;
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert(strstr(r.err.msg, "bounding box"), "%s", r.err.msg);
    shape_free(&sh_pt);
    free(out.p);
    shape_free(&sh_m);
}

/* A volume that cannot fit the segment is a limit, not a crash. */
Test(mesh_engine, a_volume_past_shared_memory_is_a_limit)
{
    float lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    engine_opts o = {.workers = 1, .shm_bytes = (size_t)4 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    engine_pipeline_job job = mesh_job(&m, 1024, VOXEL_CH_SURFACE);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    cr_assert_lt(engine_pipeline_run(e, &job, &sink, &r), 0);
    cr_assert_eq(r.err.kind, ENGINE_LIMIT, "%s", r.err.msg);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_VOXELIZE);
    free(out.p);
    engine_destroy(e);
    shape_free(&sh_m);
}

/* A worker killed while the tiles run: its tile is run again by the one
 * forked in its place, and the file is the serial one. */
typedef struct {
    engine *e;
    int killed;
} killer;

/* At the first report of the tiles' stage (the pipeline gives it the
 * fractions below 0.6), worker 0 is killed if it is there. */
static void kill_first(void *ud, const engine_progress *p)
{
    killer *k = ud;
    pid_t pid = engine_worker_pid(k->e, 0);
    if (k->killed || p->fraction >= 0.6 || pid <= 0) return;
    cr_assert_eq(kill(pid, SIGKILL), 0, "kill worker 0 (pid %d): %s", (int)pid,
                 strerror(errno));
    k->killed = 1;
}

Test(mesh_engine, a_worker_killed_mid_job_changes_nothing)
{
    float lo[3] = {-0.4f, -0.3f, -0.2f}, hi[3] = {0.4f, 0.3f, 0.2f};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    engine_pipeline_job job = mesh_job(&m, 200, VOXEL_CH_OCCUPANCY);
    engine_pipeline_report r0, r;
    vod_membuf ref = run(NULL, &job, &r0);
    engine *e = make_engine(2);
    killer k = {.e = e};
    job.progress = kill_first;
    job.ud = &k;
    vod_membuf mb = run(e, &job, &r);
    cr_assert(k.killed, "no progress report came while the tiles ran");
    cr_assert(mb.n == ref.n && memcmp(mb.p, ref.p, mb.n) == 0, "other bytes");
    cr_assert_eq(r.voxels, r0.voxels);
    free(mb.p);
    free(ref.p);
    engine_destroy(e);
    shape_free(&sh_m);
}

/* A repair asked of a watertight mesh is not run: the same voxels as the
 * plain solid, the report says so; a mesh with a hole runs it and counts
 * where its parities disagree. */
static bool not_every_seventh(uint32_t i, void *ctx)
{
    (void)ctx;
    return i % 7 != 3;
}

Test(mesh_engine, repair_runs_only_where_the_mesh_is_open)
{
    shape s;
    shape_init(&s);
    double c[3] = {0, 0, 0};
    shape_icosphere(&s, c, 1.0, 3, false);
    const mesh *m = shape_finish(&s);
    engine_pipeline_job job = mesh_job(m, 48, VOXEL_CH_OCCUPANCY);
    engine_pipeline_report plain, voted;
    vod_membuf a = run(NULL, &job, &plain);
    cr_assert(plain.fig.mesh.topo.watertight);
    cr_assert_eq(plain.fig.mesh.topo.open, 0);
    cr_assert_not(plain.fig.mesh.repair_skipped);
    job.mesh.opts.repair = MESH_REPAIR_VOTE;
    vod_membuf b = run(NULL, &job, &voted);
    cr_assert(voted.fig.mesh.repair_skipped);
    cr_assert_eq(voted.voxels, plain.voxels);
    free(a.p);
    free(b.p);

    shape_remove(&s, not_every_seventh, NULL);
    engine *e = make_engine(2);
    vod_membuf h0 = run(NULL, &job, &voted), h2 = run(e, &job, &plain);
    cr_assert_not(voted.fig.mesh.topo.watertight);
    cr_assert_gt(voted.fig.mesh.topo.open, 0);
    cr_assert_not(voted.fig.mesh.repair_skipped);
    cr_assert_gt(voted.fig.mesh.vox.disagreements, 0, "a mesh with holes: the parities disagree");
    cr_assert_eq(plain.fig.mesh.vox.disagreements, voted.fig.mesh.vox.disagreements,
                 "engine and serial count alike");
    cr_assert(h0.n == h2.n && memcmp(h0.p, h2.p, h0.n) == 0, "other bytes");
    free(h0.p);
    free(h2.p);
    engine_destroy(e);
    shape_free(&s);
}

/* ---- the grid, from the mesh's coordinates (docs/cli.md, mesh jobs) ----
 * With the mesh's bounding box as domain (fit; the CLI's default), --res N
 * voxels span the longest side of the box grown by --pad voxels each side:
 * the voxel size is the longest side over N - 2 pad, the origin the box's
 * low corner less pad voxels, and the other axes get as many voxels as
 * cover the grown box.  With --bbox (no fit), N voxels span the box's
 * longest side from its low corner.  The expected grid is computed here
 * from the vertices, never from the grid the code returns, and held
 * against the report, the file's trailer and dims, and every voxel of the
 * file (a voxel is set exactly when its centre, placed by the expected
 * grid, is inside the box mesh; the sizes below keep every face at least
 * 0.05 voxel from a centre, and every axis's cover 0.05 voxel from a whole
 * number, so rounding decides nothing). */
typedef struct {
    double vs, lo[3];
    uint32_t dims[3];
} want_grid;

static want_grid expect_fit(const float lo[3], const float hi[3], uint32_t res, uint32_t pad)
{
    want_grid w;
    double ext = 0;
    for (int a = 0; a < 3; a++) ext = fmax(ext, (double)hi[a] - lo[a]);
    w.vs = ext / (res - 2.0 * pad);
    for (int a = 0; a < 3; a++) {
        double span = ((double)hi[a] - lo[a]) / w.vs + 2.0 * pad; /* voxels */
        w.lo[a] = lo[a] - pad * w.vs;
        w.dims[a] = (uint32_t)ceil(span - 1e-9);
        cr_assert(fabs(span - round(span)) > 0.05 || fabs(span - res) < 1e-9,
                  "the test's sizes: axis %d spans %.4f voxels", a, span);
    }
    return w;
}

static want_grid expect_bbox(const double lo[3], const double hi[3], uint32_t res)
{
    want_grid w;
    double ext = 0;
    for (int a = 0; a < 3; a++) ext = fmax(ext, hi[a] - lo[a]);
    w.vs = ext / res;
    for (int a = 0; a < 3; a++) {
        double span = (hi[a] - lo[a]) / w.vs;
        w.lo[a] = lo[a];
        w.dims[a] = (uint32_t)ceil(span - 1e-9);
        cr_assert(fabs(span - round(span)) > 0.05 || span == round(span),
                  "the test's sizes: axis %d spans %.4f voxels", a, span);
    }
    return w;
}

/* The job's report, file and voxels against the expected grid w. */
static void check_grid(const engine_pipeline_job *job, const want_grid *w, const float blo[3],
                       const float bhi[3], const char *what)
{
    /* a face this close to a centre would leave the voxel to rounding */
    for (int a = 0; a < 3; a++)
        for (int side = 0; side < 2; side++) {
            double f = ((double)(side ? bhi[a] : blo[a]) - w->lo[a]) / w->vs - 0.5;
            cr_assert_gt(fabs(f - round(f)), 0.05, "%s: the test's sizes, axis %d", what, a);
        }
    engine_pipeline_report r;
    vod_membuf mb = run(NULL, job, &r);
    const double tol = 1e-9 * w->vs;
    cr_assert(fabs(r.grid.vs - w->vs) < tol, "%s: voxel size %.17g, want %.17g", what,
              r.grid.vs, w->vs);
    for (int a = 0; a < 3; a++) {
        cr_assert(fabs(r.grid.lo[a] - w->lo[a]) < tol, "%s: origin %d %.17g, want %.17g", what,
                  a, r.grid.lo[a], w->lo[a]);
        cr_assert_eq(r.grid.res[a], w->dims[a], "%s: axis %d has %u voxels, want %u", what, a,
                     r.grid.res[a], w->dims[a]);
    }
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(mb.p, mb.n, &f, &err), 0, "%s", err.msg);
    const vod_info *in = vod_get_info(f);
    uint32_t dims[3];
    cr_assert_eq(vod_level_dims(f, 0, dims), 0);
    for (int a = 0; a < 3; a++) {
        /* the trailer's floats: within their rounding */
        cr_assert(fabs(in->origin[a] - w->lo[a]) <= 1e-6 * (fabs(w->lo[a]) + w->vs), "%s: file origin %d %.9g, want %.9g",
                  what, a, in->origin[a], w->lo[a]);
        cr_assert(fabs(in->voxel_scale[a] - w->vs) <= 1e-6 * w->vs, "%s: file voxel %d %.9g, want %.9g",
                  what, a, in->voxel_scale[a], w->vs);
        cr_assert_eq(dims[a], w->dims[a], "%s: file axis %d has %u voxels, want %u", what, a,
                     dims[a], w->dims[a]);
    }
    uint64_t set = 0;
    for (uint32_t z = 0; z < w->dims[2]; z++)
        for (uint32_t y = 0; y < w->dims[1]; y++)
            for (uint32_t x = 0; x < w->dims[0]; x++) {
                uint32_t X[3] = {x, y, z};
                int in_box = 1;
                for (int a = 0; a < 3; a++) {
                    double c = w->lo[a] + (X[a] + 0.5) * w->vs;
                    in_box &= c > blo[a] && c < bhi[a];
                }
                int got = vod_voxel(f, 0, x, y, z) != 0;
                set += got;
                cr_assert_eq(got, in_box, "%s: voxel (%u,%u,%u) is %d", what, x, y, z, got);
            }
    cr_assert_gt(set, 100, "%s: only %llu voxels set", what, (unsigned long long)set);
    vod_close(f);
    free(mb.p);
}

Test(mesh_engine, the_grid_from_the_mesh_coordinates)
{
    /* the box spans 0.83 x 0.553 x 0.366 from (0.11, -0.23, 0.31): x longest */
    float lo[3] = {0.11f, -0.23f, 0.31f}, hi[3] = {0.94f, 0.323f, 0.676f};
    shape sh_m;
    mesh m = box_mesh(&sh_m, lo, hi);
    static const uint32_t cases[][2] = {{40, 1}, {40, 0}, {37, 3}, {50, 6}};
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        engine_pipeline_job job = mesh_job(&m, cases[i][0], VOXEL_CH_OCCUPANCY);
        job.mesh.pad = cases[i][1];
        want_grid w = expect_fit(m.lo, m.hi, cases[i][0], cases[i][1]);
        char what[64];
        snprintf(what, sizeof what, "res %u pad %u", cases[i][0], cases[i][1]);
        check_grid(&job, &w, m.lo, m.hi, what);
    }
    /* --bbox: the box given, its longest side (z here) res voxels, the
     * mesh cut by it */
    static const double blo[3] = {0.3, -0.1, 0.2}, bhi[3] = {0.8, 0.25, 1.0};
    engine_pipeline_job job = mesh_job(&m, 45, VOXEL_CH_OCCUPANCY);
    job.mesh.fit = 0;
    memcpy(job.lo, blo, sizeof blo);
    memcpy(job.hi, bhi, sizeof bhi);
    want_grid w = expect_bbox(blo, bhi, 45);
    check_grid(&job, &w, m.lo, m.hi, "bbox");
    /* a box whose sides are whole numbers of voxels, exactly (1, 1/2 and
     * 1/4 over voxels of 1/32): 32 x 16 x 8 voxels, no voxel more */
    static const double elo[3] = {0.140625, -0.25, 0.375}, ehi[3] = {1.140625, 0.25, 0.625};
    memcpy(job.lo, elo, sizeof elo);
    memcpy(job.hi, ehi, sizeof ehi);
    job.res = 32;
    w = expect_bbox(elo, ehi, 32);
    cr_assert(w.dims[0] == 32 && w.dims[1] == 16 && w.dims[2] == 8);
    check_grid(&job, &w, m.lo, m.hi, "exact bbox");
    shape_free(&sh_m);
}

/* Long work is not a stall: a winding-number tile that runs far longer
 * than the stall timeout ticks its worker's heartbeat, is not killed, and
 * writes the serial reference's bytes.  (Before the tiles ticked, the
 * same job failed: "mesh tile 0 stalled or killed its worker twice".) */
Test(mesh_engine, a_long_winding_tile_ticks_and_is_not_killed, .timeout = 600)
{
    shape s;
    shape_init(&s);
    double c[3] = {0, 0, 0};
    shape_icosphere(&s, c, 1.0, 4, false);
    shape_remove(&s, not_every_seventh, NULL);
    const mesh *m = shape_finish(&s);
    engine_pipeline_job job = mesh_job(m, 56, VOXEL_CH_OCCUPANCY); /* one tile */
    job.mesh.opts.repair = MESH_REPAIR_WINDING;

    /* a worker pinned to a CPU of a loaded machine (load 25 on 2 cores)
     * was seen to wait over a second for it: with less than 2 s, such a
     * machine would kill a worker that ticks */
    const double stall = 2.0;
    mesh_wind_exact = 1; /* the exact sum, seconds of work (the workers fork below) */
    engine_opts o = {.workers = 1, .shm_bytes = (size_t)256 << 20, .stall_timeout = stall};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    engine_pipeline_report r0, r;
    vod_membuf ref = run(NULL, &job, &r0), got = {0};
    vod_sink sink = {vod_mem_write, &got};
    int rc = engine_pipeline_run(e, &job, &sink, &r);
    engine_worker_info in;
    cr_assert_eq(engine_worker_info_get(e, 0, &in), 0);
    cr_assert_eq(rc, 0, "%s (quiet %.3f s, state %c)", r.err.msg, in.stalled_quiet,
                 in.stalled_state);
    cr_log_info("the tile: %.3f s, serially %.3f s", r.t_voxelize, r0.t_voxelize);
    cr_assert_geq(r.t_voxelize, 3 * stall, "the tile took %.3f s: not a long one", r.t_voxelize);
    cr_assert_gt(r.fig.mesh.vox.disagreements, 0);
    cr_assert_eq(in.stalls, 0, "the worker was taken for stalled");
    cr_assert_eq(in.replaced, 0);
    cr_assert_eq(r.stalls, 0);
    cr_assert(got.n == ref.n && memcmp(got.p, ref.p, ref.n) == 0, "other bytes");
    free(ref.p);
    free(got.p);
    engine_destroy(e);
    mesh_wind_exact = 0;
    shape_free(&s);
}

/* The tree of the repair by winding numbers is built by each worker: the
 * same bytes from 0, 1 and 2 workers, in the solid and the density. */
Test(mesh_engine, winding_repair_same_bytes_for_any_workers, .timeout = 600)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.01, 0.02, -0.03};
    shape_icosphere(&s, c, 1.0, 4, false);
    shape_remove(&s, not_every_seventh, NULL);
    const mesh *m = shape_finish(&s);
    engine *e[2] = {make_engine(1), make_engine(2)};
    static const int channels[] = {VOXEL_CH_OCCUPANCY, VOXEL_CH_DENSITY};
    for (int k = 0; k < 2; k++) {
        engine_pipeline_job job = mesh_job(m, k ? 70 : 100, channels[k]); /* 4 tiles each */
        job.mesh.opts.repair = MESH_REPAIR_WINDING;
        engine_pipeline_report r0, r;
        vod_membuf ref = run(NULL, &job, &r0);
        cr_assert_gt(r0.fig.mesh.vox.disagreements, 0);
        for (int w = 0; w < 2; w++) {
            vod_membuf got = run(e[w], &job, &r);
            cr_assert_eq(r.fig.mesh.vox.disagreements, r0.fig.mesh.vox.disagreements);
            cr_assert(got.n == ref.n && memcmp(got.p, ref.p, ref.n) == 0,
                      "channel %d, %d workers: other bytes", channels[k], w + 1);
            free(got.p);
        }
        free(ref.p);
    }
    engine_destroy(e[0]);
    engine_destroy(e[1]);
    shape_free(&s);
}

/* An open tube along z (its wall alone, no ends), as tall as it is wide:
 * the voxels around its axis are inside by the winding number (about
 * 0.7), and no triangle crosses their columns, so their tiles (the middle
 * ones of 4 x 4) have no triangle in their bins.  The winding repair takes
 * the parities along x and y from the caps, not from rows of triangles:
 * such a tile must still run on the engine as it does without one (it did
 * not, once: the middle went empty with workers). */
Test(mesh_engine, an_open_tube_is_filled_by_its_empty_tiles, .timeout = 600)
{
    shape s;
    shape_init(&s);
    enum { SIDES = 96, RINGS = 4 };
    for (int k = 0; k <= RINGS; k++)
        for (int i = 0; i < SIDES; i++) {
            double a = 2 * M_PI * i / SIDES;
            shape_vertex(&s, cos(a), sin(a), -1 + 2.0 * k / RINGS);
        }
    for (int k = 0; k < RINGS; k++)
        for (int i = 0; i < SIDES; i++) {
            uint32_t a = (uint32_t)(k * SIDES + i), b = (uint32_t)(k * SIDES + (i + 1) % SIDES);
            shape_quad(&s, a, b, b + SIDES, a + SIDES);
        }
    const mesh *m = shape_finish(&s);
    engine *e[2] = {make_engine(1), make_engine(2)};
    engine_pipeline_job job = mesh_job(m, 256, VOXEL_CH_OCCUPANCY);
    job.mesh.opts.repair = MESH_REPAIR_WINDING;
    engine_pipeline_report r0, r;
    vod_membuf ref = run(NULL, &job, &r0);
    /* the middle is filled: most of the tube's inside */
    double inside = (double)r0.voxels / (M_PI * 127.0 * 127.0 * 254.0);
    cr_assert(inside > 0.5, "%.3f of the tube's inside is filled", inside);
    for (int w = 0; w < 2; w++) {
        vod_membuf got = run(e[w], &job, &r);
        cr_assert_eq(r.voxels, r0.voxels, "%d workers", w + 1);
        cr_assert(got.n == ref.n && memcmp(got.p, ref.p, ref.n) == 0, "%d workers: other bytes",
                  w + 1);
        free(got.p);
    }
    free(ref.p);
    engine_destroy(e[0]);
    engine_destroy(e[1]);
    shape_free(&s);
}

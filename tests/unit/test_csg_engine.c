/* CSG jobs through the pipeline: the serial evaluation (no engine) and the
 * engine's csg kind with 1 and 2 workers give the same bytes for the
 * density and the occupancy, the file holds the serial volume's voxels, a
 * worker killed while the bricks run changes nothing, csg and implicit
 * jobs share an engine, and bad csg jobs fail typed. */
#include <criterion/criterion.h>
#include <errno.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "engine.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

static const char tree_text[] =
    "base = cuboid center 0.05,0,0 size 1.5,1.0,0.7 rotate 0,0,20\n"
    "hole = cylinder radius 0.3 height 2 axis z\n"
    "bump = implicit \"x^2 + y^2 + (z-0.3)^2 - 0.2\" domain -1,1\n"
    "egg  = ellipsoid center 0.4,0.3,-0.2 radii 0.3,0.2,0.25\n"
    "out  = difference(union(base, bump), hole)\n"
    "out2 = union(out, dilate(egg, 2))\n"
    "result out2\n";

static csg_tree *parse(const char *text)
{
    csg_tree *t;
    csg_error err;
    cr_assert_eq(csg_parse(text, strlen(text), &t, &err), 0, "%d:%d %s", err.line, err.col,
                 err.msg);
    return t;
}

static engine_pipeline_job csg_job(const csg_tree *t, uint32_t res, int channel)
{
    engine_pipeline_job job = {.kind = &engine_kind_csg,
                        .csg = {.tree = t, .source_name = "part.csg",
                                .source_bytes = sizeof tree_text - 1},
                        .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = res};
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
    cr_assert_eq(engine_pipeline_run(e, job, &sink, r), 0, "csg job on %s: %s",
                 e ? "an engine" : "no engine", r->err.msg);
    return m;
}

/* The file's level 0 against the tree evaluated brick by brick here, as
 * densities for the whole grid first: occupancy is density >= S; a
 * surface voxel is occupied there, and (away from the grid's faces) its
 * normal minus the densities' central differences.  Returns the voxels at
 * or above S. */
static uint64_t assert_voxels(const vod_membuf *m, const csg_tree *t, const grid_spec *g,
                              int channel)
{
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(m->p, m->n, &f, &err), 0, "%s", err.msg);
    csg_eval *ev;
    cr_assert_eq(csg_eval_new(t, g, 8, NULL, &ev), 0);
    uint32_t X = g->res[0], Y = g->res[1], Z = g->res[2];
    uint8_t *d = malloc((size_t)X * Y * Z), buf[512];
    uint32_t b[3];
    for (b[2] = 0; b[2] * 8 < Z; b[2]++)
        for (b[1] = 0; b[1] * 8 < Y; b[1]++)
            for (b[0] = 0; b[0] * 8 < X; b[0]++) {
                int uniform;
                uint8_t v;
                cr_assert_eq(csg_eval_brick(ev, b, buf, &uniform, &v), 0);
                for (uint32_t k = 0; k < 512; k++) {
                    uint32_t x = b[0] * 8 + k % 8, y = b[1] * 8 + k / 8 % 8,
                             z = b[2] * 8 + k / 64;
                    if (x < X && y < Y && z < Z)
                        d[x + (size_t)X * (y + (size_t)Y * z)] = uniform ? v : buf[k];
                }
            }
    uint64_t solid = 0, normals = 0;
    for (uint32_t z = 0; z < Z; z++)
        for (uint32_t y = 0; y < Y; y++)
            for (uint32_t x = 0; x < X; x++) {
                const uint8_t *c = d + x + (size_t)X * (y + (size_t)Y * z);
                uint32_t want = *c, got = vod_voxel(f, 0, x, y, z);
                solid += want >= CSG_S;
                if (channel == VOXEL_CH_OCCUPANCY) want = want >= CSG_S;
                if (channel == VOXEL_CH_SURFACE) {
                    cr_assert_eq(voxel_occupancy(got), *c >= CSG_S ? 255u : 0u,
                                 "voxel (%u,%u,%u)", x, y, z);
                    int edge = !x || !y || !z || x + 1 == X || y + 1 == Y || z + 1 == Z;
                    if (*c < CSG_S || edge) continue;
                    double n[3] = {(double)c[-1] - c[1], (double)c[-(ptrdiff_t)X] - c[X],
                                   (double)c[-(ptrdiff_t)X * Y] - c[(size_t)X * Y]};
                    want = voxel_surface(n);
                    normals += n[0] != 0 || n[1] != 0 || n[2] != 0;
                }
                cr_assert_eq(got, want, "voxel (%u,%u,%u)", x, y, z);
            }
    if (channel == VOXEL_CH_SURFACE) cr_assert_gt(normals, 100, "normals checked");
    free(d);
    csg_eval_free(ev);
    vod_close(f);
    return solid;
}

Test(csg_engine, serial_and_one_and_two_workers_give_the_same_bytes)
{
    csg_tree *t = parse(tree_text);
    engine *e[2] = {make_engine(1), make_engine(2)};
    static const int channels[] = {VOXEL_CH_DENSITY, VOXEL_CH_OCCUPANCY, VOXEL_CH_SURFACE};
    for (size_t c = 0; c < 3; c++) {
        /* 75: bricks cut by the grid's edge on every axis */
        engine_pipeline_job job = csg_job(t, 75, channels[c]);
        engine_pipeline_report r0, r;
        vod_membuf ref = run(NULL, &job, &r0);
        cr_assert_gt(r0.fig.csg.bricks, 0);
        cr_assert_gt(r0.fig.csg.uniform, 0, "most of the box is empty");
        cr_assert_lt(r0.fig.csg.uniform, r0.fig.csg.bricks);
        uint64_t solid = assert_voxels(&ref, t, &r0.grid, channels[c]);
        cr_assert_gt(solid, 0);
        cr_assert_eq(r0.voxels, solid, "the report counts the voxels at or above S");
        for (int w = 0; w < 2; w++) {
            vod_membuf mb = run(e[w], &job, &r);
            cr_assert(mb.n == ref.n && memcmp(mb.p, ref.p, mb.n) == 0,
                      "channel %d, %d workers: other bytes", channels[c], w + 1);
            cr_assert_eq(r.fig.csg.bricks, r0.fig.csg.bricks);
            cr_assert_eq(r.fig.csg.uniform, r0.fig.csg.uniform);
            cr_assert_eq(r.fig.csg.skipped, r0.fig.csg.skipped);
            cr_assert_eq(r.fig.csg.voxel_evals, r0.fig.csg.voxel_evals);
            cr_assert_eq(r.voxels, r0.voxels, "voxels at or above S");
            /* a run of bricks is short: a worker waiting for the master
             * between two would wait longer than it works */
            cr_assert_gt(r.offered, 0, "%d workers: no run of bricks offered ahead", w + 1);
            free(mb.p);
        }
        free(ref.p);
    }
    engine_destroy(e[0]);
    engine_destroy(e[1]);
    csg_tree_free(t);
}

/* One engine, csg and implicit jobs in turn: each one's result is its own. */
Test(csg_engine, csg_and_implicit_jobs_share_an_engine)
{
    csg_tree *t = parse(tree_text);
    const char *src = "x^2 + y^2 + z^2 - 0.5";
    expr_tape *tape = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &tape, &ee), 0);
    engine_pipeline_job cj = csg_job(t, 40, VOXEL_CH_DENSITY);
    engine_pipeline_job ij = {.kind = &engine_kind_implicit,
                       .implicit = {.tape = tape, .source = src, .source_len = strlen(src)},
                       .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = 40};
    vod_params_default(&ij.vod);
    engine_pipeline_report r;
    vod_membuf cref = run(NULL, &cj, &r), iref = run(NULL, &ij, &r);
    engine *e = make_engine(2);
    for (int round = 0; round < 2; round++) {
        vod_membuf a = run(e, &cj, &r), b = run(e, &ij, &r);
        cr_assert(a.n == cref.n && memcmp(a.p, cref.p, a.n) == 0, "csg, round %d", round);
        cr_assert(b.n == iref.n && memcmp(b.p, iref.p, b.n) == 0, "implicit, round %d", round);
        free(a.p);
        free(b.p);
    }
    engine_destroy(e);
    free(cref.p);
    free(iref.p);
    expr_tape_free(tape);
    csg_tree_free(t);
}

/* A worker killed while the bricks run: its run of bricks is evaluated
 * again by the one forked in its place, and the file is the serial one. */
typedef struct {
    engine *e;
    int killed;
} killer;

static void kill_first(void *ud, const engine_progress *p)
{
    killer *k = ud;
    pid_t pid = engine_worker_pid(k->e, 0);
    if (k->killed || p->fraction >= 0.6 || pid <= 0) return;
    cr_assert_eq(kill(pid, SIGKILL), 0, "kill worker 0 (pid %d): %s", (int)pid,
                 strerror(errno));
    k->killed = 1;
}

Test(csg_engine, a_worker_killed_mid_job_changes_nothing)
{
    csg_tree *t = parse(tree_text);
    engine_pipeline_job job = csg_job(t, 96, VOXEL_CH_DENSITY);
    engine_pipeline_report r0, r;
    vod_membuf ref = run(NULL, &job, &r0);
    engine *e = make_engine(2);
    killer k = {.e = e};
    job.progress = kill_first;
    job.ud = &k;
    vod_membuf mb = run(e, &job, &r);
    cr_assert(k.killed, "no progress report came while the bricks ran");
    cr_assert_geq(r.restarts, 1, "the killed worker was replaced");
    cr_assert(mb.n == ref.n && memcmp(mb.p, ref.p, mb.n) == 0, "other bytes");
    cr_assert_eq(r.fig.csg.bricks, r0.fig.csg.bricks);
    free(mb.p);
    free(ref.p);
    engine_destroy(e);
    csg_tree_free(t);
}

/* A cancel flag set before the job: it stops with ENGINE_CANCELLED and the
 * engine runs the next job. */
Test(csg_engine, a_cancelled_job_fails_typed_and_the_engine_goes_on)
{
    csg_tree *t = parse(tree_text);
    engine_pipeline_job job = csg_job(t, 64, VOXEL_CH_DENSITY);
    atomic_int cancel = 1;
    job.cancel = &cancel;
    engine *e = make_engine(2);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    cr_assert_eq(engine_pipeline_run(e, &job, &sink, &r), -ECANCELED, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_CANCELLED);
    job.cancel = NULL;
    engine_pipeline_report r0;
    vod_membuf ref = run(NULL, &job, &r0), mb = run(e, &job, &r);
    cr_assert(mb.n == ref.n && memcmp(mb.p, ref.p, mb.n) == 0, "other bytes");
    free(mb.p);
    free(ref.p);
    free(out.p);
    engine_destroy(e);
    csg_tree_free(t);
}

Test(csg_engine, bad_csg_jobs_fail_typed)
{
    csg_tree *t = parse(tree_text);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    engine_pipeline_job job = csg_job(t, 32, 5);
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert(strstr(r.err.msg, "density, occupancy, surface or distance"), "%s",
              r.err.msg);
    job = csg_job(t, 32, VOXEL_CH_DISTANCE); /* primitives have no distance (yet) */
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -ENOTSUP);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert(strstr(r.err.msg, "the distance channel: node '"), "%s", r.err.msg);
    job = csg_job(NULL, 32, VOXEL_CH_DENSITY);
    cr_assert_eq(engine_pipeline_run(NULL, &job, &sink, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_GRID);
    free(out.p);
    csg_tree_free(t);
}

/* A volume that cannot fit the segment is a limit, not a crash. */
Test(csg_engine, a_volume_past_shared_memory_is_a_limit)
{
    csg_tree *t = parse("n = implicit \"sin(40*x)*sin(40*y)*sin(40*z)\"\nresult n\n");
    engine_opts o = {.workers = 1, .shm_bytes = (size_t)4 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    engine_pipeline_job job = csg_job(t, 256, VOXEL_CH_DENSITY);
    vod_membuf out = {0};
    vod_sink sink = {vod_mem_write, &out};
    engine_pipeline_report r;
    cr_assert_lt(engine_pipeline_run(e, &job, &sink, &r), 0);
    cr_assert_eq(r.err.kind, ENGINE_LIMIT, "%s", r.err.msg);
    cr_assert_eq(r.stage, ENGINE_PIPELINE_VOXELIZE);
    free(out.p);
    out = (vod_membuf){0};

    /* A VOD leaf's volume past it: the same limit, naming the segment
     * (its -ENOMEM is the pool's, where a heap's would not be). */
    job = csg_job(t, 64, VOXEL_CH_DENSITY);
    vod_membuf file = run(NULL, &job, &r);
    csg_tree_free(t);
    t = parse("v = vod \"v.vod\"\nresult v\n");
    t->data[0] = malloc(file.n);
    cr_assert(t->data[0]);
    memcpy(t->data[0], file.p, file.n);
    t->data_len[0] = file.n;
    job = csg_job(t, 256, VOXEL_CH_DENSITY);
    cr_assert_eq(engine_pipeline_run(e, &job, &sink, &r), -ENOMEM, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_LIMIT, "%s", r.err.msg);
    cr_assert(strstr(r.err.msg, "the leaves' volumes does not fit in shared memory"), "%s",
              r.err.msg);
    free(out.p);
    free(file.p);
    engine_destroy(e);
    csg_tree_free(t);
}

/* The thesis's Figure 22: a cuboid less an ellipsoid dug into its top
 * face.  On the cuboid's S layer (its surface) just outside the ellipsoid
 * (its ramp, 0 < b < S) differenceA, MAX(a - b, L), drops below S: the
 * rim is bevelled; difference keeps S there: a sharp rim. */
static uint8_t *densities(const char *text, uint32_t res, vod_membuf *keep)
{
    csg_tree *t = parse(text);
    engine_pipeline_job job = csg_job(t, res, VOXEL_CH_DENSITY);
    engine_pipeline_report r;
    *keep = run(NULL, &job, &r);
    csg_tree_free(t);
    vod_file *f;
    err_info err = {0};
    cr_assert_eq(vod_read(keep->p, keep->n, &f, &err), 0, "%s", err.msg);
    uint8_t *d = malloc((size_t)res * res * res);
    for (uint32_t z = 0; z < res; z++)
        for (uint32_t y = 0; y < res; y++)
            for (uint32_t x = 0; x < res; x++)
                d[x + (size_t)res * (y + (size_t)res * z)] = (uint8_t)vod_voxel(f, 0, x, y, z);
    vod_close(f);
    return d;
}

Test(csg_engine, figure22_difference_keeps_the_rim_differenceA_bevels_it)
{
    const uint32_t res = 64;
    const char *box = "box = cuboid size 1.2,1.2,0.8\nresult box\n",
               *egg = "egg = ellipsoid center 0,0,0.4 radii 0.45,0.45,0.3\nresult egg\n",
               *dif = "box = cuboid size 1.2,1.2,0.8\n"
                      "egg = ellipsoid center 0,0,0.4 radii 0.45,0.45,0.3\n"
                      "out = difference(box, egg)\nresult out\n",
               *difa = "box = cuboid size 1.2,1.2,0.8\n"
                       "egg = ellipsoid center 0,0,0.4 radii 0.45,0.45,0.3\n"
                       "out = differenceA(box, egg)\nresult out\n";
    vod_membuf m[4];
    uint8_t *a = densities(box, res, &m[0]), *b = densities(egg, res, &m[1]),
            *d = densities(dif, res, &m[2]), *da = densities(difa, res, &m[3]);
    uint64_t rim = 0, kept = 0, bevelled = 0, same_elsewhere = 0, n = (uint64_t)res * res * res;
    for (uint64_t k = 0; k < n; k++) {
        if (a[k] == CSG_S && b[k] > CSG_L && b[k] < CSG_S) {
            rim++;
            kept += d[k] >= CSG_S;
            bevelled += da[k] < CSG_S;
        } else if (!(a[k] >= CSG_S && b[k] < CSG_S)) {
            same_elsewhere += d[k] == da[k]; /* the two agree off a >= S, b < S */
        }
    }
    cr_assert_gt(rim, 20, "the cuboid's S layer meets the ellipsoid's ramp");
    cr_assert_eq(kept, rim, "difference keeps the S layer along the rim");
    cr_assert_eq(bevelled, rim, "differenceA drops the S layer along the rim: a bevel");
    uint64_t elsewhere = 0;
    for (uint64_t k = 0; k < n; k++) elsewhere += !(a[k] >= CSG_S && b[k] < CSG_S);
    cr_assert_eq(same_elsewhere, elsewhere, "they differ only where a >= S > b");
    for (int i = 0; i < 4; i++) free(m[i].p);
    free(a), free(b), free(d), free(da);
}

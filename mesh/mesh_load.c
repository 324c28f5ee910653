/* mesh_load — the entry points of mesh.h: format detection, the dispatch
 * to the loaders (mesh_obj.c, mesh_stl.c, mesh_ply.c, mesh_off.c,
 * mesh_gltf.c, over
 * mesh_load_core.c), mmap, the mesh's release, names and messages. */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "mesh_load.h"
#include "par.h"

/* ------------------------------------------------------------------- detect */

static int starts_nocase(const char *p, const char *end, const char *w)
{
    size_t n = strlen(w);
    return (size_t)(end - p) >= n && !strncasecmp(p, w, n) &&
           ((size_t)(end - p) == n || mesh_text_space(p[n]));
}

/* The first statement of an OBJ file is one of its keywords. */
static int obj_keyword(const char *p, size_t n)
{
    static const char *const kw[] = {"v", "vt", "vn", "vp", "f", "l", "p", "o", "g", "s",
                                     "usemtl", "mtllib", "cstype", "deg", "curv", "surf"};
    for (size_t i = 0; i < sizeof kw / sizeof *kw; i++)
        if (strlen(kw[i]) == n && !memcmp(p, kw[i], n)) return 1;
    return 0;
}

static mesh_format detect(const char *buf, size_t len)
{
    if (len >= 84) {
        const unsigned char *u = (const unsigned char *)buf + 80;
        uint64_t n = (uint64_t)u[0] | (uint64_t)u[1] << 8 | (uint64_t)u[2] << 16 |
                     (uint64_t)u[3] << 24;
        if (84 + 50 * n == len) return MESH_FORMAT_STL;
    }
    if (len >= 4 && (!memcmp(buf, "ply\n", 4) || (len >= 5 && !memcmp(buf, "ply\r\n", 5))))
        return MESH_FORMAT_PLY;
    if (len >= 4 && !memcmp(buf, "glTF", 4)) return MESH_FORMAT_GLTF; /* a .glb */
    mtext t = {buf, buf + len, buf};
    mesh_text_skip_space(&t);
    if (t.p < t.end && *t.p == '{') return MESH_FORMAT_GLTF; /* JSON: a .gltf */
    for (;;) { /* past blank lines and comments */
        mesh_text_skip_space(&t);
        if (t.p < t.end && *t.p == '#') mesh_text_next_line(&t);
        else break;
    }
    size_t n = mesh_text_toklen(&t);
    if (mesh_off_keyword(t.p, n)) return MESH_FORMAT_OFF;
    if (starts_nocase(t.p, t.end, "solid")) return MESH_FORMAT_STL;
    if (obj_keyword(t.p, n)) return MESH_FORMAT_OBJ;
    return MESH_FORMAT_AUTO;
}

/* ---------------------------------------------------------------- interface */

/* A mesh file's bytes and the folder it was read from, where a .gltf's
 * external buffers are read (NULL: from bytes, refused). */
typedef struct {
    const void *buf;
    size_t len;
    const char *dir;
} mesh_src;

/* mesh_parse of src's bytes. */
static int parse_in(const mesh_src *src, mesh_format format, const mesh_limits *lim, mesh *out,
                    mesh_error *err)
{
    const void *buf = src->buf;
    size_t len = src->len;
    const char *dir = src->dir;
    mesh_error scratch;
    if (!err) err = &scratch;
    memset(err, 0, sizeof *err);
    memset(out, 0, sizeof *out);
    mbuild b = {.max_tri = lim && lim->max_triangles ? lim->max_triangles : MESH_MAX_TRIANGLES,
                .max_vert = lim && lim->max_vertices ? lim->max_vertices : MESH_MAX_VERTICES,
                .buf = buf, .err = err, .dir = dir};
    if (len == 0) return mesh_build_fail(&b, -EINVAL, MESH_BUILD_NOWHERE, "empty file");
    if (format == MESH_FORMAT_AUTO && !(format = detect(buf, len)))
        return mesh_build_fail(&b, -EINVAL, MESH_BUILD_NOWHERE,
                       "not a mesh file of a known format (OBJ, STL, PLY, OFF, glTF)");
    int rc;
    switch (format) {
    case MESH_FORMAT_OBJ: rc = mesh_parse_obj(buf, len, &b); break;
    case MESH_FORMAT_STL: rc = mesh_parse_stl(buf, len, &b); break;
    case MESH_FORMAT_PLY: rc = mesh_parse_ply(buf, len, &b); break;
    case MESH_FORMAT_OFF: rc = mesh_parse_off(buf, len, &b); break;
    case MESH_FORMAT_GLTF: rc = mesh_parse_gltf(buf, len, &b); break;
    default: rc = mesh_build_fail(&b, -EINVAL, MESH_BUILD_NOWHERE, "unknown mesh format %d", (int)format);
    }
    if (rc == 0) rc = mesh_build_finish(&b, format, out);
    mesh_build_free(&b);
    return rc;
}

int mesh_parse(const void *buf, size_t len, mesh_format format, const mesh_limits *lim,
               mesh *out, mesh_error *err)
{
    return parse_in(&(mesh_src){buf, len, NULL}, format, lim, out, err);
}

/* The folder of path, into dir. */
static const char *folder_of(const char *path, char *dir, size_t cap)
{
    const char *slash = strrchr(path, '/');
    if (!slash) return ".";
    if (slash == path) return "/";
    snprintf(dir, cap, "%.*s", (int)(slash - path), path);
    return dir;
}

/* A large file's mapping filled (MADV_POPULATE_READ) before the parse and
 * emptied (MADV_DONTNEED) before munmap in parts, one a CPU: page-table
 * work that the kernel does under the mapping's read lock, so that the
 * parts run at once (munmap's own, under the write lock, would not). */
#define MAP_PAR_MIN (4u << 20)

typedef struct {
    char *base;
    size_t len;
    int advice;
} map_parts;

static void map_part(void *ud, unsigned k, unsigned n)
{
    const map_parts *m = ud;
    size_t page = (size_t)sysconf(_SC_PAGESIZE), pages = (m->len + page - 1) / page;
    size_t from = pages * k / n * page, to = pages * (k + 1) / n * page;
    if (to > m->len) to = m->len;
    if (to > from) madvise(m->base + from, to - from, m->advice);
}

/* 1 when done in parts; 0 when the caller maps the pages as it goes. */
static int map_in_parts(char *p, size_t len, int advice)
{
    unsigned cpus = par_cpus();
    if (len < MAP_PAR_MIN || cpus < 2) return 0;
    map_parts m = {p, len, advice};
    par_run(cpus, map_part, &m);
    return 1;
}

static void *map_file(int fd, size_t len)
{
#ifdef MADV_POPULATE_READ
    void *p = mmap(NULL, len, PROT_READ, MAP_PRIVATE, fd, 0);
    if (p != MAP_FAILED && !map_in_parts(p, len, MADV_POPULATE_READ))
        madvise(p, len, MADV_POPULATE_READ);
    return p;
#else
    /* Populated at once: the parser reads every page in order anyway. */
    return mmap(NULL, len, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
#endif
}

static void unmap_file(void *p, size_t len)
{
    map_in_parts(p, len, MADV_DONTNEED);
    munmap(p, len);
}

int mesh_load(const char *path, mesh_format format, const mesh_limits *lim, mesh *out,
              mesh_error *err)
{
    mesh_error scratch;
    if (!err) err = &scratch;
    memset(err, 0, sizeof *err);
    memset(out, 0, sizeof *out);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
        int e = errno;
        return err_set(&err->info, -e, "cannot open: %s", strerror(e));
    }
    struct stat st;
    int rc = 0;
    if (fstat(fd, &st)) rc = -errno;
    else if (!S_ISREG(st.st_mode)) rc = -EINVAL;
    if (rc) {
        err_set(&err->info, rc, "%s", rc == -EINVAL ? "not a regular file" : strerror(-rc));
        close(fd);
        return rc;
    }
    if (st.st_size == 0) {
        close(fd);
        return mesh_parse("", 0, format, lim, out, err);
    }
    char dirbuf[4096];
    const char *dir = folder_of(path, dirbuf, sizeof dirbuf);
    void *p = map_file(fd, (size_t)st.st_size);
    int e = errno;
    close(fd);
    if (p == MAP_FAILED) return err_set(&err->info, -e, "cannot map: %s", strerror(e));
    rc = parse_in(&(mesh_src){p, (size_t)st.st_size, dir}, format, lim, out, err);
    unmap_file(p, (size_t)st.st_size);
    return rc;
}

void mesh_free(mesh *m)
{
    if (!m) return;
    free(m->vertices);
    free(m->triangles);
    memset(m, 0, sizeof *m);
}

const char *mesh_format_name(mesh_format f)
{
    switch (f) {
    case MESH_FORMAT_AUTO: return "auto";
    case MESH_FORMAT_OBJ: return "OBJ";
    case MESH_FORMAT_STL: return "STL";
    case MESH_FORMAT_PLY: return "PLY";
    case MESH_FORMAT_OFF: return "OFF";
    case MESH_FORMAT_GLTF: return "glTF";
    }
    return "unknown";
}

const char *mesh_error_str(const mesh_error *err, char *buf, size_t len)
{
    if (err->line) snprintf(buf, len, "line %llu: %s", (unsigned long long)err->line, err->msg);
    else if (err->offset) snprintf(buf, len, "byte %llu: %s", (unsigned long long)err->offset, err->msg);
    else snprintf(buf, len, "%s", err->msg);
    return buf;
}

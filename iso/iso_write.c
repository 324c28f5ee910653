/* Writing a mesh: PLY (binary little-endian by default, or ASCII), OBJ
 * (with "vn" normals when it has them), binary STL (facet normals from the
 * triangles; STL has no shared vertices).  Through a buffer of our own,
 * written with write(2) in large pieces. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "iso.h"

typedef struct {
    int fd, err;
    size_t n;
    uint8_t buf[1 << 16];
} out_buf;

static void flush(out_buf *o)
{
    size_t at = 0;
    while (!o->err && at < o->n) {
        ssize_t k = write(o->fd, o->buf + at, o->n - at);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) o->err = k < 0 ? -errno : -EIO;
        else at += (size_t)k;
    }
    o->n = 0;
}

static void put(out_buf *o, const void *p, size_t n)
{
    const uint8_t *s = p;
    while (n) {
        if (o->n == sizeof o->buf) flush(o);
        size_t k = sizeof o->buf - o->n < n ? sizeof o->buf - o->n : n;
        memcpy(o->buf + o->n, s, k);
        o->n += k;
        s += k;
        n -= k;
    }
}

__attribute__((format(printf, 2, 3))) static void putf(out_buf *o, const char *fmt, ...)
{
    char line[256];
    va_list ap;
    va_start(ap, fmt);
    int k = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (k > 0) put(o, line, (size_t)k < sizeof line ? (size_t)k : sizeof line - 1);
}

/* n little-endian 32-bit words: copied as they are on a little-endian
 * machine, byte by byte elsewhere. */
static void put32s(out_buf *o, const void *p, size_t n)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    put(o, p, 4 * n);
#else
    const uint8_t *s = p;
    for (size_t i = 0; i < n; i++, s += 4) {
        uint32_t v;
        memcpy(&v, s, 4);
        uint8_t b[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
        put(o, b, 4);
    }
#endif
}

static void put32(out_buf *o, const void *p)
{
    put32s(o, p, 1);
}

static void ply_header(out_buf *o, const iso_mesh *m, int ascii, const char *comment)
{
    putf(o, "ply\nformat %s 1.0\n", ascii ? "ascii" : "binary_little_endian");
    if (comment) putf(o, "comment %s\n", comment);
    putf(o, "element vertex %llu\n", (unsigned long long)m->n_vertices);
    putf(o, "property float x\nproperty float y\nproperty float z\n");
    if (m->nrm) putf(o, "property float nx\nproperty float ny\nproperty float nz\n");
    putf(o, "element face %llu\n", (unsigned long long)m->n_triangles);
    putf(o, "property list uchar uint vertex_indices\nend_header\n");
}

static void write_ply(out_buf *o, const iso_mesh *m, int ascii, const char *comment)
{
    ply_header(o, m, ascii, comment);
    for (uint64_t i = 0; i < m->n_vertices; i++) {
        const float *p = m->pos + 3 * i, *n = m->nrm ? m->nrm + 3 * i : NULL;
        if (ascii) {
            putf(o, "%.9g %.9g %.9g", (double)p[0], (double)p[1], (double)p[2]);
            if (n) putf(o, " %.9g %.9g %.9g", (double)n[0], (double)n[1], (double)n[2]);
            putf(o, "\n");
            continue;
        }
        put32s(o, p, 3);
        if (n) put32s(o, n, 3);
    }
    for (uint64_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *t = m->tri + 3 * i;
        if (ascii) {
            putf(o, "3 %u %u %u\n", t[0], t[1], t[2]);
            continue;
        }
        uint8_t three = 3;
        put(o, &three, 1);
        put32s(o, t, 3);
    }
}

static void write_obj(out_buf *o, const iso_mesh *m, const char *comment)
{
    if (comment) putf(o, "# %s\n", comment);
    for (uint64_t i = 0; i < m->n_vertices; i++) {
        const float *p = m->pos + 3 * i;
        putf(o, "v %.9g %.9g %.9g\n", (double)p[0], (double)p[1], (double)p[2]);
    }
    for (uint64_t i = 0; m->nrm && i < m->n_vertices; i++) {
        const float *n = m->nrm + 3 * i;
        putf(o, "vn %.9g %.9g %.9g\n", (double)n[0], (double)n[1], (double)n[2]);
    }
    for (uint64_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *t = m->tri + 3 * i;
        if (m->nrm)
            putf(o, "f %u//%u %u//%u %u//%u\n", t[0] + 1, t[0] + 1, t[1] + 1, t[1] + 1,
                 t[2] + 1, t[2] + 1);
        else
            putf(o, "f %u %u %u\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
}

static void facet_normal(const iso_mesh *m, const uint32_t *t, float n[3])
{
    const float *a = m->pos + 3 * t[0], *b = m->pos + 3 * t[1], *c = m->pos + 3 * t[2];
    double u[3], v[3], w[3];
    for (int d = 0; d < 3; d++) u[d] = b[d] - a[d], v[d] = c[d] - a[d];
    w[0] = u[1] * v[2] - u[2] * v[1];
    w[1] = u[2] * v[0] - u[0] * v[2];
    w[2] = u[0] * v[1] - u[1] * v[0];
    double len = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    for (int d = 0; d < 3; d++) n[d] = (float)(len > 0 ? w[d] / len : 0);
}

/* Binary STL: 80 bytes of header, a u32 count, 50 bytes per triangle.  A
 * count past 2^32 - 1 does not fit: -EFBIG. */
static int write_stl(out_buf *o, const iso_mesh *m, const char *comment)
{
    if (m->n_triangles > UINT32_MAX) return -EFBIG;
    char head[80] = {0};
    snprintf(head, sizeof head, "%s", comment ? comment : "vox mesh");
    put(o, head, sizeof head);
    uint32_t n = (uint32_t)m->n_triangles;
    put32(o, &n);
    for (uint64_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *t = m->tri + 3 * i;
        float fn[3];
        facet_normal(m, t, fn);
        put32s(o, fn, 3);
        for (int k = 0; k < 3; k++) put32s(o, &m->pos[3 * t[k]], 3);
        uint8_t attr[2] = {0, 0};
        put(o, attr, 2);
    }
    return 0;
}

int iso_write(int fd, const iso_mesh *m, iso_format f, const char *comment)
{
    if (f < ISO_FMT_PLY || f > ISO_FMT_STL) return -EINVAL;
    out_buf *o = malloc(sizeof *o); /* 64 KiB: not on the stack */
    if (!o) return -ENOMEM;
    o->fd = fd;
    o->err = 0;
    o->n = 0;
    int rc = 0;
    if (f == ISO_FMT_PLY || f == ISO_FMT_PLY_ASCII) write_ply(o, m, f == ISO_FMT_PLY_ASCII, comment);
    else if (f == ISO_FMT_OBJ) write_obj(o, m, comment);
    else rc = write_stl(o, m, comment);
    flush(o);
    if (!rc) rc = o->err;
    free(o);
    return rc;
}

iso_format iso_format_of_name(const char *s)
{
    if (!strcmp(s, "ply")) return ISO_FMT_PLY;
    if (!strcmp(s, "ply-ascii")) return ISO_FMT_PLY_ASCII;
    if (!strcmp(s, "obj")) return ISO_FMT_OBJ;
    if (!strcmp(s, "stl")) return ISO_FMT_STL;
    return ISO_FMT_NONE;
}

iso_format iso_format_of_path(const char *path)
{
    const char *dot = strrchr(path, '.'), *slash = strrchr(path, '/');
    if (!dot || (slash && dot < slash) || !strcmp(dot + 1, "ply-ascii")) return ISO_FMT_NONE;
    return iso_format_of_name(dot + 1);
}

/* Writing a mesh: PLY (binary little-endian by default, or ASCII), OBJ
 * (with "vn" normals when it has them), binary STL (facet normals from the
 * triangles; STL has no shared vertices).
 *
 * The file after its header is a run of records (vertices, normals,
 * triangles), cut into chunks of CHUNK records.  Each thread claims the
 * next chunk, formats it into a buffer of its own, waits until the chunk
 * before it has taken its place in the file (its offset plus its size
 * give this one's offset), publishes its own end, and writes its bytes
 * there with pwrite: the formatting, the most of the cost, runs on every
 * thread, and only the handing on of offsets is in order.  One thread (or
 * an fd that cannot seek, or appends) writes the chunks in order with
 * write.  A mesh still being welded (iso_write_ready) is written the same
 * way, each chunk once the records it reads are final. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "iso.h"
#include "par.h"

#define CHUNK 8192u     /* records a chunk */
#define REC_MAX 160u    /* bytes of one record at most, in every format */
#define HEAD_MAX 1024u  /* bytes of a header at most */

typedef enum { R_PLY_V, R_PLY_VA, R_PLY_F, R_PLY_FA, R_OBJ_V, R_OBJ_VN, R_OBJ_F,
               R_STL } rec_kind;

typedef struct {
    rec_kind kind;
    uint64_t n;              /* records */
} section;

typedef struct {
    const iso_mesh *m;
    const iso_ready *ready;  /* NULL: the mesh is final */
    section sec[3];
    int nsec;
    uint64_t first[4];       /* the first chunk of each section, then the total */
    int fd, seek;            /* seek: pwrite at base + offsets, else write in order */
    off_t base;
    atomic_uint_fast64_t next; /* the next chunk to claim: a counter, relaxed */
    pthread_mutex_t mu;      /* guards the four below */
    pthread_cond_t cv;
    uint64_t placed;         /* chunks whose offset is known */
    uint64_t end;            /* the offset past the last placed chunk */
    int err;                 /* the first error: the others stop */
} writer;

/* n little-endian 32-bit words at o: copied as they are on a
 * little-endian machine, byte by byte elsewhere; the bytes written. */
static size_t put32s(uint8_t *o, const void *p, size_t n)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    memcpy(o, p, 4 * n);
#else
    const uint8_t *s = p;
    for (size_t i = 0; i < n; i++, s += 4) {
        uint32_t v;
        memcpy(&v, s, 4);
        for (int b = 0; b < 4; b++) o[4 * i + b] = (uint8_t)(v >> 8 * b);
    }
#endif
    return 4 * n;
}

static size_t put_text(uint8_t *o, int k)
{
    (void)o;
    return k > 0 ? (size_t)k : 0;
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

static size_t stl_facet(const iso_mesh *m, uint64_t i, uint8_t *o)
{
    const uint32_t *t = m->tri + 3 * i;
    float fn[3];
    facet_normal(m, t, fn);
    size_t k = put32s(o, fn, 3);
    for (int c = 0; c < 3; c++) k += put32s(o + k, &m->pos[3 * t[c]], 3);
    o[k] = o[k + 1] = 0; /* the attribute byte count */
    return k + 2;
}

/* Record i of kind at o (REC_MAX bytes of room); its bytes. */
static size_t record(const iso_mesh *m, rec_kind kind, uint64_t i, uint8_t *o)
{
    const float *p = m->pos + 3 * i, *n = m->nrm ? m->nrm + 3 * i : NULL;
    const uint32_t *t = m->tri + 3 * i;
    char *s = (char *)o;
    size_t k;
    switch (kind) {
    case R_PLY_V:
        k = put32s(o, p, 3);
        return n ? k + put32s(o + k, n, 3) : k;
    case R_PLY_VA:
        k = put_text(o, snprintf(s, REC_MAX, "%.9g %.9g %.9g", (double)p[0], (double)p[1],
                                 (double)p[2]));
        if (n)
            k += put_text(o, snprintf(s + k, REC_MAX - k, " %.9g %.9g %.9g", (double)n[0],
                                      (double)n[1], (double)n[2]));
        o[k] = '\n';
        return k + 1;
    case R_PLY_F:
        o[0] = 3;
        return 1 + put32s(o + 1, t, 3);
    case R_PLY_FA:
        return put_text(o, snprintf(s, REC_MAX, "3 %u %u %u\n", t[0], t[1], t[2]));
    case R_OBJ_V:
        return put_text(o, snprintf(s, REC_MAX, "v %.9g %.9g %.9g\n", (double)p[0],
                                    (double)p[1], (double)p[2]));
    case R_OBJ_VN:
        return put_text(o, snprintf(s, REC_MAX, "vn %.9g %.9g %.9g\n", (double)n[0],
                                    (double)n[1], (double)n[2]));
    case R_OBJ_F:
        if (m->nrm)
            return put_text(o, snprintf(s, REC_MAX, "f %u//%u %u//%u %u//%u\n", t[0] + 1,
                                        t[0] + 1, t[1] + 1, t[1] + 1, t[2] + 1, t[2] + 1));
        return put_text(o, snprintf(s, REC_MAX, "f %u %u %u\n", t[0] + 1, t[1] + 1,
                                    t[2] + 1));
    case R_STL:
        return stl_facet(m, i, o);
    }
    return 0;
}

/* Chunk c's records formatted into buf; its bytes. */
static size_t format_chunk(const writer *w, uint64_t c, uint8_t *buf)
{
    int s = 0;
    while (c >= w->first[s + 1]) s++;
    uint64_t i = (c - w->first[s]) * CHUNK, end = i + CHUNK;
    if (end > w->sec[s].n) end = w->sec[s].n;
    size_t k = 0;
    for (; i < end; i++) k += record(w->m, w->sec[s].kind, i, buf + k);
    return k;
}

/* All n bytes of buf at the file's offset at (or, without seek, where it
 * stands); 0 or a negative errno. */
static int put_all(const writer *w, const uint8_t *buf, size_t n, uint64_t at)
{
    while (n) {
        ssize_t k = w->seek ? pwrite(w->fd, buf, n, w->base + (off_t)at) : write(w->fd, buf, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return k < 0 ? -errno : -EIO;
        buf += k, n -= (size_t)k, at += (uint64_t)k;
    }
    return 0;
}

/* Chunk c of n bytes: its offset once chunk c - 1 has its own; -1 after
 * an error anywhere. */
static int64_t place(writer *w, uint64_t c, size_t n)
{
    pthread_mutex_lock(&w->mu);
    while (w->placed < c && !w->err) pthread_cond_wait(&w->cv, &w->mu);
    int64_t at = w->err ? -1 : (int64_t)w->end;
    if (!w->err) {
        w->end += n;
        w->placed = c + 1;
        pthread_cond_broadcast(&w->cv);
    }
    pthread_mutex_unlock(&w->mu);
    return at;
}

static void fail(writer *w, int rc)
{
    pthread_mutex_lock(&w->mu);
    if (!w->err) w->err = rc;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

/* Until the records chunk c reads are final; 0 or the wait's error. */
static int wait_ready(const writer *w, uint64_t c)
{
    if (!w->ready) return 0;
    int s = 0;
    while (c >= w->first[s + 1]) s++;
    uint64_t hi = (c - w->first[s] + 1) * CHUNK;
    if (hi > w->sec[s].n) hi = w->sec[s].n;
    void *ud = w->ready->ud;
    switch (w->sec[s].kind) {
    case R_PLY_F: case R_PLY_FA: case R_OBJ_F:
        return w->ready->wait(ud, 1, hi);
    case R_STL: { /* a facet reads any of the vertices */
        int rc = w->ready->wait(ud, 1, hi);
        return rc ? rc : w->ready->wait(ud, 0, w->m->n_vertices);
    }
    default:
        return w->ready->wait(ud, 0, hi);
    }
}

/* One thread's part: chunks claimed until none is left.  Without seek
 * the chunks are written in order as they are placed (one thread). */
static void write_part(void *ud, unsigned k, unsigned n)
{
    writer *w = ud;
    (void)k, (void)n;
    uint8_t *buf = malloc((size_t)CHUNK * REC_MAX);
    if (!buf) {
        fail(w, -ENOMEM);
        return;
    }
    for (;;) {
        /* relaxed: the counter only hands out chunk numbers */
        uint64_t c = atomic_fetch_add_explicit(&w->next, 1, memory_order_relaxed);
        if (c >= w->first[w->nsec]) break;
        int rc = wait_ready(w, c);
        if (rc) {
            fail(w, rc);
            break;
        }
        size_t bytes = format_chunk(w, c, buf);
        int64_t at = place(w, c, bytes);
        if (at < 0) break;
        rc = put_all(w, buf, bytes, (uint64_t)at);
        if (rc) {
            fail(w, rc);
            break;
        }
    }
    free(buf);
}

/* The header into h (room for HEAD_MAX bytes and the comment); its bytes. */
static size_t header(const iso_mesh *m, iso_format f, const char *comment, char *h)
{
    size_t cap = HEAD_MAX + (comment ? strlen(comment) : 0), k = 0;
    if (f == ISO_FMT_STL) { /* 80 bytes of text, the u32 count */
        memset(h, 0, 80);
        snprintf(h, 80, "%s", comment ? comment : "vox mesh");
        uint32_t n = (uint32_t)m->n_triangles;
        return 80 + put32s((uint8_t *)h + 80, &n, 1);
    }
    if (f == ISO_FMT_OBJ) return comment ? (size_t)snprintf(h, cap, "# %s\n", comment) : 0;
    k += (size_t)snprintf(h + k, cap - k, "ply\nformat %s 1.0\n",
                          f == ISO_FMT_PLY_ASCII ? "ascii" : "binary_little_endian");
    if (comment) k += (size_t)snprintf(h + k, cap - k, "comment %s\n", comment);
    k += (size_t)snprintf(h + k, cap - k,
                          "element vertex %llu\nproperty float x\nproperty float y\n"
                          "property float z\n", (unsigned long long)m->n_vertices);
    if (m->nrm)
        k += (size_t)snprintf(h + k, cap - k,
                              "property float nx\nproperty float ny\nproperty float nz\n");
    k += (size_t)snprintf(h + k, cap - k,
                          "element face %llu\nproperty list uchar uint vertex_indices\n"
                          "end_header\n", (unsigned long long)m->n_triangles);
    return k;
}

/* The sections of records after the header, and their first chunks. */
static void sections(writer *w, iso_format f)
{
    const iso_mesh *m = w->m;
    int a = f == ISO_FMT_PLY_ASCII;
    section *s = w->sec;
    if (f == ISO_FMT_STL) s[w->nsec++] = (section){R_STL, m->n_triangles};
    else if (f == ISO_FMT_OBJ) {
        s[w->nsec++] = (section){R_OBJ_V, m->n_vertices};
        if (m->nrm) s[w->nsec++] = (section){R_OBJ_VN, m->n_vertices};
        s[w->nsec++] = (section){R_OBJ_F, m->n_triangles};
    } else {
        s[w->nsec++] = (section){a ? R_PLY_VA : R_PLY_V, m->n_vertices};
        s[w->nsec++] = (section){a ? R_PLY_FA : R_PLY_F, m->n_triangles};
    }
    for (int i = 0; i < w->nsec; i++)
        w->first[i + 1] = w->first[i] + (s[i].n + CHUNK - 1) / CHUNK;
}

int iso_write(int fd, const iso_mesh *m, iso_format f, const char *comment,
              unsigned threads)
{
    return iso_write_ready(fd, m, f, comment, threads, NULL);
}

int iso_write_ready(int fd, const iso_mesh *m, iso_format f, const char *comment,
                    unsigned threads, const iso_ready *ready)
{
    if (f < ISO_FMT_PLY || f > ISO_FMT_STL) return -EINVAL;
    if (f == ISO_FMT_STL && m->n_triangles > UINT32_MAX) return -EFBIG;
    writer *w = calloc(1, sizeof *w);
    char *h = malloc(HEAD_MAX + (comment ? strlen(comment) : 0));
    int rc = w && h ? 0 : -ENOMEM;
    if (!rc) {
        w->m = m;
        w->ready = ready;
        w->fd = fd;
        /* pwrite needs an fd that seeks, and not in append mode (where
         * Linux appends whatever the offset) */
        int fl = fcntl(fd, F_GETFL);
        w->base = threads > 1 && fl >= 0 && !(fl & O_APPEND) ? lseek(fd, 0, SEEK_CUR) : -1;
        w->seek = w->base >= 0;
        sections(w, f);
        size_t hn = header(m, f, comment, h);
        rc = put_all(w, (const uint8_t *)h, hn, 0);
        if (w->seek) w->base += (off_t)hn;
    }
    if (!rc) {
        pthread_mutex_init(&w->mu, NULL);
        pthread_cond_init(&w->cv, NULL);
        /* no more threads than chunks: each holds a chunk's buffer */
        uint64_t chunks = w->first[w->nsec];
        par_run(!w->seek ? 1 : threads < chunks ? threads : (unsigned)(chunks ? chunks : 1),
                write_part, w);
        pthread_cond_destroy(&w->cv);
        pthread_mutex_destroy(&w->mu);
        rc = w->err;
        /* the fd stands past the file, as after write */
        if (!rc && w->seek && lseek(fd, w->base + (off_t)w->end, SEEK_SET) < 0) rc = -errno;
    }
    free(h);
    free(w);
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

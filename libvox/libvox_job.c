/* A job's result as it comes in: its sink (a spool file until someone
 * receives it, then the output file or a buffer), its running CRC-32, the
 * check of the summary against both; the jobs of a connection. */
#include "vox.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "libvox_int.h"

double libvox_mono(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

vjob *libvox_find_job(vox_client *c, uint64_t id)
{
    for (vjob *j = c->jobs; j; j = j->next)
        if (j->id == id) return j;
    return NULL;
}

void libvox_free_job(vjob *j)
{
    if (j->sink == SINK_SPOOL && j->fd >= 0) close(j->fd);
    free(j->buf);
    free(j);
}

void libvox_forget_job(vox_client *c, vjob *j)
{
    for (vjob **p = &c->jobs; *p; p = &(*p)->next)
        if (*p == j) {
            *p = j->next;
            break;
        }
    libvox_free_job(j);
}

/* A job's end has been dispatched. */
void libvox_job_ended(vox_client *c, vjob *j)
{
    if (j->discard) libvox_forget_job(c, j);
}

int libvox_ignored(const vox_client *c, uint64_t id)
{
    unsigned n = c->n_ignore < IGNORE_SLOTS ? c->n_ignore : IGNORE_SLOTS;
    for (unsigned i = 0; i < n; i++)
        if (c->ignore[i] == id) return 1;
    return 0;
}

void libvox_add_ignored(vox_client *c, uint64_t id)
{
    if (!libvox_ignored(c, id)) c->ignore[c->n_ignore++ % IGNORE_SLOTS] = id;
}

int libvox_write_all(int fd, const uint8_t *p, size_t n)
{
    while (n) {
        ssize_t w = write(fd, p, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            return -errno;
        }
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* An unlinked temporary file for results nobody is receiving yet. */
static int spool_open(void)
{
    const char *dir = getenv("TMPDIR");
    if (!dir || !*dir) dir = "/tmp";
    int fd = open(dir, O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd >= 0) return fd;
    char path[PATH_MAX];
    if (snprintf(path, sizeof path, "%s/libvox.XXXXXX", dir) >= (int)sizeof path)
        return -ENAMETOOLONG;
    fd = mkostemp(path, O_CLOEXEC);
    if (fd < 0) return -errno;
    unlink(path);
    return fd;
}

static int buf_append(vjob *j, const uint8_t *p, size_t n)
{
    size_t need = (size_t)j->received + n;
    if (need > j->cap) {
        size_t cap = j->cap ? j->cap : 65536;
        while (cap < need) cap = cap > SIZE_MAX / 2 ? need : cap * 2;
        uint8_t *b = realloc(j->buf, cap);
        if (!b) return -ENOMEM;
        j->buf = b;
        j->cap = cap;
    }
    memcpy(j->buf + j->received, p, n);
    return 0;
}

static int sink_write(vjob *j, const uint8_t *p, size_t n)
{
    switch (j->sink) {
    case SINK_NONE: return 0;
    case SINK_BUF: return buf_append(j, p, n);
    case SINK_SPOOL:
        if (j->fd < 0 && (j->fd = spool_open()) < 0) {
            int rc = j->fd;
            j->fd = -1;
            return rc;
        }
        return libvox_write_all(j->fd, p, n);
    default: return libvox_write_all(j->fd, p, n);
    }
}

/* The CRC of everything but the last 4 bytes seen so far, which wait in
 * tail until more bytes come or the summary checks them. */
static void crc_feed(vjob *j, const uint8_t *p, size_t n)
{
    if (n >= 4) {
        if (j->tail_n) j->crc = (uint32_t)crc32(j->crc, j->tail, j->tail_n);
        j->crc = (uint32_t)crc32(j->crc, p, (uInt)(n - 4));
        memcpy(j->tail, p + n - 4, 4);
        j->tail_n = 4;
        return;
    }
    uint8_t t[8];
    size_t total = j->tail_n + n;
    memcpy(t, j->tail, j->tail_n);
    memcpy(t + j->tail_n, p, n);
    if (total > 4) {
        j->crc = (uint32_t)crc32(j->crc, t, (uInt)(total - 4));
        memcpy(j->tail, t + total - 4, 4);
        j->tail_n = 4;
    } else {
        memcpy(j->tail, t, total);
        j->tail_n = (unsigned)total;
    }
}

int libvox_on_chunk(vox_client *c, const Voxd__ResultChunk *m)
{
    vjob *j = libvox_find_job(c, m->job_id);
    if (!j)
        return libvox_fail(c, -EPROTO, "voxd sent a result chunk for job %llu, which is not a job of this connection",
                    (unsigned long long)m->job_id);
    if (j->done)
        return libvox_fail(c, -EPROTO, "voxd sent a result chunk for job %llu after its end",
                    (unsigned long long)m->job_id);
    if (m->offset != j->received)
        return libvox_fail(c, -EPROTO, "voxd sent job %llu's chunk at offset %llu where %llu was due",
                    (unsigned long long)m->job_id, (unsigned long long)m->offset,
                    (unsigned long long)j->received);
    /* proto_check_reply bounded offset + len by max_result_bytes. */
    if (!j->local_err) {
        int rc = sink_write(j, m->data.data, m->data.len);
        if (rc) {
            j->local_err = rc;
            libvox_set_error(&j->result, rc, j->id, "cannot store job %llu's result: %s",
                      (unsigned long long)j->id, strerror(-rc));
        }
    }
    crc_feed(j, m->data.data, m->data.len);
    j->received += m->data.len;
    j->t_data = c->t_any_data = libvox_mono();
    return 0;
}

void libvox_on_summary(vjob *j, const Voxd__Summary *m)
{
    j->done = 1;
    if (j->local_err) return;
    unsigned long long id = (unsigned long long)j->id;
    if (m->file_bytes != j->received) {
        libvox_set_error(&j->result, -EBADMSG, j->id,
                  "job %llu's result is %llu bytes, the daemon's summary says %llu", id,
                  (unsigned long long)j->received, (unsigned long long)m->file_bytes);
        return;
    }
    uint32_t own = (uint32_t)j->tail[0] | (uint32_t)j->tail[1] << 8 |
                   (uint32_t)j->tail[2] << 16 | (uint32_t)j->tail[3] << 24;
    if (j->tail_n < 4 || j->crc != m->crc32 || own != m->crc32) {
        libvox_set_error(&j->result, -EBADMSG, j->id,
                  "job %llu's result fails its CRC-32 check: computed %08x, the file says %08x, "
                  "the daemon's summary %08x",
                  id, j->crc, own, m->crc32);
        return;
    }
    j->result.code = 0;
    j->sum = (vox_summary){
        .job_id = j->id, .voxels = m->voxels, .bricks = m->bricks,
        .file_bytes = m->file_bytes, .crc32 = m->crc32,
        .seconds_queued = m->seconds_queued, .seconds_voxelize = m->seconds_voxelize,
        .seconds_write = m->seconds_write, .mpi_ranks = m->mpi_ranks};
    /* proto_check_reply made sure of 3 values each and a consistent grid. */
    const Voxd__Grid *g = m->grid;
    for (int a = 0; a < 3; a++) {
        j->sum.grid[a] = g->res[a];
        j->sum.origin[a] = g->origin[a];
    }
    j->sum.depth = g->depth;
    j->sum.voxel_size = g->voxel_size;
    const Voxd__MeshReport *mr = m->mesh;
    if (mr) {
        j->sum.has_mesh = 1;
        j->sum.mesh.triangles = mr->triangles;
        j->sum.mesh.open_edges = mr->open_edges;
        j->sum.mesh.nonmanifold_edges = mr->nonmanifold_edges;
        j->sum.mesh.watertight = mr->watertight;
        j->sum.mesh.tiles = mr->tiles;
        j->sum.mesh.repair_skipped = mr->repair_skipped;
        j->sum.mesh.disagreements = mr->disagreements;
        j->sum.mesh.disagree_bricks = mr->disagree_bricks;
    }
}

/* Move what the spool holds to the job's new sink. */
int libvox_unspool(vjob *j, int sink, int fd)
{
    int spool = j->fd;
    j->sink = sink;
    j->fd = fd;
    if (spool < 0) return 0;
    int rc = 0;
    if (j->local_err) goto out;
    if (sink == SINK_BUF) {
        size_t n = (size_t)j->received;
        j->buf = malloc(n ? n : 1);
        if (!j->buf) {
            rc = -ENOMEM;
            goto out;
        }
        j->cap = n;
    }
    uint8_t block[65536];
    off_t off = 0;
    while ((uint64_t)off < j->received) {
        size_t want = sizeof block;
        if (j->received - (uint64_t)off < want) want = (size_t)(j->received - (uint64_t)off);
        ssize_t r = pread(spool, block, want, off);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) {
            rc = r < 0 ? -errno : -EIO;
            break;
        }
        if (sink == SINK_BUF) memcpy(j->buf + off, block, (size_t)r);
        else if ((rc = libvox_write_all(fd, block, (size_t)r))) break;
        off += r;
    }
out:
    close(spool);
    if (rc) {
        j->local_err = rc;
        libvox_set_error(&j->result, rc, j->id, "cannot store job %llu's result: %s",
                  (unsigned long long)j->id, strerror(-rc));
    }
    return rc;
}

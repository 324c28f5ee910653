/* vox_mpi: rank 0 handing out the subtrees, booking their bricks (each
 * distinct one once, in a spill file), then writing the file: the levels
 * above the subtrees and every node in preorder. */
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <pthread.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "clock.h"
#include "err.h"
#include "vox_mpi.h"

/* Everything rank 0 made is dropped, the unfinished file too; the other
 * ranks are killed by MPI_Abort (their workers die with them). */
static void abort_job(mpi_ctx *ctx)
{
    outfile_abort(&ctx->out_file);
    MPI_Abort(MPI_COMM_WORLD, CLI_EXIT_FAILED);
    _exit(CLI_EXIT_FAILED);
}

/* The one static: the signal handler's way to rank 0's unfinished file. */
static const outfile *sig_out;

static void on_signal(int sig)
{
    static const char m[] = "vox_mpi: rank 0 stopped by a signal (mpirun stops every "
                            "rank when one fails; its message names the rank and host); "
                            "no file written\n";
    if (sig_out && sig_out->named) unlink(sig_out->tmp);
    ssize_t w = write(2, m, sizeof m - 1);
    (void)w;
    _exit(128 + sig);
}

void mpi_catch_signals(mpi_ctx *ctx)
{
    sig_out = &ctx->out_file;
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGHUP, on_signal);
}

static int push_node(master *m, const mpi_rec *r)
{
    if (m->n == m->cap) {
        size_t cap = m->cap ? 2 * m->cap : 4096;
        mpi_rec *v = realloc(m->nodes, cap * sizeof *v);
        if (!v) return -ENOMEM;
        m->nodes = v, m->cap = cap;
    }
    m->nodes[m->n++] = *r;
    return 0;
}

static int spill(master *m, mpi_book_entry *e, const uint8_t *data)
{
    for (size_t at = 0; at < e->size;) {
        ssize_t w = write(m->spill, data + at, e->size - at);
        if (w < 0) return -errno;
        at += (size_t)w;
    }
    e->off = m->spill_bytes;
    e->state = 2;
    m->spill_bytes += e->size;
    return 0;
}

void mpi_fail_master(master *m, const char *what, int rc)
{
    progress_done(&m->pr);
    mpi_msg("rank 0 on %s: %s: %s", m->ctx->all_hosts[0], what, strerror(-rc));
    abort_job(m->ctx);
}

/* A mesh job's task: the column, then the triangles its tiles need. */
static void send_column(master *m, int r, const wire_task *t)
{
    uint32_t tiles[4];
    mpi_column_tiles(m->grid, t->o, tiles);
    uint8_t *part;
    size_t n;
    int rc = mpi_mesh_part(m->mesh, m->bins, m->bins ? tiles : NULL, &part, &n);
    uint8_t *msg_buf = rc ? NULL : malloc(sizeof *t + n);
    if (rc || !msg_buf || sizeof *t + n > INT32_MAX)
        mpi_fail_master(m, "the triangles of a column", rc ? rc : msg_buf ? -E2BIG : -ENOMEM);
    memcpy(msg_buf, t, sizeof *t);
    memcpy(msg_buf + sizeof *t, part, n);
    free(part);
    MPI_Send(msg_buf, (int)(sizeof *t + n), MPI_BYTE, r, TAG_TASK, m->ctx->down);
    m->sent_bytes += sizeof *t + n;
    free(msg_buf);
}

static void send_task(master *m, int r)
{
    wire_task t = {.index = -1};
    if (m->next < m->cut->n) {
        t.index = (int32_t)m->next;
        t.o = m->cut->oct[m->next++];
    }
    m->rs[r].task = t.index;
    if (t.index >= 0 && m->kind == MPI_KIND_MESH) {
        send_column(m, r, &t);
        return;
    }
    MPI_Send(&t, sizeof t, MPI_BYTE, r, TAG_TASK, m->ctx->down);
    m->sent_bytes += sizeof t;
}

/* 1 when a top brick's octant o is one of task t's subtrees: t itself,
 * or for a mesh job any octant of t's column. */
static int in_task(const master *m, grid_octant t, grid_octant o)
{
    return o.level == t.level && o.x == t.x && o.y == t.y &&
           (o.z == t.z || (m->kind == MPI_KIND_MESH && o.z < m->grid->res[2]));
}

/* Each subtree's top brick to the top's builder. */
static int take_tops(master *m, grid_octant task, const mpi_topref *tops, size_t ntops,
                     const mpi_pair *pairs, size_t npairs)
{
    size_t at = 0;
    for (size_t i = 0; i < ntops; i++) {
        mpi_topref t;
        memcpy(&t, &tops[i], sizeof t);
        if (!in_task(m, task, t.o) || t.npairs > npairs - at) return -EPROTO;
        int rc = mpi_top_add(m->top, t.o, pairs + at, t.npairs);
        if (rc) return rc;
        at += t.npairs;
    }
    return at == npairs ? 0 : -EPROTO;
}

/* A task's records: book them, ask for the bytes of the new ones. */
static int take_nodes(master *m, int r, const uint8_t *buf, int n)
{
    wire_nodes h;
    if ((size_t)n < sizeof h) return -EPROTO;
    memcpy(&h, buf, sizeof h);
    uint64_t recs_bytes = (uint64_t)h.n * sizeof(mpi_rec);
    uint64_t tops_bytes = (uint64_t)h.ntops * sizeof(mpi_topref);
    if ((size_t)n != sizeof h + recs_bytes + tops_bytes + (uint64_t)h.npairs * sizeof(mpi_pair))
        return -EPROTO;
    const mpi_rec *recs = (const mpi_rec *)(buf + sizeof h);
    rank_state *rs = &m->rs[r];
    if (rs->task < 0 || rs->want) return -EPROTO; /* no task, or one unfinished */
    for (uint32_t i = 0; i < h.n; i++)
        if (recs[i].level > m->cut->node_level) return -EPROTO; /* the top is rank 0's */
    uint32_t *want = malloc((h.n ? h.n : 1) * sizeof *want);
    rs->want = malloc((h.n ? h.n : 1) * sizeof *rs->want);
    if (!want || !rs->want) return -ENOMEM;
    rs->nwant = 0;
    for (uint32_t i = 0; i < h.n; i++) {
        int fresh;
        mpi_book_entry *e = mpi_book_get(&m->book, &recs[i], &fresh);
        if (!e || push_node(m, &recs[i])) return -ENOMEM;
        if (fresh) {
            want[rs->nwant] = i;
            rs->want[rs->nwant++] = recs[i];
        }
    }
    int rc = take_tops(m, m->cut->oct[rs->task], (const mpi_topref *)(buf + sizeof h + recs_bytes),
                       h.ntops, (const mpi_pair *)(buf + sizeof h + recs_bytes + tops_bytes),
                       h.npairs);
    if (rc) return rc;
    MPI_Send(want, (int)(rs->nwant * sizeof *want), MPI_BYTE, r, TAG_WANT, m->ctx->down);
    m->sent_bytes += rs->nwant * sizeof *want;
    free(want);
    if (!rs->nwant) {
        free(rs->want);
        rs->want = NULL;
    }
    m->voxels += h.voxels;
    m->done++;
    progress_update(&m->pr, (double)m->done / (double)(m->cut->n ? m->cut->n : 1), 0,
                    m->voxels);
    return 0;
}

/* The bytes asked for, in the order asked. */
static int take_bricks(master *m, int r, const uint8_t *buf, int n)
{
    rank_state *rs = &m->rs[r];
    size_t at = 0;
    for (size_t i = 0; i < rs->nwant; i++) {
        int fresh;
        mpi_book_entry *e = mpi_book_get(&m->book, &rs->want[i], &fresh);
        if (!e || fresh) return -EPROTO;
        if (at + e->size > (size_t)n) return -EPROTO;
        int rc = spill(m, e, buf + at);
        if (rc) return rc;
        at += e->size;
    }
    return at == (size_t)n ? 0 : -EPROTO;
}

/* Rank 0's loop: hand out subtrees on request and take their bricks until
 * every rank has been told there is nothing left. */
void mpi_serve(master *m)
{
    int active = m->ctx->nranks;
    while (active) {
        MPI_Status st;
        mpi_wait_msg(m->ctx->up, MPI_ANY_SOURCE, MPI_ANY_TAG, &st);
        int r = st.MPI_SOURCE, n, rc = 0;
        uint8_t *buf = mpi_recv_msg(m->ctx, m->ctx->up, &st, &n);
        if (st.MPI_TAG == TAG_FAIL) {
            progress_done(&m->pr);
            buf[n ? n - 1 : 0] = '\0';
            mpi_msg("rank %d on %s failed: %s", r, m->ctx->all_hosts[r],
                    n ? (char *)buf : "?");
            abort_job(m->ctx);
        }
        if (st.MPI_TAG == TAG_NODES) {
            rc = take_nodes(m, r, buf, n);
            if (!rc && !m->rs[r].nwant) st.MPI_TAG = TAG_REQ; /* nothing to wait for */
        } else if (st.MPI_TAG == TAG_BRICKS) {
            rc = take_bricks(m, r, buf, n);
            free(m->rs[r].want);
            m->rs[r].want = NULL;
            m->rs[r].nwant = 0;
            st.MPI_TAG = TAG_REQ;
        }
        else if (st.MPI_TAG != TAG_REQ)
            rc = -EPROTO;
        free(buf);
        if (rc) {
            char what[128];
            snprintf(what, sizeof what, "the bricks of rank %d on %s", r,
                     m->ctx->all_hosts[r]);
            mpi_fail_master(m, what, rc);
        }
        if (st.MPI_TAG == TAG_REQ) {
            send_task(m, r);
            if (m->rs[r].task < 0) active--;
        }
    }
}

/* The nodes above the subtrees, made on a thread of their own while the
 * main thread orders the subtrees' records (mpi_finish_file): their
 * bytes stay in memory (a few hundred nodes at most), never booked or
 * spilled, so the two threads share nothing; vod_assemble finds their
 * duplicates by their bytes as it finds any. */
typedef struct {
    mpi_top *top;
    const vod_params *v;
    vod_node *nodes;
    vod_encoded *recs;
    uint8_t **data;
    size_t n, cap;
    double secs;
    int rc;
} top_part;

static int keep_top(void *ud, const vod_node *n, const vod_encoded *rec, const uint8_t *data)
{
    top_part *t = ud;
    if (t->n == t->cap) {
        size_t cap = t->cap ? 2 * t->cap : 64;
        vod_node *nv = realloc(t->nodes, cap * sizeof *nv);
        if (nv) t->nodes = nv;
        vod_encoded *rv = realloc(t->recs, cap * sizeof *rv);
        if (rv) t->recs = rv;
        uint8_t **dv = realloc(t->data, cap * sizeof *dv);
        if (dv) t->data = dv;
        if (!nv || !rv || !dv) return -ENOMEM;
        t->cap = cap;
    }
    uint8_t *b = malloc(rec->size ? rec->size : 1);
    if (!b) return -ENOMEM;
    if (rec->size) memcpy(b, data, rec->size);
    t->nodes[t->n] = *n;
    t->recs[t->n] = *rec;
    t->data[t->n++] = b;
    return 0;
}

static void *top_thread(void *ud)
{
    top_part *t = ud;
    double t0 = clock_now();
    t->rc = mpi_top_encode(t->top, t->v, keep_top, t);
    t->secs = clock_now() - t0;
    return NULL;
}

static void top_part_free(top_part *t)
{
    for (size_t i = 0; i < t->n; i++) free(t->data[i]);
    free(t->nodes);
    free(t->recs);
    free(t->data);
}

static int by_preorder(const void *a, const void *b)
{
    uint64_t x = ((const mpi_rec *)a)->preorder, y = ((const mpi_rec *)b)->preorder;
    return x < y ? -1 : x > y;
}

/* The subtrees' records in preorder, each one's bytes in the spill's map
 * (*map, m->spill_bytes long): sub[i] for m->nodes[i]. */
static int order_subtrees(master *m, const uint8_t **map, const uint8_t ***sub)
{
    qsort(m->nodes, m->n, sizeof *m->nodes, by_preorder);
    *map = NULL;
    *sub = calloc(m->n ? m->n : 1, sizeof **sub);
    if (!*sub) return -ENOMEM;
    if (m->spill_bytes) {
        void *p = mmap(NULL, m->spill_bytes, PROT_READ, MAP_SHARED, m->spill, 0);
        if (p == MAP_FAILED) return -errno;
        *map = p;
    }
    for (size_t i = 0; i < m->n; i++) {
        int fresh;
        mpi_book_entry *e = mpi_book_get(&m->book, &m->nodes[i], &fresh);
        if (!e || e->state != 2) return -EPROTO;
        (*sub)[i] = *map + e->off;
    }
    return 0;
}

/* Every node in preorder: the subtrees' (sub[i] their bytes) merged with
 * the top's, into the file (the writer's own vod_assemble, p's layout and
 * parameters, m's output file). */
static int assemble(const prep *p, master *m, const uint8_t *const *sub, const top_part *t,
                    vod_stats *st, err_info *err)
{
    size_t n = m->n + t->n;
    vod_node *nodes = calloc(n ? n : 1, sizeof *nodes);
    vod_encoded *recs = calloc(n ? n : 1, sizeof *recs);
    const uint8_t **data = calloc(n ? n : 1, sizeof *data);
    int rc = nodes && recs && data ? 0 : -ENOMEM;
    for (size_t i = 0, a = 0, b = 0; !rc && i < n; i++) {
        if (b == t->n || (a < m->n && m->nodes[a].preorder < t->nodes[b].preorder)) {
            const mpi_rec *r = &m->nodes[a];
            nodes[i] = (vod_node){.preorder = r->preorder, .level = r->level};
            recs[i] = (vod_encoded){.hash = r->hash, .size = r->size};
            data[i] = sub[a++];
        } else {
            nodes[i] = t->nodes[b];
            recs[i] = t->recs[b];
            data[i] = t->data[b++];
        }
    }
    if (rc) err_set(err, rc, "%s", strerror(-rc));
    /* outfile_write, as vox's writer: the kernel starts writing the file
     * back as it goes, so the commit's fsync has less left to do */
    vod_sink sink = {outfile_write, &m->ctx->out_file};
    vod_assembly a = {.L = &p->L, .p = &p->v, .n = n, .nodes = nodes, .recs = recs, .data = data,
                      .sink = &sink, .st = st, .err = err};
    if (!rc) rc = vod_assemble(&a);
    /* the sink's error has no message of vod_assemble's */
    if (rc && !err->msg[0]) err_set(err, rc, "%s", strerror(-rc));
    free(nodes);
    free(recs);
    free(data);
    return rc;
}

/* The distinct bricks' bytes until the file is assembled: an unnamed file
 * beside OUT (where the file's room is), else in $TMPDIR, unlinked at
 * once; its pages are the kernel's to keep or write back, so rank 0's
 * memory does not grow with the file. */
int mpi_spill_open(const char *path)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", path);
    int fd = open(dirname(dir), O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd >= 0) return fd;
    const char *t = getenv("TMPDIR");
    snprintf(dir, sizeof dir, "%s/vox_mpi.XXXXXX", t && t[0] ? t : "/tmp");
    fd = mkstemp(dir);
    if (fd >= 0) unlink(dir);
    return fd;
}

/* Rank 0's times, in seconds: the job's (its start to the last subtree)
 * and the file's write, which is, by stage (--stats): the top levels (on a
 * thread of their own) beside the subtrees' order, the assembly (of which
 * the sink's writes), the commit (fsync, link). */
typedef struct {
    double job, write;
    double top, order, assemble, commit;
} tail_times;

static void print_stats(const prep *p, const master *m, const rank_stats *all,
                        const engine_pipeline_report *r, const tail_times *tt)
{
    const grid_spec *g = &r->grid;
    const int nranks = m->ctx->nranks;
    char(*hosts)[HOST_MAX] = m->ctx->all_hosts;
    uint64_t workers = 0;
    int same = 1;
    for (int i = 0; i < nranks; i++) {
        workers += all[i].workers;
        same &= all[i].workers == all[0].workers;
    }
    char how[64];
    if (same)
        snprintf(how, sizeof how, "%d rank%s x %u worker%s", nranks, nranks > 1 ? "s" : "",
                 all[0].workers, all[0].workers == 1 ? "" : "s");
    else
        snprintf(how, sizeof how, "%d ranks, %llu workers in all", nranks,
                 (unsigned long long)workers);
    char tasks[96];
    uint32_t side = 1u << p->cut.level;
    if (p->kind == MPI_KIND_MESH)
        snprintf(tasks, sizeof tasks, "%zu columns of %ux%u voxels through z", p->cut.n,
                 side, side);
    else
        snprintf(tasks, sizeof tasks, "%zu subtrees of %u^3 voxels", p->cut.n, side);
    printf("%s: %llu voxels%s on a %ux%ux%u grid in %.3f s on %s (%s), VOD written in "
           "%.3f s\n", p->o.out, (unsigned long long)m->voxels,
           p->kind == MPI_KIND_CSG ? " at or above S" : "", g->res[0], g->res[1], g->res[2],
           tt->job, how, tasks, tt->write);
    printf("  %llu bytes, %llu bricks (%llu non-empty nodes), CRC %08x\n",
           (unsigned long long)r->st.file_bytes, (unsigned long long)r->st.bricks,
           (unsigned long long)r->st.nonempty_nodes, r->st.crc32);
    uint64_t total = 0;
    for (int i = 0; i < nranks; i++) total += all[i].bytes;
    printf("  sent to rank 0: %llu bytes (", (unsigned long long)total);
    for (int i = 0; i < nranks; i++)
        printf("%srank %d %llu", i ? ", " : "", i, (unsigned long long)all[i].bytes);
    printf("); rank 0 sent %llu bytes of tasks and requests\n",
           (unsigned long long)m->sent_bytes);
    if (!p->stats) return;
    printf("  rank 0's end: top levels %.3f s beside the records' order %.3f s, assembly "
           "%.3f s (writes %.3f s), commit %.3f s\n", tt->top, tt->order, tt->assemble,
           r->st.t.write, tt->commit);
    printf("  rank  host              subtrees   nodes  bricks sent  brick bytes   bytes sent  busy s  workers\n");
    for (int i = 0; i < nranks; i++)
        printf("  %4d  %-16.16s  %8llu  %6llu  %11llu  %11llu  %11llu  %6.3f  %7u\n", i,
               hosts[i], (unsigned long long)all[i].subtrees,
               (unsigned long long)all[i].nodes, (unsigned long long)all[i].bricks,
               (unsigned long long)all[i].brick_bytes, (unsigned long long)all[i].bytes,
               all[i].busy, all[i].workers);
}

/* Rank 0's end, after the last subtree: the top levels (a thread) beside
 * the subtrees' order, then the assembly and the commit. */
static int write_file(prep *p, master *m, engine_pipeline_report *r, tail_times *tt,
                      err_info *err)
{
    double t0 = clock_now();
    top_part t = {.top = m->top, .v = &p->v};
    pthread_t th;
    int threaded = pthread_create(&th, NULL, top_thread, &t) == 0;
    if (!threaded) top_thread(&t);
    const uint8_t *map, **sub;
    int rc = order_subtrees(m, &map, &sub);
    tt->order = clock_now() - t0;
    if (threaded) pthread_join(th, NULL);
    tt->top = t.secs;
    if (!rc) rc = t.rc;
    if (rc) err_set(err, rc, "the levels above the subtrees: %s", strerror(-rc));
    double t1 = clock_now();
    if (!rc) rc = assemble(p, m, sub, &t, &r->st, err);
    tt->assemble = clock_now() - t1;
    if (map) munmap((void *)map, m->spill_bytes);
    free(sub);
    top_part_free(&t);
    double t2 = clock_now();
    if (!rc) rc = outfile_commit(&m->ctx->out_file, p->o.out);
    tt->commit = clock_now() - t2;
    return rc;
}

void mpi_finish_file(prep *p, master *m, rank_stats *all, double t0)
{
    tail_times tt = {.job = clock_now() - t0};
    err_info err = {0};
    engine_pipeline_report r = p->plan;
    double t1 = clock_now();
    int rc = write_file(p, m, &r, &tt, &err);
    if (rc) {
        progress_done(&m->pr);
        mpi_msg("cannot write %s: %s", p->o.out, err.msg[0] ? err.msg : strerror(-rc));
        abort_job(m->ctx);
    }
    progress_done(&m->pr);
    tt.write = clock_now() - t1;
    if (!p->o.quiet) print_stats(p, m, all, &r, &tt);
}

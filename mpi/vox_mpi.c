/* vox_mpi — vox voxelize over the ranks of an Open MPI job (docs/mpi.md).
 *
 * Every rank is a slave of rank 0, one level above the engine's own
 * master–worker scheme: it asks rank 0 for a subtree, runs the engine that
 * vox runs (its forked, pinned workers, which never call MPI) on it,
 * encodes its bricks, sends their records and content keys, and then only
 * the bricks rank 0 asks for (those it holds no copy of).  Rank 0 cuts the
 * job into subtrees, hands them out on request, works on them too (a
 * thread of its own, a slave like the others), makes the levels above the
 * subtrees, and writes the file: the bytes vox voxelize writes.
 *
 * Messages: the job is broadcast once; then on the "up" communicator (to
 * rank 0) REQ (the first request), NODES (a subtree's records, its voxel
 * count and its top brick's voxels), BRICKS (the bytes asked for, in the
 * order asked), FAIL (a message); on the "down" one (from rank 0) TASK (a
 * subtree, or none left) and WANT (the records whose bytes to send).  A
 * rank's next TASK comes once its exchange is over.  Two communicators,
 * so that rank 0's two threads (MPI_THREAD_MULTIPLE) never take each
 * other's messages.  Waits poll (MPI_Iprobe and a short sleep) instead of
 * blocking: Open MPI's blocking calls spin, and the cores are the
 * workers'.
 */
#include <mpi.h>

#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "cli.h"
#include "csg.h"
#include "mesh.h"
#include "clock.h"
#include "engine.h"
#include "mpi_part.h"
#include "outfile.h"
#include "pipeline.h"
#include "par.h"
#include "progress.h"
#include "source.h"
#include "vod.h"
#include "voxel.h"

enum { TAG_REQ = 1, TAG_NODES, TAG_BRICKS, TAG_FAIL, /* up, to rank 0 */
       TAG_TASK = 11, TAG_WANT };                   /* down, from rank 0 */

#define SUBTREES_PER_RANK 8
#define HOST_MAX 64

/* The job as broadcast; status >= 0: every rank exits with it.  Behind
 * it, input_bytes of the job's input: an implicit job's tape, a CSG job's
 * tree (mpi_csg_pack); a mesh job's triangles go with its tasks. */
typedef struct {
    int32_t status, schedule;
    int32_t kind, pad;   /* mpi_kind */
    uint32_t workers, shm_mib;
    grid_spec grid;
    vod_params vod;      /* metadata NULL */
    mesh_vox_opts mesh_opts;
    uint32_t node_level, pad2;
    uint64_t input_bytes;
    char cpus[128];
} wire_job;

/* A task: an octant, or a mesh job's column followed by its triangles
 * (mpi_mesh_part). */
typedef struct {
    int32_t index;       /* -1: no subtree left */
    grid_octant o;
} wire_task;

typedef struct {
    uint64_t voxels;
    uint32_t n, ntops, npairs, pad; /* then n mpi_rec, ntops mpi_topref, npairs mpi_pair */
} wire_nodes;

/* What a rank did, gathered by rank 0 at the end. */
typedef struct {
    uint32_t workers, pad;       /* this rank's */
    uint64_t bytes, messages;    /* sent to rank 0 */
    uint64_t subtrees, nodes, bricks, brick_bytes;
    double busy;                 /* seconds voxelizing and encoding */
} rank_stats;

static MPI_Comm up, down;
static int me, nranks;
static int local_rank, local_size; /* among the ranks on this host */

#define WORKERS_AUTO UINT32_MAX /* -w not given: each rank decides */
static char hosts[1][HOST_MAX]; /* this rank's; rank 0 has all in all_hosts */
static char (*all_hosts)[HOST_MAX];
static outfile out_file;        /* rank 0's unfinished file: the signals remove
                                   it when it has a name (outfile.h) */

static void msg(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static void msg(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "vox_mpi: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "\n");
    va_end(ap);
}

/* Wait for a message without spinning: probe, then sleep a little longer
 * each time up to half a millisecond. */
static void wait_msg(MPI_Comm c, int src, int tag, MPI_Status *st)
{
    int flag = 0;
    long ns = 20000;
    for (;;) {
        MPI_Iprobe(src, tag, c, &flag, st);
        if (flag) return;
        struct timespec ts = {0, ns};
        nanosleep(&ts, NULL);
        if (ns < 500000) ns *= 2;
    }
}

/* The message st announced, into a new buffer (its size in *n). */
static void *recv_msg(MPI_Comm c, MPI_Status *st, int *n)
{
    MPI_Get_count(st, MPI_BYTE, n);
    void *buf = malloc(*n ? (size_t)*n : 1);
    if (!buf) {
        msg("rank %d on %s: out of memory for a message of %d bytes", me, hosts[0], *n);
        MPI_Abort(MPI_COMM_WORLD, 1);
    }
    MPI_Recv(buf, *n, MPI_BYTE, st->MPI_SOURCE, st->MPI_TAG, c, MPI_STATUS_IGNORE);
    return buf;
}

/* ---------------------------------------------------------------- slaves */

typedef struct {
    mpi_subtree_job sj;
    rank_stats st;
    int rc;
} slave;

static void send_up(slave *s, const void *buf, size_t n, int tag)
{
    MPI_Send(buf, (int)n, MPI_BYTE, 0, tag, up);
    s->st.bytes += n;
    s->st.messages++;
}

/* A task's exchange: its records, then the bytes rank 0 wants. */
static int on_bricks(void *ud, const mpi_bricks *b)
{
    slave *s = ud;
    size_t recs = b->n * sizeof(mpi_rec), tops = b->ntops * sizeof(mpi_topref);
    size_t n = sizeof(wire_nodes) + recs + tops + b->npairs * sizeof(mpi_pair);
    if (n > INT32_MAX) return -E2BIG;
    uint8_t *m = malloc(n);
    if (!m) return -ENOMEM;
    wire_nodes h = {.voxels = b->voxels, .n = (uint32_t)b->n, .ntops = (uint32_t)b->ntops,
                    .npairs = (uint32_t)b->npairs};
    memcpy(m, &h, sizeof h);
    if (recs) memcpy(m + sizeof h, b->recs, recs);
    if (tops) memcpy(m + sizeof h + recs, b->tops, tops);
    if (b->npairs)
        memcpy(m + sizeof h + recs + tops, b->pairs, b->npairs * sizeof(mpi_pair));
    send_up(s, m, n, TAG_NODES);
    free(m);
    s->st.nodes += b->n;
    MPI_Status st;
    wait_msg(down, 0, TAG_WANT, &st);
    int wn;
    uint32_t *want = recv_msg(down, &st, &wn);
    size_t k = (size_t)wn / sizeof *want, bytes = 0;
    for (size_t i = 0; i < k; i++) {
        if (want[i] >= b->n) { free(want); return -EPROTO; }
        bytes += b->recs[want[i]].size;
    }
    int rc = 0;
    if (k && bytes <= INT32_MAX && (m = malloc(bytes))) {
        size_t at = 0;
        for (size_t i = 0; i < k; i++) {
            memcpy(m + at, b->data[want[i]], b->recs[want[i]].size);
            at += b->recs[want[i]].size;
        }
        send_up(s, m, bytes, TAG_BRICKS);
        free(m);
        s->st.bricks += k;
        s->st.brick_bytes += bytes;
    } else if (k) {
        rc = bytes > INT32_MAX ? -E2BIG : -ENOMEM;
    }
    free(want);
    return rc;
}

/* The next task from rank 0 (a mesh job's triangles with it, in *buf
 * for the task's time): 0, 1 when none is left, or -EPROTO. */
static int next_task(slave *s, wire_task *t, uint8_t **buf, mesh *m)
{
    MPI_Status st;
    int n;
    wait_msg(down, 0, TAG_TASK, &st);
    *buf = recv_msg(down, &st, &n);
    if ((size_t)n < sizeof *t) return -EPROTO;
    memcpy(t, *buf, sizeof *t);
    if (t->index < 0) return 1;
    if (s->sj.kind != MPI_KIND_MESH) return (size_t)n == sizeof *t ? 0 : -EPROTO;
    if (mpi_mesh_view(*buf + sizeof *t, (size_t)n - sizeof *t, m)) return -EPROTO;
    s->sj.mesh = m;
    return 0;
}

/* Ask, run, exchange, until rank 0 says there is nothing left; a failure
 * goes to rank 0 as a message (it ends the job). */
static int slave_loop(slave *s)
{
    send_up(s, "", 0, TAG_REQ);
    for (;;) {
        wire_task t;
        uint8_t *buf;
        mesh part;
        char err[400], m[600];
        int rc = next_task(s, &t, &buf, &part);
        if (rc == 1) {
            free(buf);
            return 0;
        }
        double t0 = clock_now();
        if (rc) snprintf(err, sizeof err, "a task came damaged");
        else rc = mpi_subtree_run(&s->sj, t.o, on_bricks, s, err, sizeof err);
        s->st.busy += clock_now() - t0;
        s->sj.mesh = NULL;
        free(buf);
        if (rc) {
            int k = snprintf(m, sizeof m, "%s", err[0] ? err : strerror(-rc));
            send_up(s, m, (size_t)(k < (int)sizeof m ? k : (int)sizeof m - 1) + 1, TAG_FAIL);
            return rc;
        }
        s->st.subtrees++;
    }
}

/* The CPUs this rank may run on, in order; how many. */
static int rank_cpus(int *cpus, int cap)
{
    cpu_set_t set;
    int n = 0;
    if (sched_getaffinity(0, sizeof set, &set)) return 0;
    for (int c = 0; c < CPU_SETSIZE && n < cap; c++)
        if (CPU_ISSET(c, &set)) cpus[n++] = c;
    return n;
}

/* Where the workers go without --cpus: the rank's CPUs, the list turned
 * by the workers of the ranks before it on this host, so that ranks that
 * mpirun did not bind (each sees every CPU) do not pin their workers to
 * the same ones; a bound rank's own CPUs are unchanged by it.  And how
 * many without -w: the rank's CPUs, shared with the host's other ranks
 * when they are not bound. */
static int place_workers(const wire_job *j, uint32_t *workers, int *cpus)
{
    int all[ENGINE_MAX_WORKERS], n = rank_cpus(all, ENGINE_MAX_WORKERS);
    long online = sysconf(_SC_NPROCESSORS_ONLN);
    uint32_t w = j->workers;
    if (w == WORKERS_AUTO) {
        int share = n >= online && local_size > 1 ? n / local_size : n;
        w = share > 0 ? (uint32_t)share : 1;
    }
    *workers = w;
    if (j->cpus[0]) return cli_parse_cpus(j->cpus, cpus, ENGINE_MAX_WORKERS);
    for (int i = 0; i < n; i++) cpus[i] = all[(i + (size_t)local_rank * w) % (size_t)n];
    return n;
}

/* The engine of this rank (none with -w 0), then the loop; called in the
 * thread that then owns the engine (its workers die with that thread). */
static int slave_run(slave *s, const wire_job *j)
{
    engine *e = NULL;
    int cpus[ENGINE_MAX_WORKERS], ncpus = place_workers(j, &s->st.workers, cpus);
    if (s->st.workers) {
        engine_opts eo = {.workers = (int)s->st.workers, .cpus = ncpus > 0 ? cpus : NULL,
                          .ncpus = ncpus > 0 ? ncpus : 0,
                          .shm_bytes = (size_t)j->shm_mib << 20,
                          .shm_option = "--shm-size"};
        char err[256] = "", m[400];
        int rc = engine_create(&eo, &e, err, sizeof err);
        if (rc) {
            int k = snprintf(m, sizeof m, "cannot start the engine: %s",
                             err[0] ? err : strerror(-rc));
            send_up(s, m, (size_t)(k < (int)sizeof m ? k : (int)sizeof m - 1) + 1, TAG_FAIL);
            return rc;
        }
    }
    s->sj.e = e;
    int rc = slave_loop(s);
    engine_destroy(e);
    return rc;
}

/* Rank 0's own slave: its state and its job, for its thread. */
typedef struct {
    slave s;
    wire_job j;
} own_slave;

static void *slave_thread(void *ud)
{
    own_slave *o = ud;
    o->s.rc = slave_run(&o->s, &o->j);
    return NULL;
}

/* ---------------------------------------------------------------- rank 0 */

typedef struct {
    int task;            /* the subtree it holds, -1 none */
    mpi_rec *want;       /* the records asked for, waiting for BRICKS */
    size_t nwant;
} rank_state;

typedef struct {
    const mpi_cut *cut;
    const grid_spec *grid;
    mpi_kind kind;
    const mesh *mesh;        /* a mesh job's: its triangles go out with the tasks */
    const mesh_bins *bins;   /* ... binned to the tiles; NULL: every triangle
                                goes with every task (the winding number's repair) */
    mpi_book book;
    mpi_rec *nodes;      /* every node of the file, in arrival order */
    size_t n, cap;
    int spill;           /* the distinct bricks' bytes, an unlinked file */
    uint64_t spill_bytes;
    mpi_top *top;
    rank_state *rs;
    size_t next, done;
    uint64_t voxels, sent_bytes;
    progress pr;
} master;

/* Everything rank 0 made is dropped, the unfinished file too; the other
 * ranks are killed by MPI_Abort (their workers die with them). */
static void abort_job(void)
{
    outfile_abort(&out_file);
    MPI_Abort(MPI_COMM_WORLD, 1);
    _exit(1);
}

static void on_signal(int sig)
{
    static const char m[] = "vox_mpi: rank 0 stopped by a signal (mpirun stops every "
                            "rank when one fails; its message names the rank and host); "
                            "no file written\n";
    if (out_file.named) unlink(out_file.tmp);
    ssize_t w = write(2, m, sizeof m - 1);
    (void)w;
    _exit(128 + sig);
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

static void fail_master(master *m, const char *what, int rc)
{
    progress_done(&m->pr);
    msg("rank 0 on %s: %s: %s", all_hosts[0], what, strerror(-rc));
    abort_job();
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
        fail_master(m, "the triangles of a column", rc ? rc : msg_buf ? -E2BIG : -ENOMEM);
    memcpy(msg_buf, t, sizeof *t);
    memcpy(msg_buf + sizeof *t, part, n);
    free(part);
    MPI_Send(msg_buf, (int)(sizeof *t + n), MPI_BYTE, r, TAG_TASK, down);
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
    MPI_Send(&t, sizeof t, MPI_BYTE, r, TAG_TASK, down);
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
    MPI_Send(want, (int)(rs->nwant * sizeof *want), MPI_BYTE, r, TAG_WANT, down);
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
static void serve(master *m)
{
    int active = nranks;
    while (active) {
        MPI_Status st;
        wait_msg(up, MPI_ANY_SOURCE, MPI_ANY_TAG, &st);
        int r = st.MPI_SOURCE, n, rc = 0;
        uint8_t *buf = recv_msg(up, &st, &n);
        if (st.MPI_TAG == TAG_FAIL) {
            progress_done(&m->pr);
            buf[n ? n - 1 : 0] = '\0';
            msg("rank %d on %s failed: %s", r, all_hosts[r], n ? (char *)buf : "?");
            abort_job();
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
            snprintf(what, sizeof what, "the bricks of rank %d on %s", r, all_hosts[r]);
            fail_master(m, what, rc);
        }
        if (st.MPI_TAG == TAG_REQ) {
            send_task(m, r);
            if (m->rs[r].task < 0) active--;
        }
    }
}

static int put_top(void *ud, const vod_node *n, const vod_encoded *rec, const uint8_t *data)
{
    master *m = ud;
    mpi_rec r = {.preorder = n->preorder, .level = n->level, .hash = rec->hash,
                 .size = rec->size};
    mpi_key(data, rec->size, r.key);
    int fresh, rc = 0;
    mpi_book_entry *e = mpi_book_get(&m->book, &r, &fresh);
    if (!e) return -ENOMEM;
    if (fresh) rc = spill(m, e, data);
    return rc ? rc : push_node(m, &r);
}

static int by_preorder(const void *a, const void *b)
{
    uint64_t x = ((const mpi_rec *)a)->preorder, y = ((const mpi_rec *)b)->preorder;
    return x < y ? -1 : x > y;
}

/* Every node in preorder, its bytes from the spill: the file. */
static int assemble(master *m, const vod_layout *L, const vod_params *v, int fd,
                    vod_stats *st, char *err, size_t errlen)
{
    qsort(m->nodes, m->n, sizeof *m->nodes, by_preorder);
    size_t n = m->n;
    vod_node *nodes = calloc(n ? n : 1, sizeof *nodes);
    vod_encoded *recs = calloc(n ? n : 1, sizeof *recs);
    const uint8_t **data = calloc(n ? n : 1, sizeof *data);
    const uint8_t *map = NULL;
    int rc = nodes && recs && data ? 0 : -ENOMEM;
    if (!rc && m->spill_bytes) {
        void *p = mmap(NULL, m->spill_bytes, PROT_READ, MAP_SHARED, m->spill, 0);
        if (p == MAP_FAILED) rc = -errno;
        else map = p;
    }
    for (size_t i = 0; !rc && i < n; i++) {
        int fresh;
        mpi_book_entry *e = mpi_book_get(&m->book, &m->nodes[i], &fresh);
        if (!e || e->state != 2) rc = -EPROTO;
        else {
            nodes[i] = (vod_node){.preorder = m->nodes[i].preorder, .level = m->nodes[i].level};
            recs[i] = (vod_encoded){.hash = m->nodes[i].hash, .size = m->nodes[i].size};
            data[i] = map + e->off;
        }
    }
    if (rc) snprintf(err, errlen, "%s", strerror(-rc));
    vod_sink sink = {vod_fd_write, (void *)(intptr_t)fd};
    if (!rc) rc = vod_assemble(L, v, n, nodes, recs, data, &sink, st, err, errlen);
    if (rc && !err[0]) snprintf(err, errlen, "%s", strerror(-rc));
    if (map) munmap((void *)map, m->spill_bytes);
    free(nodes);
    free(recs);
    free(data);
    return rc;
}

/* ---- rank 0's file ---- */

/* The distinct bricks' bytes until the file is assembled: an unnamed file
 * beside OUT (where the file's room is), else in $TMPDIR, unlinked at
 * once; its pages are the kernel's to keep or write back, so rank 0's
 * memory does not grow with the file. */
static int spill_open(const char *path)
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

/* ---- rank 0's preparation: options, source, plan, cut ---- */

typedef struct {
    cli_job_opts o;
    int stats;
    uint32_t per_rank;
    /* --source-name: the name the file's metadata gives the source (voxd
     * runs a client's job from a private copy); "" none */
    const char *source_name;
    mpi_kind kind;
    source src;
    expr_tape *tape;       /* implicit */
    mesh mesh;             /* mesh (mesh_loaded) */
    int mesh_loaded;
    mesh_vox_opts run_opts; /* ... the repair as run: none when watertight */
    mesh_topo topo;
    mesh_bins bins;        /* ... the triangles of each tile (none: winding) */
    csg_tree *tree;        /* csg */
    uint8_t *input;        /* what follows the job: the tape, the packed tree */
    size_t input_bytes;
    vod_params v;
    char meta[JOB_META_MAX];
    vod_layout L;
    pipeline_report plan;
    mpi_cut cut;
    int fd;
} prep;

static void usage(FILE *f)
{
    fprintf(f,
"usage: mpirun [mpirun options] vox_mpi voxelize (-e EXPR | -f FILE) -o OUT [options]\n"
"       mpirun [mpirun options] vox_mpi voxelize --mesh FILE -o OUT [options]\n"
"       mpirun [mpirun options] vox_mpi csg FILE -o OUT -r N [vox csg's options]\n"
"\n"
"vox voxelize's and vox csg's jobs over the ranks of an MPI job: rank 0 cuts\n"
"the grid into subtrees (an implicit job's by its interval tests, a CSG job's\n"
"into cubes of whole bricks, a mesh job's into columns through z, each sent\n"
"with the triangles it needs) and hands them out on request, every rank (rank 0\n"
"too) runs the engine on them with -w workers of its own, and rank 0 writes\n"
"OUT, the same bytes vox voxelize -w W (vox csg -w W) writes for the job.\n"
"Only rank 0 reads files: the other hosts need the vox_mpi binary alone.\n"
"\n"
"voxelize takes vox voxelize's options (vox voxelize --help), --mesh's too\n"
"(--mode, --repair, --supersample, --pad, --bbox, --weld, --channel); csg takes vox\n"
"csg's (vox csg --help: -o, -r, -c, -d, -w, -Z, -q), its FILE a file.\n"
"\n"
"  -e, --expr EXPR       the implicit function F(x,y,z)\n"
"  -f, --file FILE       ... from a .vx file (its #@ directives apply)\n"
"  -o, --output FILE     the VOD file, written by rank 0 under a temporary\n"
"                        name and renamed when complete\n"
"  -r, --res N           voxels along the longest axis (default 256)\n"
"  -d, --domain A,B | X0,X1,Y0,Y1,Z0,Z1\n"
"                        the domain (default [-1,1]^3)\n"
"  -w, --workers N       worker processes per rank (default: the CPUs the\n"
"                        rank may run on; 0: the serial algorithm per rank)\n"
"      --cpus LIST       CPUs to pin each rank's workers to\n"
"      --shm-size MiB    each rank's shared-memory segment (default 2048)\n"
"      --schedule subtree|paper, --channel, --brick, --compress,\n"
"      --compress-level, --hash\n"
"                        as vox voxelize (vox voxelize --help)\n"
"      --subtrees N      subtrees (mesh: columns) per rank to aim for (default %d)\n"
"      --stats           a line per rank: host, subtrees, bricks and bytes sent\n"
"      --progress        the progress line, by subtrees done\n"
"      --source-name NAME  the source's name in the file's metadata (voxd's;\n"
"                        \"\" for none)\n"
"  -q, --quiet           no summary\n"
"\n"
"Under mpirun: --mca btl self,tcp for ranks on several hosts over TCP,\n"
"--oversubscribe for more ranks than cores; as root, --allow-run-as-root\n"
"(docs/mpi.md).\n", SUBTREES_PER_RANK);
}

/* Take vox_mpi's own options out of argv (the rest is vox voxelize's). */
static int own_options(prep *p, int *argc, char **argv)
{
    int k = 0;
    for (int i = 0; i < *argc; i++) {
        if (!strcmp(argv[i], "--stats")) {
            p->stats = 1;
        } else if (!strcmp(argv[i], "--subtrees")) {
            if (i + 1 >= *argc || cli_parse_uint(argv[i + 1], 1, 4096, &p->per_rank)) {
                msg("bad --subtrees: want a whole number from 1 to 4096");
                return CLI_EXIT_USAGE;
            }
            i++;
        } else if (!strcmp(argv[i], "--source-name")) {
            if (i + 1 >= *argc) {
                msg("--source-name wants a name (\"\" for none)");
                return CLI_EXIT_USAGE;
            }
            p->source_name = argv[++i];
        } else if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return CLI_EXIT_OK;
        } else {
            argv[k++] = argv[i];
        }
    }
    *argc = k;
    return -1;
}

/* The source's name in the file's metadata: --source-name's, else the
 * file's. */
static const char *source_name(const prep *p, const char *file)
{
    return !p->source_name ? file : p->source_name[0] ? p->source_name : NULL;
}

static int prepare_implicit(prep *p, pipeline_job *pj)
{
    int rc = cli_job_source(&p->o, &p->src, &p->tape);
    if (rc) return rc;
    p->kind = MPI_KIND_IMPLICIT;
    pj->kind = PIPELINE_IMPLICIT;
    pj->implicit.tape = p->tape;
    pj->implicit.source = p->src.text;
    pj->implicit.source_len = p->src.len;
    pj->implicit.source_name = source_name(p, p->src.path);
    p->input = (uint8_t *)p->tape;
    p->input_bytes = expr_tape_bytes(p->tape);
    return -1;
}

static int prepare_mesh(prep *p, pipeline_job *pj)
{
    mesh_error merr;
    if (mesh_load(p->o.mesh, MESH_FORMAT_AUTO, NULL, &p->mesh, &merr)) {
        char m[sizeof merr.msg + 64];
        msg("%s: %s", p->o.mesh, mesh_error_str(&merr, m, sizeof m));
        return CLI_EXIT_USAGE;
    }
    if (p->mesh.warning[0]) msg("warning: %s: %s", p->o.mesh, p->mesh.warning);
    if (p->o.weld >= 0 && mesh_weld(&p->mesh, p->o.weld, NULL)) {
        msg("%s: no triangle is left once welded at %g (or no memory)", p->o.mesh, p->o.weld);
        mesh_free(&p->mesh);
        return CLI_EXIT_USAGE;
    }
    p->mesh_loaded = 1;
    p->kind = MPI_KIND_MESH;
    struct stat sb;
    pj->kind = PIPELINE_MESH;
    pj->mesh.mesh = &p->mesh;
    pj->mesh.opts = p->o.mesh_opts;
    pj->mesh.pad = p->o.pad;
    pj->mesh.fit = !p->o.has_domain;
    pj->mesh.source_name = source_name(p, p->o.mesh);
    pj->mesh.source_bytes = stat(p->o.mesh, &sb) == 0 ? (uint64_t)sb.st_size : 0;
    return -1;
}

/* vox csg's options into the job's (the rest of vox_mpi reads those). */
static int prepare_csg(prep *p, int argc, char **argv, pipeline_job *pj)
{
    cli_csg_opts co;
    int rc = cli_csg_parse(argc, argv, &co);
    if (rc) return rc < 0 ? CLI_EXIT_OK : rc;
    if (!strcmp(co.in, "-")) {
        msg("vox_mpi csg reads its tree from a file, not standard input");
        return CLI_EXIT_USAGE;
    }
    uint64_t text_bytes;
    if ((rc = cli_csg_load(co.in, &p->tree, &text_bytes))) return rc;
    p->kind = MPI_KIND_CSG; /* prep_free frees the packed tree */
    if ((rc = mpi_csg_pack(p->tree, &p->input, &p->input_bytes))) {
        msg("%s: %s", co.in, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (p->input_bytes > INT32_MAX) { /* one broadcast */
        msg("%s: the tree and its files' bytes pass 2 GiB; vox_mpi broadcasts them at once",
            co.in);
        return CLI_EXIT_USAGE;
    }
    p->o.out = co.out;
    p->o.quiet = co.quiet;
    p->o.res = co.res;
    if (co.workers_given) p->o.workers = co.workers;
    p->o.shm_mib = 0; /* vox csg's: the engine's default */
    vod_params_default(&p->o.vod);
    p->o.vod.channel = co.channel;
    p->o.vod.comp = co.comp;
    memcpy(p->o.lo, co.lo, sizeof co.lo);
    memcpy(p->o.hi, co.hi, sizeof co.hi);
    pj->kind = PIPELINE_CSG;
    pj->csg.tree = p->tree;
    pj->csg.source_name = source_name(p, co.in);
    pj->csg.source_bytes = text_bytes;
    return -1;
}

/* The options of vox voxelize or vox csg, the job's input loaded. */
static int prepare_kind(prep *p, int argc, char **argv, pipeline_job *pj)
{
    cli_job_defaults(&p->o);
    p->o.workers = WORKERS_AUTO;
    if (argc >= 2 && !strcmp(argv[1], "csg")) return prepare_csg(p, argc - 1, argv + 1, pj);
    if (argc < 2 || strcmp(argv[1], "voxelize")) {
        usage(stderr);
        return CLI_EXIT_USAGE;
    }
    int rc = cli_job_parse(CLI_CMD_VOXELIZE, argc - 1, argv + 1, &p->o);
    if (rc) return rc;
    if (p->o.mode == CLI_MODE_DAEMON) {
        msg("--daemon: vox_mpi runs its jobs itself, never on a voxd");
        return CLI_EXIT_USAGE;
    }
    if (p->o.res > GRID_MAX_RES) {
        msg("bad --res '%s': want a whole number from 1 to %u", p->o.res_arg, GRID_MAX_RES);
        return CLI_EXIT_USAGE;
    }
    /* its columns without triangles hold +w, and the ranks take no empty
     * mesh yet */
    if (p->o.vod.channel == VOXEL_CH_DISTANCE) {
        msg("--channel distance is not available through vox_mpi yet: use vox voxelize");
        return CLI_EXIT_USAGE;
    }
    return p->o.mesh ? prepare_mesh(p, pj) : prepare_implicit(p, pj);
}

/* A mesh job's topology (the repair dropped when the mesh is watertight,
 * as pipeline_run drops it) and its triangles binned to the tiles. */
static int prepare_bins(prep *p)
{
    p->run_opts = p->o.mesh_opts;
    int rc = mesh_topology(&p->mesh, &p->topo);
    if (!rc && p->topo.watertight) p->run_opts.repair = MESH_REPAIR_NONE;
    if (!rc && p->run_opts.repair != MESH_REPAIR_WINDING)
        rc = mesh_bin(&p->mesh, &p->plan.grid, &p->run_opts, NULL, par_cpus(), &p->bins);
    if (rc) msg("%s: the mesh's edges and tiles: %s", p->o.mesh, strerror(-rc));
    return rc;
}

/* A mesh job's columns without a triangle are left out: they hold no
 * voxel, and a rank gets no empty mesh. */
static void drop_empty_columns(prep *p)
{
    size_t k = 0;
    for (size_t i = 0; i < p->cut.n; i++) {
        uint32_t t[4];
        mpi_column_tiles(&p->plan.grid, p->cut.oct[i], t);
        int any = 0;
        for (uint32_t ty = t[1]; ty < t[3] && !any; ty++)
            for (uint32_t tx = t[0]; tx < t[2] && !any; tx++) {
                uint64_t c = (uint64_t)ty * p->bins.tiles[0] + tx;
                any = p->bins.start[c + 1] > p->bins.start[c];
            }
        if (any) p->cut.oct[k++] = p->cut.oct[i];
    }
    p->cut.n = k;
}

/* The cut: an implicit job's by the kernel's interval tests; a CSG job's
 * octants of whole storage bricks; a mesh job's columns of whole tiles. */
static int make_cut(prep *p)
{
    size_t target = (size_t)p->per_rank * nranks;
    if (p->kind == MPI_KIND_IMPLICIT)
        return mpi_cut_make(p->tape, &p->plan.grid, &p->L, target, &p->cut);
    if (p->kind == MPI_KIND_CSG)
        return mpi_cut_grid(&p->plan.grid, &p->L, target, 4 /* CSG_VOLUME_BRICK */, 0,
                            &p->cut);
    int rc = mpi_cut_grid(&p->plan.grid, &p->L, target, 6 /* MESH_TILE */, 1, &p->cut);
    if (!rc && p->bins.start) drop_empty_columns(p);
    return rc;
}

/* -1 when the job is ready to run; else the exit code of every rank. */
static int prepare(prep *p, int argc, char **argv)
{
    p->per_rank = SUBTREES_PER_RANK;
    p->fd = -1;
    int rc = own_options(p, &argc, argv);
    if (rc >= 0) return rc;
    pipeline_job pj = {0};
    if ((rc = prepare_kind(p, argc, argv, &pj)) >= 0) return rc;
    memcpy(pj.lo, p->o.lo, sizeof pj.lo);
    memcpy(pj.hi, p->o.hi, sizeof pj.hi);
    pj.res = p->o.res;
    pj.schedule = p->o.schedule;
    pj.vod = p->o.vod;
    char err[256];
    if (pipeline_plan(&pj, &p->plan, &p->v, p->meta) ||
        vod_layout_make(&p->v, p->plan.grid.depth, &p->L, err, sizeof err)) {
        msg("%s", p->plan.err.message[0] ? p->plan.err.message : err);
        return CLI_EXIT_USAGE;
    }
    if (p->kind == MPI_KIND_MESH && prepare_bins(p)) return CLI_EXIT_FAILED;
    if ((rc = make_cut(p))) {
        msg("cutting the job into subtrees: %s", strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    /* unnamed until complete (outfile.h): no kill, not even mpirun's
     * SIGKILL, leaves a partial file */
    if ((rc = outfile_open(&out_file, p->o.out))) {
        msg("cannot create %s: %s", p->o.out, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    p->fd = out_file.fd;
    return -1;
}

static void print_stats(const prep *p, const master *m, const rank_stats *all,
                        const pipeline_report *r, double t_job, double t_write)
{
    const grid_spec *g = &r->grid;
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
           t_job, how, tasks, t_write);
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
    printf("  rank  host              subtrees   nodes  bricks sent  brick bytes   bytes sent  busy s  workers\n");
    for (int i = 0; i < nranks; i++)
        printf("  %4d  %-16.16s  %8llu  %6llu  %11llu  %11llu  %11llu  %6.3f  %7u\n", i,
               all_hosts[i], (unsigned long long)all[i].subtrees,
               (unsigned long long)all[i].nodes, (unsigned long long)all[i].bricks,
               (unsigned long long)all[i].brick_bytes, (unsigned long long)all[i].bytes,
               all[i].busy, all[i].workers);
}

static void finish_file(prep *p, master *m, rank_stats *all, double t0)
{
    double t_job = clock_now() - t0;
    char err[256] = "";
    int rc = mpi_top_encode(m->top, &p->v, put_top, m);
    if (rc) fail_master(m, "the levels above the subtrees", rc);
    pipeline_report r = p->plan;
    double t1 = clock_now();
    rc = assemble(m, &p->L, &p->v, p->fd, &r.st, err, sizeof err);
    if (!rc) rc = outfile_commit(&out_file, p->o.out);
    if (rc) {
        progress_done(&m->pr);
        msg("cannot write %s: %s", p->o.out, err[0] ? err : strerror(-rc));
        abort_job();
    }
    progress_done(&m->pr);
    if (!p->o.quiet) print_stats(p, m, all, &r, t_job, clock_now() - t1);
}

static wire_job job_of(const prep *p)
{
    wire_job j = {.status = -1, .schedule = p->o.schedule, .kind = p->kind,
                  .workers = p->o.workers, .shm_mib = p->o.shm_mib, .grid = p->plan.grid,
                  .vod = p->v, .mesh_opts = p->run_opts, .node_level = p->cut.node_level,
                  .input_bytes = p->input_bytes};
    j.vod.metadata = NULL;
    if (p->o.cpus) snprintf(j.cpus, sizeof j.cpus, "%s", p->o.cpus);
    return j;
}

/* A rank's part of job j whose input (the tape, the tree) is at input. */
static mpi_subtree_job subtree_job(const wire_job *j, const void *input, const csg_tree *tree)
{
    return (mpi_subtree_job){.kind = (mpi_kind)j->kind,
                             .tape = j->kind == MPI_KIND_IMPLICIT ? input : NULL,
                             .tree = tree, .mesh_opts = j->mesh_opts, .grid = j->grid,
                             .vod = j->vod, .node_level = j->node_level,
                             .schedule = j->schedule};
}

static void prep_free(prep *p)
{
    mpi_cut_free(&p->cut);
    expr_tape_free(p->tape);
    source_free(&p->src);
    if (p->mesh_loaded) mesh_free(&p->mesh);
    mesh_bins_free(&p->bins);
    csg_tree_free(p->tree);
    if (p->kind == MPI_KIND_CSG) free(p->input);
}

static int run_master(int argc, char **argv)
{
    static prep p;
    double t0 = clock_now();
    int status = prepare(&p, argc, argv);
    wire_job j = status >= 0 ? (wire_job){.status = status} : job_of(&p);
    MPI_Bcast(&j, sizeof j, MPI_BYTE, 0, MPI_COMM_WORLD);
    if (status >= 0) {
        prep_free(&p);
        return status;
    }
    if (j.input_bytes) MPI_Bcast(p.input, (int)j.input_bytes, MPI_BYTE, 0, MPI_COMM_WORLD);
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGHUP, on_signal);
    /* rank 0's own slave, its job right behind it (slave_thread) */
    own_slave *own = calloc(1, sizeof *own);
    master m = {.cut = &p.cut, .grid = &p.plan.grid, .kind = p.kind, .mesh = &p.mesh,
                .bins = p.bins.start ? &p.bins : NULL};
    m.spill = spill_open(p.o.out);
    m.rs = calloc((size_t)nranks, sizeof *m.rs);
    mpi_book_init(&m.book);
    if (!own || m.spill < 0 || !m.rs || mpi_top_new(&p.L, p.plan.grid.depth, p.cut.node_level, &m.top))
        fail_master(&m, "starting", m.spill < 0 ? -errno : -ENOMEM);
    progress_init(&m.pr, p.o.progress);
    own->j = j;
    own->s.sj = subtree_job(&j, p.tape, p.tree);
    pthread_t th;
    if (pthread_create(&th, NULL, slave_thread, own)) fail_master(&m, "starting", -EAGAIN);
    serve(&m);
    pthread_join(th, NULL);
    rank_stats *all = calloc((size_t)nranks, sizeof *all);
    MPI_Gather(&own->s.st, sizeof(rank_stats), MPI_BYTE, all, sizeof(rank_stats), MPI_BYTE,
               0, MPI_COMM_WORLD);
    finish_file(&p, &m, all, t0);
    free(all);
    close(m.spill);
    mpi_top_free(m.top);
    mpi_book_free(&m.book);
    free(m.nodes);
    free(m.rs);
    free(own);
    prep_free(&p);
    return 0;
}

/* ---------------------------------------------------------------- others */

/* The job's input as broadcast, checked: 0, or a message's reason. */
static const char *take_input(const wire_job *j, void *input, csg_tree **tree)
{
    if (grid_check(&j->grid)) return "the job's grid came damaged";
    if (j->kind == MPI_KIND_IMPLICIT)
        return expr_tape_validate(input, j->input_bytes) ? "the job's tape came damaged" : NULL;
    if (j->kind == MPI_KIND_CSG)
        return mpi_csg_unpack(input, j->input_bytes, tree) ? "the job's tree came damaged"
                                                            : NULL;
    return j->kind == MPI_KIND_MESH && !j->input_bytes ? NULL : "the job came damaged";
}

static int run_rank(void)
{
    wire_job j;
    MPI_Bcast(&j, sizeof j, MPI_BYTE, 0, MPI_COMM_WORLD);
    if (j.status >= 0) return j.status;
    void *input = aligned_alloc(64, (j.input_bytes + 64) / 64 * 64);
    if (!input) {
        msg("rank %d on %s: out of memory", me, hosts[0]);
        MPI_Abort(MPI_COMM_WORLD, 1);
    }
    if (j.input_bytes) MPI_Bcast(input, (int)j.input_bytes, MPI_BYTE, 0, MPI_COMM_WORLD);
    csg_tree *tree = NULL;
    const char *bad = take_input(&j, input, &tree);
    slave s = {.sj = subtree_job(&j, input, tree)};
    if (bad) {
        send_up(&s, bad, strlen(bad) + 1, TAG_FAIL);
        free(input);
        return 1;
    }
    int rc = slave_run(&s, &j);
    csg_tree_free(tree);
    free(input);
    if (rc) return 1;
    MPI_Gather(&s.st, sizeof(rank_stats), MPI_BYTE, NULL, 0, MPI_BYTE, 0, MPI_COMM_WORLD);
    return 0;
}

int main(int argc, char **argv)
{
    int provided;
    if (MPI_Init_thread(&argc, &argv, MPI_THREAD_MULTIPLE, &provided) != MPI_SUCCESS) {
        msg("MPI_Init_thread failed");
        return 1;
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &me);
    MPI_Comm_size(MPI_COMM_WORLD, &nranks);
    MPI_Comm_dup(MPI_COMM_WORLD, &up);
    MPI_Comm_dup(MPI_COMM_WORLD, &down);
    int len = 0;
    char name[MPI_MAX_PROCESSOR_NAME];
    MPI_Get_processor_name(name, &len);
    name[HOST_MAX - 1] = '\0'; /* a host name is shorter; cut, not refused */
    memcpy(hosts[0], name, HOST_MAX);
    if (me == 0 && !(all_hosts = calloc((size_t)nranks, HOST_MAX))) MPI_Abort(MPI_COMM_WORLD, 1);
    MPI_Gather(hosts[0], HOST_MAX, MPI_CHAR, all_hosts, HOST_MAX, MPI_CHAR, 0, MPI_COMM_WORLD);
    MPI_Comm host;
    MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, 0, MPI_INFO_NULL, &host);
    MPI_Comm_rank(host, &local_rank);
    MPI_Comm_size(host, &local_size);
    MPI_Comm_free(&host);
    if (me == 0 && provided < MPI_THREAD_MULTIPLE) {
        /* rank 0's own slave thread talks MPI beside its master */
        msg("this MPI library gives thread level %d, vox_mpi needs MPI_THREAD_MULTIPLE",
            provided);
        MPI_Abort(MPI_COMM_WORLD, 1);
    }
    int rc = me == 0 ? run_master(argc, argv) : run_rank();
    free(all_hosts);
    MPI_Comm_free(&up);
    MPI_Comm_free(&down);
    MPI_Finalize();
    return rc;
}

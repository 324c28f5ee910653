/* A Submit made into a job: each kind's fields, input and name from its
 * member of the Submit (the kind table below), the channel, compression and
 * hash, and the daemon's limits; the CSG tree built and checked first.
 * Then, on the engine thread, the kind's input made for the pipeline
 * (daemon_submit_input), and its figures in its Summary. */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "daemon.h"
#include "err.h"
#include "expr.h"
#include "mesh.h"
#include "vod.h"
#include "voxel.h"

int daemon_job_error(daemon_job *j, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(j->message, sizeof j->message, 0, fmt, ap);
    va_end(ap);
    j->code = code;
    return -1;
}

/* A domain of 2 values (a cube) or 6 (checked). */
static void job_domain(daemon_job *j, const double *dom, size_t n)
{
    for (int a = 0; a < 3; a++) {
        size_t k = n == 2 ? 0 : 2 * (size_t)a;
        j->lo[a] = dom[k];
        j->hi[a] = dom[k + 1];
    }
}

/* The protocol's mesh formats are mesh.h's (0: told from the contents), its
 * modes and repairs mesh_vox.h's plus one (0 being "not given"). */
_Static_assert((int)VOXD__MESH_FORMAT__MESH_FORMAT_UNSPECIFIED == MESH_FORMAT_AUTO &&
                   (int)VOXD__MESH_FORMAT__MESH_FORMAT_OBJ == MESH_FORMAT_OBJ &&
                   (int)VOXD__MESH_FORMAT__MESH_FORMAT_STL == MESH_FORMAT_STL &&
                   (int)VOXD__MESH_FORMAT__MESH_FORMAT_PLY == MESH_FORMAT_PLY &&
                   (int)VOXD__MESH_FORMAT__MESH_FORMAT_OFF == MESH_FORMAT_OFF &&
                   (int)VOXD__MESH_FORMAT__MESH_FORMAT_GLTF == MESH_FORMAT_GLTF,
               "MeshFormat numbers");
_Static_assert((int)VOXD__MESH_MODE__MESH_MODE_SOLID == MESH_SOLID + 1 &&
                   (int)VOXD__MESH_MODE__MESH_MODE_SURFACE == MESH_SURFACE + 1 &&
                   (int)VOXD__MESH_MODE__MESH_MODE_SURFACE6 == MESH_SURFACE6 + 1 &&
                   (int)VOXD__MESH_MODE__MESH_MODE_CONSERVATIVE == MESH_CONSERVATIVE + 1 &&
                   (int)VOXD__MESH_MODE__MESH_MODE_INTERIOR == MESH_INTERIOR + 1,
               "MeshMode numbers");
_Static_assert((int)VOXD__MESH_REPAIR__MESH_REPAIR_NONE == MESH_REPAIR_NONE + 1 &&
                   (int)VOXD__MESH_REPAIR__MESH_REPAIR_VOTE == MESH_REPAIR_VOTE + 1 &&
                   (int)VOXD__MESH_REPAIR__MESH_REPAIR_WINDING == MESH_REPAIR_WINDING + 1,
               "MeshRepair numbers");

/* ---------------------------------------------------------------- kinds */

/* Each kind's fields of the job from its Submit, as vox voxelize gives them
 * to the pipeline; its input inline and its file's name (proto_check made
 * sure the member is there). */
static void implicit_from_request(daemon_job *j, const Voxd__Submit *s)
{
    const Voxd__Implicit *im = s->implicit;
    job_domain(j, im->domain, im->n_domain);
    j->res = im->res;
    j->schedule = im->schedule == VOXD__SCHEDULE__SCHEDULE_PAPER ? ENGINE_SCHED_PAPER
                                                                 : ENGINE_SCHED_SUBTREE;
    j->band = im->band;
}

static const ProtobufCBinaryData *implicit_input(const Voxd__Submit *s)
{
    return &s->implicit->source;
}

static const ProtobufCBinaryData *implicit_name(const Voxd__Submit *s)
{
    return &s->implicit->source_name;
}

static int compile(daemon_job *j, expr_tape **tape)
{
    expr_limits lim;
    expr_limits_default(&lim);
    lim.max_source_bytes = j->max_expr_bytes;
    lim.max_depth = j->max_expr_depth;
    expr_error xe = {0};
    int rc = expr_compile(j->source, j->source_len, &lim, tape, &xe);
    if (rc == 0) return 0;
    int code = rc == -E2BIG ? VOXD__ERROR_CODE__LIMIT_EXCEEDED
               : rc == -EINVAL ? VOXD__ERROR_CODE__INVALID_INPUT
                               : VOXD__ERROR_CODE__INTERNAL;
    if (xe.line > 0)
        return daemon_job_error(j, code, "expression:%d:%d: %s", xe.line, xe.col, xe.msg);
    return daemon_job_error(j, code, "expression: %s", xe.msg[0] ? xe.msg : strerror(-rc));
}

/* The kind's part of the pipeline job, as vox voxelize fills it (so the
 * bytes are the same): for an expression, its tape, which *owned keeps. */
static int implicit_job(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi)
{
    (void)mpi;
    expr_tape *tape;
    if (compile(j, &tape)) return -1;
    *owned = tape;
    job->kind = &engine_kind_implicit;
    job->implicit.tape = tape;
    job->implicit.source = j->source;
    job->implicit.source_len = j->source_len;
    job->implicit.source_name = j->source_name;
    return 0;
}

static void implicit_release(void *owned)
{
    expr_tape_free(owned);
}

static void mesh_from_request(daemon_job *j, const Voxd__Submit *s)
{
    const Voxd__Mesh *m = s->mesh;
    j->fit = m->n_domain == 0;
    if (!j->fit) job_domain(j, m->domain, m->n_domain);
    j->res = m->res;
    j->pad = m->pad;
    j->mesh_format = (mesh_format)m->format; /* MESH_FORMAT_AUTO .. GLTF, the same numbers */
    j->mesh_opts.mode = m->mode ? (mesh_mode)(m->mode - 1) : MESH_SOLID;
    j->mesh_opts.repair = m->repair ? (mesh_repair)(m->repair - 1) : MESH_REPAIR_NONE;
    j->mesh_opts.supersample = m->supersample;
    j->mesh_opts.band = j->band = m->band;
    j->weld = m->weld;
    j->weld_eps = m->weld_eps;
    j->schedule = ENGINE_SCHED_SUBTREE; /* not the mesh kind's: tiles */
}

static const ProtobufCBinaryData *mesh_input(const Voxd__Submit *s)
{
    return &s->mesh->data;
}

static const ProtobufCBinaryData *mesh_name(const Voxd__Submit *s)
{
    return &s->mesh->source_name;
}

/* The mesh from the job's bytes, parsed here whatever a client did (its
 * messages with the file's line or byte); then the bytes are freed, the
 * mesh holding what the job needs, unless keep (an MPI run hands them to
 * vox_mpi).  0, or -1 with the job's error set. */
static int parse_mesh(daemon_job *j, mesh *m, int keep)
{
    mesh_limits lim = {.max_triangles = j->max_triangles};
    mesh_error me = {0};
    int rc = mesh_parse(j->source, j->source_len, j->mesh_format, &lim, m, &me);
    if (rc == 0 && j->weld && (rc = mesh_weld(m, j->weld_eps, NULL))) {
        mesh_free(m);
        return daemon_job_error(j, rc == -EINVAL ? VOXD__ERROR_CODE__INVALID_INPUT
                                                 : VOXD__ERROR_CODE__INTERNAL,
                                rc == -EINVAL ? "mesh: no triangle is left once welded at %g"
                                              : "mesh: welding at %g: out of memory", j->weld_eps);
    }
    if (rc == 0 && m->n_triangles == 0) {
        daemon_job_error(j, VOXD__ERROR_CODE__INVALID_INPUT,
                         "mesh: no triangles (%llu degenerate ones dropped)",
                         (unsigned long long)m->n_degenerate);
        mesh_free(m);
        return -1;
    }
    if (rc == 0) {
        if (!keep) {
            free(j->source);
            j->source = NULL;
        }
        return 0;
    }
    char at[48] = "";
    if (me.line) snprintf(at, sizeof at, "line %llu: ", (unsigned long long)me.line);
    else if (me.offset) snprintf(at, sizeof at, "byte %llu: ", (unsigned long long)me.offset);
    const char *why = me.msg[0] ? me.msg : strerror(-rc);
    if (rc == -E2BIG)
        return daemon_job_error(j, VOXD__ERROR_CODE__LIMIT_EXCEEDED,
                                "mesh: %s%s (this server's max_triangles is %u)", at, why,
                                j->max_triangles);
    return daemon_job_error(j, rc == -EINVAL ? VOXD__ERROR_CODE__INVALID_INPUT
                                             : VOXD__ERROR_CODE__INTERNAL,
                            "mesh: %s%s", at, why);
}

/* A mesh job's mesh, parsed here (mpi: its bytes kept for vox_mpi), which
 * *owned keeps. */
static int mesh_job(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi)
{
    mesh *m = calloc(1, sizeof *m);
    if (!m) return daemon_job_error(j, VOXD__ERROR_CODE__INTERNAL, "out of memory for the mesh");
    if (parse_mesh(j, m, mpi)) {
        free(m);
        return -1;
    }
    *owned = m;
    job->kind = &engine_kind_mesh;
    job->mesh.mesh = m;
    job->mesh.opts = j->mesh_opts;
    job->mesh.pad = j->pad;
    job->mesh.fit = j->fit;
    job->mesh.source_name = j->source_name;
    job->mesh.source_bytes = j->source_len;
    return 0;
}

static void mesh_release(void *owned)
{
    mesh_free(owned);
    free(owned);
}

/* Its figures in the Summary (on the loop thread, which sends it next). */
static void mesh_summary(const engine_pipeline_figures *f, Voxd__Summary *m)
{
    static Voxd__MeshReport mr; /* the loop thread's, until its Summary is sent */
    const engine_mesh_report *mf = &f->mesh;
    voxd__mesh_report__init(&mr);
    mr.triangles = mf->triangles;
    mr.open_edges = mf->topo.open;
    mr.nonmanifold_edges = mf->topo.nonmanifold;
    mr.watertight = mf->topo.watertight;
    mr.tiles = mf->vox.tiles;
    mr.repair_skipped = mf->repair_skipped;
    mr.disagreements = mf->vox.disagreements;
    mr.disagree_bricks = mf->vox.disagree_bricks;
    m->mesh = &mr;
}

static void csg_from_request(daemon_job *j, const Voxd__Submit *s)
{
    job_domain(j, s->csg->domain, s->csg->n_domain);
    j->res = s->csg->res;
    j->csg_source_bytes = s->csg->source_bytes;
    j->band = s->csg->band;
    j->schedule = ENGINE_SCHED_SUBTREE; /* not the csg kind's: brick runs */
}

static const ProtobufCBinaryData *csg_input(const Voxd__Submit *s)
{
    static const ProtobufCBinaryData none = {0, NULL}; /* a CSG job's tree is its own */
    (void)s;
    return &none;
}

static const ProtobufCBinaryData *csg_name(const Voxd__Submit *s)
{
    return &s->csg->source_name;
}

/* A CSG job's tree, built at its Submit, its leaves' input cut in. */
static int csg_job(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi)
{
    (void)owned, (void)mpi;
    int rc = j->input_total ? daemon_csg_input(j->csg, j->source, j->source_len) : 0;
    if (rc)
        return daemon_job_error(j, rc == -ENOMEM ? VOXD__ERROR_CODE__INTERNAL
                                                 : VOXD__ERROR_CODE__INVALID_INPUT,
                                "%s", rc == -ENOMEM ? "out of memory for the CSG leaves"
                                                    : "the CSG leaves' input does not add up");
    job->kind = &engine_kind_csg;
    job->csg.tree = j->csg;
    job->csg.source_name = j->source_name;
    job->csg.source_bytes = j->csg_source_bytes;
    return 0;
}

/* A CSG tree is built and its expressions compiled at its Submit: a bad
 * one is refused there, the daemon never runs it. */
static int csg_build(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                     size_t len)
{
    return daemon_csg_tree(s->csg, cfg->max_expr_bytes, cfg->max_expr_depth, out, msg, len);
}

/* What the daemon takes of each kind of job, from its Submit to its
 * Summary: the one place in the daemon that tells the kinds apart but for
 * daemon_mpi.c's run through MPI (docs/design.md, "Adding a kind of job"). */
typedef struct {
    const engine_kind *kind;
    Voxd__Submit__JobCase job_case;
    Voxd__JobKind status;    /* its kind in a StatusReply */
    const char *input;       /* what its input is, for messages */
    int channel;             /* VOXEL_CH_*: the channel when the Submit names none */
    int text;                /* its input is text: no NUL byte in it */
    void (*from_request)(daemon_job *j, const Voxd__Submit *s);
    const ProtobufCBinaryData *(*input_of)(const Voxd__Submit *s);
    const ProtobufCBinaryData *(*name_of)(const Voxd__Submit *s);
    /* what is built and checked before the job is queued, or NULL */
    int (*build)(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                 size_t len);
    /* its part of the pipeline job (daemon_submit_input), what it made
     * kept in *owned and freed by release (NULL: nothing) */
    int (*job)(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi);
    void (*release)(void *owned);
    /* its figures into the Summary, or NULL: none */
    void (*summary)(const engine_pipeline_figures *f, Voxd__Summary *m);
} submit_kind;

static const submit_kind submit_kinds[] = {
    {.kind = &engine_kind_implicit, .job_case = VOXD__SUBMIT__JOB_IMPLICIT,
     .status = VOXD__JOB_KIND__JOB_KIND_IMPLICIT, .input = "expression",
     .channel = VOXEL_CH_SURFACE, .text = 1, .from_request = implicit_from_request,
     .input_of = implicit_input, .name_of = implicit_name, .job = implicit_job,
     .release = implicit_release},
    {.kind = &engine_kind_mesh, .job_case = VOXD__SUBMIT__JOB_MESH,
     .status = VOXD__JOB_KIND__JOB_KIND_MESH, .input = "mesh", .channel = VOXEL_CH_OCCUPANCY,
     .from_request = mesh_from_request, .input_of = mesh_input, .name_of = mesh_name,
     .job = mesh_job, .release = mesh_release, .summary = mesh_summary},
    {.kind = &engine_kind_csg, .job_case = VOXD__SUBMIT__JOB_CSG,
     .status = VOXD__JOB_KIND__JOB_KIND_CSG, .input = "CSG tree", .channel = VOXEL_CH_DENSITY,
     .from_request = csg_from_request, .input_of = csg_input, .name_of = csg_name,
     .build = csg_build, .job = csg_job},
};
#define SUBMIT_KINDS (sizeof submit_kinds / sizeof *submit_kinds)

/* The Submit's kind (proto_check made sure it has one of the table's). */
static const submit_kind *kind_of(const Voxd__Submit *s)
{
    for (size_t k = 1; k < SUBMIT_KINDS; k++)
        if (submit_kinds[k].job_case == s->job_case) return &submit_kinds[k];
    return &submit_kinds[0];
}

/* The job's kind (daemon_job.kind is one of the table's). */
static const submit_kind *kind_of_job(const daemon_job *j)
{
    for (size_t k = 1; k < SUBMIT_KINDS; k++)
        if (submit_kinds[k].kind == j->kind) return &submit_kinds[k];
    return &submit_kinds[0];
}

static int channel_of(const Voxd__Submit *s, const submit_kind *k)
{
    switch (s->channel) {
    case VOXD__CHANNEL__CHANNEL_OCCUPANCY: return VOXEL_CH_OCCUPANCY;
    case VOXD__CHANNEL__CHANNEL_DENSITY: return VOXEL_CH_DENSITY;
    case VOXD__CHANNEL__CHANNEL_SURFACE: return VOXEL_CH_SURFACE;
    case VOXD__CHANNEL__CHANNEL_DISTANCE: return VOXEL_CH_DISTANCE;
    default: return k->channel;
    }
}

static void job_from_request(daemon_job *j, const Voxd__Submit *s)
{
    const submit_kind *k = kind_of(s);
    j->kind = k->kind;
    k->from_request(j, s);
    j->channel = channel_of(s, k);
    j->mesh_opts.channel = j->channel;
    j->brick = s->brick ? s->brick : VOD_DEFAULT_BRICK;
    j->comp = s->comp == VOXD__COMPRESSION__COMPRESSION_NONE   ? VOD_COMP_NONE
              : s->comp == VOXD__COMPRESSION__COMPRESSION_RUNL ? VOD_COMP_RUNL
                                                               : VOD_COMP_ZLIB;
    j->hash = s->hash == VOXD__HASH__HASH_XX32 ? VOD_HASH_XX32 : VOD_HASH_SFHS;
}

/* The first buffer of an input sent in chunks: it grows as bytes come, so
 * a client that declares much and sends little holds little. */
#define INPUT_FIRST_ALLOC (64u << 10)

const char *daemon_submit_input_name(const daemon_job *j)
{
    return kind_of_job(j)->input;
}

/* The job's source: the inline input, or an empty buffer for the input to
 * come. */
static int job_source(daemon_job *j, const Voxd__Submit *s)
{
    const ProtobufCBinaryData *src = kind_of(s)->input_of(s);
    size_t cap = src->len + 1;
    if (s->input_bytes) {
        j->input_total = s->input_bytes;
        j->state = DAEMON_UPLOADING;
        cap = s->input_bytes < INPUT_FIRST_ALLOC ? (size_t)s->input_bytes + 1
                                                 : INPUT_FIRST_ALLOC;
    }
    if (!(j->source = malloc(cap))) return -ENOMEM;
    j->input_cap = cap;
    if (src->len) memcpy(j->source, src->data, src->len); /* data is NULL when empty */
    j->source[src->len] = '\0';
    j->source_len = src->len;
    return 0;
}

daemon_job *daemon_submit_job(daemon_client *c, const Voxd__Submit *s)
{
    const voxd_config *cfg = &c->d->cfg;
    daemon_job *j = calloc(1, sizeof *j);
    if (!j || job_source(j, s)) {
        free(j);
        return NULL;
    }
    const ProtobufCBinaryData *name = kind_of(s)->name_of(s);
    if (name->len && !(j->source_name = strndup((const char *)name->data, name->len))) {
        free(j->source);
        free(j);
        return NULL;
    }
    job_from_request(j, s);
    j->uid = c->uid;
    j->fd = -1;
    j->max_expr_bytes = cfg->max_expr_bytes;
    j->max_expr_depth = cfg->max_expr_depth;
    j->max_triangles = cfg->max_triangles;
    j->max_result_bytes = cfg->max_result_bytes;
    j->job_timeout = cfg->job_timeout;
    j->held_sum = &c->d->results_held;
    j->t_submit = j->t_input = clock_now();
    return j;
}

int daemon_submit_is_text(const daemon_job *j)
{
    return kind_of_job(j)->text;
}

int daemon_submit_build(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                        size_t len)
{
    const submit_kind *k = kind_of(s);
    return k->build ? k->build(cfg, s, out, msg, len) : 0;
}

int daemon_submit_input(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi)
{
    *owned = NULL;
    return kind_of_job(j)->job(j, job, owned, mpi);
}

void daemon_submit_release(const daemon_job *j, void *owned)
{
    const submit_kind *k = kind_of_job(j);
    if (owned && k->release) k->release(owned);
}

Voxd__JobKind daemon_submit_status_kind(const daemon_job *j)
{
    return kind_of_job(j)->status;
}

void daemon_submit_summary(const daemon_job *j, Voxd__Summary *m)
{
    const submit_kind *k = kind_of_job(j);
    if (j->has_figures && k->summary) k->summary(&j->fig, m);
}

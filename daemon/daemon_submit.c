/* A Submit made into a job: each kind's fields, input and name from its
 * member of the Submit (the kind table below), the channel, compression and
 * hash, and the daemon's limits; the CSG tree built and checked first. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "daemon.h"
#include "vod.h"
#include "voxel.h"

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

/* A CSG tree is built and its expressions compiled at its Submit: a bad
 * one is refused there, the daemon never runs it. */
static int csg_build(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                     size_t len)
{
    return daemon_csg_tree(s->csg, cfg->max_expr_bytes, cfg->max_expr_depth, out, msg, len);
}

/* What the daemon's Submit takes of each kind of job: the one place in this
 * file that tells the kinds apart (docs/design.md, "Adding a kind of job"). */
typedef struct {
    Voxd__Submit__JobCase job_case;
    const char *input;   /* what its input is, for messages */
    int channel;         /* VOXEL_CH_*: the channel when the Submit names none */
    int text;            /* its input is text: no NUL byte in it */
    void (*from_request)(daemon_job *j, const Voxd__Submit *s);
    const ProtobufCBinaryData *(*input_of)(const Voxd__Submit *s);
    const ProtobufCBinaryData *(*name_of)(const Voxd__Submit *s);
    /* what is built and checked before the job is queued, or NULL */
    int (*build)(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                 size_t len);
} submit_kind;

static const submit_kind submit_kinds[ENGINE_PIPELINE_KINDS] = {
    [ENGINE_PIPELINE_IMPLICIT] = {VOXD__SUBMIT__JOB_IMPLICIT, "expression", VOXEL_CH_SURFACE, 1,
                           implicit_from_request, implicit_input, implicit_name, NULL},
    [ENGINE_PIPELINE_MESH] = {VOXD__SUBMIT__JOB_MESH, "mesh", VOXEL_CH_OCCUPANCY, 0,
                       mesh_from_request, mesh_input, mesh_name, NULL},
    [ENGINE_PIPELINE_CSG] = {VOXD__SUBMIT__JOB_CSG, "CSG tree", VOXEL_CH_DENSITY, 0,
                      csg_from_request, csg_input, csg_name, csg_build},
};

/* The Submit's kind (proto_check made sure it has one of the table's). */
static engine_pipeline_kind kind_of(const Voxd__Submit *s)
{
    for (int k = ENGINE_PIPELINE_IMPLICIT; k < ENGINE_PIPELINE_KINDS; k++)
        if (submit_kinds[k].job_case == s->job_case) return (engine_pipeline_kind)k;
    return ENGINE_PIPELINE_IMPLICIT;
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
    j->kind = kind_of(s);
    const submit_kind *k = &submit_kinds[j->kind];
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
    return submit_kinds[j->kind].input;
}

/* The job's source: the inline input, or an empty buffer for the input to
 * come. */
static int job_source(daemon_job *j, const Voxd__Submit *s)
{
    const ProtobufCBinaryData *src = submit_kinds[kind_of(s)].input_of(s);
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
    const ProtobufCBinaryData *name = submit_kinds[kind_of(s)].name_of(s);
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
    return submit_kinds[j->kind].text;
}

int daemon_submit_build(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                        size_t len)
{
    const submit_kind *k = &submit_kinds[kind_of(s)];
    return k->build ? k->build(cfg, s, out, msg, len) : 0;
}

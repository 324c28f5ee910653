/* Submitting a job: its Submit message per kind, inline or followed by its
 * input in InputChunks; the limits the daemon would refuse, refused unsent. */
#include "vox.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "libvox_int.h"

/* Send job id's input in InputChunks, in order; stop early when the daemon
 * ends the job.  0, or the connection's failure. */
static int upload(vox_client *c, uint64_t id, const uint8_t *data, size_t n, vox_error *err)
{
    size_t piece = c->info.chunk_size; /* within a frame: proto_check_reply */
    /* What comes meanwhile is no answer to anything; an Error with no job
     * is about a chunk (see P_DRAIN). */
    c->pending = P_DRAIN;
    c->answered = 1;
    for (size_t off = 0; off < n;) {
        vjob *j = libvox_find_job(c, id);
        if (!j || j->done) break;
        size_t k = n - off < piece ? n - off : piece;
        Voxd__InputChunk in = VOXD__INPUT_CHUNK__INIT;
        in.job_id = id;
        in.offset = off;
        in.data.data = (uint8_t *)data + off;
        in.data.len = k;
        Voxd__Request req = VOXD__REQUEST__INIT;
        req.msg_case = VOXD__REQUEST__MSG_INPUT;
        req.input = &in;
        int rc = libvox_send_request(c, &req);
        if (rc) {
            c->pending = P_NONE;
            libvox_copy_error(err, &c->fail);
            return rc;
        }
        off += k;
    }
    c->pending = P_NONE;
    int rc = libvox_ping(c, P_DRAIN, err); /* every reply up to its pong */
    vjob *j = libvox_find_job(c, id);
    if (j) j->t_accepted = libvox_mono(); /* its time to finish counts from here */
    return rc;
}

/* The band fields came after the first release: vox_job's union (and so
 * every field after it) stays where it was only while vox_mesh is its
 * largest member. */
_Static_assert(sizeof(vox_implicit) <= sizeof(vox_mesh) && sizeof(vox_csg) <= sizeof(vox_mesh),
               "vox_job's layout");

/* A Submit and the messages it points into (the caller's, on its stack). */
typedef struct {
    Voxd__Implicit im;
    Voxd__Mesh mesh;
    Voxd__Submit sub;
    Voxd__Request req;
} submit_msg;

/* The job's input, the expression or the mesh file: 0, or -EINVAL /
 * -ENOTSUP with err set. */
static int job_input(const vox_job *job, const uint8_t **data, size_t *len, vox_error *err)
{
    int k = job ? job->kind : 0;
    if (k == VOX_JOB_IMPLICIT && job->implicit.source) {
        *data = (const uint8_t *)job->implicit.source;
        *len = job->implicit.source_len ? job->implicit.source_len
                                        : strlen(job->implicit.source);
        return 0;
    }
    if (k == VOX_JOB_MESH && job->mesh.data && job->mesh.len) {
        *data = job->mesh.data;
        *len = job->mesh.len;
        return 0;
    }
    int rc = -EINVAL;
    libvox_set_error(err, rc, 0, "%s",
              k == VOX_JOB_IMPLICIT   ? "the job has no expression"
              : k == VOX_JOB_MESH     ? "the job has no mesh data"
                                      : "the job is of no known kind");
    return rc;
}

/* A file's name for the metadata, if any. */
static ProtobufCBinaryData name_bytes(const char *name)
{
    ProtobufCBinaryData b = {name ? strlen(name) : 0, (uint8_t *)name};
    return b;
}

/* The kind's message: its input inline, or left out (chunked: sent by
 * upload after the Accepted). */
static void implicit_request(const vox_job *job, const uint8_t *data, size_t len,
                             int chunked, submit_msg *m)
{
    const vox_implicit *ij = &job->implicit;
    if (!chunked) m->im.source.data = (uint8_t *)data, m->im.source.len = len;
    m->im.source_name = name_bytes(ij->source_name);
    m->im.domain = (double *)ij->domain;
    m->im.n_domain = 6;
    m->im.res = ij->res;
    m->im.schedule = (Voxd__Schedule)ij->schedule;
    m->im.band = ij->band;
    m->sub.job_case = VOXD__SUBMIT__JOB_IMPLICIT;
    m->sub.implicit = &m->im;
}

static void mesh_request(const vox_job *job, const uint8_t *data, size_t len, int chunked,
                         submit_msg *m)
{
    const vox_mesh *mj = &job->mesh;
    if (!chunked) m->mesh.data.data = (uint8_t *)data, m->mesh.data.len = len;
    m->mesh.format = (Voxd__MeshFormat)mj->format;
    m->mesh.mode = (Voxd__MeshMode)mj->mode;
    m->mesh.repair = (Voxd__MeshRepair)mj->repair;
    /* one field of vox_mesh, two of the protocol's */
    if (job->channel == VOX_CHANNEL_DISTANCE) m->mesh.band = mj->supersample;
    else m->mesh.supersample = mj->supersample;
    m->mesh.weld = mj->weld != 0;
    m->mesh.weld_eps = mj->weld_eps;
    m->mesh.source_name = name_bytes(mj->source_name);
    if (mj->fit) {
        m->mesh.pad = mj->pad;
    } else {
        m->mesh.domain = (double *)mj->domain;
        m->mesh.n_domain = 6;
    }
    m->mesh.res = mj->res;
    m->sub.job_case = VOXD__SUBMIT__JOB_MESH;
    m->sub.mesh = &m->mesh;
}

/* The Submit of job, its input inline or declared as input_bytes. */
static void submit_request(const vox_job *job, const uint8_t *data, size_t len, int chunked,
                           submit_msg *m)
{
    *m = (submit_msg){VOXD__IMPLICIT__INIT, VOXD__MESH__INIT, VOXD__SUBMIT__INIT,
                      VOXD__REQUEST__INIT};
    if (job->kind == VOX_JOB_MESH) mesh_request(job, data, len, chunked, m);
    else if (job->kind == VOX_JOB_IMPLICIT) implicit_request(job, data, len, chunked, m);
    if (chunked) m->sub.input_bytes = len;
    m->sub.channel = (Voxd__Channel)job->channel;
    m->sub.brick = job->brick;
    m->sub.comp = (Voxd__Compression)job->comp;
    m->sub.hash = (Voxd__Hash)job->hash;
    m->req.msg_case = VOXD__REQUEST__MSG_SUBMIT;
    m->req.submit = &m->sub;
}

/* What the daemon would refuse for its size, refused here unsent. */
static int check_input_size(const vox_client *c, int kind, size_t len, int chunked,
                            vox_error *err)
{
    if (kind == VOX_JOB_IMPLICIT && len > c->lim.max_expr_bytes) {
        libvox_set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "expression is %zu bytes, over this server's max_expr_bytes of %u", len,
                  c->lim.max_expr_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    if (kind == VOX_JOB_MESH && len > c->lim.max_mesh_bytes) {
        libvox_set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "mesh is %zu bytes, over this server's max_mesh_bytes of %llu", len,
                  (unsigned long long)c->lim.max_mesh_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    if (chunked && len > c->lim.max_input_bytes) {
        libvox_set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "the job's input is %zu bytes, over this server's max_input_bytes of %llu",
                  len, (unsigned long long)c->lim.max_input_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    return 0;
}

/* A CSG job's Submit: its nodes in arrays of the caller's (nodes, ptrs),
 * pointing into job. */
static void csg_request(const vox_job *job, int chunked, Voxd__CsgNode *nodes,
                        Voxd__CsgNode **ptrs, submit_msg *m, Voxd__Csg *cm)
{
    const vox_csg *cj = &job->csg;
    for (size_t i = 0; i < cj->n_nodes; i++) {
        const vox_csg_node *v = &cj->nodes[i];
        Voxd__CsgNode *n = &nodes[i];
        voxd__csg_node__init(n);
        n->op = (Voxd__CsgOp)v->op;
        n->children = (uint32_t *)v->children;
        n->n_children = v->n_children > 2 ? 2 : v->n_children;
        if (v->op == VOX_CSG_PRIMITIVE) {
            n->primitive = (Voxd__Primitive)v->primitive;
            n->center = (double *)v->center, n->n_center = 3;
            n->size = (double *)v->size, n->n_size = 3;
            n->rotate = (double *)v->rotate, n->n_rotate = 3;
            n->axis = (Voxd__Axis)v->axis;
        }
        if (v->source) {
            n->source.data = (uint8_t *)v->source;
            n->source.len = v->source_len ? v->source_len : strlen(v->source);
        }
        if (v->has_domain) n->domain = (double *)v->domain, n->n_domain = 2;
        n->scalar = v->scalar;
        n->k = v->k;
        n->name = name_bytes(v->name);
        if (v->data && chunked) n->data_bytes = v->data_len;
        else if (v->data) n->data.data = (uint8_t *)v->data, n->data.len = v->data_len;
        if (v->has_fit) n->fit = (double *)v->fit, n->n_fit = 3;
        n->scale = v->scale;
        ptrs[i] = n;
    }
    voxd__csg__init(cm);
    cm->nodes = ptrs;
    cm->n_nodes = cj->n_nodes;
    cm->domain = (double *)cj->domain;
    cm->n_domain = 6;
    cm->res = cj->res;
    cm->source_name = name_bytes(cj->source_name);
    cm->source_bytes = cj->source_bytes;
    cm->band = cj->band;
    m->sub.job_case = VOXD__SUBMIT__JOB_CSG;
    m->sub.csg = cm;
}

/* The mesh and VOD leaves' files one after the other, in node order (the
 * job's input when they go in InputChunks); *len their size. */
static uint8_t *csg_leaves_input(const vox_csg *cj, size_t *len)
{
    size_t n = 0;
    for (size_t i = 0; i < cj->n_nodes; i++)
        if (cj->nodes[i].data) n += cj->nodes[i].data_len;
    uint8_t *buf = malloc(n ? n : 1);
    if (!buf) return NULL;
    size_t off = 0;
    for (size_t i = 0; i < cj->n_nodes; i++)
        if (cj->nodes[i].data) {
            memcpy(buf + off, cj->nodes[i].data, cj->nodes[i].data_len);
            off += cj->nodes[i].data_len;
        }
    *len = n;
    return buf;
}

/* A CSG job: its tree in the Submit, which must fit a frame; the leaves'
 * files inline when they fit too and are small (inline_max), else after
 * the Accepted as the job's input. */
static int submit_csg(vox_client *c, const vox_job *job, uint64_t *job_id,
                      uint32_t *queue_position, vox_error *err)
{
    size_t n = job->csg.n_nodes;
    if (!n || !job->csg.nodes) {
        libvox_set_error(err, -EINVAL, 0, "the CSG job has no nodes");
        return -EINVAL;
    }
    size_t in_len = 0;
    uint8_t *input = csg_leaves_input(&job->csg, &in_len);
    Voxd__CsgNode *nodes = calloc(n, sizeof *nodes);
    Voxd__CsgNode **ptrs = calloc(n, sizeof *ptrs);
    int rc = 0;
    if (!nodes || !ptrs || !input) {
        libvox_set_error(err, -ENOMEM, 0, "out of memory");
        rc = -ENOMEM;
    }
    submit_msg m;
    Voxd__Csg cm;
    int chunked = 0;
    if (!rc) {
        submit_request(job, NULL, 0, 0, &m);
        csg_request(job, 0, nodes, ptrs, &m, &cm);
        chunked = in_len && (in_len > c->inline_max ||
                             protobuf_c_message_get_packed_size(&m.req.base) > c->lim.max_frame);
        if (chunked) {
            submit_request(job, NULL, 0, 0, &m);
            csg_request(job, 1, nodes, ptrs, &m, &cm);
            m.sub.input_bytes = in_len;
        }
        if (chunked && in_len > c->lim.max_input_bytes) {
            libvox_set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                      "the CSG leaves are %zu bytes, over this server's max_input_bytes of %llu",
                      in_len, (unsigned long long)c->lim.max_input_bytes);
            rc = VOX_ELIMIT_EXCEEDED;
        }
        size_t bytes = protobuf_c_message_get_packed_size(&m.req.base);
        if (!rc && bytes > c->lim.max_frame) {
            libvox_set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                      "the CSG tree's request is %zu bytes, over this server's max_frame "
                      "of %u", bytes, c->lim.max_frame);
            rc = VOX_ELIMIT_EXCEEDED;
        }
    }
    if (!rc) rc = libvox_request(c, P_SUBMIT, &m.req, err);
    free(nodes);
    free(ptrs);
    uint64_t id = rc ? 0 : c->ans_job;
    uint32_t qpos = rc ? 0 : c->ans_qpos;
    if (!rc && chunked) rc = upload(c, id, input, in_len, err);
    free(input);
    if (rc) return rc;
    *job_id = id;
    if (queue_position) *queue_position = qpos;
    return 0;
}

int vox_submit_job(vox_client *c, const vox_job *job, uint64_t *job_id,
                   uint32_t *queue_position, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    if (job && job->kind == VOX_JOB_CSG) return submit_csg(c, job, job_id, queue_position, err);
    const uint8_t *data;
    size_t len;
    int rc = job_input(job, &data, &len, err);
    if (rc) return rc;
    submit_msg m;
    submit_request(job, data, len, 0, &m);
    /* Inline when small and it fits a frame; else in InputChunks. */
    int chunked = len > c->inline_max ||
                  protobuf_c_message_get_packed_size(&m.req.base) > c->lim.max_frame;
    if ((rc = check_input_size(c, job->kind, len, chunked, err))) return rc;
    if (chunked) submit_request(job, data, len, 1, &m);
    if ((rc = libvox_request(c, P_SUBMIT, &m.req, err))) return rc;
    uint64_t id = c->ans_job;
    uint32_t qpos = c->ans_qpos;
    if (chunked && (rc = upload(c, id, data, len, err))) return rc;
    *job_id = id;
    if (queue_position) *queue_position = qpos;
    return 0;
}

int vox_submit(vox_client *c, const vox_implicit_job *job, uint64_t *job_id,
               uint32_t *queue_position, vox_error *err)
{
    if (!job) return vox_submit_job(c, NULL, job_id, queue_position, err);
    vox_job j = {
        .kind = VOX_JOB_IMPLICIT,
        .implicit = {.source = job->source, .source_len = job->source_len,
                     .source_name = job->source_name, .res = job->res,
                     .schedule = job->schedule},
        .channel = job->channel, .brick = job->brick, .comp = job->comp, .hash = job->hash};
    memcpy(j.implicit.domain, job->domain, sizeof j.implicit.domain);
    return vox_submit_job(c, &j, job_id, queue_position, err);
}

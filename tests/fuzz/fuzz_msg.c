/* Fuzz unpacking and validation: the input is one message.  It is unpacked
 * as a Request and as a Reply and validated with the default limits and with
 * tight ones.  What the validator accepts must really hold what the daemon
 * then trusts (abort otherwise): a known oneof case, enums in range, a
 * source within the limit and without NUL (or none, its size declared
 * within the limits), a finite domain with low < high, res within the
 * limit, a mesh's file within max_mesh_bytes and its options in range,
 * a CSG tree's nodes of known ops with their children earlier and its
 * leaves within the limits, an input chunk within the cap, a summary's
 * grid whole. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "proto_check.h"
#include "voxel.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void must(int cond)
{
    if (!cond) abort();
}

static void trusted_domain(const double *d, size_t n)
{
    must(n == 2 || n == 6);
    for (size_t i = 0; i < n; i += 2)
        must(isfinite(d[i]) && isfinite(d[i + 1]) && d[i] < d[i + 1]);
}

/* What the daemon takes from a mesh job without looking again. */
static void trusted_mesh(const Voxd__Submit *s, const proto_limits *lim)
{
    const Voxd__Mesh *m = s->mesh;
    must(m != NULL && m->band <= VOXEL_BAND_MAX);
    must(!m->band || s->channel == VOXD__CHANNEL__CHANNEL_DISTANCE);
    uint64_t n = s->input_bytes ? s->input_bytes : m->data.len;
    must(n >= 1 && n <= lim->max_mesh_bytes && (!s->input_bytes || !m->data.len));
    must((unsigned)m->format <= 5 && (unsigned)m->mode <= 5 && (unsigned)m->repair <= 3);
    must(m->supersample == 0 || (m->supersample >= 2 && m->supersample <= 8));
    if (m->n_domain) trusted_domain(m->domain, m->n_domain);
    must(m->res >= 1 && m->res <= lim->max_res && (uint64_t)m->pad * 2 < m->res);
    must(!m->n_domain || !m->pad);
    must(m->source_name.len <= 512 &&
         (!m->source_name.len || !memchr(m->source_name.data, '\n', m->source_name.len)));
}

/* Children an op takes (-1: not an op), written out again here. */
static int csg_arity(Voxd__CsgOp op)
{
    switch (op) {
    case VOXD__CSG_OP__CSG_PRIMITIVE: case VOXD__CSG_OP__CSG_IMPLICIT:
    case VOXD__CSG_OP__CSG_MESH: case VOXD__CSG_OP__CSG_VOD: return 0;
    case VOXD__CSG_OP__CSG_INVERSE: case VOXD__CSG_OP__CSG_SCALAR_ADD:
    case VOXD__CSG_OP__CSG_SCALAR_MUL: case VOXD__CSG_OP__CSG_ERODE:
    case VOXD__CSG_OP__CSG_DILATE: return 1;
    case VOXD__CSG_OP__CSG_UNION: case VOXD__CSG_OP__CSG_INTERSECTION:
    case VOXD__CSG_OP__CSG_DIFFERENCE: case VOXD__CSG_OP__CSG_TRIM: case VOXD__CSG_OP__CSG_CAP:
    case VOXD__CSG_OP__CSG_ADD: case VOXD__CSG_OP__CSG_MODULATE: case VOXD__CSG_OP__CSG_DIVIDE:
    case VOXD__CSG_OP__CSG_DIFFERENCE_A: case VOXD__CSG_OP__CSG_DIFFERENCE_B:
    case VOXD__CSG_OP__CSG_DIVIDE_A: return 2;
    default: return -1;
    }
}

/* What the daemon takes from a CSG job without looking again
 * (daemon_csg_tree): nodes of known ops within the limit, each with as
 * many children as its op takes and all of them earlier, a name that fits,
 * an implicit leaf's source within the limit and without NUL, a file
 * leaf's bytes inline or as input and never both, the input's size the
 * sum of the leaves', res within the limit. */
static void trusted_csg(const Voxd__Submit *s, const proto_limits *lim)
{
    const Voxd__Csg *c = s->csg;
    must(c && c->n_nodes >= 1 && c->n_nodes <= lim->max_csg_nodes &&
         c->n_nodes <= PROTO_CSG_MAX_NODES);
    uint64_t input = 0, bytes = 0;
    for (size_t i = 0; i < c->n_nodes; i++) {
        const Voxd__CsgNode *n = c->nodes[i];
        must(n && n->name.len < PROTO_CSG_NAME_MAX);
        int arity = csg_arity(n->op);
        must(arity >= 0 && n->n_children == (size_t)arity);
        for (size_t k = 0; k < n->n_children; k++) must(n->children[k] < i);
        if (n->op == VOXD__CSG_OP__CSG_IMPLICIT) {
            must(n->source.len >= 1 && n->source.len <= lim->max_expr_bytes);
            must(!memchr(n->source.data, 0, n->source.len));
            if (n->n_domain) trusted_domain(n->domain, n->n_domain);
        }
        if (n->op == VOXD__CSG_OP__CSG_MESH || n->op == VOXD__CSG_OP__CSG_VOD)
            must(!n->data.len != !n->data_bytes);
        input += n->data_bytes;
        bytes += n->data.len + n->data_bytes;
    }
    must(input == s->input_bytes && bytes <= lim->max_csg_leaf_bytes);
    if (c->n_domain) trusted_domain(c->domain, c->n_domain);
    must(c->res >= 1 && c->res <= lim->max_res && c->band <= VOXEL_BAND_MAX);
}

static void trusted_submit(const Voxd__Submit *s, const proto_limits *lim)
{
    must((unsigned)s->channel <= 4 && s->input_bytes <= lim->max_input_bytes);
    must((unsigned)s->comp <= 3 && (unsigned)s->hash <= 2);
    must(s->brick == 0 || (s->brick >= 2 && s->brick <= 256 && !(s->brick & (s->brick - 1))));
    if (s->job_case == VOXD__SUBMIT__JOB_MESH) {
        trusted_mesh(s, lim);
        return;
    }
    if (s->job_case == VOXD__SUBMIT__JOB_CSG) {
        trusted_csg(s, lim);
        return;
    }
    must(s->job_case == VOXD__SUBMIT__JOB_IMPLICIT && s->implicit);
    must(s->channel != VOXD__CHANNEL__CHANNEL_DENSITY);
    const Voxd__Implicit *im = s->implicit;
    if (s->input_bytes) {
        must(im->source.len == 0 && s->input_bytes <= lim->max_expr_bytes &&
             s->input_bytes <= lim->max_input_bytes);
    } else {
        must(im->source.len >= 1 && im->source.len <= lim->max_expr_bytes);
        must(!memchr(im->source.data, 0, im->source.len));
    }
    trusted_domain(im->domain, im->n_domain);
    must(im->res >= 1 && im->res <= lim->max_res);
    must((unsigned)im->schedule <= 2);
}

static void trusted_request(const Voxd__Request *r, const proto_limits *lim)
{
    switch (r->msg_case) {
    case VOXD__REQUEST__MSG_HELLO: must(r->hello && r->hello->version == PROTO_VERSION); break;
    case VOXD__REQUEST__MSG_SUBMIT: must(r->submit != NULL); trusted_submit(r->submit, lim); break;
    case VOXD__REQUEST__MSG_CANCEL: must(r->cancel && r->cancel->job_id); break;
    case VOXD__REQUEST__MSG_STATUS: must(r->status != NULL); break;
    case VOXD__REQUEST__MSG_PING: must(r->ping != NULL); break;
    case VOXD__REQUEST__MSG_INPUT:
        must(r->input && r->input->job_id && r->input->data.len >= 1 &&
             r->input->offset <= lim->max_input_bytes &&
             r->input->data.len <= lim->max_input_bytes - r->input->offset);
        break;
    default: abort();
    }
}

static void trusted_reply(const Voxd__Reply *r, const proto_limits *lim)
{
    switch (r->msg_case) {
    case VOXD__REPLY__MSG_CHUNK:
        must(r->chunk->job_id && r->chunk->data.len >= 1 &&
             r->chunk->data.len <= lim->chunk_size &&
             r->chunk->offset + r->chunk->data.len <= lim->max_result_bytes);
        break;
    case VOXD__REPLY__MSG_ERROR:
        must(r->error->code >= 1 && r->error->code <= 8);
        break;
    case VOXD__REPLY__MSG_STATUS:
        must(r->status->n_workers <= PROTO_MAX_WORKERS);
        break;
    case VOXD__REPLY__MSG_PROGRESS:
        must(r->progress->fraction >= 0 && r->progress->fraction <= 1);
        break;
    case VOXD__REPLY__MSG_HELLO_OK: must(r->hello_ok->limits != NULL); break;
    case VOXD__REPLY__MSG_SUMMARY: {
        const Voxd__Grid *g = r->summary->grid;
        must(g && g->n_res == 3 && g->n_origin == 3 && g->voxel_size > 0 &&
             isfinite(g->voxel_size) && g->depth >= 1 && g->depth <= 32);
        for (int a = 0; a < 3; a++)
            must(g->res[a] >= 1 && g->res[a] <= lim->max_res && isfinite(g->origin[a]));
        break;
    }
    case VOXD__REPLY__MSG_ACCEPTED:
    case VOXD__REPLY__MSG_PONG: break;
    default: abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    proto_limits lims[2];
    proto_limits_default(&lims[0]);
    lims[1] = (proto_limits){.max_frame = 4096, .max_expr_bytes = 8, .max_res = 16,
                             .max_csg_nodes = 2, .chunk_size = 16,
                             .max_result_bytes = 1024, .max_input_bytes = 64,
                             .max_mesh_bytes = 48, .max_triangles = 4};
    Voxd__Request *rq = proto_frame_unpack_request(data, size);
    if (rq) {
        for (int i = 0; i < 2; i++) {
            proto_error e;
            int rc = proto_check_request(rq, &lims[i], &e);
            if (rc == 0) trusted_request(rq, &lims[i]);
            else must(e.msg[0] && (e.code == VOXD__ERROR_CODE__INVALID_INPUT ||
                                   e.code == VOXD__ERROR_CODE__LIMIT_EXCEEDED));
        }
        voxd__request__free_unpacked(rq, NULL);
    }
    Voxd__Reply *rp = proto_frame_unpack_reply(data, size);
    if (rp) {
        for (int i = 0; i < 2; i++) {
            proto_error e;
            if (proto_check_reply(rp, &lims[i], &e) == 0) trusted_reply(rp, &lims[i]);
            else must(e.msg[0] != '\0');
        }
        voxd__reply__free_unpacked(rp, NULL);
    }
    return 0;
}

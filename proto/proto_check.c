/* proto_check — the limits table, the checks' shared pieces and the requests
 * (the daemon's side); the replies are in proto_check_reply.c.  See proto_check.h. */
#include "proto_check.h"
#include "proto_check_int.h"

#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "err.h"
#include "job_meta.h"
#include "voxel.h"

/* Each default within its own range, at compile time. */
#define RANGE_OK(name, type, def, min, max, unit, doc)                                   \
    _Static_assert((uint64_t)(min) <= (uint64_t)(def) && (uint64_t)(def) <= (uint64_t)(max), \
                   #name ": default outside its range");                                  \
    _Static_assert((uint64_t)(max) <= (type)-1, #name ": range wider than its type");
VOX_LIMITS(RANGE_OK)
#undef RANGE_OK

const proto_limit_info proto_limit_table[] = {
#define ROW(name, type, def, min, max, unit, doc)                                         \
    {#name, offsetof(proto_limits, name), sizeof(type), (def), (min), (max), #unit, doc},
    VOX_LIMITS(ROW)
#undef ROW
};
const size_t proto_n_limits = sizeof proto_limit_table / sizeof *proto_limit_table;

uint64_t proto_limit_get(const proto_limits *lim, size_t i)
{
    const proto_limit_info *r = &proto_limit_table[i];
    const char *p = (const char *)lim + r->off;
    if (r->size == sizeof(uint64_t)) {
        uint64_t v;
        memcpy(&v, p, sizeof v);
        return v;
    }
    uint32_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

void proto_limits_default(proto_limits *lim)
{
#define DEF(name, type, def, min, max, unit, doc) lim->name = (def);
    VOX_LIMITS(DEF)
#undef DEF
}

/* Both directions name every field of the table: a row without its field
 * in the Limits message does not compile (the unit test catches the
 * converse). */
void proto_limits_from_hello(const Voxd__Limits *l, proto_limits *lim)
{
#define FROM(name, type, def, min, max, unit, doc) lim->name = l->name;
    VOX_LIMITS(FROM)
#undef FROM
}

void proto_limits_to_hello(const proto_limits *lim, Voxd__Limits *l)
{
#define TO(name, type, def, min, max, unit, doc) l->name = lim->name;
    VOX_LIMITS(TO)
#undef TO
}

const char *proto_error_code_name(int code)
{
    const ProtobufCEnumValue *v =
        protobuf_c_enum_descriptor_get_value(&voxd__error_code__descriptor, code);
    return v ? v->name : "UNKNOWN";
}

__attribute__((format(printf, 3, 4)))
int proto_bad(proto_error *e, Voxd__ErrorCode code, const char *fmt, ...)
{
    int rc = code == LIMIT ? -E2BIG : -EINVAL;
    if (e) {
        va_list ap;
        va_start(ap, fmt);
        e->code = code;
        err_vfmt(e->msg, sizeof e->msg, rc, fmt, ap);
        va_end(ap);
    }
    return rc;
}

int proto_ok(proto_error *e)
{
    if (e) {
        e->code = VOXD__ERROR_CODE__ERROR_CODE_UNSPECIFIED;
        e->msg[0] = '\0';
    }
    return 0;
}

/* ---------------------------------------------------------------- pieces */

/* Length of one UTF-8 sequence at s (n bytes left), 0 if malformed. */
static size_t utf8_len(const unsigned char *s, size_t n)
{
    unsigned c = s[0];
    size_t len;
    unsigned min;
    if (c < 0x80) return 1;
    if (c >= 0xc2 && c <= 0xdf) len = 2, min = 0x80;
    else if (c >= 0xe0 && c <= 0xef) len = 3, min = 0x800;
    else if (c >= 0xf0 && c <= 0xf4) len = 4, min = 0x10000;
    else return 0;
    if (len > n) return 0;
    unsigned cp = c & (0x7fu >> len);
    for (size_t i = 1; i < len; i++) {
        if ((s[i] & 0xc0) != 0x80) return 0;
        cp = cp << 6 | (s[i] & 0x3f);
    }
    if (cp < min || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff)) return 0;
    return len;
}

/* Text for logs and terminals: bounded, UTF-8, no control characters
 * (newline and tab allowed where multiline is set). */
int proto_check_text(const char *s, size_t max, int multiline, const char *what,
                     proto_error *e)
{
    if (!s) return 0;
    size_t n = strlen(s);
    if (n > max) return proto_bad(e, INVALID, "%s is %zu bytes, limit %zu", what, n, max);
    for (size_t i = 0; i < n;) {
        unsigned char c = (unsigned char)s[i];
        if (c < 0x20 || c == 0x7f) {
            if (!(multiline && (c == '\n' || c == '\t')))
                return proto_bad(e, INVALID, "%s contains control character 0x%02x at offset %zu",
                                 what, c, i);
        }
        size_t k = utf8_len((const unsigned char *)s + i, n - i);
        if (!k) return proto_bad(e, INVALID, "%s is not valid UTF-8 at offset %zu", what, i);
        i += k;
    }
    return 0;
}

/* An expression: non-empty, within the limit, no NUL (the compiler takes a
 * C string). */
static int check_source(const ProtobufCBinaryData *s, uint32_t max,
                        const char *what, proto_error *e)
{
    if (s->len == 0) return proto_bad(e, INVALID, "%s is empty", what);
    if (s->len > max)
        return proto_bad(e, LIMIT, "%s is %zu bytes, limit %u", what, s->len, max);
    const uint8_t *nul = memchr(s->data, 0, s->len);
    if (nul)
        return proto_bad(e, INVALID, "%s source contains a NUL byte at offset %zu", what,
                         (size_t)(nul - s->data));
    return 0;
}

/* A file name for the metadata: bounded, one line, no NUL (optional). */
static int check_source_name(const ProtobufCBinaryData *s, proto_error *e)
{
    if (s->len > JOB_META_NAME_MAX)
        return proto_bad(e, LIMIT, "source_name is %zu bytes, limit %u", s->len, JOB_META_NAME_MAX);
    for (size_t i = 0; i < s->len; i++)
        if (s->data[i] == 0 || s->data[i] == '\n' || s->data[i] == '\r')
            return proto_bad(e, INVALID, "source_name contains a %s at offset %zu",
                             s->data[i] ? "line break" : "NUL byte", i);
    return 0;
}

/* A box: 6 values X0 X1 Y0 Y1 Z0 Z1 (or 2, A B, for a cube when cube_ok);
 * finite, each low < high, each extent finite. */
static int check_box(const double *v, size_t n, int cube_ok, const char *what,
                     proto_error *e)
{
    if (cube_ok ? (n != 2 && n != 6) : n != 6)
        return proto_bad(e, INVALID, "%s needs %s values, got %zu", what,
                         cube_ok ? "2 or 6" : "6", n);
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return proto_bad(e, INVALID, "%s value %zu is not finite (%g)", what, i + 1, v[i]);
    for (size_t a = 0; a < n / 2; a++) {
        double lo = v[2 * a], hi = v[2 * a + 1];
        const char *axis = n == 2 ? "" : a == 0 ? " x" : a == 1 ? " y" : " z";
        if (!(lo < hi))
            return proto_bad(e, INVALID, "%s%s: low %g is not below high %g", what, axis, lo, hi);
        if (!isfinite(hi - lo))
            return proto_bad(e, INVALID, "%s%s is too wide (%g to %g)", what, axis, lo, hi);
    }
    return 0;
}

static int check_res(uint32_t res, const proto_limits *lim, proto_error *e)
{
    if (res == 0)
        return proto_bad(e, INVALID, "res is missing (give 1 to %u)", lim->max_res);
    if (res > lim->max_res)
        return proto_bad(e, LIMIT, "res %u is over this server's limit of %u", res,
                         lim->max_res);
    return 0;
}

static const char *const channel_names[] = {"unspecified", "occupancy", "density",
                                            "surface", "distance"};

/* The output options shared by every kind of job. */
static int check_output(const Voxd__Submit *s, proto_error *e)
{
    if ((unsigned)s->channel > VOXD__CHANNEL__CHANNEL_DISTANCE)
        return proto_bad(e, INVALID, "unknown channel %d", (int)s->channel);
    uint32_t b = s->brick;
    if (b != 0 && (b < PROTO_MIN_BRICK || b > PROTO_MAX_BRICK || (b & (b - 1))))
        return proto_bad(e, INVALID, "brick %u is not a power of two from %u to %u", b,
                         PROTO_MIN_BRICK, PROTO_MAX_BRICK);
    if ((unsigned)s->comp > VOXD__COMPRESSION__COMPRESSION_RUNL)
        return proto_bad(e, INVALID, "unknown compression %d", (int)s->comp);
    if ((unsigned)s->hash > VOXD__HASH__HASH_XX32)
        return proto_bad(e, INVALID, "unknown hash %d", (int)s->hash);
    return 0;
}

/* ---------------------------------------------------------------- jobs */

/* The distance channel's band (Implicit, Mesh and Csg.band alike). */
static int check_band(uint32_t band, const Voxd__Submit *s, proto_error *e)
{
    if (band > VOXEL_BAND_MAX)
        return proto_bad(e, INVALID, "band %u is not from 1 to %u voxels (or 0: %u)", band,
                         VOXEL_BAND_MAX, VOXEL_BAND_DEFAULT);
    if (band && s->channel != VOXD__CHANNEL__CHANNEL_DISTANCE)
        return proto_bad(e, INVALID, "band %u is for channel distance", band);
    return 0;
}

/* An expression that comes as the job's input: the Submit carries its size
 * only (its bytes are checked as they arrive). */
static int check_source_input(const ProtobufCBinaryData *inline_src, uint64_t n,
                              uint32_t max, proto_error *e)
{
    if (inline_src->len)
        return proto_bad(e, INVALID,
                         "the expression comes either inline or as input_bytes, not both");
    if (n > max)
        return proto_bad(e, LIMIT, "expression is %llu bytes, limit %u", (unsigned long long)n,
                         max);
    return 0;
}

static int check_implicit(const Voxd__Implicit *im, const Voxd__Submit *s,
                          const proto_limits *lim, proto_error *e)
{
    int rc = s->input_bytes
                 ? check_source_input(&im->source, s->input_bytes, lim->max_expr_bytes, e)
                 : check_source(&im->source, lim->max_expr_bytes, "expression", e);
    if (rc) return rc;
    if ((rc = check_source_name(&im->source_name, e))) return rc;
    if ((rc = check_box(im->domain, im->n_domain, 1, "domain", e))) return rc;
    if ((rc = check_res(im->res, lim, e))) return rc;
    if ((unsigned)im->schedule > VOXD__SCHEDULE__SCHEDULE_PAPER)
        return proto_bad(e, INVALID, "unknown schedule %d", (int)im->schedule);
    if (s->channel == VOXD__CHANNEL__CHANNEL_DENSITY)
        return proto_bad(e, INVALID, "channel %s is not available for implicit jobs (use "
                         "surface, occupancy or distance)", channel_names[s->channel]);
    return check_band(im->band, s, e);
}

/* A mesh file: inline (1..max_mesh_bytes bytes, any bytes: binary formats
 * hold NULs) or declared as the job's input.  What the bytes hold is the
 * parser's to say when the job runs. */
static int check_mesh_data(const Voxd__Mesh *m, const Voxd__Submit *s,
                           const proto_limits *lim, proto_error *e)
{
    uint64_t n = s->input_bytes ? s->input_bytes : m->data.len;
    if (s->input_bytes && m->data.len)
        return proto_bad(e, INVALID, "the mesh comes either inline or as input_bytes, not both");
    if (n == 0) return proto_bad(e, INVALID, "mesh data is empty");
    if (n > lim->max_mesh_bytes)
        return proto_bad(e, LIMIT, "mesh is %llu bytes, over this server's max_mesh_bytes of %llu",
                         (unsigned long long)n, (unsigned long long)lim->max_mesh_bytes);
    return 0;
}

/* The enums and numbers of a mesh job's options. */
static int check_mesh_options(const Voxd__Mesh *m, proto_error *e)
{
    if ((unsigned)m->format > VOXD__MESH_FORMAT__MESH_FORMAT_GLTF)
        return proto_bad(e, INVALID, "unknown mesh format %d", (int)m->format);
    if ((unsigned)m->mode > VOXD__MESH_MODE__MESH_MODE_INTERIOR)
        return proto_bad(e, INVALID, "unknown mesh mode %d", (int)m->mode);
    if ((unsigned)m->repair > VOXD__MESH_REPAIR__MESH_REPAIR_WINDING)
        return proto_bad(e, INVALID, "unknown mesh repair %d", (int)m->repair);
    uint32_t k = m->supersample;
    if (k && (k < PROTO_MIN_SUPERSAMPLE || k > PROTO_MAX_SUPERSAMPLE))
        return proto_bad(e, INVALID, "supersample %u is not from %u to %u (or 0: %u)", k,
                         PROTO_MIN_SUPERSAMPLE, PROTO_MAX_SUPERSAMPLE, PROTO_MIN_SUPERSAMPLE);
    double w = m->weld_eps;
    if (!(w == 0 || (w >= PROTO_MIN_WELD && w <= PROTO_MAX_WELD)))
        return proto_bad(e, INVALID, "weld_eps %g is not 0 or from %g to %g", w, PROTO_MIN_WELD,
                         PROTO_MAX_WELD);
    if (w != 0 && !m->weld) return proto_bad(e, INVALID, "weld_eps %g without weld", w);
    return 0;
}

/* The mesh's band, and its distance's sign's mode (the solid). */
static int check_mesh_band(const Voxd__Mesh *m, const Voxd__Submit *s, proto_error *e)
{
    int dist = s->channel == VOXD__CHANNEL__CHANNEL_DISTANCE;
    int rc = check_band(m->band, s, e);
    if (rc) return rc;
    if (dist && m->mode > VOXD__MESH_MODE__MESH_MODE_SOLID)
        return proto_bad(e, INVALID,
                         "channel distance takes its sign from the solid: mode solid only");
    return 0;
}

static int check_mesh(const Voxd__Mesh *m, const Voxd__Submit *s, const proto_limits *lim,
                      proto_error *e)
{
    int rc;
    if ((rc = check_mesh_data(m, s, lim, e)) || (rc = check_mesh_options(m, e)) ||
        (rc = check_source_name(&m->source_name, e)))
        return rc;
    if (m->n_domain && (rc = check_box(m->domain, m->n_domain, 1, "domain", e))) return rc;
    if ((rc = check_res(m->res, lim, e))) return rc;
    if (m->n_domain && m->pad)
        return proto_bad(e, INVALID,
                         "pad %u is for a mesh fitted to its bounding box, not with a domain",
                         m->pad);
    if ((uint64_t)m->pad * 2 >= m->res)
        return proto_bad(e, INVALID, "pad %u leaves no voxel for the mesh in res %u (2 pad < res)",
                         m->pad, m->res);
    return check_mesh_band(m, s, e);
}

typedef struct {
    const char *name;
    int arity; /* children */
} csg_op_info;

static const csg_op_info csg_ops[] = {
    [VOXD__CSG_OP__CSG_PRIMITIVE] = {"primitive", 0},
    [VOXD__CSG_OP__CSG_IMPLICIT] = {"implicit", 0},
    [VOXD__CSG_OP__CSG_MESH] = {"mesh", 0},
    [VOXD__CSG_OP__CSG_VOD] = {"vod", 0},
    [VOXD__CSG_OP__CSG_UNION] = {"union", 2},
    [VOXD__CSG_OP__CSG_INTERSECTION] = {"intersection", 2},
    [VOXD__CSG_OP__CSG_DIFFERENCE] = {"difference", 2},
    [VOXD__CSG_OP__CSG_TRIM] = {"trim", 2},
    [VOXD__CSG_OP__CSG_CAP] = {"cap", 2},
    [VOXD__CSG_OP__CSG_ADD] = {"add", 2},
    [VOXD__CSG_OP__CSG_MODULATE] = {"modulate", 2},
    [VOXD__CSG_OP__CSG_DIVIDE] = {"divide", 2},
    [VOXD__CSG_OP__CSG_DIFFERENCE_A] = {"differenceA", 2},
    [VOXD__CSG_OP__CSG_DIFFERENCE_B] = {"differenceB", 2},
    [VOXD__CSG_OP__CSG_DIVIDE_A] = {"divideA", 2},
    [VOXD__CSG_OP__CSG_INVERSE] = {"inverse", 1},
    [VOXD__CSG_OP__CSG_SCALAR_ADD] = {"scale_add", 1},
    [VOXD__CSG_OP__CSG_SCALAR_MUL] = {"scale_mul", 1},
    [VOXD__CSG_OP__CSG_ERODE] = {"erode", 1},
    [VOXD__CSG_OP__CSG_DILATE] = {"dilate", 1},
};

static const csg_op_info *csg_op(Voxd__CsgOp op)
{
    unsigned v = (unsigned)op;
    if (v >= sizeof csg_ops / sizeof *csg_ops || !csg_ops[v].name) return NULL;
    return &csg_ops[v];
}

/* "CSG node 3 ('hole')" or "CSG node 3": how messages name a node. */
static const char *node_label(const Voxd__CsgNode *n, size_t i, char *buf, size_t len)
{
    int named = n && n->name.len > 0 && n->name.len < PROTO_CSG_NAME_MAX;
    if (named)
        snprintf(buf, len, "CSG node %zu ('%.*s')", i, (int)n->name.len,
                 (const char *)n->name.data);
    else
        snprintf(buf, len, "CSG node %zu", i);
    return buf;
}

/* A node's name: empty, or [A-Za-z_][A-Za-z0-9_]* of under 32 bytes. */
static int check_csg_name(const ProtobufCBinaryData *nm, size_t i, proto_error *e)
{
    if (nm->len >= PROTO_CSG_NAME_MAX)
        return proto_bad(e, INVALID, "CSG node %zu's name is %zu bytes, limit %u", i, nm->len,
                         PROTO_CSG_NAME_MAX - 1);
    for (size_t k = 0; k < nm->len; k++) {
        uint8_t c = nm->data[k];
        int ok_c = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' ||
                   (k > 0 && c >= '0' && c <= '9');
        if (!ok_c)
            return proto_bad(e, INVALID, "CSG node %zu's name has a byte 0x%02x at offset %zu "
                             "(names are letters, digits and _)", i, c, k);
    }
    return 0;
}

/* The fields a node of this op must not carry. */
static int check_csg_stray(const Voxd__CsgNode *n, const char *who, const char *name,
                           proto_error *e)
{
    const char *field = NULL;
    int prim = n->op == VOXD__CSG_OP__CSG_PRIMITIVE;
    int scalar_op = n->op == VOXD__CSG_OP__CSG_DIVIDE ||
                    n->op == VOXD__CSG_OP__CSG_SCALAR_ADD ||
                    n->op == VOXD__CSG_OP__CSG_SCALAR_MUL;
    int morph = n->op == VOXD__CSG_OP__CSG_ERODE || n->op == VOXD__CSG_OP__CSG_DILATE;
    if (!prim && (n->primitive || n->n_center || n->n_size || n->n_rotate || n->axis))
        field = "a primitive's fields";
    else if (n->op != VOXD__CSG_OP__CSG_IMPLICIT && (n->source.len || n->n_domain))
        field = "an expression or its domain";
    else if (n->op != VOXD__CSG_OP__CSG_MESH && n->op != VOXD__CSG_OP__CSG_VOD &&
             (n->data.len || n->data_bytes))
        field = "a file's data";
    else if (n->op != VOXD__CSG_OP__CSG_MESH && (n->n_fit || n->scale != 0))
        field = "a mesh's fit or scale";
    else if (!scalar_op && n->scalar != 0)
        field = "a scalar";
    else if (!morph && n->k)
        field = "k";
    if (field) return proto_bad(e, INVALID, "%s (%s) does not take %s", who, name, field);
    return 0;
}

/* A vector of a CSG node: 3 values (0 allowed when may_omit), each finite
 * and within PROTO_CSG_MAX_COORD, and > 0 when positive. */
typedef struct {
    const char *what; /* "center", ... */
    int may_omit, positive;
} csg_vec_rule;

static const csg_vec_rule vec_center = {"center", 1, 0}, vec_size = {"size", 0, 1},
                          vec_rotation = {"rotation", 1, 0}, vec_fit = {"fit", 0, 0};

static int check_csg_vec(const double *v, size_t n, const csg_vec_rule *r, const char *who,
                         proto_error *e)
{
    const char *what = r->what;
    int may_omit = r->may_omit, positive = r->positive;
    if (n != 3 && !(may_omit && n == 0))
        return proto_bad(e, INVALID, "%s needs 3 values for its %s%s, got %zu", who, what,
                         may_omit ? " (or none)" : "", n);
    for (size_t k = 0; k < n; k++) {
        if (!isfinite(v[k]) || fabs(v[k]) > PROTO_CSG_MAX_COORD)
            return proto_bad(e, INVALID, "%s's %s value %zu is %g, not a finite number within "
                             "+-%g", who, what, k + 1, v[k], PROTO_CSG_MAX_COORD);
        if (positive && !(v[k] > 0))
            return proto_bad(e, INVALID, "%s's %s must be positive, value %zu is %g", who, what,
                             k + 1, v[k]);
    }
    return 0;
}

static int check_csg_primitive(const Voxd__CsgNode *n, const char *who, proto_error *e)
{
    if (n->primitive == VOXD__PRIMITIVE__PRIMITIVE_UNSPECIFIED ||
        (unsigned)n->primitive > VOXD__PRIMITIVE__PRIMITIVE_CONE)
        return proto_bad(e, INVALID, "%s has unknown primitive %d", who, (int)n->primitive);
    if ((unsigned)n->axis > VOXD__AXIS__AXIS_Z)
        return proto_bad(e, INVALID, "%s has unknown axis %d", who, (int)n->axis);
    if (n->axis && n->primitive != VOXD__PRIMITIVE__PRIMITIVE_CYLINDER &&
        n->primitive != VOXD__PRIMITIVE__PRIMITIVE_CONE)
        return proto_bad(e, INVALID, "%s: only a cylinder or a cone has an axis", who);
    int rc = check_csg_vec(n->center, n->n_center, &vec_center, who, e);
    if (!rc) rc = check_csg_vec(n->size, n->n_size, &vec_size, who, e);
    if (!rc) rc = check_csg_vec(n->rotate, n->n_rotate, &vec_rotation, who, e);
    return rc;
}

static int check_csg_leaf(const Voxd__CsgNode *n, const char *who, const proto_limits *lim,
                          proto_error *e)
{
    char what[128];
    switch (n->op) {
    case VOXD__CSG_OP__CSG_PRIMITIVE:
        return check_csg_primitive(n, who, e);
    case VOXD__CSG_OP__CSG_IMPLICIT:
        snprintf(what, sizeof what, "%.96s's expression", who);
        if (n->n_domain == 0) return check_source(&n->source, lim->max_expr_bytes, what, e);
        if (n->n_domain != 2)
            return proto_bad(e, INVALID, "%s's domain needs 2 values (or none), got %zu", who,
                             n->n_domain);
        int rc = check_source(&n->source, lim->max_expr_bytes, what, e);
        snprintf(what, sizeof what, "%.96s's domain", who);
        return rc ? rc : check_box(n->domain, n->n_domain, 1, what, e);
    case VOXD__CSG_OP__CSG_MESH: case VOXD__CSG_OP__CSG_VOD:
        if (!n->data.len && !n->data_bytes)
            return proto_bad(e, INVALID, "%s: a %s leaf needs its file's data", who,
                             n->op == VOXD__CSG_OP__CSG_MESH ? "mesh" : "vod");
        if (n->data.len && n->data_bytes)
            return proto_bad(e, INVALID, "%s: its file comes inline or as input (data_bytes), "
                             "not both", who);
        if (n->n_fit && check_csg_vec(n->fit, n->n_fit, &vec_fit, who, e)) return -EINVAL;
        if (!isfinite(n->scale) || n->scale < 0 || n->scale > PROTO_CSG_MAX_COORD)
            return proto_bad(e, INVALID, "%s's scale is %g: 0 (none) or a positive number", who,
                             n->scale);
        return 0;
    case VOXD__CSG_OP__CSG_DIVIDE:
        if (!(n->scalar > 0 && n->scalar <= 1))
            return proto_bad(e, INVALID, "%s (divide) needs a scalar S_L in (0, 1], got %g", who,
                             n->scalar);
        return 0;
    case VOXD__CSG_OP__CSG_SCALAR_ADD: case VOXD__CSG_OP__CSG_SCALAR_MUL:
        if (!isfinite(n->scalar))
            return proto_bad(e, INVALID, "%s needs a finite scalar, got %g", who, n->scalar);
        return 0;
    case VOXD__CSG_OP__CSG_ERODE: case VOXD__CSG_OP__CSG_DILATE:
        if (n->k < 1 || n->k > PROTO_CSG_MAX_MORPH)
            return proto_bad(e, INVALID, "%s needs k of 1..%u voxels, got %u", who,
                             PROTO_CSG_MAX_MORPH, n->k);
        return 0;
    default: return 0;
    }
}

static int check_csg_node(const Voxd__CsgNode *n, size_t i, const proto_limits *lim,
                          proto_error *e)
{
    char who[96];
    node_label(n, i, who, sizeof who);
    if (!n) return proto_bad(e, INVALID, "%s is missing", who);
    int rc = check_csg_name(&n->name, i, e);
    if (rc) return rc;
    if (n->op == VOXD__CSG_OP__CSG_OP_UNSPECIFIED)
        return proto_bad(e, INVALID, "%s has no op", who);
    const csg_op_info *op = csg_op(n->op);
    if (!op) return proto_bad(e, INVALID, "%s has unknown op %d", who, (int)n->op);
    if (n->n_children != (size_t)op->arity)
        return proto_bad(e, INVALID, "%s (%s) needs %d %s, got %zu", who, op->name, op->arity,
                         op->arity == 1 ? "child" : "children", n->n_children);
    for (size_t k = 0; k < n->n_children; k++)
        if (n->children[k] >= i)
            return proto_bad(e, INVALID, "%s refers to node %u, which is not earlier "
                             "(children come first: no cycles)", who, n->children[k]);
    rc = check_csg_stray(n, who, op->name, e);
    return rc ? rc : check_csg_leaf(n, who, lim, e);
}

/* The longest path from the result to a leaf, and the erosions' and
 * dilations' widest sum along one (the evaluator grows a brick by it). */
static int check_csg_shape(const Voxd__Csg *c, const proto_limits *lim, proto_error *e)
{
    uint32_t depth[PROTO_CSG_MAX_NODES], margin[PROTO_CSG_MAX_NODES];
    char who[96];
    for (size_t i = 0; i < c->n_nodes; i++) {
        const Voxd__CsgNode *n = c->nodes[i];
        uint32_t d = 0, m = 0;
        for (size_t k = 0; k < n->n_children; k++) {
            if (depth[n->children[k]] > d) d = depth[n->children[k]];
            if (margin[n->children[k]] > m) m = margin[n->children[k]];
        }
        depth[i] = d + 1;
        margin[i] = m + n->k;
        if (depth[i] > lim->max_csg_depth)
            return proto_bad(e, LIMIT, "%s: the tree is deeper than this server's max_csg_depth "
                             "of %u", node_label(n, i, who, sizeof who), lim->max_csg_depth);
        if (margin[i] > PROTO_CSG_MAX_MARGIN)
            return proto_bad(e, INVALID, "%s: erosions and dilations along one path pass %u voxels",
                             node_label(n, i, who, sizeof who), PROTO_CSG_MAX_MARGIN);
    }
    return 0;
}

static int check_csg(const Voxd__Csg *c, const Voxd__Submit *s, const proto_limits *lim,
                     proto_error *e)
{
    int rc;
    if (c->n_nodes == 0) return proto_bad(e, INVALID, "CSG job has no nodes");
    uint32_t max = lim->max_csg_nodes < PROTO_CSG_MAX_NODES ? lim->max_csg_nodes
                                                            : PROTO_CSG_MAX_NODES;
    if (c->n_nodes > max)
        return proto_bad(e, LIMIT, "CSG job has %zu nodes, over this server's max_csg_nodes of %u",
                         c->n_nodes, max);
    uint64_t leaf_bytes = 0, input = 0;
    for (size_t i = 0; i < c->n_nodes; i++) {
        if ((rc = check_csg_node(c->nodes[i], i, lim, e))) return rc;
        const Voxd__CsgNode *n = c->nodes[i];
        if (n->data_bytes > lim->max_csg_leaf_bytes) /* no overflow below */
            return proto_bad(e, LIMIT, "CSG node %zu's file is %llu bytes, over this server's "
                             "max_csg_leaf_bytes of %llu", i, (unsigned long long)n->data_bytes,
                             (unsigned long long)lim->max_csg_leaf_bytes);
        if (n->data_bytes && !s->input_bytes)
            return proto_bad(e, INVALID, "CSG node %zu has data_bytes but the job declares no "
                             "input_bytes", i);
        if (n->data.len && s->input_bytes)
            return proto_bad(e, INVALID, "CSG node %zu's file is inline but the job's leaves come "
                             "as input (input_bytes)", i);
        leaf_bytes += n->data.len + n->data_bytes;
        input += n->data_bytes;
    }
    if (input != s->input_bytes)
        return proto_bad(e, INVALID, "the CSG leaves' data_bytes add up to %llu, the job declares "
                         "%llu bytes of input", (unsigned long long)input,
                         (unsigned long long)s->input_bytes);
    if (leaf_bytes > lim->max_csg_leaf_bytes)
        return proto_bad(e, LIMIT, "the CSG job's leaves are %llu bytes, over this server's "
                         "max_csg_leaf_bytes of %llu", (unsigned long long)leaf_bytes,
                         (unsigned long long)lim->max_csg_leaf_bytes);
    if ((rc = check_csg_shape(c, lim, e))) return rc;
    if ((rc = check_source_name(&c->source_name, e))) return rc;
    if ((rc = check_box(c->domain, c->n_domain, 1, "domain", e))) return rc;
    if ((rc = check_res(c->res, lim, e))) return rc;
    /* the distance channel too; which trees have one the pipeline decides
     * (csg_dist_check), naming the node */
    return check_band(c->band, s, e);
}

static int check_submit(const Voxd__Submit *s, const proto_limits *lim, proto_error *e)
{
    int rc = check_output(s, e);
    if (rc) return rc;
    if (s->input_bytes > lim->max_input_bytes)
        return proto_bad(e, LIMIT,
                         "input is %llu bytes, over this server's max_input_bytes of %llu",
                         (unsigned long long)s->input_bytes,
                         (unsigned long long)lim->max_input_bytes);
    switch (s->job_case) {
    case VOXD__SUBMIT__JOB__NOT_SET:
        return proto_bad(e, INVALID, "submit has no job (implicit, mesh or csg)");
    case VOXD__SUBMIT__JOB_IMPLICIT:
        if (!s->implicit) break;
        return check_implicit(s->implicit, s, lim, e);
    case VOXD__SUBMIT__JOB_MESH:
        if (!s->mesh) break;
        return check_mesh(s->mesh, s, lim, e);
    case VOXD__SUBMIT__JOB_CSG:
        if (!s->csg) break;
        return check_csg(s->csg, s, lim, e);
    default:
        return proto_bad(e, INVALID, "unknown job kind %d", (int)s->job_case);
    }
    return proto_bad(e, INVALID, "submit job is missing");
}

/* A piece of a job's input: whether it fits its job is the daemon's to
 * say; here, that it is something and stays within the cap. */
static int check_input_chunk(const Voxd__InputChunk *c, const proto_limits *lim,
                             proto_error *e)
{
    if (!c->job_id) return proto_bad(e, INVALID, "input chunk has no job id");
    if (c->data.len == 0)
        return proto_bad(e, INVALID, "input chunk at offset %llu is empty",
                         (unsigned long long)c->offset);
    if (c->offset > lim->max_input_bytes || c->data.len > lim->max_input_bytes - c->offset)
        return proto_bad(e, LIMIT,
                         "input chunk at offset %llu passes this server's max_input_bytes of %llu",
                         (unsigned long long)c->offset, (unsigned long long)lim->max_input_bytes);
    return 0;
}

/* ---------------------------------------------------------------- requests */

static int check_hello(const Voxd__Hello *h, proto_error *e)
{
    if (h->version != PROTO_VERSION)
        return proto_bad(e, INVALID, "protocol version %u is not supported (this server speaks %u)",
                         h->version, PROTO_VERSION);
    return proto_check_text(h->client, PROTO_MAX_NAME, 0, "client name", e);
}

/* The message of a set oneof case, NULL if a local caller set the case but
 * not the pointer. */
static const void *request_body(const Voxd__Request *r)
{
    switch (r->msg_case) {
    case VOXD__REQUEST__MSG_HELLO: return r->hello;
    case VOXD__REQUEST__MSG_SUBMIT: return r->submit;
    case VOXD__REQUEST__MSG_CANCEL: return r->cancel;
    case VOXD__REQUEST__MSG_STATUS: return r->status;
    case VOXD__REQUEST__MSG_PING: return r->ping;
    case VOXD__REQUEST__MSG_INPUT: return r->input;
    default: return NULL;
    }
}

int proto_check_request(const Voxd__Request *r, const proto_limits *lim,
                        proto_error *err)
{
    int rc;
    if (!r) return proto_bad(err, INVALID, "malformed request");
    if (r->msg_case == VOXD__REQUEST__MSG__NOT_SET)
        return proto_bad(err, INVALID, "request of no type this server knows (protocol version %u)",
                         PROTO_VERSION);
    if (!request_body(r))
        return proto_bad(err, INVALID, "request of unknown type %d", (int)r->msg_case);
    switch (r->msg_case) {
    case VOXD__REQUEST__MSG_HELLO: rc = check_hello(r->hello, err); break;
    case VOXD__REQUEST__MSG_SUBMIT: rc = check_submit(r->submit, lim, err); break;
    case VOXD__REQUEST__MSG_CANCEL:
        rc = r->cancel->job_id ? 0 : proto_bad(err, INVALID, "cancel needs a job id");
        break;
    case VOXD__REQUEST__MSG_INPUT: rc = check_input_chunk(r->input, lim, err); break;
    default: rc = 0; break; /* Status, Ping: nothing to check */
    }
    return rc ? rc : proto_ok(err);
}


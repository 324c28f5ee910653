/* proto_check — the one boundary check of everything that crosses the socket.
 *
 * protobuf-c accepts any well-formed bytes: unknown enum numbers are stored
 * as they are, NaNs and empty or huge fields pass, a oneof may be unset.
 * proto_check_request() (in the daemon) and proto_check_reply() (in the
 * client) check every field of an unpacked message once — oneof case known,
 * enum values in range, numbers finite and in range, lengths and repeated
 * counts against the limits, no NUL in a source, text printable UTF-8 — and
 * say what is wrong in words a person can act on.  Past the check the rest
 * of the code trusts the message.
 *
 * The checks are per message; what depends on the conversation (Hello must
 * come first, a Cancel names one of this client's jobs, chunks arrive in
 * order for a job this client submitted, an InputChunk belongs to a job
 * waiting for input and stays within its declared size) is the caller's.
 */
#ifndef VOXD_PROTO_CHECK_H
#define VOXD_PROTO_CHECK_H

#include <stddef.h>
#include <stdint.h>

#include "csg_limits.h"
#include "vox_limits.h"
#include "voxd.pb-c.h"

#define PROTO_VERSION 1u
/* Fixed bounds of the protocol itself (not configurable). */
#define PROTO_MAX_NAME 128u      /* Hello.client, HelloOk.server, in bytes */
#define PROTO_MAX_MESSAGE 1024u  /* Error.message, in bytes */
#define PROTO_MAX_WORKERS 256u   /* StatusReply.workers (= ENGINE_MAX_WORKERS) */
#define PROTO_MAX_STATUS_JOBS 1024u /* StatusReply.jobs: the running one and the first queued */
#define PROTO_MAX_CPUS 1024      /* a worker's cpu is -1 or below this (CPU_SETSIZE) */
#define PROTO_MAX_LEVEL 64u      /* Progress.level */
#define PROTO_MIN_BRICK 2u
#define PROTO_MAX_BRICK 256u     /* Submit.brick: 0 or a power of two in 2..256 */
#define PROTO_MIN_SUPERSAMPLE 2u /* Mesh.supersample: 0 or 2..8 */
#define PROTO_MIN_WELD 1e-30      /* Mesh.weld_eps: 0 or these (mesh.h's MESH_WELD_*) */
#define PROTO_MAX_WELD 1e30
#define PROTO_MAX_SUPERSAMPLE 8u
/* A CSG tree's fixed bounds, the evaluator's own (common/csg_limits.h):
 * nodes, name bytes with the NUL, erode/dilate k, k summed along a path;
 * and the magnitude of a primitive's coordinates and sizes (world units). */
#define PROTO_CSG_MAX_NODES CSG_MAX_NODES
#define PROTO_CSG_NAME_MAX CSG_NAME_MAX
#define PROTO_CSG_MAX_MORPH CSG_MAX_MORPH
#define PROTO_CSG_MAX_MARGIN CSG_MAX_MARGIN
#define PROTO_CSG_MAX_COORD 1e6

/* The configurable limits (the table VOX_LIMITS): config_proto_limits()
 * fills them from the daemon's config, a client takes them from HelloOk.
 * The checks here use max_expr_bytes, max_res, max_csg_nodes, max_csg_depth, chunk_size,
 * max_result_bytes, max_input_bytes and max_mesh_bytes; max_expr_depth
 * only the expression compiler can see and max_triangles only the mesh
 * parser, the others are the daemon's to count. */
typedef struct {
#define PROTO_LIMIT_FIELD(name, type, def, min, max, unit, doc) type name;
    VOX_LIMITS(PROTO_LIMIT_FIELD)
#undef PROTO_LIMIT_FIELD
} proto_limits;

/* One row of VOX_LIMITS, for code that walks the table (the config's
 * printer, the HelloOk check, the tests). */
typedef struct {
    const char *name;
    size_t off, size;   /* the field in proto_limits (and its width: 4 or 8) */
    uint64_t def, min, max;
    const char *unit;   /* "BYTES", "COUNT" or "SECONDS" */
    const char *doc;
} proto_limit_info;

extern const proto_limit_info proto_limit_table[];
extern const size_t proto_n_limits;

/* The value of row i of the table in lim. */
uint64_t proto_limit_get(const proto_limits *lim, size_t i);

typedef struct {
    Voxd__ErrorCode code; /* INVALID_INPUT or LIMIT_EXCEEDED */
    char msg[256];        /* "res 5000 is over this server's limit of 4096" */
} proto_error;

/* The defaults of config/voxd.conf. */
void proto_limits_default(proto_limits *lim);
/* A client's limits from the server's HelloOk (checked by proto_check_reply). */
void proto_limits_from_hello(const Voxd__Limits *l, proto_limits *lim);
/* The server's HelloOk Limits from its limits. */
void proto_limits_to_hello(const proto_limits *lim, Voxd__Limits *l);

/* 0 if r may be trusted; else -EINVAL (code INVALID_INPUT: malformed, or
 * a CSG mesh or VOD leaf, "not supported yet") or -E2BIG (code LIMIT_EXCEEDED:
 * over a configured limit), with err filled in.  err may be NULL. */
int proto_check_request(const Voxd__Request *r, const proto_limits *lim,
                        proto_error *err);
/* The same for what a server says (client side). */
int proto_check_reply(const Voxd__Reply *r, const proto_limits *lim,
                      proto_error *err);

/* "INVALID_INPUT", ..., or "UNKNOWN" for a number outside the enum. */
const char *proto_error_code_name(int code);

#endif

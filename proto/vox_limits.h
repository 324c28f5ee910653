/* vox_limits.h — the limits of a voxd daemon, in one table.
 *
 * Each limit is one row of VOX_LIMITS: its name, its C type, its default,
 * the range the daemon's configuration accepts, its unit and what it
 * bounds.  The name is at once the configuration key (config/voxd.conf),
 * the field of the protocol's HelloOk Limits message (proto/voxd.proto),
 * the field of the daemon's checker limits (proto_limits) and the field of
 * libvox's vox_server_info.  Every one of those is generated from this
 * table with an X-macro (as libuv's UV_HANDLE_TYPE_MAP), so a limit is
 * added in one place; a unit test checks that the Limits message has
 * exactly the fields of the table, with the same widths.
 *
 * It lives in proto/, the lowest module that every user of the table may
 * include from (config/, libvox/, daemon/ and proto_check itself), and it
 * is public, installed beside vox.h: vox_server_info, which libvox gives
 * its callers, is made of these fields.  It needs nothing but <stdint.h>.
 *
 *   #define X(name, type, def, min, max, unit, doc) ...
 *   VOX_LIMITS(X)
 *
 * unit is one of BYTES (a size: the configuration takes K, M, G, T),
 * COUNT (a plain number) or SECONDS (a duration: s, m, h, d; 0 may mean
 * none where min is 0).  Rows are in the order of the Limits message's
 * field numbers.
 */
#ifndef VOX_LIMITS_H
#define VOX_LIMITS_H

#include <stdint.h>

#define VOX_LIMITS(X)                                                                  \
    X(max_frame, uint32_t, 1u << 20, 4096u, 64u << 20, BYTES,                          \
      "bytes of one frame's message, both directions")                                 \
    X(max_expr_bytes, uint32_t, 65536u, 16u, 16u << 20, BYTES,                          \
      "bytes of an expression's source, inline or as input (also a CSG leaf's)")       \
    X(max_expr_depth, uint32_t, 256u, 1u, 1024u, COUNT,                                \
      "nesting of an expression (1024 is the expression parser's own cap)")            \
    X(max_res, uint32_t, 4096u, 1u, 65536u, COUNT, "voxels along a job's longest axis") \
    X(max_queued_jobs, uint32_t, 64u, 1u, 65536u, COUNT,                               \
      "jobs waiting or uploading their input, all clients together")                   \
    X(max_jobs_per_uid, uint32_t, 16u, 1u, 65536u, COUNT,                              \
      "jobs of one uid uploading, queued, running, or finished and not yet delivered") \
    X(job_timeout, uint32_t, 600u, 0u, 7u * 86400u, SECONDS,                           \
      "a job's running time (not its time in the queue); 0 = none")                    \
    X(max_result_bytes, uint64_t, (uint64_t)4 << 30, (uint64_t)64 << 10,               \
      (uint64_t)4 << 30, BYTES, "bytes of a job's VOD file")                           \
    X(chunk_size, uint32_t, 256u << 10, 1024u, 64u << 20, BYTES,                       \
      "bytes of one ResultChunk's data")                                               \
    X(max_csg_nodes, uint32_t, 256u, 1u, 256u, COUNT,                                  \
      "nodes of a CSG job (256 is the evaluator's own cap)")                           \
    X(max_input_bytes, uint64_t, (uint64_t)64 << 20, (uint64_t)4 << 10,                \
      (uint64_t)4 << 30, BYTES, "bytes of a job's input sent as InputChunks")          \
    X(max_mesh_bytes, uint64_t, (uint64_t)64 << 20, (uint64_t)4 << 10,                 \
      (uint64_t)4 << 30, BYTES,                                                        \
      "bytes of a mesh job's file, inline or as input (max_input_bytes caps the latter)") \
    X(max_triangles, uint32_t, 4u << 20, 1u, 64u << 20, COUNT,                         \
      "triangles of a mesh job's mesh, polygons split (64M is the loaders' own cap)")  \
    X(max_csg_depth, uint32_t, 64u, 1u, 64u, COUNT,                                    \
      "a CSG tree's longest path from its result to a leaf (64 is the evaluator's cap)") \
    X(max_csg_leaf_bytes, uint64_t, (uint64_t)64 << 20, (uint64_t)4 << 10,             \
      (uint64_t)4 << 30, BYTES, "bytes of a CSG job's mesh and VOD leaves, together")

#endif

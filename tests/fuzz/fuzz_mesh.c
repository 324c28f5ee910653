/* libFuzzer harness for the mesh loaders: any input, read as every format
 * (told from the contents, then each one forced) and under tight limits,
 * must be refused with a message and nothing held, or give a mesh that
 * keeps mesh.h's promises (indices in range and distinct, finite vertices,
 * the box around the triangles) and whose topology adds up. */
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "mesh.h"
#include "mesh_check.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_mesh(const mesh *m, mesh_format f)
{
    mesh_check_promises(m);
    if (f != MESH_FORMAT_AUTO && m->format != f) __builtin_trap();
    mesh_topo tp;
    if (mesh_topology(m, &tp)) return; /* out of memory: allowed */
    uint64_t uses = 3 * (uint64_t)m->n_triangles;
    if (tp.edges == 0 || tp.edges > uses || tp.open + tp.nonmanifold + tp.inconsistent > tp.edges)
        __builtin_trap();
    if (tp.components == 0 || tp.components > m->n_triangles) __builtin_trap();
    if (tp.watertight != (tp.open + tp.nonmanifold + tp.inconsistent == 0)) __builtin_trap();
    /* every use is counted once: an open edge has 1, a closed one 2 */
    if (tp.open + 2 * (tp.edges - tp.open - tp.nonmanifold) + 3 * tp.nonmanifold > uses)
        __builtin_trap();
    if (isnan(tp.volume)) __builtin_trap();
}

static void one(const uint8_t *data, size_t size, mesh_format f, const mesh_limits *lim)
{
    mesh m;
    mesh_error err;
    int rc = mesh_parse(data, size, f, lim, &m, &err);
    if (rc == 0) {
        if (lim && (m.n_triangles > lim->max_triangles || m.n_vertices > lim->max_vertices))
            __builtin_trap();
        check_mesh(&m, f);
        mesh_free(&m);
        return;
    }
    if (rc != -EINVAL && rc != -E2BIG && rc != -ENOMEM) __builtin_trap();
    if (!err.msg[0] || m.vertices || m.triangles) __builtin_trap(); /* refused without a message */
    if (!memchr(err.msg, '\0', sizeof err.msg)) __builtin_trap();
    if (err.code != rc) __builtin_trap(); /* the code returned, in the error too */
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const mesh_limits tight = {5, 5};
    one(data, size, MESH_FORMAT_AUTO, NULL);
    one(data, size, MESH_FORMAT_AUTO, &tight);
    for (mesh_format f = MESH_FORMAT_OBJ; f <= MESH_FORMAT_GLTF; f++) one(data, size, f, NULL);
    return 0;
}

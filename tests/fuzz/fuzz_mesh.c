/* libFuzzer harness for the mesh loaders: any input, read as every format
 * (told from the contents, then each one forced) and under tight limits,
 * must be refused with a message and nothing held, or give a mesh that
 * keeps mesh.h's promises (indices in range and distinct, finite vertices,
 * the box around the triangles) and whose topology adds up.  Read as OBJ
 * and as OFF by the every-CPU parser (whatever its size) and by the
 * one-thread one, it must give the same mesh or the same error at the same
 * line. */
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "mesh.h"
#include "mesh_check.h"
#include "mesh_load.h"

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

/* The OBJ and OFF parsers on every CPU (their min_bytes 0: any size)
 * and on one thread (SIZE_MAX): the same answer. */
static void paths_agree(const uint8_t *data, size_t size, mesh_format f, size_t *min_bytes)
{
    mesh m[2];
    mesh_error err[2];
    int rc[2];
    size_t was = *min_bytes;
    for (int k = 0; k < 2; k++) {
        *min_bytes = k ? SIZE_MAX : 0;
        rc[k] = mesh_parse(data, size, f, NULL, &m[k], &err[k]);
    }
    *min_bytes = was;
    if (rc[0] != rc[1]) __builtin_trap();
    if (rc[0]) {
        if (strcmp(err[0].msg, err[1].msg) || err[0].line != err[1].line) __builtin_trap();
        return;
    }
    if (m[0].n_vertices != m[1].n_vertices || m[0].n_triangles != m[1].n_triangles ||
        m[0].n_degenerate != m[1].n_degenerate ||
        memcmp(m[0].vertices, m[1].vertices, 12 * (size_t)m[0].n_vertices) ||
        memcmp(m[0].triangles, m[1].triangles, 12 * (size_t)m[0].n_triangles))
        __builtin_trap();
    mesh_free(&m[0]);
    mesh_free(&m[1]);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    paths_agree(data, size, MESH_FORMAT_OBJ, &mesh_obj_par_min_bytes);
    paths_agree(data, size, MESH_FORMAT_OFF, &mesh_off_par_min_bytes);
    static const mesh_limits tight = {5, 5};
    one(data, size, MESH_FORMAT_AUTO, NULL);
    one(data, size, MESH_FORMAT_AUTO, &tight);
    for (mesh_format f = MESH_FORMAT_OBJ; f <= MESH_FORMAT_GLTF; f++) one(data, size, f, NULL);
    return 0;
}

/* libFuzzer harness for the glTF loader and the weld: any input read as
 * glTF (from bytes: no external file may be named), with no limits and
 * under tight ones, must be refused with a message and nothing held, or
 * give a mesh that keeps mesh.h's promises; that mesh welded at 0 and at
 * 1e-3 must keep them too, with no more vertices or triangles than before;
 * mesh_gltf_embed on it must refuse or leave it be (it names no file it
 * may read). */
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"
#include "mesh_check.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_mesh(const mesh *m)
{
    mesh_check_promises(m);
    if (m->format != MESH_FORMAT_GLTF) __builtin_trap();
    if (!memchr(m->warning, '\0', sizeof m->warning)) __builtin_trap();
}

static void welded(const mesh *m, double eps)
{
    mesh w = *m;
    w.vertices = malloc((size_t)m->n_vertices * sizeof *w.vertices);
    w.triangles = malloc((size_t)m->n_triangles * sizeof *w.triangles);
    if (!w.vertices || !w.triangles) {
        free(w.vertices);
        free(w.triangles);
        return;
    }
    memcpy(w.vertices, m->vertices, (size_t)m->n_vertices * sizeof *w.vertices);
    memcpy(w.triangles, m->triangles, (size_t)m->n_triangles * sizeof *w.triangles);
    uint32_t merged;
    int rc = mesh_weld(&w, eps, &merged);
    if (rc == 0) {
        check_mesh(&w);
        if (w.n_vertices + merged != m->n_vertices || w.n_triangles > m->n_triangles)
            __builtin_trap();
    } else if (rc != -EINVAL && rc != -ENOMEM) {
        __builtin_trap();
    }
    mesh_free(&w);
}

static void one(const uint8_t *data, size_t size, const mesh_limits *lim)
{
    mesh m;
    mesh_error err;
    int rc = mesh_parse(data, size, MESH_FORMAT_GLTF, lim, &m, &err);
    if (rc == 0) {
        if (lim && (m.n_triangles > lim->max_triangles || m.n_vertices > lim->max_vertices))
            __builtin_trap();
        check_mesh(&m);
        if (!lim) welded(&m, 0), welded(&m, 1e-3);
        mesh_free(&m);
        return;
    }
    if (rc != -EINVAL && rc != -E2BIG && rc != -ENOMEM) __builtin_trap();
    if (!err.msg[0] || m.vertices || m.triangles) __builtin_trap();
    if (!memchr(err.msg, '\0', sizeof err.msg)) __builtin_trap();
    if (err.code != rc) __builtin_trap(); /* the code returned, in the error too */
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static const mesh_limits tight = {5, 5};
    one(data, size, NULL);
    one(data, size, &tight);
    char *out;
    size_t n;
    mesh_error err;
    int rc = mesh_gltf_embed((const char *)data, size, NULL, &out, &n, &err);
    if (rc == 0 && out) __builtin_trap(); /* no folder: nothing can be embedded */
    if (rc != 0 && rc != -EINVAL && rc != -ENOMEM && rc != -E2BIG) __builtin_trap();
    return 0;
}

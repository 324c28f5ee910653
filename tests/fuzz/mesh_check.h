/* mesh_check — mesh.h's promises about a loaded mesh, for the mesh
 * harnesses (fuzz_mesh.c, fuzz_gltf.c): triangles and vertices, finite
 * vertices, each triangle's three indices distinct and in range, every
 * vertex of a triangle inside the box lo..hi.  A broken promise traps. */
#ifndef VOXD_FUZZ_MESH_CHECK_H
#define VOXD_FUZZ_MESH_CHECK_H

#include <math.h>
#include <stdint.h>

#include "mesh.h"

static inline void mesh_check_promises(const mesh *m)
{
    if (m->n_triangles == 0 || m->n_vertices == 0) __builtin_trap();
    for (uint32_t i = 0; i < m->n_vertices; i++)
        for (int k = 0; k < 3; k++)
            if (!isfinite(m->vertices[i][k])) __builtin_trap();
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *t = m->triangles[i];
        if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) __builtin_trap();
        for (int k = 0; k < 3; k++) {
            if (t[k] >= m->n_vertices) __builtin_trap();
            for (int j = 0; j < 3; j++) {
                float x = m->vertices[t[k]][j];
                if (x < m->lo[j] || x > m->hi[j]) __builtin_trap();
            }
        }
    }
}

#endif

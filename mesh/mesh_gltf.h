/* mesh_gltf — glTF 2.0 (.gltf JSON with its buffers, .glb), internal to
 * mesh/: mesh_gltf.c reads the container, the JSON (json-c) and the
 * buffers; mesh_gltf_scene.c walks the scene's nodes and reads their
 * meshes' triangle primitives through their accessors.  docs/meshes.md
 * says what is read and what is refused. */
#ifndef VOXD_MESH_GLTF_H
#define VOXD_MESH_GLTF_H

#include <json-c/json.h>
#include <stddef.h>
#include <stdint.h>

#include "mesh_load.h"

/* A buffer's bytes, once resolved (NULL until then). */
typedef struct {
    const uint8_t *data;
    uint64_t len;       /* its byteLength: what may be read */
    void *owned;        /* decoded from a data: URI (free) */
    void *map;          /* an external file, mapped (munmap map_len) */
    size_t map_len;
} mesh_gltf_buffer;

typedef struct {
    mbuild *b;
    json_object *root;
    const uint8_t *bin;  /* a .glb's BIN chunk, or NULL */
    uint64_t bin_len;
    mesh_gltf_buffer *buf;
    size_t n_buf;
    uint64_t skipped;    /* primitives that are not triangles */
} gltf;

/* ---- mesh_gltf.c ---- */

/* A JSON object of the glTF and what a message calls it ("accessor 3"). */
typedef struct {
    json_object *o;
    const char *what;
} gltf_obj;

/* o[key] as a whole number in [0, max], def when absent (def < 0: required).
 * 0 or -EINVAL after mesh_build_fail. */
int mesh_gltf_uint(gltf *g, gltf_obj o, const char *key, int64_t def, uint64_t max, uint64_t *out);
/* o[key] as an array (required: -EINVAL when absent); NULL *out when absent
 * and optional. */
int mesh_gltf_array(gltf *g, gltf_obj o, const char *key, int required, json_object **out);
/* n numbers of the array o[key] into out; absent: out unchanged, *given 0. */
int mesh_gltf_numbers(gltf *g, gltf_obj o, const char *key, size_t n, double *out, int *given);
/* root[kind][i] as an object, i checked against the array's length. */
int mesh_gltf_item(gltf *g, const char *kind, uint64_t i, json_object **out);
/* Buffer i's bytes (resolved on first use). */
int mesh_gltf_buffer_get(gltf *g, uint64_t i, const mesh_gltf_buffer **out);

/* ---- mesh_gltf_scene.c ---- */

/* The triangles of the default scene (or scene 0, or every root node) into g->b. */
int mesh_gltf_read_scene(gltf *g);
/* The file parsed (a .glb or a JSON text), its asset checked and its
 * buffers' table made (each buffer read when first asked for); the
 * caller ends with mesh_gltf_close, whatever the result. */
int mesh_gltf_open(gltf *g, const char *buf, size_t len);
void mesh_gltf_close(gltf *g);

#endif

/* mesh — a triangle mesh in memory: what the loaders make and the mesh
 * voxelizer reads.
 *
 * Vertices are single-precision positions (every supported format stores
 * float or, for PLY, may store double: those are rounded to the nearest
 * float, which keeps a watertight mesh watertight, since shared vertices
 * are shared by index).  Triangles are three vertex indices, each below
 * n_vertices: a loader guarantees it, so code past the loader asserts it
 * and never checks again.  Polygons are fan-triangulated by the loaders;
 * degenerate triangles (two equal indices or zero area) are dropped and
 * counted.
 */
#ifndef VOXD_MESH_H
#define VOXD_MESH_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"

typedef enum {
    MESH_FORMAT_AUTO = 0, /* from the contents */
    MESH_FORMAT_OBJ,
    MESH_FORMAT_STL,      /* ascii or binary */
    MESH_FORMAT_PLY,      /* ascii, binary little or big endian */
    MESH_FORMAT_OFF,
    MESH_FORMAT_GLTF,     /* glTF 2.0: .gltf (JSON) or .glb (binary) */
} mesh_format;

typedef struct {
    uint32_t n_vertices, n_triangles;
    float (*vertices)[3];      /* n_vertices positions */
    uint32_t (*triangles)[3];  /* n_triangles, counter-clockwise seen from outside */
    uint64_t n_degenerate;     /* triangles the loader dropped */
    mesh_format format;        /* what the file was */
    float lo[3], hi[3];        /* bounding box of the triangles' vertices */
    /* "" or one line a loader wants the user to see about a file it read
     * anyway (a PLY header's unknown lines, skipped): "line 3: ..." */
    char warning[200];
} mesh;

/* The loaders' bounds: every count in a file is checked against them (and
 * against the bytes that could hold it) before anything is allocated. */
typedef struct {
    uint32_t max_triangles;    /* after triangulation; 0: MESH_MAX_TRIANGLES */
    uint32_t max_vertices;     /* 0: MESH_MAX_VERTICES */
} mesh_limits;
#define MESH_MAX_TRIANGLES (64u << 20)
#define MESH_MAX_VERTICES  (64u << 20)

/* A loader's error: the project's (common/err.h: code the errno returned,
 * msg what went wrong) and where (line for text formats, byte offset for
 * binary ones; 0 when it is not about one place). */
typedef struct {
    ERR_INFO_EMBED(info);
    uint64_t line, offset;
} mesh_error;

/* Parse the mesh in buf[0, len) (format AUTO: told from the contents).  0
 * and the mesh in *out (free with mesh_free), or a negative errno with
 * *err filled: -EINVAL malformed, -E2BIG past a limit, -ENOMEM. */
int mesh_parse(const void *buf, size_t len, mesh_format format,
               const mesh_limits *lim, mesh *out, mesh_error *err);
/* mesh_parse() of a file, mapped (mmap) rather than read.  A .gltf's
 * buffers may then name files (relative, inside its folder); from
 * mesh_parse() they may only be embedded (data: URIs) or a .glb's. */
int mesh_load(const char *path, mesh_format format, const mesh_limits *lim,
              mesh *out, mesh_error *err);
/* A .gltf to send elsewhere (vox submit): its JSON with every buffer that
 * names a file (relative to dir, as mesh_load reads it) embedded as a
 * base64 data: URI.  0 and *out (malloc, *out_len bytes), or 0 and *out
 * NULL when there is nothing to embed (not a JSON glTF, or no such
 * buffer); -EINVAL or -ENOMEM with *err. */
int mesh_gltf_embed(const char *buf, size_t len, const char *dir, char **out, size_t *out_len,
                    mesh_error *err);
void mesh_free(mesh *m);

const char *mesh_format_name(mesh_format f);

/* err as one line: "line N: msg", "byte N: msg" or "msg".  Returns buf. */
const char *mesh_error_str(const mesh_error *err, char *buf, size_t len);

/* Merge the vertices within eps of each other (distance <= eps, in the
 * mesh's units; eps = 0: exactly equal positions, -0 equal to 0), so that
 * a file that repeats its vertices (per face, or split at texture seams)
 * shares them and its topology is judged on the geometry.  Greedy in the
 * vertices' order: each goes to the lowest earlier kept vertex within eps
 * (kept ones are more than eps apart), through a hash grid: O(n), the same
 * result on any machine.  Triangles are renumbered; those the merge makes
 * degenerate are dropped (added to n_degenerate); the box is taken again.
 * eps is 0 or in [MESH_WELD_MIN, MESH_WELD_MAX]: else -EINVAL, the mesh
 * unchanged.  0 (*merged: the vertices merged away, when not NULL),
 * -ENOMEM, or -EINVAL when no triangle is left (the mesh unchanged). */
#define MESH_WELD_MIN 1e-30
#define MESH_WELD_MAX 1e30
int mesh_weld(mesh *m, double eps, uint32_t *merged);

/* The topology of a mesh, from its triangles' edges.  An edge is a pair of
 * vertex indices; each triangle uses three (the loaders drop triangles
 * with a repeated index).  The mesh is watertight when every edge is used
 * by exactly two triangles traversing it in opposite directions: closed and
 * consistently oriented, so that inside and outside are well defined (a
 * vertex where two surfaces touch is not looked for). */
typedef struct {
    uint64_t edges;        /* distinct edges */
    uint64_t open;         /* used by one triangle (the boundary) */
    uint64_t nonmanifold;  /* used by more than two */
    uint64_t inconsistent; /* used by two that traverse it in the same direction */
    uint64_t components;   /* sets of triangles connected through shared edges */
    int watertight;        /* no open, no non-manifold, no inconsistent edge */
    double volume;         /* signed (divergence theorem): positive when the
                              triangles are counter-clockwise seen from outside;
                              meaningful when watertight */
} mesh_topo;

/* 0 and *out, -ENOMEM, or -E2BIG past 2^31 - 1 triangles.  O(n) time and
 * memory in the triangles (a counting sort of the edges by their lower
 * vertex). */
int mesh_topology(const mesh *m, mesh_topo *out);

/* The edges alone: edges, open, nonmanifold, inconsistent and watertight
 * as mesh_topology gives them, components and volume left 0 (what a
 * voxelization job reports, for about half the time).  0, or -ENOMEM or
 * -E2BIG as mesh_topology. */
int mesh_edges(const mesh *m, mesh_topo *out);

#endif

/* iso — marching cubes over the bricks of a VOD file (docs/mesh-extraction.md).
 *
 * The surface is cut per brick: a task is one brick of one mip level, its
 * cells the B^3 cubes whose high corner is a voxel of the brick, its
 * samples the brick's voxels and the one-voxel apron its cells reach into
 * (the last layer of the bricks below it on each axis).  The volume is
 * read as 0 outside (one layer of empty samples around it), so a surface
 * is closed at the volume's border too; one more task brick per axis takes
 * the cells reaching into the empty layer above the volume.  Below, "local"
 * sample coordinates count from that apron: local u is voxel b B - 1 + u.
 *
 * Values.  Every channel is read as a byte: channel 1 as 0 / 255, channel
 * 2 as its density, channel 3 as its occupancy byte (with its normal),
 * channel 4 (signed distance) as 255 where negative, else 0, with its
 * floats beside: there the crossing is where the line between the two
 * distances is 0 (the zero level), and halfway on an edge to a sample
 * read as empty (outside the volume or the level).  A
 * sample is inside when its byte is above iso; the surface crosses an edge
 * from an outside sample a to an inside one b where the straight line
 * between them reaches iso + 0.5, halfway between the last outside value
 * and the first inside one, so a vertex never falls on a sample and no
 * triangle is degenerate by construction (with iso 127 an occupancy edge
 * is cut at its midpoint).
 *
 * The case table (iso_table.c) is built at first use from the cube's faces:
 * on each face the crossings are paired by one fixed rule, an exit (inside
 * to outside, walking round the face counter-clockwise seen from outside)
 * with the next entry, which on a face with two diagonal inside corners
 * joins them.  The rule depends on the face's four corners only, so the two
 * cubes sharing a face cut it the same way: the surface has no crack and
 * no doubled piece, whatever the case, and inside voxels touching along an
 * edge stay joined (18-connected inside, 6-connected outside).  The face
 * segments chain into loops, each triangulated as a fan whose diagonals
 * never join two crossings on one face (so no edge is shared with a
 * neighbour), or round a centre vertex when no such fan exists.
 *
 * Welding.  A vertex is named by its lattice edge (the edge's low sample
 * and axis, and the level): a key.  The brick owning the edge's low sample
 * owns the vertex; others refer to it by key, and the merge (iso_merge)
 * resolves those to the owner's index.  Each brick's vertices come in key
 * order, the bricks in (level, z, y, x) order, so the mesh is a function
 * of the file and the options alone: byte for byte the same whoever ran
 * which brick.
 */
#ifndef VOXD_ISO_H
#define VOXD_ISO_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "vod.h"

#define ISO_MAX_RADII 8      /* --lod-radii: at most this many spheres */
#define ISO_MAX_LEVELS 16

/* What is polygonized; shared by the master and the workers (copied into
 * the engine's block), so plain values only. */
typedef struct {
    uint32_t iso;            /* inside: byte > iso; 0..254, default 127 */
    uint32_t bits;           /* the file's voxel bits: 1, 8 or 32 */
    uint32_t normals;        /* channel 3: vertex normals from the voxels' */
    uint32_t distance;       /* channel 4: f32 samples, inside where negative,
                                the crossing where the line between them is 0 */
    uint32_t brick;          /* the file's brick side B */
    uint32_t height;         /* its treeHeight */
    uint32_t dims[ISO_MAX_LEVELS][3]; /* each level's volume (vod_level_dims) */
    float origin[3], scale[3]; /* the trailer's origin, level 0's voxel size */
    /* Levels: one (level) or adaptive (nradii > 0): a block, a cube of
     * `block` level-0 voxels (a level-0 brick, or larger so that a voxel
     * of level lod_top lies in one block), uses level i where i is the
     * first sphere of radius radii[i] round center that touches it, and
     * level lod_top = min(nradii, top level) where none does.  A level's
     * bricks read the samples of other levels' blocks as 0, so each
     * level's region is closed on its own (docs/mesh-extraction.md). */
    uint32_t level;
    uint32_t nradii, lod_top, block;
    double center[3], radii[ISO_MAX_RADII];
} iso_params;

/* What a job asks for: the iso value and one level, or the adaptive levels'
 * spheres round center when nradii > 0 (center may be NULL without them). */
typedef struct {
    uint32_t iso;            /* 0..254 */
    int level;
    const double *center;    /* [3] */
    const double *radii;     /* [nradii], increasing */
    uint32_t nradii;
} iso_request;

/* iso_params of request rq for file f.  0, or -EINVAL with its message in
 * e (may be NULL): a level past the tree, radii not increasing, a channel
 * that is not 1, 2 or 3. */
int iso_params_make(const vod_file *f, const iso_request *rq, iso_params *p, err_info *e);

/* The level the block at block coordinates b uses. */
uint32_t iso_block_level(const iso_params *p, const uint32_t b[3]);

/* ---- the input: a level's raw bricks, by key ---- */

/* A brick's key: its level and its index within the level's bricks. */
static inline uint64_t iso_brick_key(uint32_t level, uint64_t lin)
{
    return (uint64_t)level << 58 | lin;
}

/* The bricks a job reads, in memory any process can reach: n sorted keys,
 * each with the offset of its raw brick from raw (bytes of p->bits), and
 * (for iso_tasks; NULL: unknown) each one's state: every voxel inside,
 * every voxel outside, or both. */
enum { ISO_BRICK_MIXED = 0, ISO_BRICK_IN = 1, ISO_BRICK_OUT = 2 };
typedef struct {
    uint64_t n;
    const uint64_t *keys, *offs;
    const uint8_t *raw;
    uint64_t raw_bytes;
    const uint8_t *state;
} iso_input;

/* ---- tasks ---- */

typedef struct {
    uint32_t level, b[3];    /* the brick (task brick coordinates) */
} iso_task;

/* Task bricks per axis at a level: floor(dims / B) + 1 (the cells reach
 * one sample past the volume). */
void iso_task_grid(const iso_params *p, uint32_t level, uint32_t n[3]);
static inline uint64_t iso_task_key(const iso_params *p, const iso_task *t)
{
    uint32_t n[3];
    iso_task_grid(p, t->level, n);
    return iso_brick_key(t->level, ((uint64_t)t->b[2] * n[1] + t->b[1]) * n[0] + t->b[0]);
}

/* The tasks of a job: every brick whose samples touch a non-empty brick
 * of the file at its level, sorted by key, into *out (malloc'd; free it),
 * less those whose samples are all outside or (one level only) all inside
 * by the bricks' states: a solid's interior costs nothing.  0 or -ENOMEM. */
int iso_tasks(const iso_params *p, const iso_input *in, iso_task **out, uint64_t *n);

/* ---- one task's polygons ---- */

/* A reference to a vertex from a triangle: an owned edge vertex (its index
 * in the piece), a centre vertex (ISO_REF_CENTRE | index), or a vertex
 * another piece owns (ISO_REF_EXT | index in ext). */
#define ISO_REF_CENTRE 0x40000000u
#define ISO_REF_EXT 0x80000000u
#define ISO_REF_INDEX 0x3fffffffu

/* One task's output.  keys/pos/nrm: nv owned edge vertices in key order;
 * cpos/cnrm: nc centre vertices; tri: nt triangles, counter-clockwise seen
 * from outside (inside: the higher values); ext: ne keys of vertices
 * other pieces own.  nrm and cnrm only with p->normals. */
typedef struct {
    uint64_t key;            /* the task's key (iso_task_key) */
    uint32_t nv, nc, nt, ne;
    const uint64_t *keys;
    const float *pos, *nrm, *cpos, *cnrm;
    const uint32_t *tri;
    const uint64_t *ext;
} iso_piece;

/* A task's scratch and growing output, reused from task to task. */
typedef struct iso_work iso_work;
int iso_work_new(const iso_params *p, iso_work **out);
void iso_work_free(iso_work *w);
/* Polygonize task t into w; *piece then views w's arrays (valid until the
 * next call).  0, -ENOMEM, or -EINVAL for a task outside the level. */
int iso_task_run(iso_work *w, const iso_params *p, const iso_input *in,
                 const iso_task *t, iso_piece *piece);

/* The bytes of a piece laid out flat (iso_piece_pack/iso_piece_view): what
 * a worker copies into shared memory. */
size_t iso_piece_bytes(const iso_params *p, const iso_piece *pc);
void iso_piece_pack(const iso_params *p, const iso_piece *pc, void *to);
/* The view of packed bytes: pc's key and counts (nv, nc, nt, ne) as the
 * caller set them, its arrays laid over `from`; -EINVAL when they do not
 * fit in `bytes` (the counts come from another process). */
int iso_piece_view(const iso_params *p, const void *from, size_t bytes, iso_piece *pc);

/* ---- the whole mesh ---- */

typedef struct {
    uint64_t n_vertices, n_triangles;
    float *pos;              /* n_vertices x 3 */
    float *nrm;              /* n_vertices x 3, or NULL */
    uint32_t *tri;           /* n_triangles x 3 */
    /* Where the time went (wall seconds): copying the input and listing
     * the tasks, running them, welding the pieces. */
    double t_setup, t_tasks, t_weld;
    int borrowed;            /* the arrays are the engine's (its segment):
                                valid until its next job, not freed here */
} iso_mesh;

/* Welding in parts, for processes that share the work: the pieces checked
 * (keys in order and on their brick, every reference inside its piece's
 * counts; by `threads` threads at once, the error the first bad piece
 * gives, as with one) and each one's first vertex and first triangle in
 * the mesh (vbase, tbase: n + 1 entries, the last the totals); then each piece
 * welded (its references to other pieces found by key) into the mesh's
 * arrays, any process, any order: a piece writes its own vertices and
 * triangles only. */
typedef struct {
    const iso_params *p;
    const iso_piece *pc;
    uint64_t n;
    uint64_t *vbase, *tbase; /* written by iso_weld_bases */
    float *pos, *nrm;        /* nrm with p->normals */
    uint32_t *tri;
} iso_weld;
/* w's bases from its pieces (p, pc, n), its arrays not used yet. */
int iso_weld_bases(const iso_weld *w, unsigned threads, err_info *e);
int iso_weld_piece(const iso_weld *w, uint64_t i, err_info *e);

/* The pieces of every task (in task order, each task's key given) welded
 * into one mesh.  A piece is checked before it is used (they come from
 * other processes): -EPROTO with a message for one that is malformed or
 * refers to a vertex nobody owns; -ENOMEM; -E2BIG past 2^32 vertices. */
int iso_merge(const iso_params *p, const iso_piece *pieces, uint64_t n, iso_mesh *m,
              err_info *e);
void iso_mesh_free(iso_mesh *m);

/* Everything in this thread: the tasks, each polygonized, merged.  The
 * reference for the engine's parallel run.  0, or a negative errno with its
 * message in e (may be NULL). */
int iso_run_serial(const iso_params *p, const iso_input *in, iso_mesh *m, err_info *e);

/* ---- the input from an open file ---- */

/* The raw bricks of the levels p uses, copied once each (bricks the file
 * shares are shared), into memory from alloc(ud, bytes) (NULL: no room ->
 * -ENOMEM), laid out as: keys, offsets, states, raw bricks. */
int iso_input_make(const vod_file *f, const iso_params *p,
                   void *(*alloc)(void *ud, size_t bytes), void *ud, iso_input *in);
/* The same, the bricks copied (the first touch of alloc's memory) and
 * their states found by `threads` threads at once. */
int iso_input_make_threads(const vod_file *f, const iso_params *p,
                           void *(*alloc)(void *ud, size_t bytes), void *ud,
                           unsigned threads, iso_input *in);

/* ---- writing ---- */

typedef enum { ISO_FMT_NONE, ISO_FMT_PLY, ISO_FMT_PLY_ASCII, ISO_FMT_OBJ, ISO_FMT_STL } iso_format;

/* "ply", "obj", "stl" (and "ply-ascii" by name only); ISO_FMT_NONE if not. */
iso_format iso_format_of_name(const char *s);
iso_format iso_format_of_path(const char *path);
/* Write m to fd in format f, from where fd stands, formatted by `threads`
 * threads at once (each writing its chunks at their offsets: fd must seek
 * for more than one; one that cannot is written in order by one); 0 or a
 * negative errno. */
int iso_write(int fd, const iso_mesh *m, iso_format f, const char *comment,
              unsigned threads);
/* A mesh still being made while it is written: before formatting records
 * below `hi` of its vertices (tris 0) or its triangles (tris 1), the
 * writer calls wait(ud, tris, hi), which returns 0 once they are final,
 * or a negative errno that ends the write with it (the mesh will not be
 * whole).  m's counts and arrays' places must be final from the start. */
typedef struct {
    int (*wait)(void *ud, int tris, uint64_t hi);
    void *ud;
} iso_ready;
/* iso_write of a mesh that ready says is final part by part (NULL: all of
 * it now), streamed: each part written as soon as it is. */
int iso_write_ready(int fd, const iso_mesh *m, iso_format f, const char *comment,
                    unsigned threads, const iso_ready *ready);

/* ---- the case table (iso_table.c) ---- */

/* Edge slot e (0..11) of a cell: its axis (e / 4) and the offset of its
 * low corner from the cell's (bits: x, y, z). */
static inline uint32_t iso_edge_axis(uint32_t e) { return e >> 2; }
uint32_t iso_edge_corner(uint32_t e);

#define ISO_CENTRE_SLOT 12u  /* slot 12 + k: the case's k-th centre vertex */
#define ISO_MAX_TRI 16u
#define ISO_MAX_CENTRES 4u

typedef struct {
    uint8_t ntri, ncentre;
    uint8_t tri[ISO_MAX_TRI][3];          /* slots */
    uint8_t loop_len[ISO_MAX_CENTRES];    /* each centre's loop */
    uint8_t loop[ISO_MAX_CENTRES][12];
} iso_case;

/* The 256 cases (bit c: corner c inside, corner c at x = c & 1,
 * y = c >> 1 & 1, z = c >> 2), built on first use (thread-safe). */
const iso_case *iso_cases(void);

#endif

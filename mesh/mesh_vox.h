/* mesh_vox — voxelizing a triangle mesh (mesh.h) into a brick-sparse
 * volume (vod_volume.h), one tile at a time.
 *
 * A tile is a column of MESH_TILE x MESH_TILE voxels in x and y through
 * the whole grid in z: the unit of parallel work.  The workers of the
 * engine run tiles concurrently; a tile writes only the storage bricks of
 * its own column (vod_volume_put_brick, whose calls for different bricks
 * may run concurrently), so the volume's storage brick side must divide
 * MESH_TILE.  A tile's result depends on nothing but the mesh, the grid,
 * the options and the tile: any number of workers, in any order, gives the
 * same volume, and a tile run twice (after a worker's death) writes the
 * same bricks again.
 *
 * Which triangles a tile needs is decided once for the job (mesh_bin):
 * the triangles whose projection overlaps the tile's footprint (and, for
 * the repair modes, what the parity along x and y needs).  The bins are
 * flat arrays of integers, so the master can copy them into the shared
 * segment and every worker reads them there.
 */
#ifndef VOXD_MESH_VOX_H
#define VOXD_MESH_VOX_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "grid.h"
#include "mesh.h"
#include "vod_volume.h"

#define MESH_TILE 64u
/* The storage brick side of a mesh job's volume, serial or on the engine:
 * a divisor of MESH_TILE; 16^3 keeps the tables small at 4096^3 (64 MiB)
 * and a surface brick's memory low. */
#define MESH_VOLUME_BRICK 16u
/* The distance channel's (f32): its band bricks hold few band voxels, and
 * an 8^3 brick wastes less of itself beyond the band than a 16^3 one (the
 * dragon at 1024^3: 75,939 bricks of 2 KiB for 18,684 of 16 KiB). */
#define MESH_DIST_BRICK 8u

typedef enum {
    MESH_SOLID = 0,       /* voxel centres inside the mesh (parity) */
    MESH_SURFACE,         /* every voxel whose closed box a triangle touches (26-separating) */
    MESH_SURFACE6,        /* the thinner 6-separating surface */
    MESH_CONSERVATIVE,    /* solid plus surface */
    MESH_INTERIOR,        /* solid minus surface */
} mesh_mode;

typedef enum {
    MESH_REPAIR_NONE = 0, /* parity along z only */
    MESH_REPAIR_VOTE,     /* the majority of the parities along x, y and z */
    MESH_REPAIR_WINDING,  /* where they disagree, the generalized winding number */
} mesh_repair;

typedef struct {
    mesh_mode mode;
    mesh_repair repair;
    int channel;          /* VOXEL_CH_OCCUPANCY, VOXEL_CH_DENSITY, VOXEL_CH_SURFACE or
                             VOXEL_CH_DISTANCE (mode solid: its sign) */
    uint32_t supersample; /* density: samples per voxel and axis, 2..8 (0: 2) */
    uint32_t band;        /* distance: the narrow band's half width in voxels,
                             1..VOXEL_BAND_MAX (0: VOXEL_BAND_DEFAULT) */
} mesh_vox_opts;

/* The triangles of every tile: tile (tx, ty) is number ty * tiles[0] + tx
 * and holds ids[start[t] .. start[t+1]) (triangle indices, ascending). */
typedef struct {
    uint32_t tiles[2];
    uint64_t *start;      /* tiles[0] * tiles[1] + 1 entries */
    uint32_t *ids;        /* start[tiles[0] * tiles[1]] entries */
} mesh_bins;

/* What tiles found, summed by the caller over a job's tiles. */
typedef struct {
    uint64_t voxels;          /* non-zero voxels written */
    uint64_t disagreements;   /* repair modes: voxels whose parities along x, y, z differ */
    uint64_t disagree_bricks; /* storage bricks holding such voxels */
} mesh_tile_stats;

/* Bits of the volume's voxels for these options: 8 (occupancy, density),
 * 32 (surface channel: occupancy and a packed normal, voxel.h) or
 * VOD_VOLUME_F32 (distance). */
uint32_t mesh_vox_bits(const mesh_vox_opts *o);

/* The storage brick side of the volume for these options (a divisor of
 * MESH_TILE): MESH_DIST_BRICK for the distance, else MESH_VOLUME_BRICK.
 * The file's bricks do not depend on it. */
uint32_t mesh_vox_sbrick(const mesh_vox_opts *o);

/* 0 when o is a valid combination, else -EINVAL with a message. */
int mesh_vox_check(const mesh_vox_opts *o, err_info *err);
/* The band of o in voxels (o->band, or VOXEL_BAND_DEFAULT for 0). */
uint32_t mesh_vox_band(const mesh_vox_opts *o);
/* The distance beyond the band, in world units, for a grid of voxel size
 * vs: what every voxel there holds, with its sign (mesh_dist.c). */
float mesh_dist_width(const mesh_vox_opts *o, double vs);

/* The vertices on the lattice of the voxel centres (mesh_vox_int.h), one
 * int64_t[3] each: what the tiles read instead of snapping every vertex of
 * every triangle again (a flat array the master can put in the segment). */
typedef int64_t mesh_lattice[3];

/* Bin m's triangles to the tiles of grid g, and when lattice is not NULL
 * (m->n_vertices entries) snap the vertices into it for mesh_tile_run; on
 * up to threads threads (this one among them; 0 or 1: this one alone),
 * one per MESH_BIN_PART_MIN triangles at most.  The bins are the same
 * whatever the number of threads.  0, or -ENOMEM / -E2BIG (more ids than
 * memory allows). */
#define MESH_BIN_PART_MIN 32768u
int mesh_bin(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
             mesh_lattice *lattice, unsigned threads, mesh_bins *out);
void mesh_bins_free(mesh_bins *b);

/* The fast winding number's tree over a mesh's triangles (mesh_wind.c):
 * what MESH_REPAIR_WINDING's tiles read instead of summing over every
 * triangle.  It depends on the mesh and the grid alone (built the same
 * way every time, one thread), so every tile decides the same whoever
 * builds it.  0, -EINVAL (no triangles) or -ENOMEM. */
typedef struct mesh_wtree mesh_wtree;
/* Tests and benchmarks only: non-zero, no tree is built (mesh_voxelize,
 * and the engine's workers forked after it is set) and MESH_REPAIR_WINDING
 * is decided by the exact sum everywhere: the oracle.  0 by default;
 * nothing in vox or voxd sets it. */
extern int mesh_wind_exact;
int mesh_wtree_build(const mesh *m, const grid_spec *g, mesh_wtree **out);
/* Whether a job of options o lends its tiles a tree (mesh_tile_env.wtree):
 * the winding repair's, unless mesh_wind_exact asks for the exact sum. */
bool mesh_vox_lends_tree(const mesh_vox_opts *o);
/* Whether every tile of a job runs, with triangles in its bins or none: a
 * distance's (its +w bricks), and the winding repair's whose parities
 * along x and y come from the caps (a sample may be inside with no
 * triangle in its column, as in the middle of an open tube). */
bool mesh_vox_every_tile(const grid_spec *g, const mesh_vox_opts *o);
void mesh_wtree_free(mesh_wtree *t);

/* What a tile's caller lends it besides the data.  tick is called every
 * few milliseconds of work, whatever the tile does (rasterizing, the
 * winding numbers, the supersampled density): a worker's heartbeat; when
 * it returns non-zero the tile stops where it is and mesh_tile_run returns
 * -ECANCELED.  wtree: the mesh's tree for g (mesh_wtree_build) where
 * mesh_vox_lends_tree(o), or NULL: the winding numbers by the exact sum
 * over every triangle, the oracle the tree is held against (a tile then
 * builds the caps it needs for itself). */
typedef struct {
    const mesh_wtree *wtree;
    int (*tick)(void *arg);
    void *arg;
} mesh_tile_env;

/* Scratch a tile needs (the caller gives each worker one buffer). */
size_t mesh_tile_scratch_bytes(const grid_spec *g, const mesh_vox_opts *o);

/* What the tiles of one voxelization share: mesh m on grid g with options
 * o into vol, whose dims are g->res, bits mesh_vox_bits(o), and storage
 * brick side divides MESH_TILE; lattice: mesh_bin's for m and g, or NULL
 * (the tile snaps the vertices itself, the same way); env: the tree and the
 * heartbeat, or NULL; scratch: mesh_tile_scratch_bytes of it, a thread's
 * own. */
typedef struct {
    const mesh *m;
    const mesh_lattice *lattice;
    const grid_spec *g;
    const mesh_vox_opts *o;
    vod_volume *vol;
    const mesh_tile_env *env;
    void *scratch;
} mesh_tiles;

/* Voxelize tile (tx, ty) of j from the triangles ids[0, n) of j->m.  Adds
 * to *st.  0, -ECANCELED when env's tick said stop, or -ENOMEM when vol's
 * pool is full.  A tile never writes a brick that is all 0: vol must start
 * empty (as vod_volume_init leaves it). */
int mesh_tile_run(const mesh_tiles *j, const uint32_t *ids, size_t n, uint32_t tx,
                  uint32_t ty, mesh_tile_stats *st);

/* Every tile, serially: the reference for the engine (tests, -w 0). */
int mesh_voxelize(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                  vod_volume *vol, mesh_tile_stats *st);
/* The tiles tx in [tiles[0], tiles[2]), ty in [tiles[1], tiles[3]) alone
 * (NULL: every tile), serially: vox_mpi's column groups. */
int mesh_voxelize_tiles(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                        const uint32_t *tiles, vod_volume *vol, mesh_tile_stats *st);

#endif

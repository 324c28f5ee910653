/* export — what vox export's formats share (cli_export.c writes NRRD, raw,
 * binvox and VTI; export_vdb.c OpenVDB through vdb_out). */
#ifndef VOXD_EXPORT_H
#define VOXD_EXPORT_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "err.h"
#include "vod.h"

/* What is exported: the box [lo, hi) of level `level`'s voxels. */
typedef struct {
    const vod_file *f;
    const vod_info *in;
    int level;
    int normals;                  /* channel 3: the normals too */
    int distance;                 /* channel 4: f32 signed distances */
    uint32_t lo[3], hi[3], n[3];
    double origin[3], spacing[3]; /* low corner of voxel lo, and a voxel's size */
} export_box;

/* The level voxels of the box [lo, hi) (absolute level coordinates) into
 * out as bytes, x fastest, then y, then z: channel 1 as 0/1, 8-bit voxels
 * as they are, channel 3 its occupancy byte, channel 4 1 inside (a
 * negative distance); 0 where no brick is.  Safe to
 * call from several threads at once (the file is only read). */
void export_gather(const export_box *b, const uint32_t lo[3], const uint32_t hi[3],
                   uint8_t *out);
/* Channel 3's normals of the same box: comps 3 gives (nx, ny, nz) per
 * voxel, comps 4 (occupancy byte, nx, ny, nz); zeros where no voxel is.
 * Channel 4 (b->distance): comps 1, its f32 distances (0 where no brick). */
void export_gather_normals(const export_box *b, const uint32_t lo[3], const uint32_t hi[3],
                           float *out, int comps);
/* Channel 4's band: the width W of its narrow band in world units (the
 * value beyond it), from the metadata's distance_band (voxels of level 0),
 * else VOXEL_BAND_DEFAULT voxels; *band the voxels. */
double export_band_width(const vod_info *in, unsigned *band);

/* The whole box as one gzip member (RFC 1952), z slabs gathered and
 * deflated by as many threads as there are CPUs (up to 8), to fp: bytes
 * (export_gather) for comps 0, else export_gather_normals' floats.  0 or a
 * negative errno. */
int export_gzip(const export_box *b, FILE *fp, int comps);

/* The box as an OpenVDB file at path (export_vdb.c), brick by brick: a
 * BoolGrid "occupancy" for 1-bit voxels, channel 4 a FloatGrid "surface" of
 * class level set (background W, active in the band), else a FloatGrid
 * "density" of the voxel byte / 255 (channel 3: its occupancy byte), and
 * with b->normals a Vec3SGrid "normal".  Voxel indices are the level's, so a box keeps its
 * place.  src names the input in the metadata, name the output in messages
 * (path may be a /proc/self/fd link to it).  0, or a negative errno with
 * err set. */
int export_vdb(const export_box *b, const char *src, const char *path, const char *name,
               err_info *err);

#endif

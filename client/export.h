/* export — what vox export's formats share (cli_export.c writes NRRD, raw,
 * binvox and VTI; export_vdb.c OpenVDB through vdb_out). */
#ifndef VOXD_EXPORT_H
#define VOXD_EXPORT_H

#include <stddef.h>
#include <stdint.h>

#include "vod.h"

/* What is exported: the box [lo, hi) of level `level`'s voxels. */
typedef struct {
    const vod_file *f;
    const vod_info *in;
    int level;
    int normals;                  /* channel 3: the normals too */
    uint32_t lo[3], hi[3], n[3];
    double origin[3], spacing[3]; /* low corner of voxel lo, and a voxel's size */
} export_box;

/* The box as an OpenVDB file at path (export_vdb.c), brick by brick: a
 * BoolGrid "occupancy" for 1-bit voxels, else a FloatGrid "density" of the
 * voxel byte / 255 (channel 3: its occupancy byte), and with b->normals a
 * Vec3SGrid "normal".  Voxel indices are the level's, so a box keeps its
 * place.  src names the input in the metadata.  0, or a negative errno
 * with a message in err. */
int export_vdb(const export_box *b, const char *src, const char *path, char *err,
               size_t errlen);

#endif

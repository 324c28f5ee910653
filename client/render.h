/* render — direct visualization of voxels as shaded splats (section 6 and
 * Figure 6 of Stolte & Kaufman: every voxel is a point drawn with
 * its normal).
 *
 * Each voxel becomes a screen-aligned rectangle: the bounding rectangle of
 * its projected box (at least one pixel), so neighbouring voxels leave no
 * holes from any view direction, at the depth of the voxel's centre, kept
 * or dropped by a z-buffer.  Shading is ambient plus diffuse from a light
 * near the camera (a little up and to the left); a normal that faces away
 * from the viewer is flipped, so a voxelized surface seen from inside still
 * shades.  There is no randomness and no threading: the same splats give
 * the same bytes, and where two splats tie in depth the brighter one wins,
 * so the image does not depend on the order of splats at equal depth.
 *
 * The camera orbits the centre of a box (z is up): azimuth about +z from
 * +x, elevation above the xy-plane.  The box's eight corners are fitted
 * into the frame with a 5% margin on each side, orthographic or
 * perspective; render_octree and render_vod fit the box the voxels occupy
 * unless opts.fit_volume asks for the whole volume.
 *
 * Memory: width and height are at most RENDER_MAX_SIZE; the image takes
 * 7 bytes a pixel (RGB and a float depth).
 */
#ifndef VOXD_RENDER_H
#define VOXD_RENDER_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "mesh.h"
#include "octree.h"
#include "vod.h"

#define RENDER_MAX_SIZE 8192
#define RENDER_MARGIN 0.05 /* of the frame, on each side */

typedef struct {
    int width, height;   /* pixels, 1..RENDER_MAX_SIZE; default 1024 x 1024 */
    double azimuth;      /* degrees about +z, from +x; default 30 */
    double elevation;    /* degrees above the xy-plane, -90..90; default 20 */
    int perspective;     /* 0 orthographic (default), 1 perspective */
    double fov;          /* perspective vertical field of view, degrees in
                          * (0, 170); default 35 */
    double ambient;      /* 0..1, default 0.2: intensity = ambient +
                          * (1 - ambient) * max(0, n.l) */
    uint32_t background; /* 0xRRGGBB, default 0x000000 */
    uint32_t color;      /* 0xRRGGBB of a fully lit voxel, default 0xffffff */
    int fit_volume;      /* 0: frame the voxels' bounding box (default);
                          * 1: frame the whole volume box */
} render_opts;

void render_opts_default(render_opts *o);
/* 0, or -EINVAL when a field is outside the ranges above. */
int render_opts_check(const render_opts *o);

/* How world points map to the image; kept with the image so callers can
 * place things on it.  Pixel (i, j) covers [i, i+1) x [j, j+1), j down. */
typedef struct {
    int perspective;
    double eye[3];     /* perspective: camera position */
    double centre[3];  /* the framed box's centre */
    double right[3], up[3], forward[3]; /* orthonormal; forward into the scene */
    double scale;      /* orthographic: pixels per world unit */
    double focal;      /* perspective: pixels per unit of (lateral / depth) */
    double ref;        /* orthographic: depth of `centre` */
    double cx, cy;     /* pixel position of the view axis */
} render_camera;

/* Project world point p: image position (px, py) and depth (distance along
 * forward from the camera plane, > 0 in front).  Returns 0, or -ERANGE for
 * a point on or behind the perspective camera plane. */
int render_project(const render_camera *c, const double p[3], double *px,
                   double *py, double *depth);

typedef struct {
    int width, height;
    uint8_t *rgb;       /* width * height * 3, rows top to bottom */
    float *depth;       /* width * height; INFINITY where no voxel */
    uint64_t splats;    /* voxels drawn (render_mesh: triangles) */
    render_camera cam;
} render_image;

/* ---- accumulating splats ---- */

typedef struct render_ctx render_ctx;

/* Start an image framing the world box [lo, hi] (lo <= hi on every axis)
 * for voxels of world size voxel[3] (each > 0).  0, -EINVAL, or -ENOMEM. */
int render_begin(render_ctx **ctx, const render_opts *o, const double lo[3],
                 const double hi[3], const double voxel[3]);
/* Draw one voxel centred at world point p with normal n (any length; NULL
 * or zero: lit as if facing the light). */
void render_splat(render_ctx *ctx, const double p[3], const double n[3]);
/* Draw one triangle with corners p[0..2] (world) and a normal at each
 * corner, n[0..2], interpolated across it (three equal normals: flat
 * shading): every pixel whose centre it covers, z-buffered, depth and
 * normal interpolated from the corners (perspective depth through 1/depth).
 * A triangle with a corner behind the perspective camera is skipped. */
void render_triangle(render_ctx *ctx, const double p[3][3], const double n[3][3]);
/* Hand the image over to out (freed with render_image_free) and free ctx. */
void render_finish(render_ctx *ctx, render_image *out);
/* Free ctx without an image (error paths). */
void render_abort(render_ctx *ctx);

/* ---- sources ---- */

/* Figure 6: every voxel of t (channel-3 values, voxel.h), voxel (x, y, z)
 * centred at origin + (x + 0.5) * voxel.  res: the volume in voxels (for
 * fit_volume; NULL means the octree's 2^depth cube).  An empty tree gives
 * the background.  0, -EINVAL or -ENOMEM. */
int render_octree(const octree *t, const double origin[3],
                  const double voxel[3], const uint32_t res[3],
                  const render_opts *o, render_image *out);

/* Level `level` of a VOD file (0 = full resolution; level L reads the
 * parent bricks' downsampled voxels, each 2^L voxels wide, so fewer,
 * larger splats).  World placement from the file's origin and voxelScale.
 * Channel 3 (or 32-bit unspecified): the stored normals.  Channel 1 (or
 * 1-bit unspecified): normals estimated from the occupancy of the 26
 * neighbours at that level (the negated gradient), and voxels whose six
 * face neighbours are all occupied are hidden and skipped.  Other channels:
 * -ENOTSUP.  The framed box is the one the voxels occupy at that level (a
 * coarse level's box may be up to 2^L - 1 voxels larger), so levels frame
 * alike but not exactly; fit_volume frames every level the same.  Errors
 * (-EINVAL for a level outside 0..treeHeight-1 or bad options, -ENOTSUP,
 * -ENOMEM) come with a message in e. */
int render_vod(const vod_file *f, int level, const render_opts *o, render_image *out,
               err_info *e);

/* A triangle mesh (mesh.h), framing its bounding box: flat shading (each
 * triangle its face normal) or smooth (smooth 1: at each vertex the sum of
 * its triangles' area-weighted normals, interpolated).  splats counts the
 * triangles drawn.  0, -EINVAL (bad options) or -ENOMEM. */
int render_mesh(const mesh *m, const render_opts *o, int smooth, render_image *out);

/* ---- output ---- */

/* Write img as an 8-bit RGB PNG (libpng) at path, which appears whole or
 * not at all (outfile.h: an existing file is replaced only by the whole
 * new one).  0 or a negative errno (-ENOMEM when libpng could not make it,
 * else the file system's: -ENOSPC on a full disk). */
int render_write_png(const render_image *img, const char *path);
void render_image_free(render_image *img);

#endif

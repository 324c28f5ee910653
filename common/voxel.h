/* voxel — what one voxel value means (the VOD channels) and normal packing.
 *
 * Inside the engine every surface voxel is a u32 in the VOD channel-3 layout:
 * bits 0-7 occupancy (255 for a surface voxel), bits 8-19 and 20-31 the
 * octahedral encoding of its unit normal, 12 bits each.  A voxel value of 0
 * means "no voxel".
 */
#ifndef VOXD_VOXEL_H
#define VOXD_VOXEL_H

#include <math.h>
#include <stdint.h>

enum voxel_channel {
    VOXEL_CH_UNSPECIFIED = 0,
    VOXEL_CH_OCCUPANCY = 1, /* 1 bit */
    VOXEL_CH_DENSITY = 2,   /* 8 bit, L=0 H=255 S=127 */
    VOXEL_CH_SURFACE = 3,   /* 32 bit: occupancy + octahedral normal */
    VOXEL_CH_DISTANCE = 4,  /* f32 signed distance */
};

#define VOXEL_FULL 255u

/* Channel 4's narrow band: the distance is exact within K voxels of the
 * surface on each side (--band K: 1..VOXEL_BAND_MAX, default
 * VOXEL_BAND_DEFAULT), the band's width K * voxel size with the voxel's
 * sign beyond it. */
#define VOXEL_BAND_DEFAULT 3u
#define VOXEL_BAND_MAX 32u

/* Octahedral encoding of a unit vector into 2 x 12 bits (bits 8-31 of a
 * channel-3 voxel; returned already shifted).  A zero vector encodes +z. */
uint32_t voxel_pack_normal(const double n[3]);
void voxel_unpack_normal(uint32_t v, double n[3]);
/* The unit vector n of octahedral coordinates (u, v), each in [-1, 1] (a
 * packed coordinate c is c / 4095 * 2 - 1): voxel_unpack_normal's end, and
 * vod_unpack_normal's (vod/vod_downsample.h), which must agree bit for bit. */
static inline void voxel_oct_normal(double u, double v, double n[3])
{
    double z = 1.0 - fabs(u) - fabs(v);
    if (z < 0.0) { /* the lower half, folded over the diagonals */
        double fu = (1.0 - fabs(v)) * (u < 0.0 ? -1.0 : 1.0);
        double fv = (1.0 - fabs(u)) * (v < 0.0 ? -1.0 : 1.0);
        u = fu;
        v = fv;
    }
    double len = sqrt(u * u + v * v + z * z);
    n[0] = u / len;
    n[1] = v / len;
    n[2] = z / len;
}
/* voxel_surface() of the vectors (nx[i], ny[i], nz[i]) for i < n (n <= 8),
 * bit for bit, two at a time where SSE2 is there. */
void voxel_surfaces(const double *nx, const double *ny, const double *nz,
                    unsigned n, uint32_t *out);
static inline uint32_t voxel_surface(const double n[3])
{
    return VOXEL_FULL | voxel_pack_normal(n);
}
static inline uint32_t voxel_occupancy(uint32_t v) { return v & 0xffu; }

#endif

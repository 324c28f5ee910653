/* voxel — what one voxel value means (the VOD channels) and normal packing.
 *
 * Inside the engine every surface voxel is a u32 in the VOD channel-3 layout:
 * bits 0-7 occupancy (255 for a surface voxel), bits 8-19 and 20-31 the
 * octahedral encoding of its unit normal, 12 bits each.  A voxel value of 0
 * means "no voxel".
 */
#ifndef VOXD_VOXEL_H
#define VOXD_VOXEL_H

#include <stdint.h>

enum voxel_channel {
    VOXEL_CH_UNSPECIFIED = 0,
    VOXEL_CH_OCCUPANCY = 1, /* 1 bit */
    VOXEL_CH_DENSITY = 2,   /* 8 bit, L=0 H=255 S=127 */
    VOXEL_CH_SURFACE = 3,   /* 32 bit: occupancy + octahedral normal */
    VOXEL_CH_DISTANCE = 4,  /* f32 signed distance */
};

#define VOXEL_FULL 255u

/* Channel 4's narrow band: voxels each side of the surface by default */
#define VOXEL_BAND_DEFAULT 3

/* Octahedral encoding of a unit vector into 2 x 12 bits (bits 8-31 of a
 * channel-3 voxel; returned already shifted).  A zero vector encodes +z. */
uint32_t voxel_pack_normal(const double n[3]);
void voxel_unpack_normal(uint32_t v, double n[3]);
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

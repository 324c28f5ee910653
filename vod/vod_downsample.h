/* vod_downsample — spec section 3's rule for one parent voxel from its 8
 * children, shared by the VOD brick sources (the octree's aggregates, the
 * volume's mip levels), inline because they call it once per cell or voxel.
 */
#ifndef VOXD_VOD_DOWNSAMPLE_H
#define VOXD_VOD_DOWNSAMPLE_H

#include <math.h>
#include <stdint.h>
#include <string.h>

#include "voxel.h"

extern const double vod_oct_unit[4096];

/* voxel_unpack_normal bit for bit (test_vod compares them), but for its
 * first two divisions: the 4096 values of a 12-bit coordinate are a table
 * (vod_downsample.c); the rest is the same voxel_oct_normal. */
static inline void vod_unpack_normal(uint32_t packed, double n[3])
{
    voxel_oct_normal(vod_oct_unit[(packed >> 8) & 0xfffu], vod_oct_unit[(packed >> 20) & 0xfffu],
                     n);
}

/* Channel 3: occupancy is the mean rounded half up, the normal the
 * normalized sum of the normals of the occupied children; 0 (no voxel)
 * where the occupancy rounds to 0. */
static inline uint32_t vod_down_surface(const uint32_t v[8])
{
    uint32_t sum = 0;
    double n[3] = {0, 0, 0};
    for (int i = 0; i < 8; i++) {
        uint32_t occ = voxel_occupancy(v[i]);
        if (!occ) continue;
        double m[3];
        vod_unpack_normal(v[i], m);
        sum += occ;
        for (int a = 0; a < 3; a++) n[a] += m[a];
    }
    uint32_t occ = (sum + 4) / 8;
    if (occ == 0) return 0;
    double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (len > 0)
        for (int a = 0; a < 3; a++) n[a] /= len;
    return occ | voxel_pack_normal(n);
}

/* Channel 4: the mean of the 8 floats (their bits), summed in double in
 * child order and rounded once to float. */
static inline uint32_t vod_down_float(const uint32_t v[8])
{
    double sum = 0;
    for (int i = 0; i < 8; i++) {
        float f;
        memcpy(&f, &v[i], 4);
        sum += f;
    }
    float m = (float)(sum / 8);
    uint32_t u;
    memcpy(&u, &m, 4);
    return u;
}

/* Channel 1: 1 iff any child is non-zero (for voxel values at level 0 as
 * for 0/1 above); channel 2: the mean rounded half up; channels 3 and 4:
 * above. */
__attribute__((always_inline)) static inline uint32_t vod_downsample(int channel,
                                                                   const uint32_t v[8])
{
    if (channel == VOXEL_CH_SURFACE) return vod_down_surface(v);
    if (channel == VOXEL_CH_DISTANCE) return vod_down_float(v);
    if (channel == VOXEL_CH_DENSITY)
        return (v[0] + v[1] + v[2] + v[3] + v[4] + v[5] + v[6] + v[7] + 4) / 8;
    return (v[0] | v[1] | v[2] | v[3] | v[4] | v[5] | v[6] | v[7]) != 0;
}

#endif

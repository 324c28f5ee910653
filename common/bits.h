/* bits — small bit operations shared by the modules. */
#ifndef VOXD_BITS_H
#define VOXD_BITS_H

#include <stdint.h>

/* Bits set in w.  SWAR, not __builtin_popcountll: without -mpopcnt the
 * builtin is a library call, and this runs in the voxel loops. */
static inline unsigned bits_popcount64(uint64_t w)
{
    w -= (w >> 1) & 0x5555555555555555ull;
    w = (w & 0x3333333333333333ull) + ((w >> 2) & 0x3333333333333333ull);
    w = (w + (w >> 4)) & 0x0f0f0f0f0f0f0f0full;
    return (unsigned)((w * 0x0101010101010101ull) >> 56);
}

/* The 32-bit little-endian number at p (a file's bytes, any alignment). */
static inline uint32_t bits_le32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

#endif

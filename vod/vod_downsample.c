/* The table of vod_downsample.h: a 12-bit octahedral coordinate as the
 * double voxel_unpack_normal computes from it, code / 4095 * 2 - 1, folded
 * by the compiler (IEEE double arithmetic, rounded as at run time). */
#include "vod_downsample.h"

#define OCT_U(c) ((double)(c) / 4095.0 * 2.0 - 1.0)
#define T4(c) OCT_U(c), OCT_U((c) + 1), OCT_U((c) + 2), OCT_U((c) + 3)
#define T16(c) T4(c), T4((c) + 4), T4((c) + 8), T4((c) + 12)
#define T64(c) T16(c), T16((c) + 16), T16((c) + 32), T16((c) + 48)
#define T256(c) T64(c), T64((c) + 64), T64((c) + 128), T64((c) + 192)
#define T1024(c) T256(c), T256((c) + 256), T256((c) + 512), T256((c) + 768)

const double vod_oct_unit[4096] = {T1024(0), T1024(1024), T1024(2048), T1024(3072)};

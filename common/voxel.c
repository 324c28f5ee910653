/* Octahedral normal packing (Meyer et al. / Cigolle et al. 2014) into the
 * 2 x 12 bits of a channel-3 voxel. */
#include "voxel.h"

#include <math.h>

#define OCT_MAX 4095.0

static double sign_not_zero(double v) { return v < 0.0 ? -1.0 : 1.0; }

/* floor(w) clamped to 0..OCT_MAX, with w = (u/2 + 1/2) OCT_MAX + 1/2 (NaN
 * gives 0).  Without the floor() call (a libm call unless SSE4.1): for
 * 0 <= w < OCT_MAX the conversion truncates, which is floor; below 0 and
 * from OCT_MAX on, the clamp gives what it gave after floor (OCT_MAX is an
 * integer). */
static inline uint32_t quantize(double u)
{
    double w = (u * 0.5 + 0.5) * OCT_MAX + 0.5;
    if (!(w >= 0.0)) return 0; /* also catches NaN */
    if (w >= OCT_MAX) return (uint32_t)OCT_MAX;
    return (uint32_t)w;
}

uint32_t voxel_pack_normal(const double n[3])
{
    double l1 = fabs(n[0]) + fabs(n[1]) + fabs(n[2]);
    if (!(l1 > 0.0) || !isfinite(l1)) return quantize(0.0) << 8 | quantize(0.0) << 20;
    double u = n[0] / l1, v = n[1] / l1;
    if (n[2] < 0.0) {
        double fu = (1.0 - fabs(v)) * sign_not_zero(u);
        double fv = (1.0 - fabs(u)) * sign_not_zero(v);
        u = fu;
        v = fv;
    }
    return quantize(u) << 8 | quantize(v) << 20;
}

void voxel_unpack_normal(uint32_t packed, double n[3])
{
    double u = ((packed >> 8) & 0xfffu) / OCT_MAX * 2.0 - 1.0;
    double v = ((packed >> 20) & 0xfffu) / OCT_MAX * 2.0 - 1.0;
    double z = 1.0 - fabs(u) - fabs(v);
    if (z < 0.0) {
        double fu = (1.0 - fabs(v)) * sign_not_zero(u);
        double fv = (1.0 - fabs(u)) * sign_not_zero(v);
        u = fu;
        v = fv;
    }
    double len = sqrt(u * u + v * v + z * z);
    n[0] = u / len;
    n[1] = v / len;
    n[2] = z / len;
}

/* Octahedral normal packing (Meyer et al. / Cigolle et al. 2014) into the
 * 2 x 12 bits of a channel-3 voxel. */
#include "voxel.h"

#include <math.h>

#define OCT_MAX 4095.0

static double sign_not_zero(double v) { return v < 0.0 ? -1.0 : 1.0; }

static uint32_t quantize(double u)
{
    double q = floor((u * 0.5 + 0.5) * OCT_MAX + 0.5);
    if (!(q >= 0.0)) q = 0.0; /* also catches NaN */
    if (q > OCT_MAX) q = OCT_MAX;
    return (uint32_t)q;
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

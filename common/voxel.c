/* Octahedral normal packing (Meyer et al. / Cigolle et al. 2014) into the
 * 2 x 12 bits of a channel-3 voxel. */
#include "voxel.h"

#include <math.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

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
    voxel_oct_normal(((packed >> 8) & 0xfffu) / OCT_MAX * 2.0 - 1.0,
                     ((packed >> 20) & 0xfffu) / OCT_MAX * 2.0 - 1.0, n);
}

#ifdef __SSE2__
/* voxel_pack_normal for two vectors: the same operations (IEEE division,
 * and sign_not_zero's product by +-1 is a sign flip), the selects as masks;
 * quantize's clamps are max/min (NaN gives 0) before the truncation. */
static inline __m128i pack2(__m128d x, __m128d y, __m128d z)
{
    const __m128d sign = _mm_set1_pd(-0.0), one = _mm_set1_pd(1.0);
    __m128d ax = _mm_andnot_pd(sign, x), ay = _mm_andnot_pd(sign, y),
            az = _mm_andnot_pd(sign, z);
    __m128d l1 = _mm_add_pd(_mm_add_pd(ax, ay), az);
    __m128d good = _mm_and_pd(_mm_cmpgt_pd(l1, _mm_setzero_pd()),
                              _mm_cmplt_pd(l1, _mm_set1_pd(INFINITY)));
    __m128d u = _mm_div_pd(x, l1), v = _mm_div_pd(y, l1);
    __m128d fu = _mm_xor_pd(_mm_sub_pd(one, _mm_andnot_pd(sign, v)),
                            _mm_and_pd(_mm_cmplt_pd(u, _mm_setzero_pd()), sign));
    __m128d fv = _mm_xor_pd(_mm_sub_pd(one, _mm_andnot_pd(sign, u)),
                            _mm_and_pd(_mm_cmplt_pd(v, _mm_setzero_pd()), sign));
    __m128d neg = _mm_cmplt_pd(z, _mm_setzero_pd());
    u = _mm_or_pd(_mm_and_pd(neg, fu), _mm_andnot_pd(neg, u));
    v = _mm_or_pd(_mm_and_pd(neg, fv), _mm_andnot_pd(neg, v));
    u = _mm_and_pd(good, u); /* no direction: 0, 0 */
    v = _mm_and_pd(good, v);
    __m128d h = _mm_set1_pd(0.5), mx = _mm_set1_pd(OCT_MAX);
    __m128d wu = _mm_add_pd(_mm_mul_pd(_mm_add_pd(_mm_mul_pd(u, h), h), mx), h);
    __m128d wv = _mm_add_pd(_mm_mul_pd(_mm_add_pd(_mm_mul_pd(v, h), h), mx), h);
    wu = _mm_min_pd(_mm_max_pd(wu, _mm_setzero_pd()), mx); /* !(w >= 0): 0 */
    wv = _mm_min_pd(_mm_max_pd(wv, _mm_setzero_pd()), mx);
    __m128i qu = _mm_cvttpd_epi32(wu), qv = _mm_cvttpd_epi32(wv);
    return _mm_or_si128(_mm_or_si128(_mm_slli_epi32(qu, 8), _mm_slli_epi32(qv, 20)),
                        _mm_set1_epi32((int)VOXEL_FULL));
}
#endif

void voxel_surfaces(const double *nx, const double *ny, const double *nz,
                    unsigned n, uint32_t *out)
{
    unsigned i = 0;
#ifdef __SSE2__
    for (; i + 2 <= n; i += 2) {
        __m128i r = pack2(_mm_loadu_pd(&nx[i]), _mm_loadu_pd(&ny[i]), _mm_loadu_pd(&nz[i]));
        out[i] = (uint32_t)_mm_cvtsi128_si32(r);
        out[i + 1] = (uint32_t)_mm_cvtsi128_si32(_mm_srli_si128(r, 4));
    }
#endif
    for (; i < n; i++) out[i] = voxel_surface((const double[3]){nx[i], ny[i], nz[i]});
}

/* The self-test's measure of an inline 1/√x (clphong/device/peak.py
 * measure_native_rsqrt_ulp): rsqrt_dist of clphong.h, in float, with the first guess
 * RSQRT_GUESS_KIND of the host (4: native_rsqrt and one Newton step), LANES elements a
 * work-item as the shading kernel has them. native_rsqrt's accuracy is the
 * implementation's: the plan takes that guess (RSQRT_NATIVE) only where this measures
 * the result within the 2 ulp that the error model assumes. */
#include "clphong.h"

#if LANES == 1
#define LD(i, p) ((p)[i])
#define ST(v, i, p) ((p)[i] = (v))
#else
#define LD(i, p) vloadL(i, p)
#define ST(v, i, p) vstoreL(v, i, p)
#endif

__kernel void rsqrt_probe(__global const float *x, __global float *y)
{
    const size_t i = get_global_id(0);
    ST(rsqrt_dist(LD(i, x)), i, y);
}

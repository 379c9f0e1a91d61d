/* FP32 peak probe for `clphong bench`: independent multiply-add chains on
 * floatL lanes, nothing else. Each work-item runs CHAINS chains of `iterations`
 * a = a·b + c steps: 2·LANES·CHAINS·iterations flops. The result is stored so
 * that nothing is optimised away.
 *
 * An FMA unit keeps its pipeline full only with latency × units independent
 * chains in registers (8 on a 4-cycle, 2-unit core), and not more than the
 * register file holds: float16 on AVX2 is two ymm registers a chain, so 8
 * chains of 16 lanes spill where 12 of 8 lanes do not. The host
 * (clphong/device/peak.py) takes the best of a few (LANES, CHAINS).
 *
 * Defines: LANES (lanes.h) and CHAINS, set by the bench. */
#include "lanes.h"

#ifndef CHAINS
#error "CHAINS must be set by the host (clphong/device/peak.py)"
#endif

/* PEAK_DOUBLE: the same chains in double, for the device's double-to-float rate
 * (clphong/device/peak.py measure_fp64_ratio), which chooses what the shading plan
 * computes in double; out then holds doubles. */
#if PEAK_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double peakS;
#if LANES == 16
typedef double16 peakL;
#elif LANES == 8
typedef double8 peakL;
#elif LANES == 4
typedef double4 peakL;
#else
typedef double peakL;
#endif
#else
typedef float peakS;
typedef floatL peakL;
#endif

__kernel void fma_peak(__global peakS *restrict out, const uint iterations, const float b,
                       const float c)
{
    const size_t i = get_global_id(0);
    const peakL bb = (peakL)((peakS)b), cc = (peakL)((peakS)c);
    const peakS x = (peakS)0.001f * (peakS)i;
    peakL a[CHAINS];
#pragma unroll
    for (int k = 0; k < CHAINS; ++k)
        a[k] = (peakL)(x + (peakS)k);
    for (uint n = 0; n < iterations; ++n) {
#pragma unroll
        for (int k = 0; k < CHAINS; ++k)
            a[k] = MUL_ADD(a[k], bb, cc);
    }
    peakL s = a[0];
#pragma unroll
    for (int k = 1; k < CHAINS; ++k)
        s += a[k];
    ((__global peakL *)out)[i] = s;
}

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

__kernel void fma_peak(__global float *restrict out, const uint iterations, const float b,
                       const float c)
{
    const size_t i = get_global_id(0);
    const floatL bb = (floatL)(b), cc = (floatL)(c);
    const float x = 0.001f * (float)i;
    floatL a[CHAINS];
#pragma unroll
    for (int k = 0; k < CHAINS; ++k)
        a[k] = (floatL)(x + (float)k);
    for (uint n = 0; n < iterations; ++n) {
#pragma unroll
        for (int k = 0; k < CHAINS; ++k)
            a[k] = MUL_ADD(a[k], bb, cc);
    }
    floatL s = a[0];
#pragma unroll
    for (int k = 1; k < CHAINS; ++k)
        s += a[k];
    vstoreL(s, i, out);
}

/* FP32 peak probe for `clphong bench`: independent multiply-add chains on
 * floatL lanes, nothing else. Each work-item runs 8 chains of `iterations`
 * a = a·b + c steps: 2·LANES·8·iterations flops. The result is stored so that
 * nothing is optimised away.
 *
 * Defines: LANES only (lanes.h), set by the bench. */
#include "lanes.h"

#define STEP(a) a = MUL_ADD(a, bb, cc)

__kernel void fma_peak(__global float *restrict out, const uint iterations, const float b,
                       const float c)
{
    const size_t i = get_global_id(0);
    const floatL bb = (floatL)(b), cc = (floatL)(c);
    const float x = 0.001f * (float)i;
    floatL a0 = (floatL)(x), a1 = (floatL)(x + 1.0f), a2 = (floatL)(x + 2.0f),
           a3 = (floatL)(x + 3.0f), a4 = (floatL)(x + 4.0f), a5 = (floatL)(x + 5.0f),
           a6 = (floatL)(x + 6.0f), a7 = (floatL)(x + 7.0f);
    for (uint n = 0; n < iterations; ++n) {
        STEP(a0); STEP(a1); STEP(a2); STEP(a3); STEP(a4); STEP(a5); STEP(a6); STEP(a7);
    }
    vstoreL(((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7)), i, out);
}

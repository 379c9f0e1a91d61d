/* The display output: exposure, tone mapping and encoding (include/tonemap.h)
 * of stored scene-linear planes.
 *
 * The shading kernels store the beauty; this small program runs after them on
 * the same device buffer (clphong/device/display.py), so a change of tone-map
 * operator, exposure, view or output rebuilds only this kernel, never the
 * shading kernel. It also runs on frames already shaded: the banded path, the
 * contact sheet, the operator tests. Layout as shade.cl: planar R G B, `stride`
 * floats a plane, a multiple of LANES.
 *
 * DISPLAY_STRAIGHT (an output with straight alpha of a partly covered frame):
 * the input is the beauty α·S + (1 − α)·background and the display takes the
 * straight shade S = (beauty − (1 − α)·background)/α where α > 0, the
 * background elsewhere: the same float operations, in the same order and
 * uncontracted, as the host's straight_of (clphong/device/renderer.py), so the
 * one-launch and the banded display outputs agree bit for bit.
 *
 * Defines, all set by clphong/device/display.py: LANES (lanes.h),
 * DisplayTransform.defines (DISPLAY_OUT = 1 with TONEMAP, DISPLAY_MATRIX and
 * DISPLAY_ENCODING: tonemap.h) and DISPLAY_STRAIGHT. No define of the shading
 * plan: this program shades nothing.
 */
#include "lanes.h"
#include "tonemap.h"

#if !DISPLAY_OUT
#error "tonemap_apply.cl needs DISPLAY_OUT = 1 and the display's defines (DisplayTransform.defines, clphong/device/display.py)"
#endif
#ifndef DISPLAY_STRAIGHT
#error "DISPLAY_STRAIGHT must be set by clphong/device/display.py"
#endif

__kernel void tonemap_planes(__global const float *restrict rgb,
                             __global float *restrict display,
                             const uint stride,
                             const float exposure,       /* 2^EV */
                             const float4 tonemap_params,
                             const float4 m0, const float4 m1, const float4 m2,
                             __global const float *restrict alpha,   /* with DISPLAY_STRAIGHT */
                             const float4 background)                /* with DISPLAY_STRAIGHT */
{
    const size_t i = get_global_id(0);
    floatL r = vloadL(i, rgb + 0 * stride);
    floatL g = vloadL(i, rgb + 1 * stride);
    floatL b = vloadL(i, rgb + 2 * stride);
#if DISPLAY_STRAIGHT
    {
#pragma OPENCL FP_CONTRACT OFF
        const floatL a = vloadL(i, alpha);
        const floatL one_a = 1.0f - a;
        const floatL sr = (r - one_a * background.x) / a;
        const floatL sg = (g - one_a * background.y) / a;
        const floatL sb = (b - one_a * background.z) / a;
        r = SELECT((floatL)(background.x), sr, a > 0.0f);
        g = SELECT((floatL)(background.y), sg, a > 0.0f);
        b = SELECT((floatL)(background.z), sb, a > 0.0f);
    }
#endif
    display_store(r, g, b, i, display, stride, exposure, tonemap_params, m0, m1, m2);
}

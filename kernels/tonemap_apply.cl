/* Tone mapping of stored scene-linear planes: the same display_transform that
 * shade.cl fuses into its final store (include/tonemap.h), run on its own.
 *
 * Used where the frame is already shaded: the contact sheet (one frame through
 * every operator without shading it again) and the operator tests, which feed
 * chosen inputs. Layout as shade.cl: planar R G B, `stride` floats a plane, a
 * multiple of LANES.
 *
 * Defines, all set by apply_display_transform (clphong/device/display.py):
 * LANES (lanes.h) and DisplayTransform.defines, DISPLAY_OUT = 1 with TONEMAP,
 * DISPLAY_MATRIX and DISPLAY_ENCODING (tonemap.h). No define of the shading
 * plan: this program shades nothing.
 */
#include "lanes.h"
#include "tonemap.h"

#if !DISPLAY_OUT
#error "tonemap_apply.cl needs DISPLAY_OUT = 1 and the display's defines (DisplayTransform.defines, clphong/device/display.py)"
#endif

__kernel void tonemap_planes(__global const float *restrict rgb,
                             __global float *restrict display,
                             const uint stride,
                             const float exposure,       /* 2^EV */
                             const float4 tonemap_params,
                             const float4 m0, const float4 m1, const float4 m2)
{
    const size_t i = get_global_id(0);
    display_store(vloadL(i, rgb + 0 * stride), vloadL(i, rgb + 1 * stride),
                  vloadL(i, rgb + 2 * stride), i, display, stride,
                  exposure, tonemap_params, m0, m1, m2);
}

/* The obvious kernel: one pixel per work-item, float3 maths, pow().
 *
 * Kept as the baseline that `clphong bench` measures the lane kernel
 * (shade.cl) against. It is how a shader is usually written, and on PoCL it
 * runs scalar: float3 blocks the work-group vectoriser and pow(x, k) is both slow
 * and ill-conditioned (relative error ~k·u near the highlight peak). Same
 * arguments, data layout and guards as shade.cl; the light sum is naive.
 */
#define LANES 1
#include "clphong.h"
#include "tonemap.cl"   /* display_store (DISPLAY_OUT) */

__kernel void shade(__global const float *restrict gbuf,
                    __global const float *restrict maps,
                    __global float *restrict out,
                    const uint stride,
                    __global const float4 *restrict point_lights, const uint n_point,
                    __global const float4 *restrict directional_lights, const uint n_directional,
                    const float4 origin, const float4 eye, const float4 ambient,
                    const float k_d, const float4 S_uniform, const float k_uniform,
                    const float4 background,
                    const float4 eye_lo,     /* unused: this kernel is all float */
                    const float4 material_lo, const float4 S_lo,           /* unused too */
                    __global float *restrict display, const float exposure,
                    const float4 tonemap_params, const float4 display_m0,
                    const float4 display_m1, const float4 display_m2)   /* as shade.cl */
{
    const size_t i = get_global_id(0);
    const float3 P = (float3)(gbuf[i], gbuf[stride + i], gbuf[2 * stride + i]) - origin.xyz;
    const float3 n = (float3)(gbuf[3 * stride + i], gbuf[4 * stride + i], gbuf[5 * stride + i]);
    const float3 C_d = (float3)(gbuf[6 * stride + i], gbuf[7 * stride + i], gbuf[8 * stride + i]);
    if (n.x == 0.0f && n.y == 0.0f && n.z == 0.0f) {   /* background, zeroed on the host */
        out[i] = background.x; out[stride + i] = background.y; out[2 * stride + i] = background.z;
#if DISPLAY_OUT
        display_store(background.x, background.y, background.z, i, display, stride, exposure,
                      tonemap_params, display_m0, display_m1, display_m2);
#endif
        return;
    }
    uint plane = 0;
#if MAP_KD
    const float kd = maps[(plane++) * stride + i];
#else
    const float kd = k_d;
#endif
#if MAP_KS
    const float ks = maps[(plane++) * stride + i];
#else
    const float ks = 1.0f;
#endif
#if MAP_H
    const float k = (MODEL_BLINN ? 4.0f : 1.0f) * maps[(plane++) * stride + i];  /* map holds h */
#else
    const float k = k_uniform;
#endif
#if MAP_CS
    const float3 S = ks * S_uniform.xyz * (float3)(maps[plane * stride + i],
                     maps[(plane + 1) * stride + i], maps[(plane + 2) * stride + i]);
#else
    const float3 S = ks * S_uniform.xyz;
#endif
    const float3 D = C_d * kd;
#if CAMERA_ORTHO
    const float3 v = eye.xyz;
#else
    const float3 e = eye.xyz - P;
    const float3 v = dot(e, e) > 0.0f ? normalize(e) : n;   /* at the eye: head-on, as shade.cl */
#endif
    float3 E = C_d * ambient.xyz;
#if HAS_DIRECTIONAL
    for (uint j = 0; j < n_directional; ++j) {
        const float3 l = directional_lights[DIRECTIONAL_LIGHT_FLOAT4S * j].xyz;
        const float3 L = directional_lights[DIRECTIONAL_LIGHT_FLOAT4S * j + 1].xyz;
        const float NoL = dot(n, l);
        float spec = 0.0f;
#if HAS_SPECULAR
        if (NoL > 0.0f) {
#if MODEL_BLINN
            const float3 hv = l + v;
            spec = dot(hv, hv) > 0.0f ? pow(fmax(dot(n, normalize(hv)), 0.0f), k) : 0.0f;
#else
            spec = pow(fmax(dot(2.0f * NoL * n - l, v), 0.0f), k);
#endif
        }
#endif
        E += L * (D * fmax(NoL, 0.0f) + S * spec);
    }
#endif
#if HAS_POINT
    for (uint j = 0; j < n_point; ++j) {
        const float4 X = point_lights[POINT_LIGHT_FLOAT4S * j];
        const float4 L = point_lights[POINT_LIGHT_FLOAT4S * j + 1];
        const float c2 = point_lights[POINT_LIGHT_FLOAT4S * j + 2].x;
        const float3 dv = X.xyz - P;
        const float d = length(dv);
        if (d <= 0.0f)            /* light at the shaded point: no direction */
            continue;
        const float3 l = dv / d;
        const float NoL = dot(n, l);
        float spec = 0.0f;
#if HAS_SPECULAR
        if (NoL > 0.0f) {
#if MODEL_BLINN
            const float3 hv = l + v;
            spec = dot(hv, hv) > 0.0f ? pow(fmax(dot(n, normalize(hv)), 0.0f), k) : 0.0f;
#else
            spec = pow(fmax(dot(2.0f * NoL * n - l, v), 0.0f), k);
#endif
        }
#endif
        const float att = 1.0f / (X.w + L.w * d + c2 * d * d);
        E += att * L.xyz * (D * fmax(NoL, 0.0f) + S * spec);
    }
#endif
    out[i] = E.x; out[stride + i] = E.y; out[2 * stride + i] = E.z;
#if DISPLAY_OUT
    display_store(E.x, E.y, E.z, i, display, stride, exposure, tonemap_params,
                  display_m0, display_m1, display_m2);
#endif
}

/* The obvious kernel: one pixel per work-item, float3 maths, pow().
 *
 * Kept as the baseline that `clphong bench` measures the lane kernel
 * (shade.cl) against. It is how a shader is usually written, and on PoCL it
 * runs scalar: float3 blocks the work-group vectoriser and pow(x, k) is both slow
 * and ill-conditioned (relative error ~k·u near the highlight peak). Same
 * arguments (SHADE_ARGS), data layout and guards as shade.cl; the light sum is
 * naive. It is all float and ignores the hi + lo remainders eye_lo, material_lo
 * and S_lo.
 *
 * Defines: the shading plan's (clphong/device/plan.py) scene switches (plan.h);
 * the display output is kernels/tonemap_apply.cl's, as for shade.cl. The plan sets no LANES, CULLING or number format for
 * this kernel ("obvious" plans): it fixes them here, one float pixel per
 * work-item, and refuses a build that sets them.
 */
#if defined(LANES) || defined(CULLING) || defined(DIRECTIONS_FP64) || defined(SUM_FP64) \
    || defined(SPEC_INT_POW) || defined(SPEC_COS) || defined(POW_FP32) || defined(WEIGHTS_FP64)
#error "shade_obvious.cl sets LANES, CULLING and the number formats itself (one float pixel per work-item)"
#endif
#define LANES 1
#define CULLING 0           /* no tile lists: SHADE_ARGS without them */
#define DIRECTIONS_FP64 0   /* all float: pointrec_t is float4 (clphong.h) */
#define SUM_FP64 0
#define SPEC_INT_POW 0      /* pow(), not binary powering */
#define SPEC_COS 0
#define POW_FP32 0
#define WEIGHTS_FP64 0
#include "clphong.h"
#include "plan.h"
#include "shade_args.h"

__kernel void shade(SHADE_ARGS)   /* include/shade_args.h, as shade.cl */
{
    const size_t i = get_global_id(0) + item0;   /* as shade.cl */
    const float3 P = (float3)(gbuf[i], gbuf[stride + i], gbuf[2 * stride + i]) - origin.xyz;
    const float3 n = (float3)(gbuf[3 * stride + i], gbuf[4 * stride + i], gbuf[5 * stride + i]);
    const float3 C_d = (float3)(gbuf[6 * stride + i], gbuf[7 * stride + i], gbuf[8 * stride + i]);
    if (n.x == 0.0f && n.y == 0.0f && n.z == 0.0f) {   /* background, zeroed on the host */
        out[i] = background.x; out[stride + i] = background.y; out[2 * stride + i] = background.z;
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
#if HAS_SPOT
        /* glTF's spot factor t², as lights.h's spot_factor */
        const float4 A = point_lights[POINT_LIGHT_FLOAT4S * j + 2];
        const float4 K = point_lights[POINT_LIGHT_FLOAT4S * j + 3];
        const float t = clamp(-dot(l, A.yzw) * K.x + K.y, 0.0f, 1.0f);
        const float att = t * t / (X.w + L.w * d + c2 * d * d);
#else
        const float att = 1.0f / (X.w + L.w * d + c2 * d * d);
#endif
        E += att * L.xyz * (D * fmax(NoL, 0.0f) + S * spec);
    }
#endif
#if COVERAGE
    /* α·S + (1 − α)·background, as shade.cl */
    const float alpha = gbuf[12 * stride + i];
    const float3 O = alpha * E + (1.0f - alpha) * background.xyz;
#else
    const float3 O = E;
#endif
    out[i] = O.x; out[stride + i] = O.y; out[2 * stride + i] = O.z;
}

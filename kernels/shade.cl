/* clphong entry point: E = E_A + Σ_i (E_D + E_S)_i / (c0_i + c1_i·d_i + c2_i·d_i²)
 *
 * Data layout (structure of arrays, `stride` floats a plane, stride a multiple
 * of LANES, padding pixels are background):
 *   gbuf: Px Py Pz  Nx Ny Nz  Cr Cg Cb
 *         P is as stored (float32); the kernel subtracts `origin`, a float32
 *         point near the scene, so P − origin is exact for P within a factor 2
 *         of it (Sterbenz) and distances keep their digits far from the world
 *         origin. N is unit (normalised on the host in float64) and exactly 0 on
 *         background pixels. C is the albedo C_d.
 *   maps: the planes named by MAP_KD, MAP_KS, MAP_H, MAP_CS (k_d, k_s, h, C_s rgb),
 *         in that order, only those present.
 *   out:  R G B.
 * Each work-item shades LANES consecutive pixels as one vector.
 */
#include "clphong.h"
#include "brdf.cl"
#include "lights.cl"

/* Add x to the running sum s; Neumaier's compensation c collects the rounding
 * error of each addition, so the sum of N lights errs by ~2u instead of ~N·u
 * (POCL-NOTES "Light sums"). */
#if COMPENSATED_SUM
#define ACCUMULATE(s, c, x) do { \
        const floatL t_ = (s) + (x); \
        (c) += select(((x) - t_) + (s), ((s) - t_) + (x), (intL)(fabs(s) >= fabs(x))); \
        (s) = t_; } while (0)
#else
#define ACCUMULATE(s, c, x) ((s) += (x))
#endif

__kernel void shade(__global const float *restrict gbuf,
                    __global const float *restrict maps,
                    __global float *restrict out,
                    const uint stride,
                    __global const float4 *restrict point_lights, const uint n_point,
                    __global const float4 *restrict directional_lights, const uint n_directional,
                    const float4 origin,     /* subtracted from P and (on the host) from lights */
                    const float4 eye,        /* perspective: eye − origin; orthographic: unit v */
                    const float4 ambient,    /* k_a·Σ ambient radiance, rgb */
                    const float k_d,         /* uniform k_d, used without MAP_KD */
                    const float4 S_uniform,  /* k_s·C_s, used without MAP_KS / MAP_CS */
                    const float k_uniform,   /* exponent h or 4h, used without MAP_H */
                    const float4 background)
{
    const size_t i = get_global_id(0);
    pixel_t p;
    p.px = vloadL(i, gbuf + 0 * stride) - origin.x;
    p.py = vloadL(i, gbuf + 1 * stride) - origin.y;
    p.pz = vloadL(i, gbuf + 2 * stride) - origin.z;
    p.nx = vloadL(i, gbuf + 3 * stride);
    p.ny = vloadL(i, gbuf + 4 * stride);
    p.nz = vloadL(i, gbuf + 5 * stride);
    const floatL Cr = vloadL(i, gbuf + 6 * stride);
    const floatL Cg = vloadL(i, gbuf + 7 * stride);
    const floatL Cb = vloadL(i, gbuf + 8 * stride);

    /* Per-pixel material: D = C_d·k_d, S = C_s·k_s, exponent k. */
    uint plane = 0;
#if MAP_KD
    const floatL kd = vloadL(i, maps + (plane++) * stride);
#else
    const floatL kd = (floatL)(k_d);
#endif
    const floatL Dr = Cr * kd, Dg = Cg * kd, Db = Cb * kd;
#if MAP_KS
    const floatL ks = vloadL(i, maps + (plane++) * stride);
#else
    const floatL ks = (floatL)(1.0f);   /* k_s is folded into S_uniform */
#endif
#if MAP_H
    const floatL k_map = vloadL(i, maps + (plane++) * stride);
#endif
#if MAP_CS
    const floatL Sr = ks * vloadL(i, maps + (plane + 0) * stride) * S_uniform.x;
    const floatL Sg = ks * vloadL(i, maps + (plane + 1) * stride) * S_uniform.y;
    const floatL Sb = ks * vloadL(i, maps + (plane + 2) * stride) * S_uniform.z;
#else
    const floatL Sr = ks * S_uniform.x, Sg = ks * S_uniform.y, Sb = ks * S_uniform.z;
#endif
#if HAS_SPECULAR
#if MAP_H
    p.k = MODEL_BLINN ? 4.0f * k_map : k_map;   /* the map holds h; Blinn uses 4h */
#else
    p.k = (floatL)(k_uniform);
#endif
#endif

#if CAMERA_ORTHO
    p.vx = (floatL)(eye.x);
    p.vy = (floatL)(eye.y);
    p.vz = (floatL)(eye.z);
#else
    {
        const floatL ex = eye.x - p.px, ey = eye.y - p.py, ez = eye.z - p.pz;
        const floatL inv = rsqrt(MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez)));
        p.vx = ex * inv;
        p.vy = ey * inv;
        p.vz = ez * inv;
    }
#endif

    /* Ambient: E_A = C_d·k_a·Σ ambient radiance. */
    floatL sr = Cr * ambient.x, sg = Cg * ambient.y, sb = Cb * ambient.z;
    floatL cr = (floatL)(0.0f), cg = (floatL)(0.0f), cb = (floatL)(0.0f);

#if HAS_DIRECTIONAL
    for (uint j = 0; j < n_directional; ++j) {
        const float4 l = directional_lights[3 * j + 0];
        const float4 L = directional_lights[3 * j + 1];
        const float4 h = directional_lights[3 * j + 2];
        const weights_t w = shade_directional_light(&p, l, h);
        ACCUMULATE(sr, cr, L.x * MUL_ADD(Dr, w.diffuse, Sr * w.specular));
        ACCUMULATE(sg, cg, L.y * MUL_ADD(Dg, w.diffuse, Sg * w.specular));
        ACCUMULATE(sb, cb, L.z * MUL_ADD(Db, w.diffuse, Sb * w.specular));
    }
#endif
#if HAS_POINT
    for (uint j = 0; j < n_point; ++j) {
        const float4 X = point_lights[3 * j + 0];   /* position, c0 */
        const float4 L = point_lights[3 * j + 1];   /* radiance, c1 */
        const float4 Q = point_lights[3 * j + 2];   /* c2 */
        const weights_t w = shade_point_light(&p, X, L.w, Q.x);
        ACCUMULATE(sr, cr, L.x * MUL_ADD(Dr, w.diffuse, Sr * w.specular));
        ACCUMULATE(sg, cg, L.y * MUL_ADD(Dg, w.diffuse, Sg * w.specular));
        ACCUMULATE(sb, cb, L.z * MUL_ADD(Db, w.diffuse, Sb * w.specular));
    }
#endif

    /* Background pixels (zero normal, set by the host) take the background value. */
    const intL bg = (intL)((p.nx == 0.0f) & (p.ny == 0.0f) & (p.nz == 0.0f));
    vstoreL(select(sr + cr, (floatL)(background.x), bg), i, out + 0 * stride);
    vstoreL(select(sg + cg, (floatL)(background.y), bg), i, out + 1 * stride);
    vstoreL(select(sb + cb, (floatL)(background.z), bg), i, out + 2 * stride);
}

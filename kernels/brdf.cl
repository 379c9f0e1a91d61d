/* Phong reflection model terms (Phong 1975; Blinn 1977), after the notes
 * ../shared/phong-model-notes.txt. Mirrored in float64 by clphong/reference.py. */
#ifndef BRDF_CL
#define BRDF_CL
#include "clphong.h"

/* Lambert's cosine law: E_D ∝ max(n·l, 0). */
inline floatL lambert(floatL NoL)
{
    return fmax(NoL, (floatL)(0.0f));
}

/* Phong: δ = 1 − r·v with r = 2n(n·l) − l.
 * For unit r and v, 1 − r·v = |r − v|²/2 exactly. The right-hand side has no
 * cancellation near the highlight peak (r·v → 1), where the naive 1 − r·v loses
 * all its digits, and the normalisation errors of r and v cancel to first order
 * (POCL-NOTES "Conditioning of pow"). */
inline floatL phong_delta(floatL nx, floatL ny, floatL nz,
                          floatL lx, floatL ly, floatL lz,
                          floatL vx, floatL vy, floatL vz, floatL NoL)
{
    const floatL two_NoL = NoL + NoL;
    const floatL ex = MUL_ADD(two_NoL, nx, -lx) - vx;   /* r − v */
    const floatL ey = MUL_ADD(two_NoL, ny, -ly) - vy;
    const floatL ez = MUL_ADD(two_NoL, nz, -lz) - vz;
    return 0.5f * MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
}

/* Blinn-Phong: δ = 1 − n·h with h = (l + v)/|l + v|, as |n − h|²/2 (see above).
 * Guard: for l = −v the half vector is undefined; δ = 1 (n·h taken as 0) so the
 * term vanishes for h > 0. */
inline floatL blinn_delta(floatL nx, floatL ny, floatL nz,
                          floatL lx, floatL ly, floatL lz,
                          floatL vx, floatL vy, floatL vz)
{
    const floatL hx = lx + vx, hy = ly + vy, hz = lz + vz;
    const floatL hh = MUL_ADD(hx, hx, MUL_ADD(hy, hy, hz * hz));
    const floatL inv = rsqrt(hh);
    const floatL ex = nx - hx * inv, ey = ny - hy * inv, ez = nz - hz * inv;
    const floatL delta = 0.5f * MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
    return select(delta, (floatL)(1.0f), (intL)(hh <= 0.0f));
}

/* Blinn-Phong with a half vector that is constant per light (orthographic camera
 * and a directional light, Blinn 1977): δ = |n − h|²/2 with h from the host.
 * Guard: h.w ≠ 0 flags l = −v (undefined half vector): δ = 1, as above. */
inline floatL blinn_delta_const_h(floatL nx, floatL ny, floatL nz, float4 h)
{
    if (h.w != 0.0f)
        return (floatL)(1.0f);
    const floatL ex = nx - h.x, ey = ny - h.y, ez = nz - h.z;
    return 0.5f * MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
}

/* max(cos, 0)^k with cos = 1 − δ, as exp(k·log1p(−δ)).
 * log1p keeps full relative accuracy for small δ, so the relative error of the
 * result is ~k·δ·u plus the error of δ itself: bounded for any exponent, where
 * pow(cos, k) loses k·u (POCL-NOTES: 2000 ulp at k = 2000).
 * Guards: δ ≥ 1 means cos ≤ 0, so max(cos, 0)^k = 0 for k > 0; 0^0 := 1, as pow
 * defines it, so k = 0 gives 1 wherever the term is on. */
inline floatL specular_power(floatL delta, floatL k)
{
    const floatL s = exp(k * log1p(-delta));
    const floatL at_zero = select((floatL)(0.0f), (floatL)(1.0f), (intL)(k == 0.0f));
    return select(s, at_zero, (intL)(delta >= 1.0f));
}

#endif /* BRDF_CL */

/* Phong reflection model terms (Phong 1975; Blinn 1977), after the notes
 * ../shared/phong-model-notes.txt. Mirrored by the float64 reference
 * (clphong/reference/).
 *
 * Reads the number formats only (clphong.h): no define of the scene (plan.h). */
#ifndef CLPHONG_BRDF_H
#define CLPHONG_BRDF_H
#include "clphong.h"

/* Lambert's cosine law: E_D ∝ max(n·l, 0). */
inline wL lambert(wL NoL)
{
    return MAX0(NoL);
}

/* x clamped to [0, 1], with comparisons: PoCL 3.0 calls clamp() out of line. */
inline dirL clamp01(dirL x)
{
    return SELECT_DIR(SELECT_DIR(x, (dirL)(1.0f), x > (dirL)(1.0f)), (dirL)(0.0f), x < (dirL)(0.0f));
}

/* Schlick's Fresnel factor (1 − cos α)⁵ for cos α clamped to [0, 1] (the weight
 * W = f0 + (1 − f0)·(1 − cos α)⁵ of FRESNEL, shade.cl): three multiplies. */
inline dirL schlick_weight(dirL cos_a)
{
    const dirL m = (dirL)(1.0f) - clamp01(cos_a);
    const dirL m2 = m * m;
    return m2 * m2 * m;
}

/* Phong: δ = 1 − r·v with r = 2n(n·l) − l.
 * For unit r and v, 1 − r·v = |r − v|²/2 exactly. The right-hand side has no
 * cancellation near the highlight peak (r·v → 1), where the naive 1 − r·v loses
 * all its digits, and the normalisation errors of r and v cancel to first order
 * (POCL-NOTES "Conditioning of pow"). */
inline dirL phong_delta(dirL nx, dirL ny, dirL nz,
                        dirL lx, dirL ly, dirL lz,
                        dirL vx, dirL vy, dirL vz, dirL NoL)
{
    const dirL two_NoL = NoL + NoL;
    const dirL ex = MUL_ADD(two_NoL, nx, -lx) - vx;   /* r − v */
    const dirL ey = MUL_ADD(two_NoL, ny, -ly) - vy;
    const dirL ez = MUL_ADD(two_NoL, nz, -lz) - vz;
    return 0.5f * MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
}

/* Blinn-Phong: δ = 1 − n·h with h = (l + v)/|l + v|, as |n − h|²/2 (see above).
 * Guard: for l = −v the half vector is undefined; δ = 1 (n·h taken as 0) so the
 * term vanishes for h > 0. */
inline dirL blinn_delta(dirL nx, dirL ny, dirL nz,
                        dirL lx, dirL ly, dirL lz,
                        dirL vx, dirL vy, dirL vz)
{
    const dirL hx = lx + vx, hy = ly + vy, hz = lz + vz;
    const dirL hh = MUL_ADD(hx, hx, MUL_ADD(hy, hy, hz * hz));
    const dirL inv = RSQRT_DIR(hh);
    const dirL ex = nx - hx * inv, ey = ny - hy * inv, ez = nz - hz * inv;
    const dirL delta = 0.5f * MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
    return SELECT_DIR(delta, (dirL)(1.0f), hh <= (dirL)(0.0f));
}

/* Blinn-Phong with a half vector that is constant per light (orthographic camera
 * and a directional light, Blinn 1977): δ = |n − h|²/2 with h from the host.
 * h_lo = h − float(h) from the host (0 unless DIRECTIONS_FP64).
 * Guard: h.w ≠ 0 flags l = −v (undefined half vector): δ = 1, as above. */
inline dirL blinn_delta_const_h(dirL nx, dirL ny, dirL nz, float4 h, float4 h_lo)
{
    if (h.w != 0.0f)
        return (dirL)(1.0f);
    const dirL ex = nx - ((dirS)h.x + (dirS)h_lo.x);
    const dirL ey = ny - ((dirS)h.y + (dirS)h_lo.y);
    const dirL ez = nz - ((dirS)h.z + (dirS)h_lo.z);
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
    const floatL at_zero = SELECT((floatL)(0.0f), (floatL)(1.0f), k == 0.0f);
    return SELECT(s, at_zero, delta >= 1.0f);
}

#if WEIGHTS_FP64 && !SPEC_INT_POW
/* specular_power in double, for a non-whole exponent (or a shininess map) where
 * the weights are double (CPU devices): δ is not rounded to float, and log1p and
 * exp add a few 2⁻⁵³ instead of a few u, so lights that cancel each other keep
 * their digits here too. Same guards. */
inline wL specular_power_fp64(dirL delta, wL k)
{
    const doubleL s = exp(k * log1p(-delta));
    const doubleL at_zero = SELECT_DIR((doubleL)(0.0), (doubleL)(1.0), k == 0.0);
    return SELECT_DIR(s, at_zero, delta >= 1.0);
}
#endif

#if SPEC_COS
/* SPEC_COS (double directions, or POW_FP32, and a whole exponent): the integer
 * power takes the cosine itself, formed in double (in float with POW_FP32). The
 * cancellation that |r − v|²/2 and |n − h|²/2 avoid costs nothing in double:
 * 1 − δ = cos carries an absolute error of a few 2⁻⁵³ plus the directions' own
 * (2⁻⁴⁷), and x^K turns an absolute error e of x into K·e/x relative, ≤ 10⁻⁹ near
 * the peak even for K = 65536 (docs/error-model.md). It also saves a square root:
 * the lights loop ran 1.35× faster on the bench scene (Blinn, K = 128).
 * With POW_FP32 (the fast path: float directions and power) the cosine is formed
 * in float: an absolute error of ~8u/|l + v| (Blinn) or ~24u (Phong) near the
 * peak, so K·8u relative there where |r − v|²/2 and |n − h|²/2 had ~0, which the
 * fast path's own bound allows (its powering alone is 2K·u); for Blinn it saves
 * the half vector's 1/√x, its normalisation and |n − h|²/2 (docs/bench.md).
 *
 * Phong: max(r·v, 0) with r·v = (2n(n·l) − l)·v = 2(n·l)(n·v) − l·v. */
inline dirL phong_cos(dirL lx, dirL ly, dirL lz, dirL vx, dirL vy, dirL vz,
                      dirL NoL, dirL NoV)
{
    const dirL LoV = MUL_ADD(lx, vx, MUL_ADD(ly, vy, lz * vz));
    const dirL x = MUL_ADD(NoL + NoL, NoV, -LoV);
    return SELECT_DIR(x, (dirL)(0.0f), x <= (dirL)(0.0f));    /* max(r·v, 0); NaN stays NaN */
}

/* Blinn-Phong: (n·h)² = (n·l + n·v)²/|l + v|² where n·h > 0, else 0, so that
 * ((n·h)²)^(K/2) = max(n·h, 0)^K for an even K with no square root.
 * Guards, as blinn_delta: l = −v (|l + v| = 0, the half vector undefined) gives 0
 * (n·h taken as 0), so the term vanishes for K > 0; |l + v|² below FLT_MIN counts
 * as FLT_MIN (no division by 0; the cap below). Where |l + v| is only rounding
 * noise (l within ~2⁻⁵² of −v), n·(l + v) and |l + v|² are both noise and their
 * ratio can be anything: capped at 1, as a normalised half vector
 * gives (the error model bounds the whole term there, and culling assumes a
 * specular weight ≤ 1). */
inline dirL blinn_cos_sq(dirL lx, dirL ly, dirL lz, dirL vx, dirL vy, dirL vz,
                         dirL NoL, dirL NoV)
{
    const dirL hx = lx + vx, hy = ly + vy, hz = lz + vz;
    const dirL hh = MUL_ADD(hx, hx, MUL_ADD(hy, hy, hz * hz));
    /* max(q, 0)² / max(|l + v|², FLT_MIN), then min(·, 1): comparisons that compile to
       max and min, no masks (1.03x the fast path on Zen 3). q ≤ 0 gives 0; l = −v gives
       q = 0 exactly (n·l = −n·v), so 0; a NaN q (NaN inputs) gives 0, as the masks did */
    const dirL q0 = NoL + NoV;                   /* n·(l + v) */
    const dirL q = q0 > (dirL)(0.0f) ? q0 : (dirL)(0.0f);
    const dirL hm = hh > (dirL)(FLT_MIN) ? hh : (dirL)(FLT_MIN);
    const dirL y = q * q / hm;
    return y < (dirL)(1.0f) ? y : (dirL)(1.0f);
}

/* Blinn-Phong with a half vector constant per light (blinn_delta_const_h):
 * (n·h)² where n·h > 0, else 0; 0 where h is undefined (h.w ≠ 0). */
inline dirL blinn_cos_sq_const_h(dirL nx, dirL ny, dirL nz, float4 h, float4 h_lo)
{
    if (h.w != 0.0f)
        return (dirL)(0.0f);
    const dirL x = MUL_ADD(nx, HI_LO(h.x, h_lo.x), MUL_ADD(ny, HI_LO(h.y, h_lo.y), nz * HI_LO(h.z, h_lo.z)));
    return SELECT_DIR((dirL)(0.0f), x * x, x > (dirL)(0.0f));
}
#endif

#if SPEC_INT_POW
/* x^K for x ≥ 0 (the callers clamp: phong_cos, blinn_cos_sq, 1 − δ) and a whole
 * exponent K ≤ 65536 (the plan's SPEC_INT_POW), by binary powering in double
 * (in float with POW_FP32, the fast path), then converted once to the weights'
 * type: ⌊log2 K⌋ squarings, and one product per set bit but bit 0 (for an even
 * K the first is 1·x^(2^j)): int_pow_multiplies of clphong/device/plan.py. They
 * add at most ~K·2⁻⁵³ relative (~K·u in float); an absolute error e of x becomes
 * K·e/x relative.
 * Guards: K = 0 gives 1 (0⁰ := 1); a NaN x (NaN inputs under the "pass"
 * policy) gives NaN, for K = 0 too (a uniform branch: K is the same for every
 * work-item; a comparison, not isnan, which PoCL 3.0 calls out of line). No
 * clamp or select per light otherwise: 1.06× on the bench scene. */
inline wL specular_power_cos(powL x, uint K)
{
    if (K == 0u)
        return POW_TO_W(SELECT_DIR((powL)(1.0f), x, x != x));
    powL s = (K & 1u) ? x : (powL)(1.0f);
    powL b = x;
    for (uint e = K >> 1; e != 0u; e >>= 1) {
        b *= b;
        if (e & 1u)
            s *= b;
    }
    return POW_TO_W(s);
}

/* max(1 − δ, 0)^K: specular_power_cos of x = 1 − δ, in double (in float with
 * POW_FP32: 1 − δ then errs by u, the products by ~K·u; docs/error-model.md).
 * δ ≥ 0 is exact in double (from float, or dirL already), and so is 1 − δ to
 * within 2⁻⁵³. The result therefore errs by one rounding (u to float, 2⁻⁵³ with
 * WEIGHTS_FP64) plus K·|Δδ|/(1 − δ) from δ
 * itself: the exp/log1p form's bound without its ulps and without its
 * 4u·|k·log1p(−δ)| (the rounding of y = k·log1p(−δ) before exp), at the cost of
 * ~2·log2(K) double multiplies instead of two out-of-line builtins
 * (docs/error-model.md).
 * Guards, as specular_power: δ ≥ 1 gives x = 0, so 0 for K > 0; K = 0 gives 1;
 * a NaN δ gives NaN (NaN ≥ 1 is false, so x = 1 − NaN). */
inline wL specular_power_int(dirL delta, uint K)
{
    const powL d = TO_POW(delta);
    return specular_power_cos(SELECT_DIR((powL)(1.0f) - d, (powL)(0.0f), d >= (powL)(1.0f)), K);
}
#endif

#endif /* CLPHONG_BRDF_H */

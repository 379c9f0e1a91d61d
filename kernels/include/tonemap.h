/* clphong tone mapping: scene-linear working-space RGB -> display RGB.
 *
 * Mirrored by the float64 reference (clphong/reference/tonemap.py: same names,
 * same order of operations, same guards); its error model (error_bound there)
 * is the tolerance of every test of this file.
 *
 * Defines (chosen by the host's plan, clphong/device/plan.py, from
 * DisplayTransform.defines in clphong/device/display.py, which also builds
 * tonemap_apply.cl with them):
 *   DISPLAY_OUT       1: the entry point also stores display RGB (`display` planes)
 *   TONEMAP           operator ID, Filament style (the TONEMAP_* values below)
 *   DISPLAY_MATRIX    1: convert working-space RGB to Rec.709 primaries with the
 *                     host's 3x3 matrix (ACEScg working space); 0: identity
 *   DISPLAY_ENCODING  0: display-linear Rec.709; 1: sRGB (IEC 61966-2-1) encoded
 *
 * The pipeline, per pixel (display_transform):
 *   c = exposure·c               exposure = 2^EV, applied before tone mapping
 *   c = M·c                      working space -> Rec.709 (DISPLAY_MATRIX)
 *   c = max(c, 0)                every operator is defined on [0, inf); negative
 *                                values only come from out-of-gamut colours of M
 *   c = tonemap_<op>(c)          display-linear Rec.709 in [0, 1]
 *   c = encode_srgb(c)           (DISPLAY_ENCODING == 1)
 * Every published operator below is defined on linear Rec.709/sRGB input,
 * which is why M comes first.
 */
#ifndef CLPHONG_TONEMAP_H
#define CLPHONG_TONEMAP_H
#include "lanes.h"

#define TONEMAP_NONE              0
#define TONEMAP_REINHARD          1
#define TONEMAP_REINHARD_EXTENDED 2
#define TONEMAP_HABLE             3
#define TONEMAP_ACES_HILL         4
#define TONEMAP_AGX               5
#define TONEMAP_PBR_NEUTRAL       6

#ifndef DISPLAY_OUT
#error "DISPLAY_OUT must be set by the shading plan (clphong/device/plan.py)"
#endif
#if DISPLAY_OUT
#ifndef TONEMAP
#error "TONEMAP must be set by the shading plan (clphong/device/plan.py) with DISPLAY_OUT"
#endif
#ifndef DISPLAY_MATRIX
#error "DISPLAY_MATRIX must be set by the shading plan (clphong/device/plan.py) with DISPLAY_OUT"
#endif
#ifndef DISPLAY_ENCODING
#error "DISPLAY_ENCODING must be set by the shading plan (clphong/device/plan.py) with DISPLAY_OUT"
#endif
#else
/* DISPLAY_OUT = 0: the plan sets no operator (clphong/device/plan.py puts
   DISPLAY_OUT alone), and no entry point calls display_store, which is compiled
   but never run: these values (none, no matrix, sRGB) only let it compile. */
#ifndef TONEMAP
#define TONEMAP TONEMAP_NONE
#endif
#ifndef DISPLAY_MATRIX
#define DISPLAY_MATRIX 0
#endif
#ifndef DISPLAY_ENCODING
#define DISPLAY_ENCODING 1
#endif
#endif

typedef struct { floatL r, g, b; } rgbL;

inline rgbL make_rgbL(floatL r, floatL g, floatL b)
{
    rgbL c;
    c.r = r; c.g = g; c.b = b;
    return c;
}

/* Row-major 3x3 matrix (rows m0, m1, m2; .w unused) times c. */
inline rgbL mat3_apply(const float4 m0, const float4 m1, const float4 m2, const rgbL c)
{
    return make_rgbL(MUL_ADD(m0.x, c.r, MUL_ADD(m0.y, c.g, m0.z * c.b)),
                     MUL_ADD(m1.x, c.r, MUL_ADD(m1.y, c.g, m1.z * c.b)),
                     MUL_ADD(m2.x, c.r, MUL_ADD(m2.y, c.g, m2.z * c.b)));
}

inline floatL clamp01(floatL x)
{
    return fmin(fmax(x, (floatL)(0.0f)), (floatL)(1.0f));
}

/* ---------------------------------------------------------------- operators
 * Each takes display-bound linear Rec.709 RGB >= 0 and returns display-linear
 * Rec.709 RGB (clamped to [0, 1] by display_transform when it is not already).
 */

/* none: clip to the display range [0, 1] (what oiiotool --colorconvert and
 * Blender's "Standard" view do). */
inline rgbL tonemap_none(const rgbL c)
{
    return make_rgbL(clamp01(c.r), clamp01(c.g), clamp01(c.b));
}

/* Reinhard, Stark, Shirley, Ferwerda 2002, "Photographic Tone Reproduction for
 * Digital Images", eq. 3: L_d = L/(1 + L), applied per channel (as three.js
 * ReinhardToneMapping does) rather than to luminance. */
inline floatL reinhard_curve(floatL x)
{
    return x / (1.0f + x);
}

inline rgbL tonemap_reinhard(const rgbL c)
{
    return make_rgbL(reinhard_curve(c.r), reinhard_curve(c.g), reinhard_curve(c.b));
}

/* Reinhard et al. 2002, eq. 4: L_d = L·(1 + L/L_white²)/(1 + L), per channel;
 * L_white (the smallest value mapped to 1) is the white point; inv_white2 =
 * 1/L_white² is computed on the host. Values above L_white exceed 1 and clip. */
inline floatL reinhard_extended_curve(floatL x, float inv_white2)
{
    return x * MUL_ADD(x, inv_white2, 1.0f) / (1.0f + x);
}

inline rgbL tonemap_reinhard_extended(const rgbL c, float inv_white2)
{
    return make_rgbL(clamp01(reinhard_extended_curve(c.r, inv_white2)),
                     clamp01(reinhard_extended_curve(c.g, inv_white2)),
                     clamp01(reinhard_extended_curve(c.b, inv_white2)));
}

/* Hable 2010, "Uncharted 2: HDR Lighting" (GDC) and "Filmic Tonemapping
 * Operators" (filmicworlds.com, 2010): the filmic curve
 *   f(x) = (x(Ax + CB) + DE)/(x(Ax + B) + DF) − E/F
 * with A = 0.15 (shoulder strength), B = 0.50 (linear strength), C = 0.10
 * (linear angle), D = 0.20 (toe strength), E = 0.02, F = 0.30 (toe numerator
 * and denominator), the published exposure bias 2, and white scale 1/f(W)
 * (W = 11.2 published; host-computed). */
inline floatL hable_partial(floatL x)
{
    const float A = 0.15f, B = 0.50f, C = 0.10f, D = 0.20f, E = 0.02f, F = 0.30f;
    return MUL_ADD(x, MUL_ADD(A, x, C * B), D * E) / MUL_ADD(x, MUL_ADD(A, x, B), D * F) - E / F;
}

inline rgbL tonemap_hable(const rgbL c, float white_scale)
{
    const float exposure_bias = 2.0f;
    return make_rgbL(clamp01(hable_partial(exposure_bias * c.r) * white_scale),
                     clamp01(hable_partial(exposure_bias * c.g) * white_scale),
                     clamp01(hable_partial(exposure_bias * c.b) * white_scale));
}

/* ACES filmic, Stephen Hill's fit (MJP's BakingLab, ACES.hlsl, 2016): the
 * sRGB -> XYZ -> D65_2_D60 -> AP1 -> RRT_SAT input matrix, the RRT+ODT
 * rational fit, the ODT_SAT -> XYZ -> D60_2_D65 -> sRGB output matrix, clamp. */
inline floatL aces_hill_rrt_odt_fit(floatL v)
{
    const floatL a = MUL_ADD(v, v + 0.0245786f, -0.000090537f);
    const floatL b = MUL_ADD(v, MUL_ADD(0.983729f, v, 0.4329510f), 0.238081f);
    return a / b;
}

inline rgbL tonemap_aces_hill(const rgbL c)
{
    const float4 in0 = (float4)(0.59719f, 0.35458f, 0.04823f, 0.0f);
    const float4 in1 = (float4)(0.07600f, 0.90834f, 0.01566f, 0.0f);
    const float4 in2 = (float4)(0.02840f, 0.13383f, 0.83777f, 0.0f);
    const float4 out0 = (float4)(1.60475f, -0.53108f, -0.07367f, 0.0f);
    const float4 out1 = (float4)(-0.10208f, 1.10813f, -0.00605f, 0.0f);
    const float4 out2 = (float4)(-0.00327f, -0.07276f, 1.07602f, 0.0f);
    rgbL v = mat3_apply(in0, in1, in2, c);
    v = make_rgbL(aces_hill_rrt_odt_fit(v.r), aces_hill_rrt_odt_fit(v.g), aces_hill_rrt_odt_fit(v.b));
    v = mat3_apply(out0, out1, out2, v);
    return make_rgbL(clamp01(v.r), clamp01(v.g), clamp01(v.b));
}

/* AgX, Benjamin Wrensch's minimal analytic fit ("Minimal AgX Implementation",
 * iolite-engine.com/blog_posts/minimal_agx_implementation, 2024; MIT): the
 * Rec.709 inset matrix, log2 encoding over [−12.47393, 4.026069] EV, the 6th
 * order polynomial fit of the AgX base contrast sigmoid (mean error² 3.67e-6),
 * the outset (inverse inset) matrix, and the blog's agxEotf linearisation
 * pow(·, 2.2), so the result is display-linear like every other operator. */
inline floatL agx_contrast_approx(floatL x)
{
    const floatL x2 = x * x;
    const floatL x4 = x2 * x2;
    return 15.5f * x4 * x2 - 40.14f * x4 * x + 31.96f * x4 - 6.868f * x2 * x
           + 0.4298f * x2 + 0.1191f * x - 0.00232f;
}

inline floatL agx_log_encode(floatL x)
{
    const float min_ev = -12.47393f, max_ev = 4.026069f;
    /* Guard: log2(0) = −inf (and NaN below 0, which the inset of values >= 0
     * never gives); 1e-10 is far below 2^min_ev = 1.7e-4, so it clamps the same. */
    const floatL ev = clamp(log2(fmax(x, (floatL)(1e-10f))), min_ev, max_ev);
    return (ev - min_ev) / (max_ev - min_ev);
}

inline floatL agx_linearize(floatL x)
{
    /* Guard: the outset matrix has negative entries, so a saturated colour can
     * give a slightly negative value, where pow is undefined: 0 is its clip. */
    return pow(fmax(x, (floatL)(0.0f)), (floatL)(2.2f));
}

inline rgbL tonemap_agx(const rgbL c)
{
    const float4 in0 = (float4)(0.842479062253094f, 0.0784335999999992f, 0.0792237451477643f, 0.0f);
    const float4 in1 = (float4)(0.0423282422610123f, 0.878468636469772f, 0.0791661274605434f, 0.0f);
    const float4 in2 = (float4)(0.0423756549057051f, 0.0784336f, 0.879142973793104f, 0.0f);
    const float4 out0 = (float4)(1.19687900512017f, -0.0980208811401368f, -0.0990297440797205f, 0.0f);
    const float4 out1 = (float4)(-0.0528968517574562f, 1.15190312990417f, -0.0989611768448433f, 0.0f);
    const float4 out2 = (float4)(-0.0529716355144438f, -0.0980434501171241f, 1.15107367264116f, 0.0f);
    rgbL v = mat3_apply(in0, in1, in2, c);
    v = make_rgbL(agx_contrast_approx(agx_log_encode(v.r)),
                  agx_contrast_approx(agx_log_encode(v.g)),
                  agx_contrast_approx(agx_log_encode(v.b)));
    v = mat3_apply(out0, out1, out2, v);
    return make_rgbL(clamp01(agx_linearize(v.r)), clamp01(agx_linearize(v.g)),
                     clamp01(agx_linearize(v.b)));
}

/* Khronos PBR Neutral (KhronosGroup/ToneMapping, PBR_Neutral/README.md, 2024),
 * the exact published formula: a Fresnel offset (x − 6.25x² below 0.08, else
 * 0.04), the identity up to startCompression = 0.8 − 0.04, then a rational
 * shoulder newPeak = 1 − d²/(peak + d − startCompression) and a desaturation
 * towards newPeak with g = 1 − 1/(0.15·(peak − newPeak) + 1). */
inline rgbL tonemap_pbr_neutral(const rgbL c)
{
    const float start_compression = 0.8f - 0.04f;
    const float desaturation = 0.15f;
    const float d = 1.0f - start_compression;
    const floatL x = fmin(c.r, fmin(c.g, c.b));
    const floatL offset = select((floatL)(0.04f), x - 6.25f * x * x, (intL)(x < 0.08f));
    const floatL r = c.r - offset, g = c.g - offset, b = c.b - offset;
    const floatL peak = fmax(r, fmax(g, b));
    const floatL new_peak = 1.0f - d * d / (peak + d - start_compression);
    /* Guard: below the compression start the formula returns c − offset; the
     * selects below keep that exactly (and avoid 0/0 for a black pixel). */
    const intL compress = (intL)(peak >= start_compression);
    const floatL scale = select((floatL)(1.0f), new_peak / peak, compress);
    const floatL mix_g = select((floatL)(0.0f),
                                1.0f - 1.0f / MUL_ADD(desaturation, peak - new_peak, 1.0f), compress);
    /* mix(a, b, t) = a + (b − a)·t */
    const floatL rs = r * scale, gs = g * scale, bs = b * scale;
    return make_rgbL(clamp01(MUL_ADD(new_peak - rs, mix_g, rs)),
                     clamp01(MUL_ADD(new_peak - gs, mix_g, gs)),
                     clamp01(MUL_ADD(new_peak - bs, mix_g, bs)));
}

/* ---------------------------------------------------------------- encoding */

/* IEC 61966-2-1:1999 sRGB inverse EOTF (piecewise): 12.92·x at and below
 * 0.0031308, else 1.055·x^(1/2.4) − 0.055; x^(1/2.4) as exp2(log2(x)/2.4),
 * 3 ulp each in OpenCL 1.2 instead of pow's 16. */
inline floatL encode_srgb(floatL x)
{
    const floatL lo = 12.92f * x;
    /* Guard: log2 only of the upper branch's domain, so no log2(0) = −inf. */
    const floatL xh = fmax(x, (floatL)(0.0031308f));
    const floatL hi = MUL_ADD(1.055f, exp2(log2(xh) * (1.0f / 2.4f)), -0.055f);
    return select(hi, lo, (intL)(x <= 0.0031308f));
}

/* ---------------------------------------------------------------- pipeline */

#define DISPLAY_SATURATE 16777216.0f   /* 2^24 */

inline floatL display_clip(floatL x)
{
    return fmin(fmax(x, (floatL)(0.0f)), (floatL)(DISPLAY_SATURATE));
}

/* params: x = inv_white2 (reinhard-extended) or white_scale (hable); m0..m2:
 * working space -> Rec.709 (rows), used with DISPLAY_MATRIX. */
inline rgbL display_transform(rgbL c, const float exposure, const float4 params,
                              const float4 m0, const float4 m1, const float4 m2)
{
    c = make_rgbL(c.r * exposure, c.g * exposure, c.b * exposure);
#if DISPLAY_MATRIX
    c = mat3_apply(m0, m1, m2, c);
#endif
    /* Guard: [0, 2^24]. Every operator is saturated long before 2^24 (Reinhard's
     * x/(1 + x) within 2^-24 of 1), and above it x² in the ACES fit and Hable
     * overflows (inf/inf = NaN, shown black); +inf (an overflowed sum) shows white. */
    c = make_rgbL(display_clip(c.r), display_clip(c.g), display_clip(c.b));
#if TONEMAP == TONEMAP_NONE
    c = tonemap_none(c);
#elif TONEMAP == TONEMAP_REINHARD
    c = tonemap_reinhard(c);
#elif TONEMAP == TONEMAP_REINHARD_EXTENDED
    c = tonemap_reinhard_extended(c, params.x);
#elif TONEMAP == TONEMAP_HABLE
    c = tonemap_hable(c, params.x);
#elif TONEMAP == TONEMAP_ACES_HILL
    c = tonemap_aces_hill(c);
#elif TONEMAP == TONEMAP_AGX
    c = tonemap_agx(c);
#elif TONEMAP == TONEMAP_PBR_NEUTRAL
    c = tonemap_pbr_neutral(c);
#else
#error "unknown TONEMAP operator ID"
#endif
#if DISPLAY_ENCODING == 1
    c = make_rgbL(encode_srgb(c.r), encode_srgb(c.g), encode_srgb(c.b));
#endif
    return c;
}

/* Store the display RGB of LANES pixels at work-item i (planar R G B). */
inline void display_store(const floatL r, const floatL g, const floatL b, const size_t i,
                          __global float *restrict display, const uint stride,
                          const float exposure, const float4 params,
                          const float4 m0, const float4 m1, const float4 m2)
{
    const rgbL c = display_transform(make_rgbL(r, g, b), exposure, params, m0, m1, m2);
    vstoreL(c.r, i, display + 0 * stride);
    vstoreL(c.g, i, display + 1 * stride);
    vstoreL(c.b, i, display + 2 * stride);
}

#endif /* CLPHONG_TONEMAP_H */

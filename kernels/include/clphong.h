/* clphong device code: the shading kernels' number formats and light records.
 *
 * The shading kernels (shade.cl, shade_obvious.cl) and their includes are
 * specialised only with -D defines chosen by the host's shading plan
 * (clphong/device/plan.py). Each is checked by the header that reads it, which
 * refuses to compile without it (#error, no silent default):
 *
 *   lanes.h     LANES: pixels per work-item
 *   plan.h      MODEL_BLINN … CULL_TILE: what the scene needs (model, lights, maps,
 *               culling)
 *   tonemap.h   DISPLAY_OUT …: the fused display output
 *   clphong.h   (this header) the number formats:
 *
 *   DIRECTIONS_FP64  positions, directions, n·l and δ in double (the accurate default
 *                    where the device has cl_khr_fp64); 0: in float (only the integer
 *                    specular power below may still run in double)
 *   SUM_FP64         the light sum in double, rounded once (devices with fast double);
 *                    0: COMPENSATED_SUM decides (Neumaier or naive, in float)
 *   SPEC_INT_POW     the specular exponent k (h, or 4h for Blinn) is one whole number
 *                    K ≤ 65536 for every pixel: x^K by binary powering in double
 *                    (needs cl_khr_fp64) instead of exp(k·log1p(−δ))
 *   SPEC_K           with SPEC_INT_POW: K itself, so the powering unrolls (no branch
 *                    per bit of a run-time exponent)
 *   SPEC_COS         with SPEC_INT_POW and DIRECTIONS_FP64: the power's base is the
 *                    cosine itself, formed in double (Phong r·v = 2(n·l)(n·v) − l·v;
 *                    Blinn (n·h)² = (n·l + n·v)²/|l + v|², raised to K/2, K even)
 *                    instead of 1 − δ with δ = |r − v|²/2 or |n − h|²/2 (brdf.h)
 *   POW_FP32         with SPEC_INT_POW and float directions (the "fast" path): the
 *                    binary powering in float, not double (relative error ~2K·u)
 *   WEIGHTS_FP64     with DIRECTIONS_FP64 and SUM_FP64: the weights, the falloff and
 *                    each light's product L·att·(D·w_d + S·w_s) in double, added to
 *                    the double sum: nothing is rounded to float before the result
 *
 * shade_obvious.cl is all float: it sets these (and LANES, CULLING) itself.
 *
 * Names follow the notes (../shared/phong-model-notes.txt): NoL, RoV, NoH, k_a,
 * k_d, k_s, h, c0, c1, c2, C_d, C_s. Every function here is mirrored by the
 * float64 reference (clphong/reference/), with the same names and the same
 * guards.
 */
#ifndef CLPHONG_H
#define CLPHONG_H
#include "lanes.h"

#ifndef DIRECTIONS_FP64
#error "DIRECTIONS_FP64 must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef SUM_FP64
#error "SUM_FP64 must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef SPEC_INT_POW
#error "SPEC_INT_POW must be set by the shading plan (clphong/device/plan.py)"
#endif
#if SPEC_INT_POW && !defined(SPEC_K)
#error "SPEC_K must be set by the shading plan (clphong/device/plan.py) with SPEC_INT_POW"
#endif
#ifndef SPEC_COS
#error "SPEC_COS must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef POW_FP32
#error "POW_FP32 must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef WEIGHTS_FP64
#error "WEIGHTS_FP64 must be set by the shading plan (clphong/device/plan.py)"
#endif
#if POW_FP32 && !(SPEC_INT_POW && !DIRECTIONS_FP64)
#error "POW_FP32 needs SPEC_INT_POW and float directions"
#endif
#if SPEC_COS && !(SPEC_INT_POW && (DIRECTIONS_FP64 || POW_FP32))
#error "SPEC_COS needs SPEC_INT_POW, and DIRECTIONS_FP64 or POW_FP32"
#endif
#if WEIGHTS_FP64 && !(DIRECTIONS_FP64 && SUM_FP64)
#error "WEIGHTS_FP64 needs DIRECTIONS_FP64 and SUM_FP64"
#endif

/* doubleL: LANES doubles, for whatever the plan computes in double
 * (DIRECTIONS_FP64, SPEC_INT_POW, SUM_FP64); longL its same-size integers. */
#if DIRECTIONS_FP64 || (SPEC_INT_POW && !POW_FP32) || SUM_FP64
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#if LANES == 16
typedef double16 doubleL;
typedef long16 longL;
#define TO_DOUBLE(x) convert_double16(x)
#define DOUBLE_TO_FLOAT(x) convert_float16(x)
#define AS_DOUBLE_L(x) as_double16(x)
#define AS_LONG_L(x) as_long16(x)
#elif LANES == 8
typedef double8 doubleL;
typedef long8 longL;
#define TO_DOUBLE(x) convert_double8(x)
#define DOUBLE_TO_FLOAT(x) convert_float8(x)
#define AS_DOUBLE_L(x) as_double8(x)
#define AS_LONG_L(x) as_long8(x)
#elif LANES == 4
typedef double4 doubleL;
typedef long4 longL;
#define TO_DOUBLE(x) convert_double4(x)
#define DOUBLE_TO_FLOAT(x) convert_float4(x)
#define AS_DOUBLE_L(x) as_double4(x)
#define AS_LONG_L(x) as_long4(x)
#else
typedef double doubleL;
typedef long longL;
#define TO_DOUBLE(x) ((double)(x))
#define DOUBLE_TO_FLOAT(x) ((float)(x))
#define AS_DOUBLE_L(x) as_double(x)
#define AS_LONG_L(x) as_long(x)
#endif
#endif

/* dirL: the type of positions, directions, n·l and δ (and dirS its scalar).
 * float32 directions carry a rounding of ~u each; through n·l near grazing
 * and through δ into x^k (condition number k) that becomes a relative error far
 * above u (docs/error-model.md). With DIRECTIONS_FP64 they are computed in double
 * from the float32 inputs, hi+lo float pairs from the host (normal, eye,
 * directional lights) and the point lights' float64 records, and only n·l, δ
 * (for exp/log1p; the integer power takes δ in double) and att·L are rounded to
 * float, or nothing at all before the sum with WEIGHTS_FP64: the error of every
 * term is then a few u, relative.
 * HI_LO(hi, lo): a host float64 value sent as float hi + lo, in dirS (hi alone
 * in float). */
#if DIRECTIONS_FP64
typedef double dirS;
typedef doubleL dirL;
#define TO_FLOAT(x) DOUBLE_TO_FLOAT(x)
#define TO_DIR(x) TO_DOUBLE(x)
#define HI_LO(hi, lo) ((dirS)(hi) + (dirS)(lo))
#else
typedef float dirS;
typedef floatL dirL;
#define TO_FLOAT(x) (x)
#define TO_DIR(x) (x)
#define HI_LO(hi, lo) (hi)
#endif

/* RSQRT_DIR(x): 1/√x for dirL, x > 0 (callers select their own value for 0).
 * In double, PoCL 3.0 calls rsqrt out of line as a square root and a division
 * on every 4-lane half; inline, four Newton steps y·(1.5 − x/2·y²) from the
 * exponent-halving first guess (magic constant 0x5FE6EB50C7B537A9, relative
 * error ≤ 3.4e-2) reach ≤ 2.5 double ulp: measured 2.44·2⁻⁵³ over x = 1e-90 ..
 * 1e90 and 10⁶ random x in [0.5, 4] against long double (steps 1-4: 1.8e-3,
 * 4.6e-6, 3.2e-11, 2.7e-16), far inside the 2⁻⁴⁷ unit of the fp64 error model.
 * x = 0 gives +inf, as rsqrt does.
 * The lights loop ran 1.12× faster (bench scene, 16 lanes).
 * In float, likewise (PoCL 3.0 calls the float rsqrt out of line too): three
 * Newton steps from 0x5F375A86 (relative error ≤ 1.8e-3 after one step, 4.6e-6
 * after two, 3.2e-11 after three, then float rounding) stay within the
 * builtin's 2 ulp that the error model assumes (1.92 ulp measured, tested
 * exhaustively on [1, 4), which covers every float x ≥ 2·FLT_MIN: a factor 4 in
 * x moves the guess and each step by exactly ½); the float path's lights loop
 * ran 1.06× faster. Its limits:
 *  - below 2·FLT_MIN, h = x/2 flushes to 0 (-cl-denorms-are-zero) and the
 *    result is 3.3–3.5× too large: its one use, Blinn's |l + v|² < 2.4e-38,
 *    then gives |n − h| > 2, so δ > 1 and no highlight, where the bound already
 *    allows the whole term;
 *  - x = +∞ gives −∞, not 0, and a guard for it cost 12 % of the float path's
 *    lights loop (PoCL 3.0, any form of it): so the float RSQRT_DIR takes finite
 *    x only (Blinn's |l + v|² ≤ 4, once per light); RSQRT_DIST, for squared
 *    distances that overflow float beyond ≈ 1.8e19 (to the eye, once per pixel,
 *    and to a light with double directions), adds the guards (rsqrt_dist); the
 *    float lights loop caps its d²/16 instead (RSQRT_LIGHT). */
/* The first guess: the hardware's 14-bit estimate where the target has one
 * (AVX-512 vrsqrt14pd/ps, relative error ≤ 2⁻¹⁴, through clang's target
 * builtins: there is no OpenCL C builtin for it, and PoCL's native_rsqrt is the
 * full-precision one), so two Newton steps reach double (2⁻¹⁴ → 5.6e-9 → 5e-17)
 * and one reaches float (5.6e-9 ≪ 2⁻²⁴); AVX's 12-bit vrsqrtps (≤ 1.5·2⁻¹²)
 * takes two in float. Elsewhere the exponent-halving guesses above, with four
 * steps in double and three in float. Each step costs ~12 cycles of latency
 * on the lights loop's critical path. */
/* RSQRT_BUILTIN (the plan's, clphong/device/plan.py): the OpenCL C builtin rsqrt, within
 * the specification's 2 ulp in float and double, where the platform's is faster than the
 * steps below (Intel's CPU runtime: an SVML call, __ocl_svml_z0_rsqrt16 in double, still
 * 1.5-2x the lights loop of the steps, whose AVX-512 guess Intel's target-independent
 * front end cannot select; in float RSQRT_NATIVE below does better where measured);
 * PoCL 3.0 calls it out of line too, and there the inline steps below win. */
/* RSQRT_NATIVE (the plan's, float directions only): the first guess is native_rsqrt,
 * whose accuracy OpenCL leaves to the implementation, then one Newton step: the plan
 * sets it only where the self-test measured this guess and step within 2 ulp over every
 * float of [1, 4), the bottom binade and a spread to FLT_MAX (clphong/device/peak.py
 * measure_native_rsqrt_ulp). Intel's CPU runtime inlines native_rsqrt as the hardware
 * estimate (AVX-512 vrsqrt14ps, ≤ 2⁻¹⁴), where its builtin rsqrt is an out-of-line
 * call that spills every vector register: the fast path's lights loop ran 1.06x
 * faster (Zen 5). The guards of rsqrt_dist apply, as to every inline guess. */
#if defined(RSQRT_NATIVE) && RSQRT_NATIVE && !DIRECTIONS_FP64 && !defined(RSQRT_GUESS_KIND)
#define RSQRT_GUESS_KIND 4
#endif
#if defined(RSQRT_BUILTIN) && RSQRT_BUILTIN && !defined(RSQRT_GUESS_KIND)
#define RSQRT_GUESS_KIND 3
#endif
#ifndef RSQRT_GUESS_KIND   /* 0: portable, 1: AVX vrsqrtps, 2: AVX-512 vrsqrt14, 3: the builtin,
                              4: native_rsqrt and one step (float); a test may set it */
#if defined(__AVX512F__) && (LANES == 16 || (LANES == 8 && DIRECTIONS_FP64))
#define RSQRT_GUESS_KIND 2
#elif defined(__AVX__) && !DIRECTIONS_FP64 && (LANES == 16 || LANES == 8)
#define RSQRT_GUESS_KIND 1
#else
#define RSQRT_GUESS_KIND 0
#endif
#endif
#if RSQRT_GUESS_KIND == 3
/* the OpenCL C builtin itself (2 ulp by the specification, in float and double) */
#define RSQRT_STEPS 0
#elif RSQRT_GUESS_KIND == 2 && DIRECTIONS_FP64 && LANES == 16
#define RSQRT_GUESS(x) ((dirL)(__builtin_ia32_rsqrt14pd512_mask((x).lo, (double8)(0.0), (uchar)0xFF), \
                               __builtin_ia32_rsqrt14pd512_mask((x).hi, (double8)(0.0), (uchar)0xFF)))
#define RSQRT_STEPS 2
#elif RSQRT_GUESS_KIND == 2 && DIRECTIONS_FP64 && LANES == 8
#define RSQRT_GUESS(x) __builtin_ia32_rsqrt14pd512_mask((x), (double8)(0.0), (uchar)0xFF)
#define RSQRT_STEPS 2
#elif RSQRT_GUESS_KIND == 2 && !DIRECTIONS_FP64 && LANES == 16
#define RSQRT_GUESS(x) __builtin_ia32_rsqrt14ps512_mask((x), (float16)(0.0f), (ushort)0xFFFF)
#define RSQRT_STEPS 1
#elif RSQRT_GUESS_KIND == 1 && !DIRECTIONS_FP64 && LANES == 16
#define RSQRT_GUESS(x) ((dirL)(__builtin_ia32_rsqrtps256((x).lo), __builtin_ia32_rsqrtps256((x).hi)))
#define RSQRT_STEPS 2
#elif RSQRT_GUESS_KIND == 1 && !DIRECTIONS_FP64 && LANES == 8
#define RSQRT_GUESS(x) __builtin_ia32_rsqrtps256(x)
#define RSQRT_STEPS 2
#elif RSQRT_GUESS_KIND == 4 && !DIRECTIONS_FP64
#define RSQRT_GUESS(x) native_rsqrt(x)
#define RSQRT_STEPS 1
#elif RSQRT_GUESS_KIND == 0 && DIRECTIONS_FP64
#define RSQRT_GUESS(x) AS_DOUBLE_L((longL)(0x5FE6EB50C7B537A9L) - (AS_LONG_L(x) >> 1))
#define RSQRT_STEPS 4
#elif RSQRT_GUESS_KIND == 0
#define RSQRT_GUESS(x) AS_FLOAT_L((intL)(0x5F375A86) - (AS_INT_L(x) >> 1))
#define RSQRT_STEPS 3
#else
#error "RSQRT_GUESS_KIND does not fit this LANES and number format"
#endif

#if DIRECTIONS_FP64
#define NEWTON_RSQRT(y, h) ((y) * (1.5 - (h) * (y) * (y)))
#else
#define NEWTON_RSQRT(y, h) ((y) * (1.5f - (h) * (y) * (y)))
#endif

#if RSQRT_GUESS_KIND == 3
/* the builtin (in float, for x < 2^124 only on some platforms: see rsqrt_dist below) */
inline dirL rsqrt_dir(dirL x) { return rsqrt(x); }
#elif RSQRT_GUESS_KIND == 4
/* native_rsqrt's guess y and one Newton step written as y + (y/2)·e, e = 1 − (x·y)·y
 * with the bracket in one fused multiply-add: e is small (|e| ≈ 2ε ≤ 7.3e-4 for a
 * 12-bit estimate's relative error ε ≤ 1.5·2⁻¹²), so the step adds a small correction
 * to y and rounds once more; what remains is Newton's own ≈1.5·ε², and about 0.2 ulp
 * from rounding x·y. The textbook (y/2)·(3 − (x·y)·y) also rounds the bracket, ≈ 2, to
 * float, and the product after it: 2.39 ulp against this form's 1.74 over the
 * self-test's probe floats on Zen 3 (Intel's runtime, 12-bit vrsqrtps; at 16, 8, 4 and
 * 1 lanes), 1.53 against 0.87 on PoCL (not measured on Zen 4 or 5). Within the error
 * model's 2 ulp there, so the plan takes it where the textbook form was refused (the
 * fast path 1.23-1.26x the builtin's call, median of 30 frames, three processes,
 * 2026-12-07). x/2 is never formed, so x in [FLT_MIN, 2·FLT_MIN) needs no rescaling in
 * rsqrt_dist (x·y ≈ 2⁻⁶³ there). */
inline dirL rsqrt_dir(dirL x)
{
    /* no guard for 0 (NaN there): RSQRT_DIR's callers select their own value, and
       rsqrt_dist adds rsqrt(0) = +inf, which the shading loop folds into its own
       select for d² = 0; blinn_delta's select for |l + v|² = 0 now stands alone
       (one compare and one blend fewer a light, the pixels' bits unchanged) */
    const dirL y = RSQRT_GUESS(x);
    const dirL e = MUL_ADD(-(x * y), y, (dirL)(1.0f));
    return MUL_ADD((dirL)(0.5f) * y, e, y);
}
#else
/* the guess and its Newton steps, for x > 0 (rsqrt_dir adds the value at 0) */
inline dirL rsqrt_steps(dirL x)
{
    dirL y = RSQRT_GUESS(x);
    const dirL h = 0.5f * x;
    y = NEWTON_RSQRT(y, h);
#if RSQRT_STEPS > 1
    y = NEWTON_RSQRT(y, h);
#endif
#if RSQRT_STEPS > 2
    y = NEWTON_RSQRT(y, h);
#endif
#if RSQRT_STEPS > 3
    y = NEWTON_RSQRT(y, h);
#endif
    return y;
}
inline dirL rsqrt_dir(dirL x)
{
    return x == 0.0f ? (dirL)(INFINITY) : rsqrt_steps(x);   /* as rsqrt(0) = +inf */
}
#define RSQRT_STEPS_ONLY(x) rsqrt_steps(x)
#endif
#define RSQRT_DIR(x) rsqrt_dir(x)
#if DIRECTIONS_FP64
#define RSQRT_DIST(x) rsqrt_dir(x)
#elif RSQRT_GUESS_KIND == 3
/* the builtin has the guards below, but Intel's CPU runtime 2026.2 on an AVX2 host (Zen
   3) returns 2.4e-19 for every x ≥ 2^126 with denormals flushed, at 1, 8 and 16 lanes
   (2e7 ulp; right at 4 lanes): x > 2^125 is scaled by 2^-4 first (exact) and the result
   by 2^-2 (exact), +∞ still gives 0. The self-test measures this form at each width
   (clphong/device/peak.py measure_builtin_rsqrt_ulp) and the plan takes it only within
   2 ulp. RSQRT_DIR's callers pass |l + v|² ≤ 4 only. */
inline dirL rsqrt_dist(dirL x)
{
    const intL huge = x > 0x1p125f;
    const dirL y = rsqrt(SELECT(x, x * 0x1p-4f, huge));
    return SELECT(y, y * 0x1p-2f, huge);
}
#define RSQRT_DIST(x) rsqrt_dist(x)
#else
/* 1/√x for a squared distance in float: rsqrt_dir with the two guards that the
   builtin has and rsqrt_dir lacks. x > FLT_MAX (d ≳ 1.8e19; +∞) gives 0, as
   rsqrt(+∞). x in [FLT_MIN, 2·FLT_MIN), where rsqrt_dir's x/2 flushes to 0, is
   scaled by 2^64 first (exact) and the result by 2^32; below FLT_MIN x is
   already 0 (-cl-denorms-are-zero), which gives +∞ as rsqrt(0). Inline, where
   PoCL 3.0 calls the builtin out of line, spilling every vector register
   around the call, once per light: 1.02-1.07x on the fast path's lights loop. */
#if RSQRT_GUESS_KIND == 4
/* native_rsqrt's step never forms x/2 (rsqrt_dir above): no rescaling; rsqrt_dir leaves
   0 to its callers, so rsqrt(0) = +∞ is selected here */
inline dirL rsqrt_dist(dirL x)
{
    return SELECT(SELECT(rsqrt_dir(x), (dirL)(INFINITY), x == 0.0f), (dirL)(0.0f), x > FLT_MAX);
}
#else
inline dirL rsqrt_dist(dirL x)
{
    const intL tiny = x < 2.0f * FLT_MIN;
    const dirL y = rsqrt_dir(SELECT(x, x * 0x1p64f, tiny));
    return SELECT(SELECT(y, y * 0x1p32f, tiny), (dirL)(0.0f), x > FLT_MAX);
}
#endif
#define RSQRT_DIST(x) rsqrt_dist(x)
#endif

/* RSQRT_LIGHT(x), float directions: the lights loop's 4/√(16x + 2⁻¹²²) for x = d²/16,
 * the squared distance of the quartered positions: the light records come with their
 * positions × 1/4, c1 × 4 and c2 × 16 (clphong/device/frame.py shading_records), and
 * shade.cl quarters the pixel's P − origin. Every scaling is by a power of 2, so l =
 * (Δ/4)·(4/d) and d/4 = (d²/16)·(4/d) carry the bits of Δ·(1/d) and d²·(1/d) unscaled,
 * and Horner's (d/4)·((d/4)·16c2 + 4c1) + c0 those of d·(d·c2 + c1) + c0, where nothing
 * leaves float's normal range; the loop saves the 2⁻² and 2⁻⁴ scalings the builtin
 * needed and every select (docs/bench.md).
 * - The bias 2⁻¹²⁶ (2⁻¹²² on d²) keeps the result finite at x = 0 (l = 0·2⁶³ = 0, no
 *   select) and moves it by ≤ 2⁻²⁷ relative (1/16 ulp) for d² ≥ 2⁻⁹⁶; below that the error
 *   model calls the float path unbounded (D2_FLOOR, docs/error-model.md). There the
 *   inline steps' x/2 may flush (x < 2⁻¹²⁵): their result is off, but finite.
 * - The cap 2¹²⁵ (d ≥ 2⁶⁴·√2, beyond the bounded range d² ≤ FLT_MAX) keeps the input
 *   below Intel's AVX2 fault (the builtin returns 2.4e-19 for x ≥ 2¹²⁶ there, rsqrt_dist
 *   above) and never +∞, so d/4 = x·(4/d) needs no select for ∞·0 either. A frame with a
 *   light that far from a pixel takes POINT_GUARD's selects (lights.h, plan.py), which
 *   give such a light nothing, as before.
 * Double directions keep RSQRT_DIST and the select: their d² never flushes. */
#if !DIRECTIONS_FP64
#define LIGHT_D2_CAP 0x1p125f
#define CAP_LIGHT_D2(x) ((x) < (dirL)(LIGHT_D2_CAP) ? (x) : (dirL)(LIGHT_D2_CAP))
#if RSQRT_GUESS_KIND == 3
#define RSQRT_LIGHT(x) rsqrt(CAP_LIGHT_D2(x) + 0x1p-126f)
#else
#ifndef RSQRT_STEPS_ONLY
#define RSQRT_STEPS_ONLY(x) rsqrt_dir(x)    /* native_rsqrt's step: no select at 0 either */
#endif
#define RSQRT_LIGHT(x) RSQRT_STEPS_ONLY(CAP_LIGHT_D2(x) + 0x1p-126f)
#endif
#endif

/* sumL: the type of the running light sums; double with SUM_FP64. */
#if SUM_FP64
typedef doubleL sumL;
#define TO_SUM(x) TO_DOUBLE(x)
#define SUM_TO_FLOAT(x) DOUBLE_TO_FLOAT(x)
#else
typedef floatL sumL;
#define TO_SUM(x) (x)
#define SUM_TO_FLOAT(x) (x)
#endif

/* wL: the type of the weights, the falloff and each light's product
 * L·att·(D·w_d + S·w_s) (wS its scalar): double with WEIGHTS_FP64, else float.
 * DIR_TO_W, FLOAT_TO_W: from dirL and from floatL. W_HI_LO(hi, lo): a host
 * float64 value sent as float hi + lo, in wS (hi alone in float). */
#if WEIGHTS_FP64
typedef doubleL wL;
typedef double wS;
#define DIR_TO_W(x) (x)
#define FLOAT_TO_W(x) TO_DOUBLE(x)
#define W_HI_LO(hi, lo) ((double)(hi) + (double)(lo))
#else
typedef floatL wL;
typedef float wS;
#define DIR_TO_W(x) TO_FLOAT(x)
#define FLOAT_TO_W(x) (x)
#define W_HI_LO(hi, lo) (hi)
#endif

/* powL: the type of the power's base (1 − δ, or the cosine with SPEC_COS) and of
 * its powers with SPEC_INT_POW (double; from dirL, a conversion to the same type
 * where the directions are in double). POW_TO_W: to the weights' type. */
#if SPEC_INT_POW && POW_FP32
typedef floatL powL;          /* float directions and weights: no conversion */
#define TO_POW(x) (x)
#define POW_TO_W(x) (x)
#elif SPEC_INT_POW
typedef doubleL powL;
#define TO_POW(x) TO_DOUBLE(x)
#if WEIGHTS_FP64
#define POW_TO_W(x) (x)
#else
#define POW_TO_W(x) DOUBLE_TO_FLOAT(x)
#endif
#endif

/* Layout of the light records, written by the host's pack_lights (clphong/device/).
 * Point lights: pointrec_t, double4 with DIRECTIONS_FP64 (the host's float64
 * values as they are: the rebased position, falloff and radiance need no hi+lo
 * pairs and no conversion per work-item; 1.07× on the bench scene), else
 * float4. Directional lights: float4. */
#if DIRECTIONS_FP64
typedef double4 pointrec_t;
#else
typedef float4 pointrec_t;
#endif
/* Point records on the host: (x, y, z, c0) (r, g, b, c1) (c2, ax, ay, az) (s, o, 0, 0)
 * (clphong/device/culling.py POINT_RECORD); the kernels read POINT_LIGHT_FLOAT4S of
 * them (plan.h: 3 without spots). */
#define DIRECTIONAL_LIGHT_FLOAT4S 6 /* (lx, ly, lz, 0) (r, g, b, 0) (hx, hy, hz, undefined)
                                       (l − float(l), 0) (h − float(h), 0)
                                       (radiance − float(radiance), 0) */

#endif /* CLPHONG_H */

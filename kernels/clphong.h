/* clphong device code: common definitions.
 *
 * Every kernel source includes this header. Specialisation is done only with
 * -D defines chosen by the host's shading plan (clphong/plan.py):
 *
 *   LANES            pixels per work-item held in explicit SIMD vectors (1, 4, 8 or 16)
 *   MODEL_BLINN      0: Phong (r·v)^h           1: Blinn-Phong (n·h)^(4h)
 *   HAS_POINT        point lights present (with 1/(c0 + c1·d + c2·d²) falloff)
 *   HAS_DIRECTIONAL  directional lights present (no falloff)
 *   HAS_SPECULAR     k_s > 0 somewhere (uniform or in a map)
 *   CAMERA_ORTHO     viewer at infinity: v is constant
 *   BLINN_CONST_H    orthographic camera + Blinn: each directional light's half vector is
 *                    constant and precomputed on the host (Blinn 1977)
 *   MAP_KD, MAP_KS, MAP_H, MAP_CS   per-pixel material maps present
 *   COMPENSATED_SUM  Neumaier-compensated light sum (error ~2u instead of ~N·u)
 *   HAS_ATTENUATION  some point light has c1 ≠ 0 or c2 ≠ 0; 0: the falloff is 1/c0,
 *                    a constant per light (no distance polynomial, no division per pixel)
 *   CULLING          point lights come from per-tile lists built by cull.cl, whose
 *                    dropped lights sum to at most the user's budget ε (clphong/cull.py)
 *   CULL_TILE        screen tile edge of the lists, pixels (16)
 *   DIRECTIONS_FP64  positions, directions, n·l and δ in double (the accurate default
 *                    where the device has cl_khr_fp64); 0: in float (only the integer
 *                    specular power below may still run in double)
 *   SUM_FP64         the light sum in double, rounded once (devices with fast double);
 *                    0: COMPENSATED_SUM decides (Neumaier or naive, in float)
 *   SPEC_INT_POW     the specular exponent k (h, or 4h for Blinn) is one whole number
 *                    K ≤ 65536 for every pixel: x^K by binary powering in double
 *                    (needs cl_khr_fp64) instead of exp(k·log1p(−δ))
 *   SPEC_COS         with SPEC_INT_POW and DIRECTIONS_FP64: the power's base is the
 *                    cosine itself, formed in double (Phong r·v = 2(n·l)(n·v) − l·v;
 *                    Blinn (n·h)² = (n·l + n·v)²/|l + v|², raised to K/2, K even)
 *                    instead of 1 − δ with δ = |r − v|²/2 or |n − h|²/2 (brdf.cl)
 *   POW_FP32         with SPEC_INT_POW and float directions (the "fast" path): the
 *                    binary powering in float, not double (relative error ~2K·u)
 *   WEIGHTS_FP64     with DIRECTIONS_FP64 and SUM_FP64: the weights, the falloff and
 *                    each light's product L·att·(D·w_d + S·w_s) in double, added to
 *                    the double sum: nothing is rounded to float before the result
 *
 * Names follow the notes (../shared/phong-model-notes.txt): NoL, RoV, NoH, k_a,
 * k_d, k_s, h, c0, c1, c2, C_d, C_s. The float64 mirror of every function here
 * is clphong/reference.py, with the same names and the same guards.
 */
#ifndef CLPHONG_H
#define CLPHONG_H

#ifndef LANES
#define LANES 16
#endif
#ifndef MODEL_BLINN
#define MODEL_BLINN 0
#endif
#ifndef HAS_POINT
#define HAS_POINT 1
#endif
#ifndef HAS_DIRECTIONAL
#define HAS_DIRECTIONAL 1
#endif
#ifndef HAS_SPECULAR
#define HAS_SPECULAR 1
#endif
#ifndef CAMERA_ORTHO
#define CAMERA_ORTHO 0
#endif
#ifndef BLINN_CONST_H
#define BLINN_CONST_H 0
#endif
#ifndef MAP_KD
#define MAP_KD 0
#endif
#ifndef MAP_KS
#define MAP_KS 0
#endif
#ifndef MAP_H
#define MAP_H 0
#endif
#ifndef MAP_CS
#define MAP_CS 0
#endif
#ifndef COMPENSATED_SUM
#define COMPENSATED_SUM 1
#endif
#ifndef HAS_ATTENUATION
#define HAS_ATTENUATION 1
#endif
#ifndef CULLING
#define CULLING 0
#endif
#ifndef CULL_TILE
#define CULL_TILE 16
#endif
#ifndef DIRECTIONS_FP64
#define DIRECTIONS_FP64 0
#endif
#ifndef SPEC_INT_POW
#define SPEC_INT_POW 0
#endif
#ifndef SUM_FP64
#define SUM_FP64 0
#endif
#ifndef SPEC_COS
#define SPEC_COS 0
#endif
#ifndef WEIGHTS_FP64
#define WEIGHTS_FP64 0
#endif
#ifndef POW_FP32
#define POW_FP32 0
#endif
#if POW_FP32 && !(SPEC_INT_POW && !DIRECTIONS_FP64)
#error "POW_FP32 needs SPEC_INT_POW and float directions"
#endif
#if SPEC_COS && !(SPEC_INT_POW && DIRECTIONS_FP64)
#error "SPEC_COS needs SPEC_INT_POW and DIRECTIONS_FP64"
#endif
#if WEIGHTS_FP64 && !(DIRECTIONS_FP64 && SUM_FP64)
#error "WEIGHTS_FP64 needs DIRECTIONS_FP64 and SUM_FP64"
#endif

/* floatL: one value per pixel of the work-item's LANES pixels. PoCL vectorises
 * only the innermost work-item loop, and a per-pixel loop over lights keeps it
 * scalar (POCL-NOTES "Why the vectorisation must be explicit"), so the lanes
 * are explicit vectors across pixels. */
/* vloadL, vstoreL: LANES consecutive floats at p + i·LANES, as vloadN/vstoreN,
 * through a vector type whose alignment is lowered to a float's (clang honours
 * aligned() on a typedef): PoCL 3.0 calls vload16/vstore16 out of line, once
 * per plane and work-item; inline (with finish_sum's copysign gone too) the
 * bench scene's full 1080p frame shaded 1.3× faster with 2 lights (17.9 → 13.8
 * ms) and as fast at N = 256 (the G-buffer planes are numpy's, 16-byte
 * aligned; tested misaligned too). all() stays the builtin: an inline form,
 * with the other two, cost 4 % at N = 256. */
#define LANE_ACCESS(F, I) \
    typedef F __attribute__((aligned(4))) floatL_u; \
    typedef I __attribute__((aligned(4))) intL_u;
#if LANES == 16
typedef float16 floatL;
typedef int16 intL;
#define AS_FLOAT_L(x) as_float16(x)
#define AS_INT_L(x) as_int16(x)
LANE_ACCESS(float16, int16)
#elif LANES == 8
typedef float8 floatL;
typedef int8 intL;
#define AS_FLOAT_L(x) as_float8(x)
#define AS_INT_L(x) as_int8(x)
LANE_ACCESS(float8, int8)
#elif LANES == 4
typedef float4 floatL;
typedef int4 intL;
#define AS_FLOAT_L(x) as_float4(x)
#define AS_INT_L(x) as_int4(x)
LANE_ACCESS(float4, int4)
#elif LANES == 1
typedef float floatL;
typedef int intL;
#define AS_FLOAT_L(x) as_float(x)
#define AS_INT_L(x) as_int(x)
#define vloadL(i, p) ((p)[(i)])
#define vstoreL(v, i, p) ((p)[(i)] = (v))
#else
#error "LANES must be 1, 4, 8 or 16"
#endif
#if LANES > 1
#define vloadL(i, p) (((__global const floatL_u *)(p))[(i)])
#define vstoreL(v, i, p) (((__global floatL_u *)(p))[(i)] = (v))
/* an intL mask into a private int[LANES] */
#define vstoreI(v, p) (*(intL_u *)(p) = (v))
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
 *    x only (Blinn's |l + v|² ≤ 4, once per light), and RSQRT_DIST, for squared
 *    distances (to a light, once per light, and to the eye, once per pixel)
 *    that overflow float beyond ≈ 1.8e19, stays the builtin (rsqrt(+∞) = 0). */
#if DIRECTIONS_FP64
inline dirL rsqrt_dir(dirL x)
{
    dirL y = AS_DOUBLE_L((longL)(0x5FE6EB50C7B537A9L) - (AS_LONG_L(x) >> 1));
    const dirL h = 0.5 * x;
    y = y * (1.5 - h * y * y);
    y = y * (1.5 - h * y * y);
    y = y * (1.5 - h * y * y);
    y = y * (1.5 - h * y * y);
    return x == 0.0 ? (dirL)(INFINITY) : y;   /* as rsqrt(0) = +inf */
}
#else
inline dirL rsqrt_dir(dirL x)
{
    dirL y = AS_FLOAT_L((intL)(0x5F375A86) - (AS_INT_L(x) >> 1));
    const dirL h = 0.5f * x;
    y = y * (1.5f - h * y * y);
    y = y * (1.5f - h * y * y);
    y = y * (1.5f - h * y * y);
    return x == 0.0f ? (dirL)(INFINITY) : y;  /* as rsqrt(0) = +inf */
}
#endif
#define RSQRT_DIR(x) rsqrt_dir(x)
#if DIRECTIONS_FP64
#define RSQRT_DIST(x) rsqrt_dir(x)
#else
#define RSQRT_DIST(x) rsqrt(x)
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

/* SELECT(a, b, c): c ? b : a per lane, as select(a, b, c) for vector masks from
 * comparisons (OpenCL C defines the vector ?: as select). Written as ?: because
 * PoCL 3.0 compiles select, fmax and fabs on 8-lane vectors for znver3 as
 * out-of-line calls with the AVX calling convention: inlined, the light loop ran
 * 1.32× faster, bit-identical (measured: 960×540, 64 point lights, Blinn).
 * MAX0(x) = max(x, 0) (0 for NaN, like fmax(NaN, 0)); ABS(x) = |x| (−0 stays −0,
 * which only feeds comparisons). Also right for scalars (LANES = 1) and for
 * dirL, whatever its mask type. */
#define SELECT(a, b, c) ((c) ? (b) : (a))
/* ALL_LANES(m): every lane of the intL mask m is true (all() for vectors). */
#if LANES == 1
#define ALL_LANES(m) ((m) != 0)
#else
#define ALL_LANES(m) all(m)
#endif
#define SELECT_DIR(a, b, c) SELECT(a, b, c)
#define MAX0(x) ((x) > 0.0f ? (x) : 0.0f)
#define ABS(x) ((x) < 0.0f ? -(x) : (x))

/* a·b + c. Not fma(): PoCL 3.0's LLVM cannot select fma for float16 ("Cannot
 * select: i64 = fma"); OpenCL's default FP_CONTRACT still lets it fuse. */
#define MUL_ADD(a, b, c) ((a) * (b) + (c))

/* Layout of the light records, written by clphong/render.py (pack_lights).
 * Point lights: pointrec_t, double4 with DIRECTIONS_FP64 (the host's float64
 * values as they are: the rebased position, falloff and radiance need no hi+lo
 * pairs and no conversion per work-item; 1.07× on the bench scene), else
 * float4. Directional lights: float4. */
#if DIRECTIONS_FP64
typedef double4 pointrec_t;
#else
typedef float4 pointrec_t;
#endif
#define POINT_LIGHT_FLOAT4S 3       /* (x, y, z, c0) (r, g, b, c1) (c2, 0, 0, 0) */
#define DIRECTIONAL_LIGHT_FLOAT4S 6 /* (lx, ly, lz, 0) (r, g, b, 0) (hx, hy, hz, undefined)
                                       (l − float(l), 0) (h − float(h), 0)
                                       (radiance − float(radiance), 0) */

#endif /* CLPHONG_H */

/* clphong device code: LANES pixels per work-item, as explicit vectors.
 *
 * Every kernel source includes this header (directly, or through clphong.h or
 * tonemap.h). It reads one define, which every host path sets:
 *
 *   LANES            pixels per work-item held in explicit SIMD vectors (1, 4, 8 or 16):
 *                    the shading plan's (clphong/device/plan.py) for shade.cl, the
 *                    culling pass's (clphong/device/culling.py) for cull.cl, the display
 *                    kernel's (clphong/device/display.py) for tonemap_apply.cl, the
 *                    bench's for peak.cl; shade_obvious.cl sets 1 itself
 *
 * It gives the lane types (floatL, intL), their loads and stores, and the
 * inline forms of select, max, abs and a·b + c that every kernel uses.
 */
#ifndef CLPHONG_LANES_H
#define CLPHONG_LANES_H

#ifndef LANES
#error "LANES must be set by the host: the shading plan (clphong/device/plan.py), or the caller of cull.cl, tonemap_apply.cl or peak.cl"
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
#define CONVERT_INT_L(x) convert_int16(x)
LANE_ACCESS(float16, int16)
#elif LANES == 8
typedef float8 floatL;
typedef int8 intL;
#define AS_FLOAT_L(x) as_float8(x)
#define AS_INT_L(x) as_int8(x)
#define CONVERT_INT_L(x) convert_int8(x)
LANE_ACCESS(float8, int8)
#elif LANES == 4
typedef float4 floatL;
typedef int4 intL;
#define AS_FLOAT_L(x) as_float4(x)
#define AS_INT_L(x) as_int4(x)
#define CONVERT_INT_L(x) convert_int4(x)
LANE_ACCESS(float4, int4)
#elif LANES == 1
typedef float floatL;
typedef int intL;
#define AS_FLOAT_L(x) as_float(x)
#define AS_INT_L(x) as_int(x)
#define CONVERT_INT_L(x) ((int)(x))
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

/* SELECT(a, b, c): c ? b : a per lane, as select(a, b, c) for vector masks from
 * comparisons (OpenCL C defines the vector ?: as select). Written as ?: because
 * PoCL 3.0 compiles select, fmax and fabs on 8-lane vectors for znver3 as
 * out-of-line calls with the AVX calling convention: inlined, the light loop ran
 * 1.32× faster, bit-identical (measured: 960×540, 64 point lights, Blinn).
 * MAX0(x) = max(x, 0) (0 for NaN, like fmax(NaN, 0)); ABS(x) = |x| (−0 stays −0,
 * which only feeds comparisons). Also right for scalars (LANES = 1) and for
 * dirL (clphong.h), whatever its mask type. */
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

#endif /* CLPHONG_LANES_H */

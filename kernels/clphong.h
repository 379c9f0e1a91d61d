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

/* floatL: one value per pixel of the work-item's LANES pixels. PoCL vectorises
 * only the innermost work-item loop, and a per-pixel loop over lights keeps it
 * scalar (POCL-NOTES "Why the vectorisation must be explicit"), so the lanes
 * are explicit vectors across pixels. */
#if LANES == 16
typedef float16 floatL;
typedef int16 intL;
#define vloadL vload16
#define vstoreL vstore16
#elif LANES == 8
typedef float8 floatL;
typedef int8 intL;
#define vloadL vload8
#define vstoreL vstore8
#elif LANES == 4
typedef float4 floatL;
typedef int4 intL;
#define vloadL vload4
#define vstoreL vstore4
#elif LANES == 1
typedef float floatL;
typedef int intL;
#define vloadL(i, p) ((p)[(i)])
#define vstoreL(v, i, p) ((p)[(i)] = (v))
#else
#error "LANES must be 1, 4, 8 or 16"
#endif

/* a·b + c. Not fma(): PoCL 3.0's LLVM cannot select fma for float16 ("Cannot
 * select: i64 = fma"); OpenCL's default FP_CONTRACT still lets it fuse. */
#define MUL_ADD(a, b, c) ((a) * (b) + (c))

/* Layout of the light records (float4 each), shared with clphong/plan.py. */
#define POINT_LIGHT_FLOAT4S 3       /* (x, y, z, c0) (r, g, b, c1) (c2, 0, 0, 0) */
#define DIRECTIONAL_LIGHT_FLOAT4S 3 /* (lx, ly, lz, 0) (r, g, b, 0) (hx, hy, hz, 0) */

#endif /* CLPHONG_H */

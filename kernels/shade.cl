/* clphong entry point: E = E_A + Σ_i (E_D + E_S)_i / (c0_i + c1_i·d_i + c2_i·d_i²)
 *
 * Data layout (structure of arrays, `stride` floats a plane, stride a multiple
 * of LANES, padding pixels are background):
 *   gbuf: Px Py Pz  Nx Ny Nz  Cr Cg Cb  nx ny nz
 *         P is as stored (float32); the float path subtracts `origin`, a float32
 *         point near the scene, so P − origin is exact for P within a factor 2
 *         of it (Sterbenz) and distances keep their digits far from the world
 *         origin. DIRECTIONS_FP64 gets origin = 0: P is exact in double and the
 *         point lights' float64 records are not rebased, so L − P is rounded
 *         once, however close the light. N is unit (normalised on
 *         the host in float64, rounded to float) and exactly 0 on background
 *         pixels; n is its float64 remainder N64 − N, used with DIRECTIONS_FP64.
 *         C is the albedo C_d.
 *   maps: the planes named by MAP_KD, MAP_KS, MAP_H, MAP_CS (k_d, k_s, h, C_s rgb),
 *         in that order, only those present.
 *         With COVERAGE, plane 12 is the coverage α (the host un-premultiplied C_d).
 *   out:  R G B (the beauty, α·E + (1 − α)·background with COVERAGE), then with
 *         N_GROUPS the light groups' R G B (α·E_g each), then with AOV_DIFFUSE
 *         the diffuse R G B (ambient included), with AOV_SPECULAR the specular
 *         R G B (α-premultiplied too), all from this one pass.
 * Each work-item shades LANES consecutive pixels as one vector.
 *
 * Defines: all of the shading plan's (clphong/device/plan.py), each required by
 * the header that reads it: LANES (lanes.h), the number formats (clphong.h), the
 * scene's switches and CULL_TILE with CULLING (plan.h). The display output is
 * not here: kernels/tonemap_apply.cl runs on the stored planes, so a change of
 * tone-map operator, view or output never rebuilds this kernel.
 */
#include "clphong.h"
#include "plan.h"
#include "brdf.h"
#include "lights.h"
#include "shade_args.h"
#include "envtable.h"

/* LIGHT_TILE (set by the plan, clphong/device/plan.py): 0, each work-item reads the
 * light records from global memory (CPUs: the records of one light are the same
 * for every lane and stay in L1); T > 0, the work-group stages T lights at a time
 * through local memory, every work-item loading a share, as n-body codes do (GPUs:
 * one global read per light per work-group instead of per work-item). The sum's
 * order and every operation are the same: the pixels are bit-identical. The
 * culled loop (CULLING) reads its per-tile lists as before. */
#ifndef LIGHT_TILE
#error "LIGHT_TILE must be set by the shading plan (clphong/device/plan.py)"
#endif
/* DIR_CULLING: directional lights from per-tile lists (cull.cl dir_count/dir_write),
 * not with staging (plan.py); CULL_TILE is their tile edge. The lists are in light
 * order, so with light groups each group walks on while the index is below its end. */
#ifndef DIR_CULLING
#error "DIR_CULLING must be set by the shading plan (clphong/device/plan.py)"
#endif
#if DIR_CULLING && (LIGHT_TILE || !defined(CULL_TILE))
#error "DIR_CULLING needs CULL_TILE, and not LIGHT_TILE"
#endif
/* LIGHT_TILE: the staged records, F float4s (pointrec_t) each, then the light loop
   over the tile; every work-item of the group runs the loads and both barriers, a
   work-item of background pixels only skips the shading. */
#define STAGE(tile, src, F, begin, end, body) \
    for (uint t0_ = (begin); t0_ < (end); t0_ += LIGHT_TILE) { \
        const uint n_ = min((uint)LIGHT_TILE, (end) - t0_); \
        barrier(CLK_LOCAL_MEM_FENCE); \
        for (uint q_ = (uint)get_local_id(0); q_ < n_ * (F); q_ += (uint)get_local_size(0)) \
            (tile)[q_] = (src)[(size_t)t0_ * (F) + q_]; \
        barrier(CLK_LOCAL_MEM_FENCE); \
        for (uint jj_ = 0; jj_ < (lit ? n_ : 0u); ++jj_) { body(tile + (F) * jj_) } \
    }

/* LIGHT_UNROLL (set by the plan): U > 1, the light loops take U lights an iteration,
 * one after another in the same order, then the last count mod U one at a time. The
 * sums see the same operations in the same order: the pixels are bit-identical
 * (tests/device/test_light_unroll.py). What it buys is independent work in one
 * iteration: a light's chain (distance, 1/√d², l, h, the power, the falloff, the
 * sum) is ~40 dependent operations long, and an out-of-order CPU core overlapped
 * only part of the next light's chain with it; written out, the compiler
 * interleaves U chains (Zen 5, Intel's CPU runtime, 1080p × 256 lights: fast
 * 2.29 → 2.91 GPLE/s at U = 4, accurate 1.54 → 2.07; docs/bench.md). Intel's
 * compiler ignored opencl_unroll_hint on these loops. */
#ifndef LIGHT_UNROLL
#error "LIGHT_UNROLL must be set by the shading plan (clphong/device/plan.py)"
#endif
#if LIGHT_UNROLL == 8
#define UNROLLED_BODIES(body, rec, j) body(rec(j)) body(rec((j) + 1)) body(rec((j) + 2)) \
    body(rec((j) + 3)) body(rec((j) + 4)) body(rec((j) + 5)) body(rec((j) + 6)) body(rec((j) + 7))
#elif LIGHT_UNROLL == 4
#define UNROLLED_BODIES(body, rec, j) body(rec(j)) body(rec((j) + 1)) body(rec((j) + 2)) \
    body(rec((j) + 3))
#elif LIGHT_UNROLL == 2
#define UNROLLED_BODIES(body, rec, j) body(rec(j)) body(rec((j) + 1))
#elif LIGHT_UNROLL > 1
#error "LIGHT_UNROLL must be 0, 1, 2, 4 or 8"
#endif
/* body(rec(j)) for j in [begin, end), in order; rec(j): light j's record */
#if LIGHT_UNROLL > 1
#define FOR_LIGHTS(begin, end, rec, body) { \
        uint j_ = (begin); \
        for (; j_ + LIGHT_UNROLL <= (end); j_ += LIGHT_UNROLL) { UNROLLED_BODIES(body, rec, j_) } \
        for (; j_ < (end); ++j_) { body(rec(j_)) } }
#else
#define FOR_LIGHTS(begin, end, rec, body) \
    for (uint j_ = (begin); j_ < (end); ++j_) { body(rec(j_)) }
#endif

/* A tile's list (cull.cl: light indices, in light order) from the cursor cur on, to
 * last: with light groups only this group's entries (indices below end), the cursor
 * staying where the next group's begin; without, every entry (FOR_LIGHTS). rec(j):
 * the record of the list's entry j. */
#if N_GROUPS
#define WALK_LIST(cur, last, list, end, rec, body) \
    for (; (cur) < (last) && (list)[cur] < (end); ++(cur)) { body(rec(cur)) }
#else
#define WALK_LIST(cur, last, list, end, rec, body) FOR_LIGHTS(cur, last, rec, body)
#endif

/* Add x to the running sum s (POCL-NOTES "Light sums"). SUM_FP64: s is double,
 * so N float terms err by ≤ N·2⁻⁵³ of Σ|x| before the one final rounding to
 * float (c is unused); it ran 4 % (fp64 directions) to 9 % (float directions)
 * faster than Neumaier's compensation on the bench scene. COMPENSATED_SUM
 * (devices without fast double): Neumaier's compensation c collects the
 * rounding error of each addition, so the sum errs by ~2u instead of ~N·u. */
#if SUM_FP64
#define ACCUMULATE(s, c, x) ((s) += TO_SUM(x))
#elif COMPENSATED_SUM
#define ACCUMULATE(s, c, x) do { \
        const floatL t_ = (s) + (x); \
        (c) += SELECT(((x) - t_) + (s), ((s) - t_) + (x), ABS(s) >= ABS(x)); \
        (s) = t_; } while (0)
#else
#define ACCUMULATE(s, c, x) ((s) += (x))
#endif

/* The sum s plus its compensation c, saturated: a value beyond the float range
 * becomes ±FLT_MAX (documented: never an Inf from finite inputs), and an overflow
 * inside the compensation (∞ − ∞ = NaN in c, or c = ∓∞ beside s = ±∞) does not
 * turn s into NaN. A NaN in
 * s itself (only from NaN inputs under the "pass" policy) stays NaN. With
 * SUM_FP64 the double sum is saturated, then rounded once (c is unused). */
#if SUM_FP64
inline floatL finish_sum(sumL s, floatL c)
{
    /* ±FLT_MAX by the sign, not copysign: PoCL 3.0 calls that out of line, three
       times per work-item (1.18× at N = 1) */
    const sumL t = ABS(s) > (sumL)(FLT_MAX) ? SELECT((sumL)(-FLT_MAX), (sumL)(FLT_MAX), s > 0.0) : s;
    return SUM_TO_FLOAT(t);
}
#else
inline floatL finish_sum(floatL s, floatL c)
{
    /* x != x: NaN; |t| > FLT_MAX: ±∞ (false for NaN). Written with ?: and
       comparisons: PoCL 3.0 calls select, isnan, isinf and copysign out of
       line (lanes.h, SELECT), which cost 2× at N = 1 on the bench scene.
       s + c is NaN where c is (∞ − ∞ inside the compensation) and also where
       s = ±∞ and c = ∓∞ (s overflowed, its rounding error too): s then. */
    const floatL sc = s + c;
    const floatL t = SELECT(sc, s, sc != sc);
    return SELECT(t, SELECT((floatL)(-FLT_MAX), (floatL)(FLT_MAX), t > 0.0f), ABS(t) > FLT_MAX);
}
#endif

/* A layer's value premultiplied by coverage (α = 1 without COVERAGE). */
#if COVERAGE
#define COVER(x) (alpha * (x))
#else
#define COVER(x) (x)
#endif
/* The first out plane of the diffuse and the specular layer. */
#define OUT_DIFFUSE (3 + 3 * N_GROUPS)
#define OUT_SPECULAR (OUT_DIFFUSE + 3 * AOV_DIFFUSE)

__kernel void shade(SHADE_ARGS)   /* include/shade_args.h */
{
    const size_t i = get_global_id(0) + item0;   /* pieces: item0 instead of a global offset,
                                                    whose work-group function PoCL 3.0 does not
                                                    specialise (1.12x slower at 1080p x 256) */
#if LIGHT_TILE && HAS_POINT && !CULLING
    __local pointrec_t point_tile[LIGHT_TILE * POINT_LIGHT_FLOAT4S];
#endif
#if LIGHT_TILE && HAS_DIRECTIONAL
    __local float4 directional_tile[LIGHT_TILE * DIRECTIONAL_LIGHT_FLOAT4S];
#endif
    pixel_t p;
    p.px = TO_DIR(vloadL(i, gbuf + 0 * stride)) - (dirS)origin.x;
    p.py = TO_DIR(vloadL(i, gbuf + 1 * stride)) - (dirS)origin.y;
    p.pz = TO_DIR(vloadL(i, gbuf + 2 * stride)) - (dirS)origin.z;
    const floatL Nx = vloadL(i, gbuf + 3 * stride);
    const floatL Ny = vloadL(i, gbuf + 4 * stride);
    const floatL Nz = vloadL(i, gbuf + 5 * stride);
#if DIRECTIONS_FP64
    p.nx = TO_DIR(Nx) + TO_DIR(vloadL(i, gbuf + 9 * stride));
    p.ny = TO_DIR(Ny) + TO_DIR(vloadL(i, gbuf + 10 * stride));
    p.nz = TO_DIR(Nz) + TO_DIR(vloadL(i, gbuf + 11 * stride));
#else
    p.nx = Nx;
    p.ny = Ny;
    p.nz = Nz;
#endif
    const floatL Cr = vloadL(i, gbuf + 6 * stride);
    const floatL Cg = vloadL(i, gbuf + 7 * stride);
    const floatL Cb = vloadL(i, gbuf + 8 * stride);

    /* Per-pixel material in the weights' type: D = C_d·k_d, S = C_s·k_s, exponent k.
       With WEIGHTS_FP64 they are formed in double from the float32 inputs and the
       host's float64 k_d and k_s·C_s (hi + lo), as the ambient term below: nothing
       is rounded before the sum, so lights that cancel lose no digits to them. */
    uint plane = 0;
#if MAP_KD
    const wL kd_w = FLOAT_TO_W(vloadL(i, maps + (plane++) * stride));
#else
    const wL kd_w = (wL)(W_HI_LO(k_d, material_lo.w));
#endif
    const wL Dr_w = FLOAT_TO_W(Cr) * kd_w, Dg_w = FLOAT_TO_W(Cg) * kd_w, Db_w = FLOAT_TO_W(Cb) * kd_w;
#if MAP_KS
    const wL ks_w = FLOAT_TO_W(vloadL(i, maps + (plane++) * stride));
#else
    const wL ks_w = (wL)(1.0f);   /* k_s is folded into S_uniform */
#endif
#if MAP_H
    const floatL k_map = vloadL(i, maps + (plane++) * stride);
#endif
#if MAP_CS
    const wL Sr_b = ks_w * FLOAT_TO_W(vloadL(i, maps + (plane + 0) * stride)) * W_HI_LO(S_uniform.x, S_lo.x);
    const wL Sg_b = ks_w * FLOAT_TO_W(vloadL(i, maps + (plane + 1) * stride)) * W_HI_LO(S_uniform.y, S_lo.y);
    const wL Sb_b = ks_w * FLOAT_TO_W(vloadL(i, maps + (plane + 2) * stride)) * W_HI_LO(S_uniform.z, S_lo.z);
#elif SPEC_GREY
    /* the three channels of k_s·C_s are equal (plan.h): one value, so that each light's
       S·w_s is one product for the three sums, not three equal ones */
    const wL Sr_b = ks_w * W_HI_LO(S_uniform.x, S_lo.x);
    const wL Sg_b = Sr_b, Sb_b = Sr_b;
#else
    const wL Sr_b = ks_w * W_HI_LO(S_uniform.x, S_lo.x);
    const wL Sg_b = ks_w * W_HI_LO(S_uniform.y, S_lo.y);
    const wL Sb_b = ks_w * W_HI_LO(S_uniform.z, S_lo.z);
#endif
#if HAS_SPECULAR
#if SPEC_INT_POW
    /* a whole number (clphong/device/plan.py); with SPEC_COS Blinn raises (n·h)²
       to K/2 (K even) */
    p.K = SPEC_COS && MODEL_BLINN ? (uint)SPEC_K / 2u : (uint)SPEC_K;   /* a constant: unrolled */
#elif MAP_H
    p.k = FLOAT_TO_W(MODEL_BLINN ? 4.0f * k_map : k_map);   /* the map holds h; Blinn uses 4h */
#else
    p.k = (wL)(W_HI_LO(k_uniform, S_lo.w));
#endif
#endif

    const dirS eye_x = HI_LO(eye.x, eye_lo.x), eye_y = HI_LO(eye.y, eye_lo.y),
               eye_z = HI_LO(eye.z, eye_lo.z);
#if CAMERA_ORTHO
    p.vx = (dirL)(eye_x);
    p.vy = (dirL)(eye_y);
    p.vz = (dirL)(eye_z);
#else
    {
        /* Guard: a pixel exactly at the eye has no view direction; it is seen
           head-on, v := n (as the reference), not 0·rsqrt(0) = NaN. */
        const dirL ex = eye_x - p.px, ey = eye_y - p.py, ez = eye_z - p.pz;
        const dirL ee = MUL_ADD(ex, ex, MUL_ADD(ey, ey, ez * ez));
        const dirL inv = RSQRT_DIST(ee);
        p.vx = SELECT_DIR(ex * inv, p.nx, ee <= (dirL)(0.0f));
        p.vy = SELECT_DIR(ey * inv, p.ny, ee <= (dirL)(0.0f));
        p.vz = SELECT_DIR(ez * inv, p.nz, ee <= (dirL)(0.0f));
    }
#endif
#if !DIRECTIONS_FP64
    /* the point lights' loop works in quarter units: their records come with positions
       × 1/4 (frame.py shading_records), and P − origin is quartered to match, now that v
       is formed (exact, as long as it stays normal: RSQRT_LIGHT in clphong.h) */
    p.px *= 0.25f;
    p.py *= 0.25f;
    p.pz *= 0.25f;
#endif

#if SPEC_COS
    p.NoV = MUL_ADD(p.nx, p.vx, MUL_ADD(p.ny, p.vy, p.nz * p.vz));
#endif
    /* The specular weight: the constant k_s·C_s, or with FRESNEL Phong's W(α) in
       its place (Schlick: k_s·(f0 + (1 − f0)(1 − cos α)⁵), f0 compiled in as
       float32 hi + lo bits). Phong: cos α = n·v, one W per pixel. Blinn-Phong:
       cos α = v·h per light, so S·f0 multiplies the specular weight and
       S·(1 − f0) its Fresnel part (weights_t.fresnel, lights.h). */
#if FRESNEL
    const wL f0r = W_HI_LO(as_float((uint)FRESNEL_F0R), as_float((uint)FRESNEL_F0R_LO));
    const wL f0g = W_HI_LO(as_float((uint)FRESNEL_F0G), as_float((uint)FRESNEL_F0G_LO));
    const wL f0b = W_HI_LO(as_float((uint)FRESNEL_F0B), as_float((uint)FRESNEL_F0B_LO));
#if MODEL_BLINN
    const wL Sr_w = Sr_b * f0r, Sg_w = Sg_b * f0g, Sb_w = Sb_b * f0b;
    const wL Sr1_w = Sr_b * (1.0f - f0r), Sg1_w = Sg_b * (1.0f - f0g), Sb1_w = Sb_b * (1.0f - f0b);
#else
    const wL F5 = DIR_TO_W(schlick_weight(MUL_ADD(p.nx, p.vx, MUL_ADD(p.ny, p.vy, p.nz * p.vz))));
    const wL Sr_w = Sr_b * MUL_ADD(1.0f - f0r, F5, f0r);
    const wL Sg_w = Sg_b * MUL_ADD(1.0f - f0g, F5, f0g);
    const wL Sb_w = Sb_b * MUL_ADD(1.0f - f0b, F5, f0b);
#endif
#else
    const wL Sr_w = Sr_b, Sg_w = Sg_b, Sb_w = Sb_b;
#endif
    /* Ambient: E_A = C_d·k_a·Σ ambient radiance. */
    sumL sr = TO_SUM(FLOAT_TO_W(Cr) * W_HI_LO(ambient.x, material_lo.x));
    sumL sg = TO_SUM(FLOAT_TO_W(Cg) * W_HI_LO(ambient.y, material_lo.y));
    sumL sb = TO_SUM(FLOAT_TO_W(Cb) * W_HI_LO(ambient.z, material_lo.z));
    floatL cr = (floatL)(0.0f), cg = (floatL)(0.0f), cb = (floatL)(0.0f);
#if AOV_DIFFUSE
    sumL dr = sr, dg = sg, db = sb;          /* the diffuse layer holds the ambient term */
    floatL dcr = (floatL)(0.0f), dcg = (floatL)(0.0f), dcb = (floatL)(0.0f);
#endif
#if AOV_SPECULAR
    sumL qr = (sumL)(0.0), qg = (sumL)(0.0), qb = (sumL)(0.0);
    floatL qcr = (floatL)(0.0f), qcg = (floatL)(0.0f), qcb = (floatL)(0.0f);
#endif

    /* Background pixels (zero normal, set by the host) take the background value
       below; a work-item of background pixels only skips the lights (the sky of
       a render, or a frame's padding, costs nothing per light). */
    const intL bg = (intL)((Nx == 0.0f) & (Ny == 0.0f) & (Nz == 0.0f));
    const uint lit = !ALL_LANES(bg);
#if COVERAGE
    const floatL alpha = vloadL(i, gbuf + 12 * stride);
#endif
/* The beauty's term of one light (its radiance L, times the falloff unless the weights w
   carry it: FALLOFF_ON_WEIGHTS, lights.h): one
   expression, so that the compiler contracts it with the sum exactly as it did
   before the layers existed (bit-identical beauty with or without them). */
/* S·w_s, plus with Blinn's per-light Fresnel S1·w_f (S1 the S·(1 − f0) of S)
   (S1 is not evaluated otherwise, so Sr1_w… need not exist) */
#if FRESNEL && MODEL_BLINN
#define SPEC_TERM(S, S1, w) MUL_ADD(S, (w).specular, (S1) * (w).fresnel)
#else
#define SPEC_TERM(S, S1, w) ((S) * (w).specular)
#endif
#define ADD_BEAUTY(s, c, L, D, S, S1, w) ACCUMULATE(s, c, (L) * MUL_ADD(D, (w).diffuse, SPEC_TERM(S, S1, w)))
#if N_GROUPS
#define ADD_GROUP(Lr, Lg, Lb, w) do { ADD_BEAUTY(gr, gcr, Lr, Dr_w, Sr_w, Sr1_w, w); \
        ADD_BEAUTY(gg, gcg, Lg, Dg_w, Sg_w, Sg1_w, w); \
        ADD_BEAUTY(gb, gcb, Lb, Db_w, Sb_w, Sb1_w, w); } while (0)
#else
#define ADD_GROUP(Lr, Lg, Lb, w) do { } while (0)
#endif
#if AOV_DIFFUSE
#define ADD_DIFFUSE(Lr, Lg, Lb, w) do { ACCUMULATE(dr, dcr, (Lr) * (Dr_w * (w).diffuse)); \
        ACCUMULATE(dg, dcg, (Lg) * (Dg_w * (w).diffuse)); \
        ACCUMULATE(db, dcb, (Lb) * (Db_w * (w).diffuse)); } while (0)
#else
#define ADD_DIFFUSE(Lr, Lg, Lb, w) do { } while (0)
#endif
#if AOV_SPECULAR
#define ADD_SPECULAR(Lr, Lg, Lb, w) do { ACCUMULATE(qr, qcr, (Lr) * SPEC_TERM(Sr_w, Sr1_w, w)); \
        ACCUMULATE(qg, qcg, (Lg) * SPEC_TERM(Sg_w, Sg1_w, w)); \
        ACCUMULATE(qb, qcb, (Lb) * SPEC_TERM(Sb_w, Sb1_w, w)); } while (0)
#else
#define ADD_SPECULAR(Lr, Lg, Lb, w) do { } while (0)
#endif
/* One light into the beauty and every layer the plan asks for. */
#define ADD_LIGHT(Lr, Lg, Lb, w) do { \
        ADD_BEAUTY(sr, cr, Lr, Dr_w, Sr_w, Sr1_w, w); ADD_BEAUTY(sg, cg, Lg, Dg_w, Sg_w, Sg1_w, w); \
        ADD_BEAUTY(sb, cb, Lb, Db_w, Sb_w, Sb1_w, w); \
        ADD_GROUP(Lr, Lg, Lb, w); ADD_DIFFUSE(Lr, Lg, Lb, w); ADD_SPECULAR(Lr, Lg, Lb, w); \
    } while (0)

#if ENV_TABLE
    /* The environment's tables (envtable.h): E(n) into the diffuse term, T(R) into the
       specular, once a pixel, as one light with a weight per channel; its sun is among
       the directional lights. */
    floatL env_Er = (floatL)(0.0f), env_Eg = (floatL)(0.0f), env_Eb = (floatL)(0.0f);
    floatL env_Tr = (floatL)(0.0f), env_Tg = (floatL)(0.0f), env_Tb = (floatL)(0.0f);
    if (lit) {
        floatL y, x;
        env_table_coords(TO_FLOAT(p.nx), TO_FLOAT(p.ny), TO_FLOAT(p.nz), env_rotation,
                         (float)ENV_D_ROWS, (float)ENV_D_COLS, &y, &x);
        env_table_lookup(env_table, ENV_D_ROWS, ENV_D_COLS, y, x, &env_Er, &env_Eg, &env_Eb);
#if HAS_SPECULAR
        const dirL NoV2 = 2.0f * MUL_ADD(p.nx, p.vx, MUL_ADD(p.ny, p.vy, p.nz * p.vz));
        env_table_coords(TO_FLOAT(MUL_ADD(NoV2, p.nx, -p.vx)), TO_FLOAT(MUL_ADD(NoV2, p.ny, -p.vy)),
                         TO_FLOAT(MUL_ADD(NoV2, p.nz, -p.vz)), env_rotation,
                         (float)ENV_S_ROWS, (float)ENV_S_COLS, &y, &x);
        env_table_lookup(env_table + ENV_S_OFFSET, ENV_S_ROWS, ENV_S_COLS, y, x,
                         &env_Tr, &env_Tg, &env_Tb);
#endif
    }
/* the tables' term of one channel into a sum: D·E + S·T */
#define ENV_TERM(D, S, E, T) MUL_ADD(D, FLOAT_TO_W(E), (S) * FLOAT_TO_W(T))
    ACCUMULATE(sr, cr, ENV_TERM(Dr_w, Sr_w, env_Er, env_Tr));
    ACCUMULATE(sg, cg, ENV_TERM(Dg_w, Sg_w, env_Eg, env_Tg));
    ACCUMULATE(sb, cb, ENV_TERM(Db_w, Sb_w, env_Eb, env_Tb));
#if AOV_DIFFUSE
    ACCUMULATE(dr, dcr, Dr_w * FLOAT_TO_W(env_Er));
    ACCUMULATE(dg, dcg, Dg_w * FLOAT_TO_W(env_Eg));
    ACCUMULATE(db, dcb, Db_w * FLOAT_TO_W(env_Eb));
#endif
#if AOV_SPECULAR
    ACCUMULATE(qr, qcr, Sr_w * FLOAT_TO_W(env_Tr));
    ACCUMULATE(qg, qcg, Sg_w * FLOAT_TO_W(env_Tg));
    ACCUMULATE(qb, qcb, Sb_w * FLOAT_TO_W(env_Tb));
#endif
#endif
#if HAS_POINT && CULLING
    /* The tile of this work-item's first pixel (as cull.cl bounds it); padding
       work-items past the last tile shade background only. */
    const uint q0 = (uint)(i * LANES);
    const uint tile = (q0 / width / CULL_TILE) * tiles_x + (q0 % width) / CULL_TILE;
    const uint2 range = tile < n_tiles && lit ? tile_ranges[tile] : (uint2)(0, 0);
    uint m = range.x;      /* the tile's list, in light order, walked once across the groups */
#endif
#if DIR_CULLING
    /* this work-item's tile (as cull.cl bounds it), its list of directional lights */
    const uint dq0 = (uint)(i * LANES);
    const uint dtile = (dq0 / dir_width / CULL_TILE) * dir_tiles_x + (dq0 % dir_width) / CULL_TILE;
    const uint2 dir_range = dtile < dir_n_tiles && lit ? dir_ranges[dtile] : (uint2)(0, 0);
    uint dm = dir_range.x;  /* the tile's directional list, walked once across the groups */
#endif
    /* Light groups: the host sorts the lights by group; group g's directional lights
       are [dir_end[g-1], dir_end[g]), its point lights [point_end[g-1], point_end[g])
       (group_table = dir_end[0..G-1], point_end[0..G-1]). Each group is summed from
       its own ambient term beside the beauty. Without groups: one pass over all. */
    for (uint g = 0; g < (N_GROUPS ? N_GROUPS : 1u); ++g) {
        const uint d_begin = N_GROUPS && g ? group_table[g - 1] : 0u;
        const uint d_end = N_GROUPS ? group_table[g] : n_directional;
        const uint p_begin = N_GROUPS && g ? group_table[N_GROUPS + g - 1] : 0u;
        const uint p_end = N_GROUPS ? group_table[N_GROUPS + g] : n_point;
#if N_GROUPS
        const float4 A_g = group_ambient[2 * g], A_lo = group_ambient[2 * g + 1];
        sumL gr = TO_SUM(FLOAT_TO_W(Cr) * W_HI_LO(A_g.x, A_lo.x));
        sumL gg = TO_SUM(FLOAT_TO_W(Cg) * W_HI_LO(A_g.y, A_lo.y));
        sumL gb = TO_SUM(FLOAT_TO_W(Cb) * W_HI_LO(A_g.z, A_lo.z));
        floatL gcr = (floatL)(0.0f), gcg = (floatL)(0.0f), gcb = (floatL)(0.0f);
#if ENV_TABLE
        if ((int)g == ENV_GROUP) {      /* the environment's tables, in its group */
            ACCUMULATE(gr, gcr, ENV_TERM(Dr_w, Sr_w, env_Er, env_Tr));
            ACCUMULATE(gg, gcg, ENV_TERM(Dg_w, Sg_w, env_Eg, env_Tg));
            ACCUMULATE(gb, gcb, ENV_TERM(Db_w, Sb_w, env_Eb, env_Tb));
        }
#endif
#endif
#if HAS_DIRECTIONAL
/* one directional light's record (6 float4s) into the sums */
#define DIRECTIONAL_BODY(rec) { \
            const float4 L = (rec)[1], L_lo = (rec)[5];   /* radiance, as hi + lo */ \
            const weights_t w = shade_directional_light(&p, (rec)[0], (rec)[3], (rec)[2], (rec)[4]); \
            ADD_LIGHT(W_HI_LO(L.x, L_lo.x), W_HI_LO(L.y, L_lo.y), W_HI_LO(L.z, L_lo.z), w); }
#if DIR_CULLING
        /* the lights some normal of this work-item's tile may face (the others add exactly
           0 there: n·l ≤ 0 for each of its pixels); with groups, this group's entries */
#define DIR_LISTED_RECORD(j) (directional_lights + DIRECTIONAL_LIGHT_FLOAT4S * dir_lights[j])
        WALK_LIST(dm, dir_range.x + dir_range.y, dir_lights, d_end, DIR_LISTED_RECORD,
                  DIRECTIONAL_BODY)
#elif LIGHT_TILE
        STAGE(directional_tile, directional_lights, DIRECTIONAL_LIGHT_FLOAT4S, d_begin, d_end,
              DIRECTIONAL_BODY)
#else
#define DIRECTIONAL_RECORD(j) (directional_lights + DIRECTIONAL_LIGHT_FLOAT4S * (j))
        FOR_LIGHTS(lit ? d_begin : d_end, d_end, DIRECTIONAL_RECORD, DIRECTIONAL_BODY)
#endif
#endif
#if HAS_POINT
/* one point light's record (POINT_LIGHT_FLOAT4S pointrec_t's) into the sums */
#if HAS_SPOT
#define POINT_WEIGHTS(rec) shade_point_light(&p, X.x, X.y, X.z, X.w, L.w, Q.x, L.x, L.y, L.z, \
            Q.y, Q.z, Q.w, (rec)[3].x, (rec)[3].y, &ar, &ag, &ab)   /* rec[3]: the cone's s, o */
#else
#define POINT_WEIGHTS(rec) shade_point_light(&p, X.x, X.y, X.z, X.w, L.w, Q.x, L.x, L.y, L.z, \
            &ar, &ag, &ab)
#endif
#define POINT_BODY(rec) { \
            const pointrec_t X = (rec)[0];   /* position, c0 */ \
            const pointrec_t L = (rec)[1];   /* radiance, c1 */ \
            const pointrec_t Q = (rec)[2];   /* c2, a spot's axis */ \
            wL ar, ag, ab;                   /* radiance (× attenuation(d) × the cone, unless \
                                                the weights carry it: lights.h) */ \
            const weights_t w = POINT_WEIGHTS(rec); \
            ADD_LIGHT(ar, ag, ab, w); }
#if CULLING
        /* this group's part of the tile's list: its entries below p_end */
#define LISTED_RECORD(j) (point_lights + POINT_LIGHT_FLOAT4S * tile_lights[j])
        WALK_LIST(m, range.x + range.y, tile_lights, p_end, LISTED_RECORD, POINT_BODY)
#elif LIGHT_TILE
        STAGE(point_tile, point_lights, POINT_LIGHT_FLOAT4S, p_begin, p_end, POINT_BODY)
#else
#define POINT_RECORD(j) (point_lights + POINT_LIGHT_FLOAT4S * (j))
        FOR_LIGHTS(lit ? p_begin : p_end, p_end, POINT_RECORD, POINT_BODY)
#endif
#endif
#if N_GROUPS
        /* group g: α·E_g (0 on background pixels) */
        vstoreL(COVER(SELECT(finish_sum(gr, gcr), (floatL)(0.0f), bg)), i, out + (3 + 3 * g) * stride);
        vstoreL(COVER(SELECT(finish_sum(gg, gcg), (floatL)(0.0f), bg)), i, out + (4 + 3 * g) * stride);
        vstoreL(COVER(SELECT(finish_sum(gb, gcb), (floatL)(0.0f), bg)), i, out + (5 + 3 * g) * stride);
#endif
    }

    /* the straight (un-premultiplied) shade S, the background where not shaded */
    const floatL Er = SELECT(finish_sum(sr, cr), (floatL)(background.x), bg);
    const floatL Eg = SELECT(finish_sum(sg, cg), (floatL)(background.y), bg);
    const floatL Eb = SELECT(finish_sum(sb, cb), (floatL)(background.z), bg);
#if COVERAGE
    /* α·S + (1 − α)·background: S itself where α = 1, the background where α = 0 */
    const floatL Or = MUL_ADD(alpha, Er, (1.0f - alpha) * background.x);
    const floatL Og = MUL_ADD(alpha, Eg, (1.0f - alpha) * background.y);
    const floatL Ob = MUL_ADD(alpha, Eb, (1.0f - alpha) * background.z);
#else
    const floatL Or = Er, Og = Eg, Ob = Eb;
#endif
    vstoreL(Or, i, out + 0 * stride);
    vstoreL(Og, i, out + 1 * stride);
    vstoreL(Ob, i, out + 2 * stride);
#ifdef SELFTEST_FAULT
    /* test-only: the last lane of each work-item made wrong by a factor (1 + SELFTEST_FAULT),
       set only by the self-test's fault injection (tests/device/test_selftest.py) to show
       that a wrong lane is caught; never in a plan */
    out[i * LANES + (LANES - 1)] *= 1.0f + SELFTEST_FAULT;
#endif
#if AOV_DIFFUSE
    vstoreL(COVER(SELECT(finish_sum(dr, dcr), (floatL)(0.0f), bg)), i, out + (OUT_DIFFUSE + 0) * stride);
    vstoreL(COVER(SELECT(finish_sum(dg, dcg), (floatL)(0.0f), bg)), i, out + (OUT_DIFFUSE + 1) * stride);
    vstoreL(COVER(SELECT(finish_sum(db, dcb), (floatL)(0.0f), bg)), i, out + (OUT_DIFFUSE + 2) * stride);
#endif
#if AOV_SPECULAR
    vstoreL(COVER(SELECT(finish_sum(qr, qcr), (floatL)(0.0f), bg)), i, out + (OUT_SPECULAR + 0) * stride);
    vstoreL(COVER(SELECT(finish_sum(qg, qcg), (floatL)(0.0f), bg)), i, out + (OUT_SPECULAR + 1) * stride);
    vstoreL(COVER(SELECT(finish_sum(qb, qcb), (floatL)(0.0f), bg)), i, out + (OUT_SPECULAR + 2) * stride);
#endif
}

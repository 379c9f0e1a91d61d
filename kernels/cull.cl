/* Error-bounded tiled light culling: per-tile point-light lists.
 *
 * Plain attenuation 1/(c0 + c1·d + c2·d²) never reaches zero, so a light has no
 * radius. Instead each screen tile gets an upper bound b_j of light j's possible
 * contribution to any of its pixels (any channel), and lights are dropped only
 * while the sum of the dropped bounds stays within the user's budget ε (output
 * radiance). Every pixel's culling error is then ≤ Σ dropped b_j ≤ ε.
 *
 * A tile is the set of work-items (LANES consecutive pixels each) whose FIRST
 * pixel lies in a CULL_TILE × CULL_TILE block of the image; shade.cl looks a
 * work-item's list up the same way, so a work-item that wraps onto the next row
 * is bounded with the tile that shades it.
 *
 * Two levels (clphong/device/culling.py): super-tiles of CULL_SUPER × CULL_SUPER
 * tiles are culled first against all lights with a share of the budget (ε/4);
 * each tile then considers only its super-tile's list, with the rest. A pixel's
 * dropped lights sum to ≤ ε in all.
 *
 * Kernels, run in this order by clphong/device/culling.py, once per level:
 *   tile_bounds  one work-item per tile: world-space bounds of P (rebased), of
 *                the unit normals, of |D| = |C_d·k_d| and |S| = |k_s·C_s| (negative
 *                albedo may cancel a term: the budget bounds |dropped sum|), max |P|.
 *   cull_count   LANES tiles per work-item: pass 1 over the lights. Sums the
 *                bounds below the thresholds τ_m = ε·2^−m and picks the largest τ
 *                whose sum fits the budget; writes τ, the budget left over, and
 *                the number of lights at or above τ (the list's capacity).
 *   cull_write   LANES tiles per work-item: pass 2. Drops b < τ, then greedily
 *                drops further lights (in light order) while the budget lasts;
 *                writes the kept indices in light order, so that with nothing
 *                dropped the light sum is the brute-force sum, bit for bit.
 *
 * Bound of light j in a tile (docs/error-model.md, "Culling"):
 *   b = (1 + 32u)·max_c L_c·(D_c·min(NoL⁺, 1) + S_c·[NoL⁺ > 0]) / p⁻
 *   d⁻   = (1 − 16u)·distance from the light to the tile's box of P, a lower
 *          bound of the shading kernel's distance (float or double) for every
 *          pixel;
 *   p⁻   = p_scale·(p(d⁻), or the host's lower bound of p's minimum where d⁻ is
 *          left of the vertex of a polynomial with c1 < 0), a lower bound of the
 *          1/attenuation the kernel computes, from float32 or float64
 *          coefficients (p_scale = 1 − 8u·κ_p);
 *   NoL⁺ = upper bound of n·(L − P) over the boxes of n and P (interval
 *          arithmetic), over d⁻, plus the float32 error of n·l; the specular
 *          term is gated on n·l > 0, so it is bounded by 1 unless NoL⁺ ≤ 0.
 * The diffuse weight is ≤ 1 + 5u and the specular power ≤ 1 + 3 ulp; the 32u
 * covers these and the roundings of the bound itself.
 *
 * Defines, all set by the culling pass (build_tile_lists,
 * clphong/device/culling.py): LANES (lanes.h), CULL_TILE and CULL_SUPER, and of
 * the shading plan only the material layout that D and S are bounded from,
 * CULL_DEFINES: HAS_SPECULAR, MAP_KD, MAP_KS, MAP_H, MAP_CS, and HAS_SPOT (the cone's
 * bound is compiled in only for scenes with spots: 12 % of the small-reach scene's
 * culling time without). This program reads
 * no other define of the plan (so one cull program serves every shading variant
 * of a material layout) and includes no header that would (lanes.h only).
 */
#include "lanes.h"

#ifndef HAS_SPECULAR
#error "HAS_SPECULAR must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef MAP_KD
#error "MAP_KD must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef MAP_KS
#error "MAP_KS must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef MAP_H
#error "MAP_H must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef MAP_CS
#error "MAP_CS must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef HAS_SPOT
#error "HAS_SPOT must be set by the culling pass (CULL_DEFINES, clphong/device/culling.py)"
#endif
#ifndef CULL_TILE
#error "CULL_TILE must be set by the culling pass (clphong/device/culling.py)"
#endif
/* Thresholds τ_m = ε·2^−m, m = 1 … CULL_LEVELS (down to ε·6·10⁻⁸). Steps of 2,
 * not 16: the τ picked is within 2× of the best single threshold, so a tile
 * drops more lights for the same budget (bench, small-reach scene, 65 536 lights
 * at ε = 10⁻³: 0.43 % kept → 0.23 %, and the culling kernels 1.75 s → 1.03 s,
 * since the super-tiles' lists shrink too). */
#define CULL_LEVELS 24
/* A super-tile is CULL_SUPER × CULL_SUPER tiles; its lists are the candidates
 * of its tiles' lists (clphong/device/culling.py: two levels, ε/4 and the rest). */
#ifndef CULL_SUPER
#error "CULL_SUPER must be set by the culling pass (clphong/device/culling.py)"
#endif
#define U_F32 5.9604644775390625e-8f   /* 2^-24 */

/* PoCL 3.0 calls its fmax, fmin, fabs, select and sqrt builtins out of line
 * (an AVX-ABI call per use, measured with objdump on znver3), which dominated the
 * light loops below; these inline forms compile to single vector instructions.
 * Their NaN behaviour differs from the builtins', which the bound does not rely
 * on: a NaN bound is turned into +inf (kept) in light_bound. */
#define MAX_(a, b) ((a) > (b) ? (a) : (b))
#define MIN_(a, b) ((a) < (b) ? (a) : (b))
#define SEL_(a, b, c) ((c) ? (b) : (a))
#define ABS1_(x) ((x) < 0.0f ? -(x) : (x))     /* scalar |x| (−0 stays −0: only fed to MAX_ with 0) */
#if LANES == 16
#define ABS_(x) as_float16(as_int16(x) & 0x7fffffff)
#elif LANES == 8
#define ABS_(x) as_float8(as_int8(x) & 0x7fffffff)
#elif LANES == 4
#define ABS_(x) as_float4(as_int4(x) & 0x7fffffff)
#else
#define ABS_(x) as_float(as_int(x) & 0x7fffffff)
#endif

/* Per-tile planes written by tile_bounds (n_tiles_pad floats each). */
enum { T_LOX, T_LOY, T_LOZ, T_HIX, T_HIY, T_HIZ,
       T_NLOX, T_NLOY, T_NLOZ, T_NHIX, T_NHIY, T_NHIZ,
       T_DR, T_DG, T_DB, T_SR, T_SG, T_SB, T_R,
       /* signed minima, for the relative budget's floor (tile_floor): D = C_d·k_d and
          C_d per channel, and S = k_s·C_s over the channels */
       T_DMR, T_DMG, T_DMB, T_CMR, T_CMG, T_CMB, T_SMIN, T_PLANES };

/* Cull-light records, 5 float4 each (pack_cull_lights, clphong/device/culling.py):
 *   (x, y, z, c0) (c1, c2, vertex, p_vertex_lo) (p_scale, r, g, b) (|L|, ax, ay, az)
 *   (s, o, 0, 0): a spot's unit axis a and cone t = clamp(cos θ·s + o, 0, 1) (a point
 *   light: s = 0, o = 1, no cone) */
#define CULL_LIGHT_FLOAT4S 5

__kernel void tile_bounds(__global const float *restrict gbuf,
                          __global const float *restrict maps,
                          const uint stride, const uint width, const uint n_pixels,
                          const uint tile_size, const uint tiles_x, const uint n_tiles,
                          const uint n_tiles_pad,
                          const float4 origin, const float k_d, const float4 S_uniform,
                          __global float *restrict tiles)
{
    const uint t = get_global_id(0);
    if (t >= n_tiles_pad)
        return;
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    float nlo[3] = {INFINITY, INFINITY, INFINITY}, nhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    float D[3] = {0.0f, 0.0f, 0.0f}, S[3] = {0.0f, 0.0f, 0.0f}, R2 = 0.0f;
    float Dm[3] = {INFINITY, INFINITY, INFINITY}, Cm[3] = {INFINITY, INFINITY, INFINITY};
    float Sm = INFINITY;
    int nan_seen = 0;      /* a NaN anywhere (--nonfinite pass): MIN_/MAX_ skip it, so no floor */
    if (t < n_tiles) {
        const uint x0 = (t % tiles_x) * tile_size;   /* ≥ width: a padding tile, empty */
        const uint x1 = min(x0 + tile_size, width);
        const uint y0 = (t / tiles_x) * tile_size;
        for (uint y = y0; y < y0 + tile_size && x0 < x1; ++y) {
            const ulong row = (ulong)y * width;
            if (row + x0 >= n_pixels)
                break;
            /* work-items whose first pixel is in [row + x0, row + x1) */
            const ulong first = (row + x0 + LANES - 1) / LANES;
            const ulong last = (row + x1 + LANES - 1) / LANES;
            for (ulong item = first; item < last; ++item) {
                for (uint m = 0; m < LANES; ++m) {
                    const ulong q = item * LANES + m;
                    if (q >= stride)
                        break;
                    const float nx = gbuf[3 * stride + q], ny = gbuf[4 * stride + q],
                                nz = gbuf[5 * stride + q];
                    /* background (zero normal): not shaded, not bounded */
                    if (nx == 0.0f && ny == 0.0f && nz == 0.0f)
                        continue;
                    const float p[3] = {gbuf[q] - origin.x, gbuf[stride + q] - origin.y,
                                        gbuf[2 * stride + q] - origin.z};
                    const float n[3] = {nx, ny, nz};
                    for (int c = 0; c < 3; ++c) {
                        lo[c] = MIN_(lo[c], p[c]);
                        hi[c] = MAX_(hi[c], p[c]);
                        nlo[c] = MIN_(nlo[c], n[c]);
                        nhi[c] = MAX_(nhi[c], n[c]);
                    }
                    R2 = MAX_(R2, MUL_ADD(p[0], p[0], MUL_ADD(p[1], p[1], p[2] * p[2])));
                    /* D and S exactly as shade.cl computes them */
                    uint plane = 0;
#if MAP_KD
                    const float kd = maps[(plane++) * stride + q];
#else
                    const float kd = k_d;
#endif
                    for (int c = 0; c < 3; ++c) {
                        const float C = gbuf[(6 + c) * stride + q];
                        nan_seen |= !(C * kd == C * kd) | !(p[c] == p[c]) | !(n[c] == n[c]);
                        D[c] = MAX_(D[c], ABS1_(C * kd));
                        Dm[c] = MIN_(Dm[c], C * kd);
                        Cm[c] = MIN_(Cm[c], C);
                    }
#if HAS_SPECULAR
#if MAP_KS
                    const float ks = maps[(plane++) * stride + q];
#else
                    const float ks = 1.0f;
#endif
#if MAP_H
                    plane++;
#endif
                    const float Su[3] = {S_uniform.x, S_uniform.y, S_uniform.z};
                    for (int c = 0; c < 3; ++c) {
#if MAP_CS
                        const float s = ks * maps[(plane + c) * stride + q] * Su[c];
#else
                        const float s = ks * Su[c];
#endif
                        S[c] = MAX_(S[c], ABS1_(s));
                        Sm = MIN_(Sm, s);
                        nan_seen |= !(s == s);
                    }
#endif
                }
            }
        }
    }
    const float v[T_PLANES] = {lo[0], lo[1], lo[2], hi[0], hi[1], hi[2],
                               nlo[0], nlo[1], nlo[2], nhi[0], nhi[1], nhi[2],
                               D[0], D[1], D[2], S[0], S[1], S[2],
                               sqrt(R2) * (1.0f + 2.0f * U_F32),    /* max |P|, rounded up */
                               nan_seen ? -INFINITY : Dm[0], Dm[1], Dm[2], Cm[0], Cm[1], Cm[2],
                               Sm};
    for (int k = 0; k < T_PLANES; ++k)
        tiles[k * n_tiles_pad + t] = v[k];
}

/* The bounds of super-tiles of super × super tiles, merged from the tiles'
 * (tile_bounds at the finer level): a super-tile's pixels are exactly the union
 * of its tiles' (the same first-pixel rule, tiles_x a multiple of super), every
 * field is a min or a max, and R (sqrt, then ×(1 + 2u)) is monotone in R², so
 * the result is bit-identical to tile_bounds run on the super-tiles, without
 * reading the frame a second time. Tiles past fine_tiles_y, and padding
 * super-tiles, contribute the empty record (±∞ bounds, zeros). */
__kernel void merge_bounds(__global const float *restrict fine, const uint fine_tiles_x,
                           const uint fine_tiles_y, const uint fine_pad, const uint super,
                           const uint tiles_x, const uint n_tiles, const uint n_tiles_pad,
                           __global float *restrict tiles)
{
    const uint t = get_global_id(0);
    if (t >= n_tiles_pad)
        return;
    float v[T_PLANES];
    for (int k = 0; k < T_PLANES; ++k)
        v[k] = k < T_HIX ? INFINITY : (k < T_NLOX ? -INFINITY : (k < T_NHIX ? INFINITY
               : (k < T_DR ? -INFINITY : (k < T_DMR ? 0.0f : INFINITY))));
    if (t < n_tiles) {
        const uint fx0 = (t % tiles_x) * super, fy0 = (t / tiles_x) * super;
        for (uint fy = fy0; fy < min(fy0 + super, fine_tiles_y); ++fy)
            for (uint fx = fx0; fx < fx0 + super; ++fx) {
                const uint f = fy * fine_tiles_x + fx;
                for (int k = 0; k < T_PLANES; ++k) {
                    const float x = fine[k * fine_pad + f];
                    const int is_min = k < T_HIX || (k >= T_NLOX && k < T_NHIX) || k >= T_DMR;
                    v[k] = is_min ? MIN_(v[k], x) : MAX_(v[k], x);
                }
            }
    }
    for (int k = 0; k < T_PLANES; ++k)
        tiles[k * n_tiles_pad + t] = v[k];
}

typedef struct {
    floatL lox, loy, loz, hix, hiy, hiz;
    floatL nlox, nloy, nloz, nhix, nhiy, nhiz;
    floatL Dr, Dg, Db, Sr, Sg, Sb, R;
    intL empty;
} tile_t;

inline tile_t load_tiles(__global const float *tiles, size_t i, uint n_tiles_pad)
{
    tile_t t;
    t.lox = vloadL(i, tiles + T_LOX * n_tiles_pad);
    t.loy = vloadL(i, tiles + T_LOY * n_tiles_pad);
    t.loz = vloadL(i, tiles + T_LOZ * n_tiles_pad);
    t.hix = vloadL(i, tiles + T_HIX * n_tiles_pad);
    t.hiy = vloadL(i, tiles + T_HIY * n_tiles_pad);
    t.hiz = vloadL(i, tiles + T_HIZ * n_tiles_pad);
    t.nlox = vloadL(i, tiles + T_NLOX * n_tiles_pad);
    t.nloy = vloadL(i, tiles + T_NLOY * n_tiles_pad);
    t.nloz = vloadL(i, tiles + T_NLOZ * n_tiles_pad);
    t.nhix = vloadL(i, tiles + T_NHIX * n_tiles_pad);
    t.nhiy = vloadL(i, tiles + T_NHIY * n_tiles_pad);
    t.nhiz = vloadL(i, tiles + T_NHIZ * n_tiles_pad);
    t.Dr = vloadL(i, tiles + T_DR * n_tiles_pad);
    t.Dg = vloadL(i, tiles + T_DG * n_tiles_pad);
    t.Db = vloadL(i, tiles + T_DB * n_tiles_pad);
    t.Sr = vloadL(i, tiles + T_SR * n_tiles_pad);
    t.Sg = vloadL(i, tiles + T_SG * n_tiles_pad);
    t.Sb = vloadL(i, tiles + T_SB * n_tiles_pad);
    t.R = vloadL(i, tiles + T_R * n_tiles_pad);
    /* an empty tile (no shaded pixel) keeps its +inf/−inf box */
    t.empty = (intL)(t.lox > t.hix);
    return t;
}

/* Upper bound of n_c·w_c for n_c ∈ [a, b], w_c ∈ [lo, hi]: the largest corner product. */
inline floatL interval_product_max(floatL a, floatL b, floatL lo, floatL hi)
{
    return MAX_(MAX_(a * lo, a * hi), MAX_(b * lo, b * hi));
}

/* b_j: upper bound of light j's contribution to any pixel and channel of the tile
 * (see the header comment), each channel c's in units of its budget: max_c b_c·inv_c
 * (inv = 1: output radiance; the relative budget: 1/B_c, so that the dropped sums
 * stay within every channel's own budget B_c). 0 for empty tiles and where every
 * channel's bound is 0; +inf where no bound holds (p⁻ ≤ 0, a light inside the box
 * with c0 ≤ 0, non-finite data, a channel without a budget: inv_c = ∞). */
/* The relative budget's 1/B_c per channel of a work-item's tiles (kernels below:
 * budget_inverse), or 1 in each (absolute). */
typedef struct {
    floatL r, g, b;
} inv3_t;

/* b·inv, with a zero bound staying 0 (not 0·∞) */
inline floatL scaled_bound(floatL b, floatL inv)
{
    return SEL_(b * inv, (floatL)(0.0f), (intL)(b == 0.0f));
}

inline floatL light_bound(const tile_t *t, float4 A, float4 B, float4 C, float4 E, float4 F,
                          const inv3_t *inv)
{
    /* distance from the light to the box (0 inside it) */
    const floatL dx = MAX_(t->lox - A.x, 0.0f) + MAX_(A.x - t->hix, 0.0f);
    const floatL dy = MAX_(t->loy - A.y, 0.0f) + MAX_(A.y - t->hiy, 0.0f);
    const floatL dz = MAX_(t->loz - A.z, 0.0f) + MAX_(A.z - t->hiz, 0.0f);
    /* − 2u(|P| + |L|): the kernel may use P and L in double (DIRECTIONS_FP64), not
       the float32 roundings the box and the records hold */
    const floatL d_lo = MAX_(MUL_ADD(sqrt(MUL_ADD(dx, dx, MUL_ADD(dy, dy, dz * dz))),
                                     (floatL)(1.0f - 16.0f * U_F32),
                                     -2.0f * U_F32 * (t->R + E.x)), 0.0f);
    /* p⁻: p(d⁻) right of the vertex, the host's lower bound of min p left of it */
    const floatL p_d = MUL_ADD(d_lo, MUL_ADD(d_lo, (floatL)(B.y), (floatL)(B.x)), (floatL)(A.w));
    const floatL p_lo = SEL_(p_d, (floatL)(B.w), (intL)(d_lo < B.z)) * C.x;
    /* n·(L − P) ≤ Σ_c max over the corners of [nlo, nhi]×[L − hi, L − lo] */
    const floatL ux = interval_product_max(t->nlox, t->nhix, A.x - t->hix, A.x - t->lox);
    const floatL uy = interval_product_max(t->nloy, t->nhiy, A.y - t->hiy, A.y - t->loy);
    const floatL uz = interval_product_max(t->nloz, t->nhiz, A.z - t->hiz, A.z - t->loz);
    /* + the roundings of the differences, products and sum (4u of Σ|·|, doubled) */
    const floatL ub = (ux + uy + uz) + 8.0f * U_F32 * (ABS_(ux) + ABS_(uy) + ABS_(uz));
    /* the kernel's n·l errs by ε_NoL = η_n + η_l + 4u, η_l = u(2 + (|P| + |L|)/d),
       doubled (docs/error-model.md) */
    const floatL margin = U_F32 * (12.0f + 2.0f * (t->R + E.x) / d_lo);
    const floatL NoL_hi = SEL_(MAX_(ub, 0.0f) / d_lo + margin, (floatL)(INFINITY),
                                 (intL)(d_lo <= 0.0f));
    const floatL w_d = MIN_(NoL_hi, 1.0f + 16.0f * U_F32);
    const floatL w_s = SEL_((floatL)(0.0f), (floatL)(1.0f + 16.0f * U_F32), (intL)(NoL_hi > 0.0f));
    const floatL br = C.y * MUL_ADD(t->Dr, w_d, t->Sr * w_s);
    const floatL bg = C.z * MUL_ADD(t->Dg, w_d, t->Sg * w_s);
    const floatL bb = C.w * MUL_ADD(t->Db, w_d, t->Sb * w_s);
    /* A spot's cone: cos θ = a·(P − L)/|P − L| ≤ ua = max over the box of a·(P − L)
       (each axis at a corner, plus 8u of the terms for the roundings), over d⁻ where
       ua > 0, else over d⁺ (the farthest corner, rounded up: a negative numerator
       over a larger distance is nearer 0), plus the kernel's error of cos θ (margin,
       as n·l's); t is increasing in cos θ (s > 0), so t(cos⁺)², with x's roundings
       (4u of its terms) and 4u in t², bounds the factor: 0 for a tile wholly behind
       an outer = 90° spot's plane too. s = 0 (a point light): factor 1 exactly. */
#if HAS_SPOT
    const floatL fx = MAX_(ABS_(t->lox - A.x), ABS_(t->hix - A.x));
    const floatL fy = MAX_(ABS_(t->loy - A.y), ABS_(t->hiy - A.y));
    const floatL fz = MAX_(ABS_(t->loz - A.z), ABS_(t->hiz - A.z));
    const floatL d_hi = MUL_ADD(sqrt(MUL_ADD(fx, fx, MUL_ADD(fy, fy, fz * fz))),
                                (floatL)(1.0f + 16.0f * U_F32), 2.0f * U_F32 * (t->R + E.x));
    const floatL ax = MAX_(E.y * (t->lox - A.x), E.y * (t->hix - A.x));
    const floatL ay = MAX_(E.z * (t->loy - A.y), E.z * (t->hiy - A.y));
    const floatL az = MAX_(E.w * (t->loz - A.z), E.w * (t->hiz - A.z));
    const floatL ua = (ax + ay + az) + 8.0f * U_F32 * (ABS_(ax) + ABS_(ay) + ABS_(az));
    const floatL cos_hi = MIN_(SEL_(SEL_(ua / d_lo, ua / d_hi, (intL)(ua <= 0.0f)) + margin,
                                    (floatL)(1.0f), (intL)(d_lo <= 0.0f)), (floatL)(1.0f));
    const floatL x_hi = MUL_ADD(cos_hi, (floatL)(F.x), (floatL)(F.y))
                        + 4.0f * U_F32 * MUL_ADD(ABS_(cos_hi), (floatL)(F.x), (floatL)(ABS1_(F.y)));
    const floatL t_hi = MIN_(MAX_(x_hi, (floatL)(0.0f)), (floatL)(1.0f));
    const floatL cone = F.x > 0.0f ? t_hi * t_hi * (1.0f + 4.0f * U_F32) : (floatL)(1.0f);
#else
    const floatL cone = (floatL)(1.0f);
#endif
    /* each channel in its budget's units (inv = 1: the same bits as unscaled); a zero
       channel stays 0, and a bound that is 0 in every channel, or a zero cone, is 0
       even where a channel's inv is ∞ */
    const floatL scaled = MAX_(MAX_(scaled_bound(br, inv->r), scaled_bound(bg, inv->g)),
                               scaled_bound(bb, inv->b));
    const floatL mx = MAX_(MAX_(br, bg), bb);
    /* a zero cone zeroes only a finite bound: ∞·0 (a non-finite tile) stays kept */
    const intL zero = (intL)(mx == 0.0f) | ((intL)(cone == 0.0f) & (intL)(mx < INFINITY));
    const floatL b = SEL_(scaled * cone / p_lo * (1.0f + 32.0f * U_F32), (floatL)(0.0f), zero);
    /* no bound where p⁻ ≤ 0 or anything is NaN: keep the light */
    const floatL safe = SEL_((floatL)(INFINITY), b, (intL)((p_lo > 0.0f) & (b >= 0.0f)));
    return SEL_(safe, (floatL)(0.0f), t->empty);
}

/* 1/B (B = 0: +inf, nothing but zero bounds dropped) */
inline floatL inverse_budget(floatL B)
{
    return SEL_((floatL)(INFINITY), 1.0f / B, (intL)(B > 0.0f));
}

/* The relative budget: 1/B_c of work-item i's tiles per channel (tile_floor's three
 * planes from tile_budget on), or 1 (absolute: bounds as they are). */
inline inv3_t budget_inverse(__global const float *tile_budget, uint relative, size_t i,
                             uint n_tiles_pad)
{
    inv3_t v;
    if (!relative) {
        v.r = v.g = v.b = (floatL)(1.0f);
        return v;
    }
    v.r = inverse_budget(vloadL(i, tile_budget));
    v.g = inverse_budget(vloadL(i, tile_budget + n_tiles_pad));
    v.b = inverse_budget(vloadL(i, tile_budget + 2 * (size_t)n_tiles_pad));
    return v;
}

/* Light groups under the relative budget: the lights are in group order, so a walk
 * in light order moves to group g's budget plane once j reaches the previous group's end
 * (n_groups = 0: one group, nothing to do). */
inline void next_group(uint j, uint *g, uint *g_end, inv3_t *inv, uint n_groups,
                       __global const uint *point_end, __global const float *tile_budget,
                       uint n_tiles_pad, size_t i)
{
    while (j >= *g_end) {
        *g += 1;
        *g_end = *g < n_groups ? point_end[*g] : 0xffffffffu;
        *inv = budget_inverse(tile_budget + 3 * (size_t)(*g) * n_tiles_pad, 1u, i, n_tiles_pad);
    }
}

/* The budget the float32 sums may use: computed sums of n positive terms are
 * within (n − 1)u of the exact ones, so ε·(1 − 2n·u) keeps the exact dropped
 * sum ≤ ε. */
inline float usable_budget(float budget, uint n)
{
    return MAX_(budget * (1.0f - 2.0f * (float)n * U_F32), 0.0f);
}

/* The candidate lights of work-item i's LANES tiles, as (first, count): all
 * n_point lights, or the list of the super-tile holding the LANES tiles (the host
 * pads tiles_x to a multiple of CULL_SUPER ≥ LANES, so they share one). */
inline uint2 candidates(size_t i, __global const uint2 *cand_ranges, uint use_cand, uint n_point,
                        uint tiles_x, uint super_tiles)
{
    if (!use_cand)
        return (uint2)(0, n_point);
    const uint t = (uint)(i * LANES);
    const uint s = (t / tiles_x / CULL_SUPER) * (tiles_x / CULL_SUPER) + (t % tiles_x) / CULL_SUPER;
    return s < super_tiles ? cand_ranges[s] : (uint2)(0, 0);
}

/* Lower bound of n_c·w_c for n_c ∈ [a, b], w_c ∈ [lo, hi]: the smallest corner product. */
inline floatL interval_product_min(floatL a, floatL b, floatL lo, floatL hi)
{
    return MIN_(MIN_(a * lo, a * hi), MIN_(b * lo, b * hi));
}

/* The relative budget's floor (clphong/device/culling.py, relative=True): per tile,
 * a proven lower bound T⁻_c of every shaded pixel's total in each channel c, and
 * the tile's budgets scale·T⁻_c, one plane per channel (three per light group), written
 * to budget_out (output radiance). The
 * total's terms are all ≥ 0 where the host calls this (no negative radiance): the
 * specular terms are bounded below by 0, and every other term by
 *   ambient      A_c·min C_d,c;
 *   directional  L_c·min D_c·max(NoL⁻, 0), NoL⁻ = Σ_k min(n_k·l_k) over the box of n;
 *   point        L_c·min D_c·max(NoL⁻, 0)/p⁺, NoL⁻ = (lower bound of n·(L − P) over
 *                the boxes)/d⁺ − the kernel's margin for n·l (light_bound's), and
 *                p⁺ = p(d⁺) for c0, c1, c2 ≥ 0 (p increasing); 0 for a spot (its cone
 *                is not bounded below) or any other falloff;
 *   cluster      a light tree's representative (F.w = r > 0: a ball of radius r about
 *                its record holds every light it stands for, pack_cull_lights): as a
 *                point light whose d⁻ is less r and d⁺ more r, and n·(L − P) less |n|·r.
 *                Each of its lights y adds R_y·(n·u)⁺/p(d) ≥ R_y·NoL⁻/p⁺, and R = Σ R_y;
 *                representatives marked F.z = 1 add 0;
 * each rounded down (1 − 32u), and the float32 sum of n terms by (1 − 2nu). A tile
 * with a negative minimum of D, C_d or S, or a NaN in any of its pixels' inputs
 * (tile_bounds writes min D_r = −∞ then), has no floor: budget 0 (nothing dropped
 * that could matter). Lights are the candidates (the super-tile's kept lights at the fine
 * level): dropped lights add ≥ 0, so the floor over fewer lights still holds. */
__kernel void tile_floor(__global const float *restrict tiles, const uint n_tiles_pad,
                         __global const float4 *restrict lights, const uint n_point,
                         __global const uint2 *restrict cand_ranges,
                         __global const uint *restrict cand_lights, const uint use_cand,
                         const uint tiles_x, const uint super_tiles,
                         __global const float4 *restrict dirs, const uint n_dir,
                         const float4 ambient, const float scale,
                         /* light groups (n_groups > 0): each group's point and directional
                            ends (the lights are in group order) and k_a·A_g, rounded down */
                         const uint n_groups, __global const uint *restrict point_end,
                         __global const uint *restrict dir_end,
                         __global const float4 *restrict group_ambient,
                         __global float *restrict budget_out)
{
    const size_t i = get_global_id(0);
    if ((i + 1) * LANES > n_tiles_pad)
        return;
    const tile_t t = load_tiles(tiles, i, n_tiles_pad);
    const floatL Dmr = vloadL(i, tiles + T_DMR * n_tiles_pad);
    const floatL Dmg = vloadL(i, tiles + T_DMG * n_tiles_pad);
    const floatL Dmb = vloadL(i, tiles + T_DMB * n_tiles_pad);
    const floatL Cmr = vloadL(i, tiles + T_CMR * n_tiles_pad);
    const floatL Cmg = vloadL(i, tiles + T_CMG * n_tiles_pad);
    const floatL Cmb = vloadL(i, tiles + T_CMB * n_tiles_pad);
    const floatL Smin = vloadL(i, tiles + T_SMIN * n_tiles_pad);
    const floatL low = (floatL)(1.0f - 32.0f * U_F32);
    const intL negative = (intL)(Dmr < 0.0f) | (intL)(Dmg < 0.0f) | (intL)(Dmb < 0.0f)
                          | (intL)(Cmr < 0.0f) | (intL)(Cmg < 0.0f) | (intL)(Cmb < 0.0f)
                          | (intL)(Smin < 0.0f);
    const float sum_low = MAX_(1.0f - 2.0f * (float)(n_point + n_dir + 1) * U_F32, 0.0f);
    const uint2 range = candidates(i, cand_ranges, use_cand, n_point, tiles_x, super_tiles);
    uint c = range.x;                      /* candidates in light order: group by group */
    for (uint g = 0; g < (n_groups ? n_groups : 1u); ++g) {
        const float4 amb = n_groups ? group_ambient[g] : ambient;
        const uint d_begin = n_groups && g ? dir_end[g - 1] : 0u;
        const uint d_end = n_groups ? dir_end[g] : n_dir;
        const uint p_end = n_groups ? point_end[g] : 0xffffffffu;
        /* ambient */
        floatL Tr = MAX_(amb.x * Cmr, 0.0f) * low, Tg = MAX_(amb.y * Cmg, 0.0f) * low,
               Tb = MAX_(amb.z * Cmb, 0.0f) * low;
        /* directional lights: (l, 0) (L, 0) then 4 float4s the bound does not read */
        for (uint j = d_begin; j < d_end; ++j) {
            const float4 l = dirs[6 * j], L = dirs[6 * j + 1];
            const floatL nx = MIN_(t.nlox * l.x, t.nhix * l.x);
            const floatL ny = MIN_(t.nloy * l.y, t.nhiy * l.y);
            const floatL nz = MIN_(t.nloz * l.z, t.nhiz * l.z);
            /* the sum's roundings, and the normal's and l's float32 roundings (4u) */
            const floatL w = MAX_((nx + ny + nz) - 8.0f * U_F32 * (ABS_(nx) + ABS_(ny) + ABS_(nz))
                                  - 4.0f * U_F32, 0.0f) * low;
            Tr = MUL_ADD(L.x * w, Dmr, Tr);
            Tg = MUL_ADD(L.y * w, Dmg, Tg);
            Tb = MUL_ADD(L.z * w, Dmb, Tb);
        }
        for (; c < range.x + range.y; ++c) {
            const uint j = use_cand ? cand_lights[c] : c;
            if (j >= p_end)
                break;                     /* the next group's */
            const __global float4 *Lr = lights + CULL_LIGHT_FLOAT4S * j;
            const float4 A = Lr[0], B = Lr[1], C = Lr[2], E = Lr[3], F = Lr[4];
            if (F.x != 0.0f || F.z != 0.0f || A.w < 0.0f || B.x < 0.0f
                || B.y < 0.0f)
                continue;  /* a spot, a coefficient float32 cannot hold to a relative u
                              (F.z), a falloff not increasing in d */
            const float rad = F.w;         /* a cluster's ball (0: a light) */
            const floatL dx = MAX_(t.lox - A.x, 0.0f) + MAX_(A.x - t.hix, 0.0f);
            const floatL dy = MAX_(t.loy - A.y, 0.0f) + MAX_(A.y - t.hiy, 0.0f);
            const floatL dz = MAX_(t.loz - A.z, 0.0f) + MAX_(A.z - t.hiz, 0.0f);
            const floatL d_lo0 = MAX_(MUL_ADD(sqrt(MUL_ADD(dx, dx, MUL_ADD(dy, dy, dz * dz))),
                                             (floatL)(1.0f - 16.0f * U_F32),
                                             -2.0f * U_F32 * (t.R + E.x)), 0.0f);
            const floatL fx = MAX_(ABS_(t.lox - A.x), ABS_(t.hix - A.x));
            const floatL fy = MAX_(ABS_(t.loy - A.y), ABS_(t.hiy - A.y));
            const floatL fz = MAX_(ABS_(t.loz - A.z), ABS_(t.hiz - A.z));
            const floatL d_hi0 = MUL_ADD(sqrt(MUL_ADD(fx, fx, MUL_ADD(fy, fy, fz * fz))),
                                        (floatL)(1.0f + 16.0f * U_F32), 2.0f * U_F32 * (t.R + E.x));
            const floatL lx = interval_product_min(t.nlox, t.nhix, A.x - t.hix, A.x - t.lox);
            const floatL ly = interval_product_min(t.nloy, t.nhiy, A.y - t.hiy, A.y - t.loy);
            const floatL lz = interval_product_min(t.nloz, t.nhiz, A.z - t.hiz, A.z - t.loz);
            const floatL lb0 = (lx + ly + lz) - 8.0f * U_F32 * (ABS_(lx) + ABS_(ly) + ABS_(lz));
            /* a cluster: every light within r of the record (|n| ≤ 1 + 16u; the sums'
               and products' roundings: (1 ∓ 4u), 4u of the terms) */
            const floatL d_lo = rad > 0.0f ? MAX_(d_lo0 - rad * (1.0f + 4.0f * U_F32), 0.0f)
                                             * (1.0f - 4.0f * U_F32) : d_lo0;
            const floatL d_hi = rad > 0.0f ? (d_hi0 + rad) * (1.0f + 4.0f * U_F32) : d_hi0;
            const floatL lb = rad > 0.0f ? lb0 - rad * (1.0f + 16.0f * U_F32)
                                           - 4.0f * U_F32 * (ABS_(lb0) + rad) : lb0;
            const floatL margin = U_F32 * (12.0f + 2.0f * (t.R + E.x) / d_lo);
            /* d⁻ = 0 (the light may be in the box): margin = +inf, no floor */
            const floatL NoL_lo = MAX_(SEL_(lb / d_hi - margin, (floatL)(0.0f),
                                            (intL)(d_lo <= 0.0f)), 0.0f);
            const floatL p_hi = MUL_ADD(d_hi, MUL_ADD(d_hi, (floatL)(B.y), (floatL)(B.x)),
                                        (floatL)(A.w)) * (1.0f + 8.0f * U_F32);
            /* p⁺ = 0 or ∞ (or NaN) adds nothing */
            const floatL w = SEL_((floatL)(0.0f), NoL_lo / p_hi * low,
                                  (intL)((p_hi > 0.0f) & (p_hi < INFINITY) & (NoL_lo > 0.0f)));
            Tr = MUL_ADD(C.y * w, Dmr, Tr);
            Tg = MUL_ADD(C.z * w, Dmg, Tg);
            Tb = MUL_ADD(C.w * w, Dmb, Tb);
        }
        /* T_c ≥ 0 is false for NaN; a tile without a floor in one channel gets none in
           any (all its budgets 0) */
        const intL ok = (intL)(!negative) & (intL)(Tr >= 0.0f) & (intL)(Tr < INFINITY)
                        & (intL)(Tg >= 0.0f) & (intL)(Tg < INFINITY)
                        & (intL)(Tb >= 0.0f) & (intL)(Tb < INFINITY) & (intL)(!t.empty);
        /* (1 − 2u): the roundings of · sum_low and · scale */
        const float k = scale * (1.0f - 2.0f * U_F32);
        __global float *out = budget_out + 3 * (size_t)g * n_tiles_pad;
        vstoreL(SEL_((floatL)(0.0f), Tr * sum_low * k, ok), i, out);
        vstoreL(SEL_((floatL)(0.0f), Tg * sum_low * k, ok), i, out + n_tiles_pad);
        vstoreL(SEL_((floatL)(0.0f), Tb * sum_low * k, ok), i, out + 2 * (size_t)n_tiles_pad);
    }
}

__kernel void cull_count(__global const float *restrict tiles, const uint n_tiles_pad,
                         __global const float4 *restrict lights, const uint n_point,
                         /* candidates: with use_cand, the lights of this work-item's
                            super-tile (a coarse pass's lists), else all n_point */
                         __global const uint2 *restrict cand_ranges,
                         __global const uint *restrict cand_lights, const uint use_cand,
                         const uint tiles_x, const uint super_tiles,
                         const float budget,
                         /* relative: each tile's own budget (tile_floor), else budget; with
                            n_groups, one plane of budgets per light group */
                         __global const float *restrict tile_budget, const uint relative,
                         const uint n_groups, __global const uint *restrict point_end,
                         __global float *restrict tau_out,
                         __global float *restrict left_out,
                         __global uint *restrict capacity_out)
{
    const size_t i = get_global_id(0);
    if ((i + 1) * LANES > n_tiles_pad)
        return;
    const tile_t t = load_tiles(tiles, i, n_tiles_pad);
    /* relative: the bounds in units of the tile's budget B (b·(1/B), 2 roundings: 4u
       off the budget of 1), so that the thresholds below stay one per level */
    const float eps = relative ? usable_budget(1.0f, n_point) * (1.0f - 4.0f * U_F32)
                               : usable_budget(budget, n_point);
    inv3_t inv = budget_inverse(tile_budget, relative, i, n_tiles_pad);
    uint g = 0, g_end = n_groups ? point_end[0] : 0xffffffffu;
    float tau[CULL_LEVELS];
    floatL sum[CULL_LEVELS];
    intL below[CULL_LEVELS];
    float level = eps;
    for (int m = 0; m < CULL_LEVELS; ++m) {
        level *= 0.5f;
        tau[m] = level;
        sum[m] = (floatL)(0.0f);
        below[m] = (intL)(0);
    }
    const uint2 range = candidates(i, cand_ranges, use_cand, n_point, tiles_x, super_tiles);
    for (uint c = range.x; c < range.x + range.y; ++c) {
        const uint j = use_cand ? cand_lights[c] : c;
        const __global float4 *L = lights + CULL_LIGHT_FLOAT4S * j;
        next_group(j, &g, &g_end, &inv, n_groups, point_end, tile_budget, n_tiles_pad, i);
        const floatL b = light_bound(&t, L[0], L[1], L[2], L[3], L[4], &inv);
        for (int m = 0; m < CULL_LEVELS; ++m) {
            const intL is_below = (intL)(b < tau[m]);
            sum[m] += SEL_((floatL)(0.0f), b, is_below);
            below[m] -= is_below;            /* a true comparison is −1 per lane */
        }
    }
    /* the largest τ whose dropped sum fits; none: τ = 0 (nothing below it) */
    floatL best_tau = (floatL)(0.0f), best_sum = (floatL)(0.0f);
    intL best_below = (intL)(0);
    for (int m = CULL_LEVELS - 1; m >= 0; --m) {
        const intL fits = (intL)(sum[m] <= eps);
        best_tau = select(best_tau, (floatL)(tau[m]), fits);
        best_sum = select(best_sum, sum[m], fits);
        best_below = select(best_below, below[m], fits);
    }
#if LANES == 1
    /* scalar comparisons give 1, not −1: `below` counted down */
    best_below = -best_below;
#endif
    vstoreL(best_tau, i, tau_out);
    vstoreL(fmax(eps - best_sum, 0.0f), i, left_out);
    const intL cap = (intL)(range.y) - best_below;
#if LANES == 1
    capacity_out[i] = (uint)cap;
#else
    int caps[LANES];
    vstoreI(cap, caps);
    for (int m = 0; m < LANES; ++m)
        capacity_out[i * LANES + m] = caps[m];
#endif
}

__kernel void cull_write(__global const float *restrict tiles, const uint n_tiles_pad,
                         __global const float4 *restrict lights, const uint n_point,
                         /* candidates: with use_cand, the lights of this work-item's
                            super-tile (a coarse pass's lists), else all n_point */
                         __global const uint2 *restrict cand_ranges,
                         __global const uint *restrict cand_lights, const uint use_cand,
                         const uint tiles_x, const uint super_tiles,
                         __global const float *restrict tile_budget, const uint relative,
                         const uint n_groups, __global const uint *restrict point_end,
                         __global const float *restrict tau_in,
                         /* cull_count's unused budget in; what the greedy drops below
                            leave of it out (the light tree's cut adds a super-tile's) */
                         __global float *restrict left_io,
                         __global const uint *restrict offsets,
                         __global uint *restrict counts_out,
                         __global uint *restrict tile_lights)
{
    const size_t i = get_global_id(0);
    if ((i + 1) * LANES > n_tiles_pad)
        return;
    const tile_t t = load_tiles(tiles, i, n_tiles_pad);
    const floatL tau = vloadL(i, tau_in);
    floatL left = vloadL(i, left_io);
    inv3_t inv = budget_inverse(tile_budget, relative, i, n_tiles_pad);
    uint g = 0, g_end = n_groups ? point_end[0] : 0xffffffffu;
    uint off[LANES], cnt[LANES];
    for (int m = 0; m < LANES; ++m) {
        off[m] = offsets[i * LANES + m];
        cnt[m] = 0;
    }
    const uint2 range = candidates(i, cand_ranges, use_cand, n_point, tiles_x, super_tiles);
    for (uint c = range.x; c < range.x + range.y; ++c) {
        const uint j = use_cand ? cand_lights[c] : c;
        const __global float4 *L = lights + CULL_LIGHT_FLOAT4S * j;
        next_group(j, &g, &g_end, &inv, n_groups, point_end, tile_budget, n_tiles_pad, i);
        const floatL b = light_bound(&t, L[0], L[1], L[2], L[3], L[4], &inv);
        const intL at_or_above = (intL)(b >= tau);   /* b is never NaN (light_bound) */
        const intL greedy = at_or_above & (intL)(b <= left);
        left = SEL_(left, left - b, greedy);
        const intL keep = at_or_above & ~greedy;
#if LANES == 1
        if (keep)
            tile_lights[off[0] + cnt[0]++] = j;
#else
        if (any(keep)) {
            int k[LANES];
            vstoreI(keep, k);
            for (int m = 0; m < LANES; ++m)
                if (k[m])
                    tile_lights[off[m] + cnt[m]++] = j;
        }
#endif
    }
    for (int m = 0; m < LANES; ++m)
        counts_out[i * LANES + m] = cnt[m];
    vstoreL(left, i, left_io);
}

/* Directional lights per tile (DIR_CULLING, clphong/device/culling.py build_dir_lists):
 * a tile keeps light l unless the shading kernel's n·l is ≤ 0 at every one of its
 * pixels, where the light adds exactly 0 (max(n·l, 0) = 0, the specular term gated
 * on n·l > 0): so the lists change no pixel. The bound of the kernel's n·l over the
 * tile's box of normals: Σ_c max(nlo_c·l_c, nhi_c·l_c), plus the roundings of that
 * sum (8u of its terms) and of the kernel's n·l from the hi + lo normal and direction
 * (32u: |n|, |l| ≈ 1). NaN keeps the light. One work-item per tile (not LANES tiles:
 * each tile's loop is short and the implicit vectoriser takes the tiles). */
inline int dir_reaches(__global const float *tiles, uint n_tiles_pad, uint t, float4 l)
{
    const float a = MAX_(tiles[T_NLOX * n_tiles_pad + t] * l.x, tiles[T_NHIX * n_tiles_pad + t] * l.x);
    const float b = MAX_(tiles[T_NLOY * n_tiles_pad + t] * l.y, tiles[T_NHIY * n_tiles_pad + t] * l.y);
    const float c = MAX_(tiles[T_NLOZ * n_tiles_pad + t] * l.z, tiles[T_NHIZ * n_tiles_pad + t] * l.z);
    const float ub = (a + b + c) + 8.0f * U_F32 * (ABS1_(a) + ABS1_(b) + ABS1_(c)) + 32.0f * U_F32;
    return !(ub <= 0.0f);
}

inline int tile_is_empty(__global const float *tiles, uint n_tiles_pad, uint t)
{
    return tiles[T_LOX * n_tiles_pad + t] > tiles[T_HIX * n_tiles_pad + t];
}

/* A tile whose inputs hold a NaN or an infinity (--nonfinite pass lets them through):
 * there a light facing away adds ∞·0 = NaN, not 0, so the tile keeps every light. Its
 * box, |P|, D and S planes not finite, or tile_bounds' NaN flag (min D_r = −∞). */
inline int tile_is_nonfinite(__global const float *tiles, uint n_tiles_pad, uint t)
{
    int bad = tiles[T_DMR * n_tiles_pad + t] == -INFINITY;
    for (int k = T_LOX; k <= T_R; ++k)
        bad |= !isfinite(tiles[k * n_tiles_pad + t]);
    return bad;
}

__kernel void dir_count(__global const float *restrict tiles, const uint n_tiles_pad,
                        const uint n_tiles, __global const float4 *restrict dirs,
                        const uint n_dir, __global uint *restrict count_out)
{
    const uint t = get_global_id(0);
    if (t >= n_tiles_pad)
        return;
    uint n = 0;
    if (t < n_tiles && !tile_is_empty(tiles, n_tiles_pad, t)) {
        const int all = tile_is_nonfinite(tiles, n_tiles_pad, t);
        for (uint j = 0; j < n_dir; ++j)
            n += all || dir_reaches(tiles, n_tiles_pad, t, dirs[6 * j]);
    }
    count_out[t] = n;
}

__kernel void dir_write(__global const float *restrict tiles, const uint n_tiles_pad,
                        const uint n_tiles, __global const float4 *restrict dirs,
                        const uint n_dir, __global const uint *restrict offsets,
                        __global const uint *restrict counts, __global uint *restrict lists)
{
    const uint t = get_global_id(0);
    if (t >= n_tiles || tile_is_empty(tiles, n_tiles_pad, t))
        return;
    const int all = tile_is_nonfinite(tiles, n_tiles_pad, t);
    uint k = offsets[t];
    const uint end = k + counts[t];      /* dir_count's: never past it, whatever the compiler */
    for (uint j = 0; j < n_dir && k < end; ++j)
        if (all || dir_reaches(tiles, n_tiles_pad, t, dirs[6 * j]))
            lists[k++] = j;
}

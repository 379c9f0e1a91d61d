/* Lights and distance falloff, after ../shared/phong-model-notes.txt
 * ("Compensation of Light Distance", "Multiple Lights"). Mirrored by the float64
 * reference (clphong/reference/). */
#ifndef CLPHONG_LIGHTS_H
#define CLPHONG_LIGHTS_H
#include "clphong.h"
#include "plan.h"
#include "brdf.h"

/* 1/(c0 + c1·d + c2·d²), Horner form, in dirL: with DIRECTIONS_FP64 it cannot
 * under- or overflow for float inputs (c2·d² at d = 1e-20 is 1e-40, below float's
 * normal range). The scene parser rejects polynomials that go negative for
 * d ≥ 0; c0 = 0 reaches 0 only at d = 0, where shade_point_light adds nothing. */
inline dirL attenuation(dirS c0, dirS c1, dirS c2, dirL d)
{
#if HAS_ATTENUATION
    return 1.0f / MUL_ADD(d, MUL_ADD(d, (dirL)(c2), (dirL)(c1)), (dirL)(c0));
#else
    /* every point light has c1 = c2 = 0 (clphong/device/plan.py): the same 1/c0,
       once per light instead of a division per pixel */
    return (dirL)(1.0f / c0);
#endif
}

/* A pixel's shading inputs, all rebased or unit as described in shade.cl. */
typedef struct {
    dirL px, py, pz;        /* position, minus the frame origin and quartered (as it is
                               with DIRECTIONS_FP64): the point lights' loop's units */
    dirL nx, ny, nz;        /* unit normal */
    dirL vx, vy, vz;        /* unit direction to the viewer */
#if SPEC_COS
    dirL NoV;               /* n·v */
#endif
#if HAS_SPECULAR && SPEC_INT_POW
    uint K;                 /* the whole specular exponent, the same for every pixel
                               (K/2 with SPEC_COS and Blinn: the base is (n·h)²) */
#elif HAS_SPECULAR
    wL k;                   /* specular exponent: h (Phong) or 4h (Blinn); the scene's
                               float64 value (as hi + lo) with WEIGHTS_FP64 */
#endif
} pixel_t;

/* The specular power of δ at pixel p in the plan's form (brdf.h), as wL. */
#if SPEC_INT_POW
#define SPECULAR_POWER(delta, p) specular_power_int((delta), (p)->K)
#elif WEIGHTS_FP64
#define SPECULAR_POWER(delta, p) specular_power_fp64((delta), (p)->k)
#else
#define SPECULAR_POWER(delta, p) FLOAT_TO_W(specular_power(TO_FLOAT(delta), (p)->k))
#endif

/* Diffuse and specular weights of one light at a pixel: the factors of
 * C_d·k_d and C_s·k_s, before the light's radiance and falloff (wL: double with
 * WEIGHTS_FP64, else float). */
typedef struct {
    wL diffuse;
    wL specular;
#if FRESNEL && MODEL_BLINN
    wL fresnel;      /* specular × (1 − v·h)⁵: the part of W that varies per light */
#endif
} weights_t;

#if FRESNEL && MODEL_BLINN
/* cos α = v·h = √((1 + l·v)/2) for h = (l + v)/|l + v| (l = −v: h is undefined,
 * the specular weight is 0, and this is 0). */
inline dirL v_dot_h(const pixel_t *p, dirL lx, dirL ly, dirL lz)
{
    const dirL x = (dirL)(0.5f) * ((dirL)(1.0f) + MUL_ADD(lx, p->vx, MUL_ADD(ly, p->vy, lz * p->vz)));
    return sqrt(SELECT_DIR(x, (dirL)(0.0f), x < (dirL)(0.0f)));
}
#endif

/* Both terms for a unit direction l towards the light. The specular term is on
 * only where n·l > 0 (the notes' E_S needs a lit side); the gate uses n·l
 * as the weights have it (rounded to float unless WEIGHTS_FP64), whose sign is
 * that of the dirL value (or 0). */
inline weights_t shade_direction(const pixel_t *p, dirL lx, dirL ly, dirL lz, dirL NoL_dir)
{
    weights_t w;
    const wL NoL = DIR_TO_W(NoL_dir);
    w.diffuse = lambert(NoL);
#if HAS_SPECULAR && SPEC_COS
#if MODEL_BLINN
    const dirL x = blinn_cos_sq(lx, ly, lz, p->vx, p->vy, p->vz, NoL_dir, p->NoV);
#else
    const dirL x = phong_cos(lx, ly, lz, p->vx, p->vy, p->vz, NoL_dir, p->NoV);
#endif
    w.specular = SELECT((wL)(0.0f), specular_power_cos(x, p->K), NoL > 0.0f);
#elif HAS_SPECULAR
#if MODEL_BLINN
    const dirL delta = blinn_delta(p->nx, p->ny, p->nz, lx, ly, lz, p->vx, p->vy, p->vz);
#else
    const dirL delta = phong_delta(p->nx, p->ny, p->nz, lx, ly, lz, p->vx, p->vy, p->vz, NoL_dir);
#endif
    w.specular = SELECT((wL)(0.0f), SPECULAR_POWER(delta, p), NoL > 0.0f);
#else
    w.specular = (wL)(0.0f);
#endif
#if FRESNEL && MODEL_BLINN
    w.fresnel = w.specular * DIR_TO_W(schlick_weight(v_dot_h(p, lx, ly, lz)));
#endif
    return w;
}

/* A spot's cone factor (glTF KHR_lights_punctual, Filament): t², t = clamp(cos θ·s
 * + o, 0, 1), θ the angle between the spot's unit axis a and the direction from
 * the light to the shaded point, −l: cos θ = −l·a. s = 1/(cos inner − cos outer)
 * and o = −cos outer·s come from the host in float64 (scene.spot_scale_offset);
 * a point light's record has a = 0, s = 0, o = 1: a factor of exactly 1.
 */
inline dirL spot_factor(dirL lx, dirL ly, dirL lz, dirS ax, dirS ay, dirS az, dirS s, dirS o)
{
    const dirL cos_theta = -MUL_ADD(lx, (dirL)(ax), MUL_ADD(ly, (dirL)(ay), lz * (dirL)(az)));
    const dirL t = clamp01(MUL_ADD(cos_theta, (dirL)(s), (dirL)(o)));
    return t * t;
}

/* A point light at L (rebased on the frame origin and quartered, or as it is with
 * DIRECTIONS_FP64), falloff coefficients c0, c1 (4c1 quartered),
 * c2 (16c2 quartered) and radiance R, all in dirS (double from the host's float64 records
 * with DIRECTIONS_FP64, shade.cl): l = (L − P)/d. With FALLOFF_ON_WEIGHTS (plan.py)
 * returns the weights times attenuation(d) and in *ar, *ag, *ab the radiance. Else returns
 * the unattenuated weights (≤ 1), and in *ar, *ag, *ab the light's radiance times
 * attenuation(d), formed in dirL and then converted to the weights' type, so that a huge
 * falloff and a tiny intensity (or the reverse) meet before anything is rounded to float.
 * Guards: a light exactly at the shaded point (d = 0) has no direction; it
 * contributes nothing (l := 0, d := 0, so n·l = 0 switches both terms off), as in
 * the reference. In float, d²/16 is capped at 2¹²⁵ (RSQRT_LIGHT, clphong.h): a light that
 * far (d ≥ 2⁶⁴·√2, where the error model calls the pixels unbounded) gets nothing from
 * POINT_GUARD's selects, which the plan compiles for any frame with a light 2⁶⁴ or more
 * from a pixel (frame.has_far_lights). */
#ifndef FALLOFF_ON_WEIGHTS
#error "FALLOFF_ON_WEIGHTS must be set by the shading plan (clphong/device/plan.py)"
#endif
inline weights_t shade_point_light(const pixel_t *p, dirS Lx, dirS Ly, dirS Lz,
                                   dirS c0, dirS c1, dirS c2, dirS Rr, dirS Rg, dirS Rb,
#if HAS_SPOT
                                   dirS ax, dirS ay, dirS az, dirS s, dirS o,
#endif
                                   wL *ar, wL *ag, wL *ab)
{
    const dirL dx = Lx - p->px, dy = Ly - p->py, dz = Lz - p->pz;
    const dirL d2 = MUL_ADD(dx, dx, MUL_ADD(dy, dy, dz * dz));
#if DIRECTIONS_FP64
    const dirL inv_d = SELECT_DIR(RSQRT_DIST(d2), (dirL)(0.0f), d2 <= (dirL)(0.0f));
#elif POINT_GUARD
    /* d2 is d²/16 here, and inv_d 4/d (RSQRT_LIGHT: the records come quartered); a light
       beyond the cap (d ≥ 2⁶⁴·√2) gets l = 0, as NO_LIGHT's select gives it no falloff */
    const dirL inv_d = SELECT_DIR(RSQRT_LIGHT(d2), (dirL)(0.0f), d2 > (dirL)(LIGHT_D2_CAP));
#else
    const dirL inv_d = RSQRT_LIGHT(d2);   /* d2 = d²/16, inv_d = 4/d; finite at d = 0 (l = 0) */
#endif
    const dirL lx = dx * inv_d, ly = dy * inv_d, lz = dz * inv_d;
    const dirL NoL = MUL_ADD(p->nx, lx, MUL_ADD(p->ny, ly, p->nz * lz));
    weights_t w = shade_direction(p, lx, ly, lz, NoL);
#if DIRECTIONS_FP64
    /* finite in double: |P| ≤ FLT_MAX, and the scene refuses a light position
       beyond float (clphong/model/scene.py), so d² < 3·(2·FLT_MAX)² */
    const dirL d = d2 * inv_d;
#define NO_LIGHT (d2 <= (dirL)(0.0f))     /* d = 0: 1/c0 may be ∞ (POINT_GUARD) */
#else
    /* d/4, which the records' 4c1 and 16c2 expect; finite, as inv_d is (the cap) */
    const dirL d = d2 * inv_d;
    /* d = 0, or d² beyond the cap (then d/4 may be ∞·0 = NaN under the guard) */
#define NO_LIGHT ((d2 <= (dirL)(0.0f)) | (d2 > (dirL)(LIGHT_D2_CAP)))
#endif
    /* NO_LIGHT's select only where the plan's POINT_GUARD says some light needs it: at
       d = 0, l = 0 already (both weights 0), so only c0 = 0 (an infinite falloff, ∞·0)
       needs it, or on the float path a 4c1 or 16c2 beyond float (∞·0 at d = 0); and a
       frame with a light beyond the cap from some pixel (float path), whose l and falloff
       would be wrong there: it gets nothing, as the error model's "unbounded" pixels say.
       Elsewhere the weights are 0 at d = 0 and the falloff finite: two compares, an or
       and a blend fewer a light. */
#if HAS_SPOT
    /* the cone scales the falloff (at d = 0, l = 0 and the factor is t(o)², times 0) */
    const dirL att0 = attenuation(c0, c1, c2, d) * spot_factor(lx, ly, lz, ax, ay, az, s, o);
#else
    const dirL att0 = attenuation(c0, c1, c2, d);
#endif
#if POINT_GUARD
    const dirL att = SELECT_DIR(att0, (dirL)(0.0f), NO_LIGHT);   /* d = 0 (or ∞): nothing */
#else
    const dirL att = att0;
#endif
#undef NO_LIGHT
#if FALLOFF_ON_WEIGHTS
    /* the plan's FALLOFF_ON_WEIGHTS (double weights, or a float loop whose every falloff
       stays ≤ 1.5, so that D·att·w_d cannot overflow): the weights take att (two
       products), the radiance stays as it is, and the sums form R·(D·att·w_d + S·att·w_s):
       one product a light fewer than (att·R)·(D·w_d + S·w_s) and no more roundings in a
       term (the error model's five: clphong/reference/shading.py). 1.06-1.07x on Intel's
       runtime (Zen 3), both paths; PoCL level (docs/bench.md). */
    w.diffuse *= att;
    w.specular *= att;
#if FRESNEL && MODEL_BLINN
    w.fresnel *= att;
#endif
    *ar = Rr;
    *ag = Rg;
    *ab = Rb;
#else
    *ar = DIR_TO_W(att * Rr);
    *ag = DIR_TO_W(att * Rg);
    *ab = DIR_TO_W(att * Rb);
#endif
    return w;
}

/* A directional light: l is constant (unit, towards the light; l_lo and h_lo
 * are the host's float64 remainders, used with DIRECTIONS_FP64), no falloff. */
inline weights_t shade_directional_light(const pixel_t *p, float4 l, float4 l_lo, float4 h, float4 h_lo)
{
    const dirS lx = HI_LO(l.x, l_lo.x), ly = HI_LO(l.y, l_lo.y), lz = HI_LO(l.z, l_lo.z);
    const dirL NoL = MUL_ADD(p->nx, lx, MUL_ADD(p->ny, ly, p->nz * lz));
#if BLINN_CONST_H && HAS_SPECULAR
    weights_t w;
    const wL NoLw = DIR_TO_W(NoL);
    w.diffuse = lambert(NoLw);
#if SPEC_COS
    const dirL x = blinn_cos_sq_const_h(p->nx, p->ny, p->nz, h, h_lo);
    w.specular = SELECT((wL)(0.0f), specular_power_cos(x, p->K), NoLw > 0.0f);
#else
    const dirL delta = blinn_delta_const_h(p->nx, p->ny, p->nz, h, h_lo);
    w.specular = SELECT((wL)(0.0f), SPECULAR_POWER(delta, p), NoLw > 0.0f);
#endif
#if FRESNEL
    w.fresnel = w.specular * DIR_TO_W(schlick_weight(v_dot_h(p, (dirL)(lx), (dirL)(ly), (dirL)(lz))));
#endif
    return w;
#else
    return shade_direction(p, (dirL)(lx), (dirL)(ly), (dirL)(lz), NoL);
#endif
}

#endif /* CLPHONG_LIGHTS_H */

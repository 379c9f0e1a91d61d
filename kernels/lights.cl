/* Lights and distance falloff, after ../shared/phong-model-notes.txt
 * ("Compensation of Light Distance", "Multiple Lights"). Mirrored in float64
 * by clphong/reference.py. */
#ifndef LIGHTS_CL
#define LIGHTS_CL
#include "clphong.h"
#include "brdf.cl"

/* 1/(c0 + c1·d + c2·d²), Horner form. The scene parser rejects polynomials that
 * reach zero or go negative for d ≥ 0, so the denominator is positive. */
inline floatL attenuation(float c0, float c1, float c2, floatL d)
{
    return 1.0f / MUL_ADD(d, MUL_ADD(d, (floatL)(c2), (floatL)(c1)), (floatL)(c0));
}

/* A pixel's shading inputs, all rebased or unit as described in shade.cl. */
typedef struct {
    floatL px, py, pz;      /* position, minus the frame origin */
    floatL nx, ny, nz;      /* unit normal */
    floatL vx, vy, vz;      /* unit direction to the viewer */
#if HAS_SPECULAR
    floatL k;               /* specular exponent: h (Phong) or 4h (Blinn) */
#endif
} pixel_t;

/* Diffuse and specular weights of one light at a pixel: the factors of
 * C_d·k_d and C_s·k_s, before the light's radiance and falloff. */
typedef struct {
    floatL diffuse;
    floatL specular;
} weights_t;

/* Both terms for a unit direction l towards the light. The specular term is on
 * only where n·l > 0 (the notes' E_S needs a lit side). */
inline weights_t shade_direction(const pixel_t *p, floatL lx, floatL ly, floatL lz, floatL NoL)
{
    weights_t w;
    w.diffuse = lambert(NoL);
#if HAS_SPECULAR
#if MODEL_BLINN
    const floatL delta = blinn_delta(p->nx, p->ny, p->nz, lx, ly, lz, p->vx, p->vy, p->vz);
#else
    const floatL delta = phong_delta(p->nx, p->ny, p->nz, lx, ly, lz, p->vx, p->vy, p->vz, NoL);
#endif
    w.specular = select((floatL)(0.0f), specular_power(delta, p->k), (intL)(NoL > 0.0f));
#else
    w.specular = (floatL)(0.0f);
#endif
    return w;
}

/* A point light at L (rebased): l = (L − P)/d, scaled by attenuation(d).
 * Guard: a light exactly at the shaded point (d = 0) has no direction; it
 * contributes nothing (NoL := 0 switches both terms off). */
inline weights_t shade_point_light(const pixel_t *p, float4 L, float c1, float c2)
{
    const floatL dx = L.x - p->px, dy = L.y - p->py, dz = L.z - p->pz;
    const floatL d2 = MUL_ADD(dx, dx, MUL_ADD(dy, dy, dz * dz));
    /* d = 0 (the light at the shaded point): l := 0 and d := 0, so n.l = 0 and
       nothing is added, as in the reference; rsqrt(0) = inf would give 0*inf = NaN. */
    const intL at_light = (intL)(d2 <= 0.0f);
    const floatL inv_d = select(rsqrt(d2), (floatL)(0.0f), at_light);
    const floatL lx = dx * inv_d, ly = dy * inv_d, lz = dz * inv_d;
    floatL NoL = MUL_ADD(p->nx, lx, MUL_ADD(p->ny, ly, p->nz * lz));
    NoL = select(NoL, (floatL)(0.0f), at_light);
    weights_t w = shade_direction(p, lx, ly, lz, NoL);
    const floatL att = attenuation(L.w, c1, c2, d2 * inv_d);
    w.diffuse *= att;
    w.specular *= att;
    return w;
}

/* A directional light: l is constant (unit, towards the light), no falloff. */
inline weights_t shade_directional_light(const pixel_t *p, float4 l, float4 h)
{
    const floatL NoL = MUL_ADD(p->nx, l.x, MUL_ADD(p->ny, l.y, p->nz * l.z));
#if BLINN_CONST_H && HAS_SPECULAR
    weights_t w;
    w.diffuse = lambert(NoL);
    const floatL delta = blinn_delta_const_h(p->nx, p->ny, p->nz, h);
    w.specular = select((floatL)(0.0f), specular_power(delta, p->k), (intL)(NoL > 0.0f));
    return w;
#else
    return shade_direction(p, (floatL)(l.x), (floatL)(l.y), (floatL)(l.z), NoL);
#endif
}

#endif /* LIGHTS_CL */

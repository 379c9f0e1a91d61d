/* clphong device code: what the scene needs, as the shading plan chose it.
 *
 * The shading kernels (shade.cl, shade_obvious.cl) and lights.h compile in only
 * what the scene uses, with these -D defines of the host's shading plan
 * (clphong/device/plan.py), which must set every one of them (clphong.h lists
 * the other headers' defines):
 *
 *   MODEL_BLINN      0: Phong (r·v)^h           1: Blinn-Phong (n·h)^(4h)
 *   HAS_POINT        point lights present (with 1/(c0 + c1·d + c2·d²) falloff)
 *   HAS_SPOT         some point light is a spot: its falloff is scaled by the cone
 *                    factor t², t = clamp(cos θ·s + o, 0, 1) (lights.h, spot_factor)
 *   HAS_DIRECTIONAL  directional lights present (no falloff)
 *   HAS_SPECULAR     k_s > 0 somewhere (uniform or in a map)
 *   FRESNEL          Schlick's weight W(α) in place of C_s (material.fresnel), with
 *                    f0 per channel as float32 bits FRESNEL_F0R, _G, _B and their
 *                    float64 remainders FRESNEL_F0R_LO, … (shade.cl)
 *   CAMERA_ORTHO     viewer at infinity: v is constant
 *   BLINN_CONST_H    orthographic camera + Blinn: each directional light's half vector is
 *                    constant and precomputed on the host (Blinn 1977)
 *   MAP_KD, MAP_KS, MAP_H, MAP_CS   per-pixel material maps present
 *   SPEC_GREY        k_s·C_s has three equal channels (no C_s map, no Fresnel): one S
 *                    serves all three, so S·w_s is formed once a light (the same bits)
 *   COMPENSATED_SUM  Neumaier-compensated light sum (error ~2u instead of ~N·u)
 *   HAS_ATTENUATION  some point light has c1 ≠ 0 or c2 ≠ 0; 0: the falloff is 1/c0,
 *                    a constant per light (no distance polynomial, no division per pixel)
 *   POINT_GUARD      some point light has c0 = 0; or, on the float lanes path, a light
 *                    2⁶⁴ or more from a pixel of the frame: the selects of lights.h for
 *                    d = 0 (and beyond the cap in float); 0: no select
 *   FALLOFF_ON_WEIGHTS  (lane kernel, lights.h) the weights take each light's falloff
 *                    and the radiance stays bare: double weights, or a float loop whose
 *                    every falloff stays ≤ 1.5 (c0 ≥ 0.7, c1, c2 ≥ 0)
 *   CULLING          point lights come from per-tile lists built by cull.cl, whose
 *                    dropped lights sum to at most the user's budget ε
 *                    (clphong/device/culling.py)
 *   CULL_TILE        with CULLING: screen tile edge of the lists, pixels (the culling
 *                    pass's TILE, clphong/device/culling.py, which builds them)
 *   DIR_CULLING      (shade.cl) directional lights from per-tile lists of those some
 *                    normal of the tile may face (cull.cl dir_count): exact; with
 *                    CULL_TILE as their tile edge
 *   COVERAGE         gbuf plane 12 is the coverage α: outputs are α-premultiplied,
 *                    the beauty over the background (α·S + (1 − α)·background)
 *   N_GROUPS         number of light-group layers (0: none); the host sorts lights by group
 *   AOV_DIFFUSE, AOV_SPECULAR   the diffuse (with ambient) and specular layers
 *
 * shade_obvious.cl shades the beauty only: the plan refuses layers for it.
 *
 * shade_obvious.cl reads no culling lists: it sets CULLING = 0 itself. The plan
 * sets BLINN_CONST_H, COMPENSATED_SUM, HAS_ATTENUATION and POINT_GUARD for it too, unused.
 */
#ifndef CLPHONG_PLAN_H
#define CLPHONG_PLAN_H

#ifndef MODEL_BLINN
#error "MODEL_BLINN must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef HAS_POINT
#error "HAS_POINT must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef HAS_SPOT
#error "HAS_SPOT must be set by the shading plan (clphong/device/plan.py)"
#endif
/* float4s (double4s with DIRECTIONS_FP64) per point-light record as the shading
 * kernels read them: (x, y, z, c0) (r, g, b, c1) (c2, ax, ay, az), and a spot's
 * (s, o, 0, 0) only in scenes with spots (clphong/device/frame.py shading_records
 * drops that fourth from the host's records otherwise: 3/4 of the bytes gathered
 * through the tile lists). */
#if HAS_SPOT
#define POINT_LIGHT_FLOAT4S 4
#else
#define POINT_LIGHT_FLOAT4S 3
#endif
#ifndef HAS_DIRECTIONAL
#error "HAS_DIRECTIONAL must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef HAS_SPECULAR
#error "HAS_SPECULAR must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef FRESNEL
#error "FRESNEL must be set by the shading plan (clphong/device/plan.py)"
#endif
#if FRESNEL && !defined(FRESNEL_F0B_LO)
#error "FRESNEL needs FRESNEL_F0R, _G, _B and their _LO remainders (clphong/device/plan.py)"
#endif
#ifndef CAMERA_ORTHO
#error "CAMERA_ORTHO must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef BLINN_CONST_H
#error "BLINN_CONST_H must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef MAP_KD
#error "MAP_KD must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef MAP_KS
#error "MAP_KS must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef MAP_H
#error "MAP_H must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef MAP_CS
#error "MAP_CS must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef SPEC_GREY
#error "SPEC_GREY must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef COMPENSATED_SUM
#error "COMPENSATED_SUM must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef HAS_ATTENUATION
#error "HAS_ATTENUATION must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef POINT_GUARD
#error "POINT_GUARD must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef CULLING
#error "CULLING must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef COVERAGE
#error "COVERAGE must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef N_GROUPS
#error "N_GROUPS must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef AOV_DIFFUSE
#error "AOV_DIFFUSE must be set by the shading plan (clphong/device/plan.py)"
#endif
#ifndef AOV_SPECULAR
#error "AOV_SPECULAR must be set by the shading plan (clphong/device/plan.py)"
#endif
/* CULL_TILE is read only with CULLING (shade.cl's tile of a work-item): only then
   is it required. */
#if CULLING && !defined(CULL_TILE)
#error "CULL_TILE must be set by the shading plan (clphong/device/plan.py) with CULLING"
#endif

#endif /* CLPHONG_PLAN_H */

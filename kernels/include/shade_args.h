/* The kernel arguments of the `shade` entry point, written once: shade.cl and
 * shade_obvious.cl both declare `__kernel void shade(SHADE_ARGS)`, so adding an
 * argument happens here and in the host's one set_args (Renderer.render,
 * clphong/device/renderer.py), which passes them in this order: the frame, the
 * lights and the uniforms, then display_kernel_args (clphong/device/display.py)
 * from `display` on, then with CULLING the tile lists' kernel_args
 * (clphong/device/culling.py), then with DIR_CULLING the directional lists' (the same). shade_obvious.cl takes the same list and ignores
 * what it does not use (the hi + lo remainders: it is all float).
 *
 * pointrec_t is clphong.h's (float4 unless DIRECTIONS_FP64); CULLING is plan.h's.
 */
#ifndef CLPHONG_SHADE_ARGS_H
#define CLPHONG_SHADE_ARGS_H
#include "clphong.h"
#include "plan.h"

#if CULLING
/* per-tile point-light lists (cull.cl): (offset, count) per tile and the kept
   light indices, in light order */
#define SHADE_CULL_ARGS , \
    __global const uint2 *restrict tile_ranges, \
    __global const uint *restrict tile_lights, \
    const uint width, const uint tiles_x, const uint n_tiles
#else
#define SHADE_CULL_ARGS
#endif

#if defined(DIR_CULLING) && DIR_CULLING
/* per-tile directional-light lists (cull.cl dir_count/dir_write): (offset, count) per
   tile and the indices of the lights some normal of the tile may face, in light order;
   the tiles' geometry as the point lists' */
#define SHADE_DIR_ARGS , \
    __global const uint2 *restrict dir_ranges, \
    __global const uint *restrict dir_lights, \
    const uint dir_width, const uint dir_tiles_x, const uint dir_n_tiles
#else
#define SHADE_DIR_ARGS
#endif

#define SHADE_ARGS \
    __global const float *restrict gbuf, \
    __global const float *restrict maps, \
    __global float *restrict out, \
    const uint stride, \
    const uint item0,        /* the launch's first work-item (a launch in pieces: renderer.py) */ \
    __global const pointrec_t *restrict point_lights, const uint n_point, \
    __global const float4 *restrict directional_lights, const uint n_directional, \
    const float4 origin,     /* subtracted from P and (on the host) from lights; 0 with DIRECTIONS_FP64 */ \
    const float4 eye,        /* perspective: eye − origin; orthographic: unit v */ \
    const float4 ambient,    /* k_a·Σ ambient radiance, rgb */ \
    const float k_d,         /* uniform k_d, used without MAP_KD */ \
    const float4 S_uniform,  /* k_s·C_s, used without MAP_KS / MAP_CS */ \
    const float k_uniform,   /* exponent h or 4h, used without MAP_H */ \
    const float4 background, \
    const float4 eye_lo,     /* eye − float(eye), used with DIRECTIONS_FP64 */ \
    const float4 material_lo,  /* ambient − float(ambient) (xyz), k_d − float(k_d) (w) */ \
    const float4 S_lo,         /* S_uniform − float(S_uniform) (xyz), k − float(k) (w); both with WEIGHTS_FP64 */ \
    __global const uint *restrict group_table,     /* with N_GROUPS: dir_end[G], point_end[G] */ \
    __global const float4 *restrict group_ambient, /* with N_GROUPS: k_a·A_g as hi, lo per group */ \
    __global const float4 *restrict env_table,     /* with ENV_TABLE: the tables (envtable.h) */ \
    const float env_rotation  /* with ENV_TABLE: the environment's rotation about +y, radians */ \
    SHADE_CULL_ARGS SHADE_DIR_ARGS

#endif /* CLPHONG_SHADE_ARGS_H */

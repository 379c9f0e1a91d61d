/* clphong device code: an environment light as two tables (issue 25; ENV_TABLE).
 *
 * The host (clphong/model/env_table.py) tabulates, for the map less its sun, the
 * diffuse sum E(n) = Σ_t E_t max(n·l_t, 0) and the Phong lobe T(R) = Σ_t E_t
 * max(l_t·R, 0)^h (R = 2(n·v)n − v, so l·R = r·v) on lat-long grids, exact at
 * their nodes; the sun's texels are directional lights. A table is (rows + 2) ×
 * cols float4s (rgb, w unused), row j at latitude π/2 − Δ(j − 1), Δ = π/(rows − 1)
 * (rows 0 and rows + 1 lie over the poles), column c at longitude π − 2π·c/cols,
 * periodic. Both are read with 4 × 4 Lagrange cubics, as the float64 twins
 * env_table_coords and env_table_lookup in clphong/model/env_table.py.
 *
 * Defines (the shading plan's, clphong/device/plan.py), read only with ENV_TABLE:
 *   ENV_D_ROWS, ENV_D_COLS     the diffuse table's rows and columns
 *   ENV_S_ROWS, ENV_S_COLS     the lobe table's (with HAS_SPECULAR), at float4
 *                              index ENV_S_OFFSET of the same buffer
 *   ENV_GROUP                  the light group the environment belongs to, or -1
 */
#ifndef CLPHONG_ENVTABLE_H
#define CLPHONG_ENVTABLE_H
#include "clphong.h"

#ifndef ENV_TABLE
#error "ENV_TABLE must be set by the shading plan (clphong/device/plan.py)"
#endif
#if ENV_TABLE
#if !defined(ENV_D_ROWS) || !defined(ENV_D_COLS) || !defined(ENV_GROUP)
#error "ENV_TABLE needs ENV_D_ROWS, ENV_D_COLS and ENV_GROUP (clphong/device/plan.py)"
#endif
#if HAS_SPECULAR && (!defined(ENV_S_ROWS) || !defined(ENV_S_COLS) || !defined(ENV_S_OFFSET))
#error "ENV_TABLE with HAS_SPECULAR needs ENV_S_ROWS, ENV_S_COLS and ENV_S_OFFSET"
#endif

/* Lagrange weights of the nodes -1, 0, 1, 2 at t in [0, 1] */
#define CUBIC_WEIGHTS(t, w) do { \
        const floatL a_ = (t) + 1.0f, b_ = (t) - 1.0f, c_ = (t) - 2.0f; \
        (w)[0] = -(t) * b_ * c_ * (1.0f / 6.0f); \
        (w)[1] = a_ * b_ * c_ * 0.5f; \
        (w)[2] = -a_ * (t) * c_ * 0.5f; \
        (w)[3] = a_ * (t) * b_ * (1.0f / 6.0f); } while (0)

/* Table positions (y, x) of unit direction d in the world: its map-frame longitude is
   atan2(d.x, d.z) − rotation (radians); x is wrapped into [0, cols). The latitude is
   atan2(d.y, |d.xz|), well conditioned at the poles (asin is not). */
inline void env_table_coords(floatL dx, floatL dy, floatL dz, float rotation,
                             float rows, float cols, floatL *y, floatL *x)
{
    const float PI_F = 3.14159265358979f;
    const floatL lat = atan2(dy, sqrt(MUL_ADD(dx, dx, dz * dz)));
    const floatL lon = atan2(dx, dz) - rotation;
    *y = 1.0f + (0.5f * PI_F - lat) * ((rows - 1.0f) / PI_F);
    const floatL xx = (PI_F - lon) * (cols / (2.0f * PI_F));
    *x = xx - cols * floor(xx / cols);
}

/* The table at (y, x): 16 float4 texels a lane, gathered lane by lane. */
inline void env_table_lookup(__global const float4 *restrict table, int rows, int cols,
                             floatL y, floatL x, floatL *r, floatL *g, floatL *b)
{
    /* fmax/fmin: a NaN position (a NaN normal under --nonfinite pass) reads node 1 or 0,
       never outside the table; its pixel stays NaN through the weights */
    const floatL y0f = fmin(fmax(floor(y), (floatL)(1.0f)), (floatL)(rows - 1));
    const floatL x0f = fmin(fmax(floor(x), (floatL)(0.0f)), (floatL)(cols - 1));
    floatL wy[4], wx[4];
    CUBIC_WEIGHTS(y - y0f, wy);
    CUBIC_WEIGHTS(x - x0f, wx);
#if LANES > 1
    int yi[LANES], xi[LANES];
    vstoreI(CONVERT_INT_L(y0f), yi);
    vstoreI(CONVERT_INT_L(x0f), xi);
#endif
    floatL sr = (floatL)(0.0f), sg = (floatL)(0.0f), sb = (floatL)(0.0f);
    for (int a = 0; a < 4; ++a) {
        floatL tr = (floatL)(0.0f), tg = (floatL)(0.0f), tb = (floatL)(0.0f);
        for (int c = 0; c < 4; ++c) {
#if LANES > 1
            float vr[LANES], vg[LANES], vb[LANES];
            for (int k = 0; k < LANES; ++k) {
                const int xc = (xi[k] + cols - 1 + c) % cols;
                const float4 t = table[(yi[k] - 1 + a) * cols + xc];
                vr[k] = t.x;
                vg[k] = t.y;
                vb[k] = t.z;
            }
            const floatL er = *(const floatL_u *)vr, eg = *(const floatL_u *)vg,
                         eb = *(const floatL_u *)vb;
#else
            const float4 t = table[((int)y0f - 1 + a) * cols + ((int)x0f + cols - 1 + c) % cols];
            const floatL er = t.x, eg = t.y, eb = t.z;
#endif
            tr = MUL_ADD(wx[c], er, tr);
            tg = MUL_ADD(wx[c], eg, tg);
            tb = MUL_ADD(wx[c], eb, tb);
        }
        sr = MUL_ADD(wy[a], tr, sr);
        sg = MUL_ADD(wy[a], tg, sg);
        sb = MUL_ADD(wy[a], tb, sb);
    }
    *r = sr;
    *g = sg;
    *b = sb;
}
#endif /* ENV_TABLE */

#endif /* CLPHONG_ENVTABLE_H */

/* The light tree's node bounds on the device, in double: one work-item per
 * (tile, node) pair, each channel's bound of the error of using the node's
 * representative for its lights over the tile's boxes.
 *
 * This is clphong/model/light_tree.py cluster_terms, line for line, for point
 * lights (the tree's nodes without a spot's cone; the host bounds those). Its
 * float64 numpy form is the reference: tests/device/test_node_bound.py holds the
 * two together on random pairs. The derivation is in light_tree.py's module
 * docstring and docs/error-model.md; every constant there is the same here. The
 * bound carries its own slack (1 + 10⁻⁶, and the margins in U for the float32
 * shading), far above double's roundings, so libm's last-ulp differences from
 * numpy's move it by ~10⁻¹⁵ relative and nothing else.
 *
 * Tile records (TILE_DOUBLES, rebased): lo[3] hi[3] nlo[3] nhi[3] D[3] S[3].
 * Node records (NODE_DOUBLES + the falloff's turning points): lo[3] hi[3] (rebased)
 * c0 c1 c2, R[3], M[3], F[3], Q[3] (the moments with the record's float32
 * roundings already added, as cluster_terms adds them), then N_ONE turning points
 * of A′ and N_TWO of A″ (NaN: none), then the Taylor term's TAYLOR_DOUBLES: 4 turning
 * points of |A‴| (NaN: none), the float64 representative p_k (rebased), F[3][3] (each
 * channel's Σ R (p_i − p_k)), M[3][6] (each channel's Σ R ΔΔᵀ: xx yy zz xy xz yz),
 * T3[3] (Σ R |Δ|³) and rp (the record's position rounding).
 *
 * Defines (clphong/device/nodebound.py): N_ONE, N_TWO; LOBE (1: the lobe's exponent
 * K ≥ 1 is the argument K; 0: a shininess map or K < 1, the range alone), BLINN,
 * FRESNEL, PERSPECTIVE; THETA_POINTS (clphong/model/taylor.py).
 */
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define TILE_DOUBLES 18
#define NODE_DOUBLES 21
#define TAYLOR_DOUBLES 38
#define U_D 5.9604644775390625e-8          /* 2^-24: clphong.core.floats.U */
#define SLOPE_SLACK_D 1e-9                 /* clphong.model.falloff.SLOPE_SLACK */
#define PI_D 3.141592653589793

typedef struct {
    double x, y, z;
} v3;

inline v3 mk(double x, double y, double z) { v3 r = {x, y, z}; return r; }
inline double sum3(v3 a) { return a.x + a.y + a.z; }
inline double max3(v3 a) { return fmax(fmax(a.x, a.y), a.z); }
inline v3 sub(v3 a, v3 b) { return mk(a.x - b.x, a.y - b.y, a.z - b.z); }
inline v3 add(v3 a, v3 b) { return mk(a.x + b.x, a.y + b.y, a.z + b.z); }
inline v3 scl(v3 a, double s) { return mk(a.x * s, a.y * s, a.z * s); }
inline double dot(v3 a, v3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline v3 load3(__global const double *p) { return mk(p[0], p[1], p[2]); }
/* numpy's maximum/minimum propagate NaN; OpenCL's fmax/fmin do not: these do */
inline double nmax(double a, double b) { return (a != a || b != b) ? NAN : (a > b ? a : b); }
inline double nmin(double a, double b) { return (a != a || b != b) ? NAN : (a < b ? a : b); }
inline v3 vmax(v3 a, v3 b) { return mk(nmax(a.x, b.x), nmax(a.y, b.y), nmax(a.z, b.z)); }
inline v3 vmin(v3 a, v3 b) { return mk(nmin(a.x, b.x), nmin(a.y, b.y), nmin(a.z, b.z)); }
inline v3 vabs(v3 a) { return mk(fabs(a.x), fabs(a.y), fabs(a.z)); }
inline double nmax3(v3 a) { return nmax(nmax(a.x, a.y), a.z); }

/* _interval_dot: bounds of a·b over the boxes (lo, hi) */
inline double interval_lo1(double alo, double ahi, double blo, double bhi)
{
    return nmin(nmin(alo * blo, alo * bhi), nmin(ahi * blo, ahi * bhi));
}
inline double interval_hi1(double alo, double ahi, double blo, double bhi)
{
    return nmax(nmax(alo * blo, alo * bhi), nmax(ahi * blo, ahi * bhi));
}
inline double interval_dot_lo(v3 alo, v3 ahi, v3 blo, v3 bhi)
{
    return interval_lo1(alo.x, ahi.x, blo.x, bhi.x) + interval_lo1(alo.y, ahi.y, blo.y, bhi.y)
           + interval_lo1(alo.z, ahi.z, blo.z, bhi.z);
}
inline double interval_dot_hi(v3 alo, v3 ahi, v3 blo, v3 bhi)
{
    return interval_hi1(alo.x, ahi.x, blo.x, bhi.x) + interval_hi1(alo.y, ahi.y, blo.y, bhi.y)
           + interval_hi1(alo.z, ahi.z, blo.z, bhi.z);
}

/* _unit: x/|x| and |x| (0/0: NaN, as numpy) */
inline v3 unit(v3 x, double *n)
{
    *n = sqrt(sum3(mk(x.x * x.x, x.y * x.y, x.z * x.z)));
    return mk(x.x / *n, x.y / *n, x.z / *n);
}

/* _angle: from atan2 */
inline double angle(v3 a, v3 b)
{
    const v3 c = mk(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
    return atan2(sqrt(c.x * c.x + c.y * c.y + c.z * c.z), sum3(mk(a.x * b.x, a.y * b.y, a.z * b.z)));
}

/* _cone: half-angle of the directions to a ball of radius r at distance d */
inline double cone(double radius, double dist)
{
    return dist > radius ? asin(clamp(radius / dist, 0.0, 1.0)) : PI_D;
}

/* _peak: max over x ∈ [0, c] of x^a·(1 − x²)^b */
inline double peak(double c, double a, double b)
{
    const double xs = sqrt(a / (a + 2.0 * b));
    const double x = nmin(c, xs);
    const double y = 1.0 - x * x;
    /* b is 1/2 or 1 here: sqrt and the product are pow's own values, at less cost */
    return pow(x, a) * (b == 0.5 ? sqrt(y) : (b == 1.0 ? y : pow(y, b)));
}

inline double falloff_slope(double c0, double c1, double c2, double x)
{
    const double p = c0 + x * (c1 + x * c2);
    return (c1 + 2.0 * c2 * x) / (p * p);
}

inline double falloff_curve(double c0, double c1, double c2, double x)
{
    const double p = c0 + x * (c1 + x * c2);
    const double n = x * (3.0 * c2 * c2 * x + 3.0 * c1 * c2) + (c1 * c1 - c0 * c2);
    return 2.0 * fabs(n) / (p * p * p);
}

/* light_tree.py diffuse_gradient_sup: sup |∇g| over c ∈ [c_lo, c_hi] (|∇g|² is linear
 * in c²: an end of the range) */
inline double diffuse_gradient_sup(double c_lo, double c_hi, double L, double A1)
{
    const double c = L >= A1 ? c_lo : c_hi;
    return sqrt((1.0 - c * c) * L * L + c * c * A1 * A1);
}

/* light_tree.py diffuse_hessian_sup: the spectral norm's sup over c ∈ [c_lo, c_hi],
 * 0 ≤ m ≤ M, |A″| ≤ A2 (the derivation is there) */
inline double hessian_vertex(double c_lo, double c_hi, double M, double alpha)
{
    const double P = fabs(alpha - M);
    const double Q = (alpha + M) * (alpha + M) - 4.0 * M * M;
    double top = 2.0 * P * M / sqrt(Q * (Q - P * P));
    top = isnan(top) ? 0.0 : top;
    const double c = Q >= 0.0 ? c_hi : fmin(fmax(top, c_lo), c_hi);
    return 0.5 * (c * P + sqrt(c * c * ((alpha + M) * (alpha + M)) + 4.0 * (1.0 - c * c) * M * M));
}

inline double diffuse_hessian_sup(double c_lo, double c_hi, double M, double A2)
{
    if (!(isfinite(M) && isfinite(A2) && isfinite(c_lo) && isfinite(c_hi))) {
        const double mm = nmax(M, A2);
        return sqrt(M * M + mm * mm) + 0.0 * (c_lo + c_hi);
    }
    return fmax(fmax(0.0, hessian_vertex(c_lo, c_hi, M, A2)), hessian_vertex(c_lo, c_hi, M, -A2));
}

/* falloff.py falloff_third_sup's |A‴| at x */
inline double falloff_third(double c0, double c1, double c2, double x)
{
    const double p = c0 + x * (c1 + x * c2);
    const double p1 = c1 + 2.0 * c2 * x;
    return 6.0 * fabs(p1 * (2.0 * c2 * p - p1 * p1)) / (p * p) / (p * p);
}

/* taylor.py third_derivative_sup: sup‖∇³g‖ from c⁺, d⁻ and φ's sups: the cubic form
 * a·t³ + b·ts² + c·st² + e·s³ on a grid of THETA_POINTS over [0, π/2] (θ stepped by a
 * rotation), plus the slope's margin */
inline double third_derivative_sup(double c_hi, double d, double f1, double f2, double f3)
{
    const double k1 = f2, k2 = f1 / d;
    const double B = f2 / d + f1 / (d * d);
    const double a = 3.0 * c_hi * k1 + c_hi * d * f3;
    const double b = 3.0 * c_hi * k2 + 3.0 * c_hi * d * B;
    const double c = 3.0 * k1, e = 3.0 * k2;
    const double step = (PI_D / 2.0) / (THETA_POINTS - 1);
    const double C = cos(step), S = sin(step);
    double best = 0.0, t = 1.0, s = 0.0;
    for (int j = 0; j < THETA_POINTS; ++j) {
        const double t2 = t * t, s2 = s * s;
        best = fmax(best, a * (t2 * t) + b * (t * s2) + c * (s * t2) + e * (s2 * s));
        const double tn = t * C - s * S;
        s = s * C + t * S;
        t = tn;
    }
    return best + 3.0 * (a + b + c + e) * step / 2.0;
}

/* light_tree.py taylor_term and taylor.py taylor_diffuse: each channel's Taylor bound of
 * the diffuse error over the tile, in out (without D), for a surely lit pair; Tn: the
 * node's Taylor block */
inline void taylor_term(const v3 p0, const v3 m0, const double r, const double dn,
                        const __global double *Tn, const double c0, const double c1,
                        const double c2, const double d_lo, const double A_lo, const double a1,
                        const double a2, const double c_hi, const double hess, double out[3])
{
    double s3 = falloff_third(c0, c1, c2, d_lo);
    for (int j = 0; j < 4; ++j) {
        const double q = Tn[j];
        s3 = fmax(s3, q > d_lo ? falloff_third(c0, c1, c2, q) : 0.0);
    }
    const double a3 = s3 * (1.0 + SLOPE_SLACK_D);
    const double dl2 = d_lo * d_lo, dl3 = dl2 * d_lo;
    const double f1 = a1 / d_lo + A_lo / dl2;
    const double f2 = a2 / d_lo + 2.0 * a1 / dl2 + 2.0 * A_lo / dl3;
    const double f3 = a3 / d_lo + 3.0 * a2 / dl2 + 6.0 * a1 / dl3 + 6.0 * A_lo / (dl3 * d_lo);
    const double sup3 = third_derivative_sup(c_hi, d_lo, f1, f2, f3);
    const v3 x = sub(load3(Tn + 4), p0);
    const double d = sqrt(sum3(mk(x.x * x.x, x.y * x.y, x.z * x.z)));
    const v3 u = mk(x.x / d, x.y / d, x.z / d);
    const double p = c0 + d * (c1 + d * c2);
    const double A = 1.0 / p, A1 = -(c1 + 2.0 * c2 * d) / (p * p);
    const double A2 = 2.0 * (d * (3.0 * c2 * c2 * d + 3.0 * c1 * c2) + c1 * c1 - c0 * c2) / (p * p * p);
    const double phi = A / d;
    const double d2 = d * d;
    const double phi1 = A1 / d - A / d2;
    const double phi2 = A2 / d - 2.0 * A1 / d2 + 2.0 * A / (d2 * d);
    for (int c = 0; c < 3; ++c) {
        const v3 F = load3(Tn + 7 + 3 * c);
        const __global double *M = Tn + 16 + 6 * c;
        const double uF = F.x * u.x + F.y * u.y + F.z * u.z;
        const v3 w1 = add(scl(F, phi), scl(x, phi1 * uF));
        const v3 Mu = mk(M[0] * u.x + M[3] * u.y + M[4] * u.z,
                         M[3] * u.x + M[1] * u.y + M[5] * u.z,
                         M[4] * u.x + M[5] * u.y + M[2] * u.z);
        const double uMu = Mu.x * u.x + Mu.y * u.y + Mu.z * u.z;
        const double trM = M[0] + M[1] + M[2];
        const v3 w2 = add(scl(Mu, 2.0 * phi1), scl(x, phi2 * uMu + (phi1 / d) * (trM - uMu)));
        const double first = fabs(sum3(mk(w1.x * m0.x, w1.y * m0.y, w1.z * m0.z)))
            + dn * sqrt(sum3(mk(w1.x * w1.x, w1.y * w1.y, w1.z * w1.z)))
            + (hess * r) * sqrt(sum3(mk(F.x * F.x, F.y * F.y, F.z * F.z)));
        const double second = fabs(sum3(mk(w2.x * m0.x, w2.y * m0.y, w2.z * m0.z)))
            + dn * sqrt(sum3(mk(w2.x * w2.x, w2.y * w2.y, w2.z * w2.z)))
            + (sup3 * r) * trM;
        out[c] = first + 0.5 * second + sup3 * Tn[34 + c] / 6.0;
    }
}

/* What a tile's bounds share over every node: its boxes, widened by the float32
 * rounding of the positions they hold (tlo, thi), and, where it has specular, the
 * tile's side of specular_cosine (its normals' cone, centre and radius, and its view
 * cone): formed once per tile by tile_cut, once per pair by node_terms. */
typedef struct {
    v3 lo, hi, nlo, nhi, D, S, tlo, thi;
    double reach;          /* the largest |coordinate| of the widened box */
    int spec;              /* any S */
    v3 p0, m0;             /* the Taylor term's tile centre (widened box) and normals' centre */
    double r, dn;          /* their half-diagonals */
    v3 n0, ct, v0;
    double a_n, rt, a_v;
} tile_c;

inline tile_c tile_consts(const __global double *T, const v3 eye)
{
    tile_c t;
    t.lo = load3(T);
    t.hi = load3(T + 3);
    t.nlo = load3(T + 6);
    t.nhi = load3(T + 9);
    t.D = load3(T + 12);
    t.S = load3(T + 15);
    const double pad = 4.0 * U_D * nmax3(add(vabs(t.lo), vabs(t.hi)));
    t.tlo = sub(t.lo, mk(pad, pad, pad));
    t.thi = add(t.hi, mk(pad, pad, pad));
    t.reach = nmax3(vmax(vabs(t.tlo), vabs(t.thi)));
    t.spec = t.S.x != 0.0 || t.S.y != 0.0 || t.S.z != 0.0;
    const v3 tw = sub(t.thi, t.tlo), nw = sub(t.nhi, t.nlo);
    t.p0 = scl(add(t.tlo, t.thi), 0.5);
    t.r = 0.5 * sqrt(sum3(mk(tw.x * tw.x, tw.y * tw.y, tw.z * tw.z)));
    t.m0 = scl(add(t.nlo, t.nhi), 0.5);
    t.dn = 0.5 * sqrt(sum3(mk(nw.x * nw.x, nw.y * nw.y, nw.z * nw.z)));
    if (t.spec) {
        double len;
        t.n0 = unit(scl(add(t.nlo, t.nhi), 0.5), &len);
        const double corner = sum3(vmin(mk(t.nlo.x * t.n0.x, t.nlo.y * t.n0.y, t.nlo.z * t.n0.z),
                                        mk(t.nhi.x * t.n0.x, t.nhi.y * t.n0.y, t.nhi.z * t.n0.z)));
        t.a_n = corner > 0.0 ? acos(clamp(corner, -1.0, 1.0)) : PI_D;
        t.ct = scl(add(t.lo, t.hi), 0.5);
        unit(sub(t.hi, t.lo), &t.rt);
        t.rt *= 0.5;
#if PERSPECTIVE
        double de;
        t.v0 = unit(sub(eye, t.ct), &de);
        t.a_v = cone(t.rt, de);
#else
        t.v0 = eye;
        t.a_v = 0.0;
#endif
    }
    return t;
}

/* specular_cosine: an upper bound c of the lobe's cosine over the boxes (1: none);
 * s_half: sin(γ⁺/2), γ⁺ ≤ π the largest angle between u and v (Blinn-Phong; 1 for Phong) */
inline double specular_cosine(const tile_c *t, v3 blo, v3 bhi, double *s_half)
{
    const v3 n0 = t->n0, ct = t->ct, v0 = t->v0;
    const double a_n = t->a_n, rt = t->rt, a_v = t->a_v;
    const v3 cb = scl(add(blo, bhi), 0.5);
    double rb, dist;
    unit(sub(bhi, blo), &rb);
    rb *= 0.5;
    const v3 u0 = unit(sub(cb, ct), &dist);
    const double a_u = cone(rt + rb, dist);
    double beta;
#if BLINN
    const double gamma = angle(u0, v0) + a_u + a_v;
    double hl;
    const v3 h0 = unit(add(u0, v0), &hl);
    const double d_h = (a_u + a_v) / (2.0 * cos(nmin(gamma, PI_D) / 2.0));
    beta = gamma < PI_D ? angle(n0, h0) - a_n - d_h : -1.0;
    *s_half = fmin(sin(nmin(gamma, PI_D) / 2.0) + 1e-5, 1.0);    /* NaN: 1 */
#else
    *s_half = 1.0;
    const v3 r0 = sub(scl(n0, 2.0 * sum3(mk(n0.x * u0.x, n0.y * u0.y, n0.z * u0.z))), u0);
    beta = angle(r0, v0) - a_u - 2.0 * a_n - a_v;
#endif
    if (isnan(beta))
        beta = -1.0;
    const double c = fmin(cos(clamp(beta, 0.0, PI_D / 2.0)) + 1e-5, 1.0);
    return beta > 0.0 ? c : 1.0;
}

/* _view_dot_lower: a lower bound of u·v over the boxes, in [−1, 0] */
inline double view_dot_lower(v3 blo, v3 bhi, v3 thi, v3 tlo, double d_lo, v3 eye)
{
#if PERSPECTIVE
    const v3 vlo = sub(eye, thi), vhi = sub(eye, tlo);
    const double num_lo = interval_dot_lo(sub(blo, thi), sub(bhi, tlo), vlo, vhi);
    const v3 far = add(vmax(vlo, mk(0.0, 0.0, 0.0)), vmax(scl(vhi, -1.0), mk(0.0, 0.0, 0.0)));
    const double den = d_lo * sqrt(sum3(mk(far.x * far.x, far.y * far.y, far.z * far.z)));
#else
    const double num_lo = interval_dot_lo(sub(blo, thi), sub(bhi, tlo), eye, eye);
    const double den = d_lo;
#endif
    double uv = num_lo >= 0.0 ? 0.0 : num_lo / den;
    if (isnan(uv) || uv == -INFINITY)
        uv = -1.0;
    return clamp(uv, -1.0, 0.0);
}

/* cluster_terms for one (tile, node) pair: each channel's bound, in out */
inline void node_term(const tile_c *tc, const __global double *N, const v3 eye, const double K,
                      double out[3])
{
    const v3 nlo = tc->nlo, nhi = tc->nhi, D = tc->D, S = tc->S;
    const v3 tlo = tc->tlo, thi = tc->thi;
    const v3 blo = load3(N), bhi = load3(N + 3);
    const double c0 = N[6], c1 = N[7], c2 = N[8];
    const v3 Rk = load3(N + 9), M = load3(N + 12), F = load3(N + 15), Q = load3(N + 18);
    const v3 zero = mk(0.0, 0.0, 0.0);
    const v3 gap = add(vmax(sub(blo, thi), zero), vmax(sub(tlo, bhi), zero));
    const double d_lo = sqrt(sum3(mk(gap.x * gap.x, gap.y * gap.y, gap.z * gap.z)));
    const double A_lo = 1.0 / (c0 + d_lo * (c1 + d_lo * c2));
    const double lip = A_lo / d_lo;
    const double nl_lo = interval_dot_lo(nlo, nhi, sub(blo, thi), sub(bhi, tlo));
    const double nl_hi = interval_dot_hi(nlo, nhi, sub(blo, thi), sub(bhi, tlo));
    const v3 span = sub(vmax(bhi, thi), vmin(blo, tlo));
    const double d_hi = sqrt(sum3(mk(span.x * span.x, span.y * span.y, span.z * span.z)));
    const double reach = tc->reach + nmax3(vmax(vabs(blo), vabs(bhi)));
    const double margin = U_D * (12.0 + 2.0 * reach / d_lo);
    const int dark = nl_hi / d_hi + margin <= 0.0;
    const int lit = nl_lo / d_hi - margin > 0.0;
    const double nu_hi = nmin((nl_hi > 0.0 ? nl_hi / d_lo : 0.0) + margin, 1.0);
    /* the falloff's slopes over d ≥ d⁻ (falloff_slopes) */
    const double a1_lo = falloff_slope(c0, c1, c2, d_lo);
    double s1 = a1_lo, s2 = falloff_curve(c0, c1, c2, d_lo);
    for (int j = 0; j < N_ONE; ++j) {
        const double r = N[NODE_DOUBLES + j];
        s1 = fmax(s1, r > d_lo ? falloff_slope(c0, c1, c2, r) : 0.0);
    }
    for (int j = 0; j < N_TWO; ++j) {
        const double r = N[NODE_DOUBLES + N_ONE + j];
        s2 = fmax(s2, r > d_lo ? falloff_curve(c0, c1, c2, r) : 0.0);
    }
    const double a1 = s1 * (1.0 + SLOPE_SLACK_D), a2 = s2 * (1.0 + SLOPE_SLACK_D);
    /* diffuse, over the cosine's range c ∈ [c⁻, c⁺] (c⁻ = 0 unless surely lit) */
    const double g_hi = A_lo * nu_hi;
    const double c_lo = lit ? clamp(nl_lo / d_hi - margin, 0.0, 1.0) : 0.0;
    const double grad = diffuse_gradient_sup(c_lo, nu_hi, lip, a1);
    const double m = (lip + a1_lo) / d_lo;
    const double hess = diffuse_hessian_sup(c_lo, nu_hi, m, a2);
    double e[3];
    const double Rc[3] = {Rk.x, Rk.y, Rk.z}, Mc[3] = {M.x, M.y, M.z}, Fc[3] = {F.x, F.y, F.z},
                 Qc[3] = {Q.x, Q.y, Q.z}, Dc[3] = {D.x, D.y, D.z}, Sc[3] = {S.x, S.y, S.z};
    /* Taylor's terms themselves, with the remainder, where surely lit (light_tree.py) */
    double tay[3] = {INFINITY, INFINITY, INFINITY};
    if (lit) {
        const __global double *Tn = N + NODE_DOUBLES + N_ONE + N_TWO;
        taylor_term(tc->p0, tc->m0, tc->r, tc->dn, Tn, c0, c1, c2, d_lo, A_lo, a1, a2,
                    nu_hi, hess, tay);
        for (int c = 0; c < 3; ++c)
            tay[c] = tay[c] * 1.0 + grad * Rc[c] * Tn[37];
    }
    for (int c = 0; c < 3; ++c) {
        const double e_rng = Rc[c] * g_hi;
        const double e_lip = grad * Mc[c];
        const double e_two = grad * Fc[c] + 0.5 * hess * Qc[c];
        e[c] = Dc[c] * fmin(fmin(fmin(e_rng, e_lip), lit ? e_two : INFINITY), tay[c]);
    }
    /* specular (where the tile has any) */
    if (tc->spec) {
        double sp[3];
#if LOBE
        double s_half;
        const double cs = specular_cosine(tc, blo, bhi, &s_half);
        const double cK = pow(cs, K);
        /* bend: ∇²x's part across h (r), over sin θ (light_tree.py's _specular_bound) */
#if BLINN
        const double uv = view_dot_lower(blo, bhi, thi, tlo, d_lo, eye);
        const double huv = sqrt(fmax(2.0 + 2.0 * uv, 0.0));
        const double g = 1.0 / (d_lo * huv);
        const double bend = 2.0 * s_half * g * g + (2.0 / sqrt(3.0)) * g / d_lo;
#else
        const double g = 1.0 / d_lo;
        const double bend = g * g;
#endif
        const int fres = BLINN && FRESNEL;
        const double h1 = peak(cs, K - 1.0, 0.5);
        const double A1 = a1, A2 = nmax(a2, a1_lo / d_lo);
        /* ∇P ⊥ u ∥ ∇A: the two parts in quadrature (light_tree.py's module docstring) */
        const double sgrad = hypot(A_lo * (K * h1 * g + (fres ? 5.0 * g * cK : 0.0)), cK * A1);
        const int second = K >= 2.0 && !fres;
        double shess = 0.0;
        if (second) {
            const double f1 = peak(cs, K - 2.0, 1.0);
            /* K(K−1)x^(K−2)·∇x∇xᵀ ⪰ 0 ⪰ −K·x^K·JᵀJ: the larger norm; the cross term once */
            shess = (A_lo * (nmax(K * (K - 1.0) * f1, K * cK) * g * g + K * h1 * bend)
                     + K * h1 * g * A1 + cK * A2);
        }
        for (int c = 0; c < 3; ++c) {
            const double rng = Rc[c] * (A_lo * cK);
            double e_lip = sgrad * Mc[c];
            if (second)
                e_lip = fmin(e_lip, sgrad * Fc[c] + 0.5 * shess * Qc[c]);
            sp[c] = lit ? fmin(e_lip, rng) : rng;
        }
#else
        for (int c = 0; c < 3; ++c)
            sp[c] = Rc[c] * A_lo;
#endif
        for (int c = 0; c < 3; ++c)
            e[c] = e[c] + Sc[c] * sp[c];
    }
    for (int c = 0; c < 3; ++c) {
        double v = e[c] + U_D * Rc[c] * A_lo * (Dc[c] + Sc[c]);
        v = d_lo > 0.0 ? v : INFINITY;             /* the boxes touch (or NaN): none */
        out[c] = dark ? 0.0 : v;
    }
}

__kernel void node_terms(__global const double *restrict tiles,
                         __global const double *restrict nodes, const uint node_doubles,
                         __global const uint *restrict pair_tile,
                         __global const uint *restrict pair_node, const uint n_pairs,
                         const double eye_x, const double eye_y, const double eye_z,
                         const double K, __global double *restrict out)
{
    const uint i = get_global_id(0);
    if (i >= n_pairs)
        return;
    double e[3];
    const v3 eye = mk(eye_x, eye_y, eye_z);
    const tile_c tc = tile_consts(tiles + (size_t)pair_tile[i] * TILE_DOUBLES, eye);
    node_term(&tc, nodes + (size_t)pair_node[i] * node_doubles, eye, K, e);
    for (int c = 0; c < 3; ++c)
        out[3 * (size_t)i + c] = e[c];
}

/* cluster_bounds for one pair, per channel: each channel's term in units of the
 * tile's budget (scale: each channel's 1/budget), × (1 + 10⁻⁶), in b[0 … 3); a channel
 * whose term is 0 stays 0; no bound (NaN in any channel): +inf in all. Returns the
 * largest (the cut's order). */
inline double node_bound(const tile_c *tc, const __global double *N,
                         const __global double *scale, const v3 eye, const double K,
                         double b[3])
{
    double e[3];
    node_term(tc, N, eye, K, e);
    double m = 0.0;
    for (int c = 0; c < 3; ++c) {
        const double v = e[c] == 0.0 ? 0.0 : e[c] * scale[c];
        if (isnan(v)) {
            b[0] = b[1] = b[2] = INFINITY;
            return INFINITY;
        }
        b[c] = v * (1.0 + 1e-6);
        m = fmax(m, b[c]);
    }
    return m;
}

/* the binary max-heap of a tile's cut: the largest channel's bound (the order) in hb,
 * the slot holding the entry's node and each channel's bound in hs; n entries */
inline void heap_push(__global double *hb, __global uint *hs, uint n, double b, uint slot)
{
    while (n > 0) {
        const uint up = (n - 1) >> 1;
        if (!(hb[up] < b))
            break;
        hb[n] = hb[up];
        hs[n] = hs[up];
        n = up;
    }
    hb[n] = b;
    hs[n] = slot;
}

/* remove the root of a heap of n entries (n ≥ 1): the last entry sinks from the top */
inline void heap_pop(__global double *hb, __global uint *hs, uint n)
{
    const double b = hb[n - 1];
    const uint slot = hs[n - 1];
    --n;
    uint i = 0;
    for (;;) {
        uint c = 2 * i + 1;
        if (c >= n)
            break;
        if (c + 1 < n && hb[c + 1] > hb[c])
            ++c;
        if (!(hb[c] > b))
            break;
        hb[i] = hb[c];
        hs[i] = hs[c];
        i = c;
    }
    hb[i] = b;
    hs[i] = slot;
}

/* tile_cut's new entry, node k with each channel's bound b and order o: into a free slot,
 * else a new one (the slots in use are the heap's h < cap), the heap and the running
 * sums of the finite entries (n_inf counts the others) */
inline void cut_push(__global double *hb, __global uint *hs, __global uint *sk,
                     __global double *sb, __global const uint *fs, uint *h, uint *n_slots,
                     uint *n_free, uint *n_inf, double total[3], const double o,
                     const double b[3], const uint k)
{
    const uint slot = *n_free > 0 ? fs[--*n_free] : (*n_slots)++;
    sk[slot] = k;
    for (int c = 0; c < 3; ++c)
        sb[3 * slot + c] = b[c];
    heap_push(hb, hs, (*h)++, o, slot);
    if (isinf(o))
        ++*n_inf;
    else
        for (int c = 0; c < 3; ++c)
            total[c] += b[c];
}

/* a[i]'s value v sinks into the max-heap a[0 … n) below i */
inline void sift_down(__global uint *a, uint i, const uint n, const uint v)
{
    for (uint c; (c = 2 * i + 1) < n; i = c) {
        if (c + 1 < n && a[c + 1] > a[c])
            ++c;
        if (a[c] <= v)
            break;
        a[i] = a[c];
    }
    a[i] = v;
}

/* sort a[0 … n) ascending in place (heapsort: no scratch, n log n) */
inline void sort_records(__global uint *a, const uint n)
{
    for (uint s = n / 2; s-- > 0;)
        sift_down(a, s, n, a[s]);
    for (uint end = n; end-- > 1;) {
        const uint v = a[end];
        a[end] = a[0];
        sift_down(a, 0, end, v);
    }
}

/* The light tree's cut per tile, on the device (clphong/model/light_tree.py
 * greedy_cut is its float64 reference): from the roots, the node with the largest
 * bound (its largest channel's) is split until each channel's bounds sum to ≤ limit
 * (in units of the tile's budget for that channel: scale) or no node is left, as
 * Lightcuts does. A leaf reached is its light, kept
 * where its super-tile's culling kept it (the bits of kept); the nodes left are the
 * clusters. Each tile's list: its super-tile's lights under no node (extra), the
 * leaves and the clusters' representatives, as records (light_rec, node_rec) in
 * record order, at lists + tile·cap; counts (3 a tile): its length, or CUT_OVERFLOW where cap entries
 * could not hold it (the host then gives the tile its super-tile's list), its
 * clusters and the lights they stand for (node_size: each node's); sums: the cut's
 * largest channel's sum.
 * One work-item per tile of tile0 … tile0 + n, each with 4·cap doubles of heap_b (the
 * heap's orders, then each slot's three channels) and 3·cap uints of heap_k (the heap's
 * slots, each slot's node, the free slots): an entry's channels stay in its slot while
 * the heap moves only its order and slot. */
#define CUT_OVERFLOW 0xffffffffu
__kernel void tile_cut(__global const double *restrict tiles,
                       __global const double *restrict scale,
                       __global const double *restrict nodes, const uint node_doubles,
                       __global const int *restrict children, const uint n_leaves,
                       __global const uint *restrict roots, const uint n_roots,
                       __global const uint *restrict kept, const uint kept_words,
                       __global const uint *restrict tile_super,
                       __global const uint *restrict extra_range,
                       __global const uint *restrict extra,
                       __global const uint *restrict light_rec,
                       __global const uint *restrict node_rec,
                       __global const uint *restrict node_size,
                       const double eye_x, const double eye_y, const double eye_z,
                       const double K, const double limit, const uint cap,
                       __global double *restrict heap_b, __global uint *restrict heap_k,
                       __global uint *restrict lists, __global uint *restrict counts,
                       __global double *restrict sums, const uint tile0, const uint n)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const uint t = tile0 + i;
    const __global double *T = tiles + (size_t)t * TILE_DOUBLES;
    const __global double *sc = scale + 3 * (size_t)t;
    __global double *hb = heap_b + (size_t)i * cap * 4;
    __global double *sb = hb + cap;
    __global uint *hs = heap_k + (size_t)i * cap * 3;
    __global uint *sk = hs + cap, *fs = hs + 2 * cap;
    __global uint *out = lists + (size_t)t * cap;
    const v3 eye = mk(eye_x, eye_y, eye_z);
    if (T[0] > T[3] || T[1] > T[4] || T[2] > T[5]) {      /* no shaded pixel */
        counts[3 * t] = counts[3 * t + 1] = counts[3 * t + 2] = 0;
        sums[t] = 0.0;
        return;
    }
    const tile_c tc = tile_consts(T, eye);
    const uint s = tile_super[t];
    const __global uint *mask = kept + (size_t)s * kept_words;
    uint m = 0, h = 0, n_inf = 0, n_slots = 0, n_free = 0;
    const uint e0 = extra_range[2 * s], e1 = e0 + extra_range[2 * s + 1];
    if (e1 - e0 > cap) {
        counts[3 * t] = CUT_OVERFLOW;
        return;
    }
    for (uint j = e0; j < e1; ++j)
        out[m++] = extra[j];
    /* each channel's sum of the finite bounds; n_inf: the entries with none */
    double total[3] = {0.0, 0.0, 0.0};
    double b[3];
    for (uint r = 0; r < n_roots; ++r) {
        if (m + h >= cap) {
            counts[3 * t] = CUT_OVERFLOW;
            return;
        }
        const double o = node_bound(&tc, nodes + (size_t)roots[r] * node_doubles, sc, eye, K, b);
        cut_push(hb, hs, sk, sb, fs, &h, &n_slots, &n_free, &n_inf, total, o, b, roots[r]);
    }
    for (;;) {
        if (n_inf == 0 && total[0] <= limit && total[1] <= limit && total[2] <= limit) {
            /* the running sums drift by roundings: the cut's own sums decide */
            double exact[3] = {0.0, 0.0, 0.0};
            for (uint j = 0; j < h; ++j)
                for (int c = 0; c < 3; ++c)
                    exact[c] += sb[3 * hs[j] + c];
            if (exact[0] <= limit && exact[1] <= limit && exact[2] <= limit)
                break;
            for (int c = 0; c < 3; ++c)
                total[c] = exact[c];
        }
        if (h == 0)
            break;
        const uint top = hs[0], k = sk[top];
        if (isinf(hb[0]))
            --n_inf;
        else
            for (int c = 0; c < 3; ++c)
                total[c] -= sb[3 * top + c];
        heap_pop(hb, hs, h--);
        fs[n_free++] = top;                /* its slot: free for the next entry */
        for (int side = 0; side < 2; ++side) {
            const int c = children[2 * k + side];
            if (c < (int)n_leaves) {
                if ((mask[c >> 5] >> (c & 31)) & 1u) {
                    if (m + h >= cap) {
                        counts[3 * t] = CUT_OVERFLOW;
                        return;
                    }
                    out[m++] = light_rec[c];
                }
                continue;
            }
            if (m + h >= cap) {
                counts[3 * t] = CUT_OVERFLOW;
                return;
            }
            const uint kk = (uint)c - n_leaves;
            const double o = node_bound(&tc, nodes + (size_t)kk * node_doubles, sc, eye, K, b);
            cut_push(hb, hs, sk, sb, fs, &h, &n_slots, &n_free, &n_inf, total, o, b, kk);
        }
    }
    double sum[3] = {0.0, 0.0, 0.0};
    uint covered = 0;
    for (uint j = 0; j < h; ++j) {
        const uint slot = hs[j], k = sk[slot];
        for (int c = 0; c < 3; ++c)
            sum[c] += sb[3 * slot + c];
        covered += node_size[k];
        out[m++] = node_rec[k];
    }
    sort_records(out, m);              /* in record order, as the kernels walk lists */
    counts[3 * t] = m;
    counts[3 * t + 1] = h;
    counts[3 * t + 2] = covered;
    sums[t] = fmax(fmax(sum[0], sum[1]), sum[2]);
}

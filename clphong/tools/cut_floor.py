"""The floor of light-tree cuts (issue 16): how small can a cut be at a budget ε?

Lightcuts-style trees (Walter et al. 2005; the light trees of Cycles and pbrt-v4)
replace a node's lights by one representative with the node's total radiance. A
cut whose error is *bounded* by ε needs Σ over its nodes of a bound of each node's
error ≤ ε; a bound is never below the node's true error. So the cut chosen with
the true errors, per pixel (an oracle: no bound, no tile), is a lower bound of
the size of every bounded cut that sums per-node errors, whatever the bound.

For sample pixels of the bench G-buffer this builds a kd-tree over the scene's
point lights (median splits on the longest axis), takes as each node's
representative a virtual light at its radiance-weighted centroid (the choice
that cancels the first-order error), and refines greedily (the node of largest
true error first) until the true errors sum to ≤ ε. The shading is the float64
reference's model (clphong.reference.shading), per light, on that pixel.

    python -m clphong.tools.cut_floor --eps 1e-3,1e-2 --pixels 8
"""

from __future__ import annotations

import argparse
import heapq
import sys

import numpy as np

from ..model.light_tree import (
    SpecularModel,
    TileBoxes,
    build_light_tree,
    choose_cut,
    cluster_bounds,
    leaf_ranges,
)
from ..reference import shading as reference
from .bench import bench_gbuffer, bench_scene
from .report import markdown_table


def _pixels_of(scene, gbuffer, idx):
    """The reference's Pixels, D and S of the shaded pixels ``idx`` (flat indices)."""
    px, C, D, S, fg = reference._inputs(scene, gbuffer)
    pos = np.cumsum(fg) - 1                      # flat pixel -> index among shaded pixels
    k = pos[idx]
    sub = reference.Pixels(p=px.p[k], n=px.n[k], v=px.v[k], k=px.k[k], blinn=px.blinn,
                           specular=px.specular, f0=px.f0)
    return sub, D[k], S[k]


def light_contributions(px, D, S, Y, R, att):
    """(K, M, 3) contribution of K point lights at Y (K, 3) with radiance R (K, 3)
    and attenuation (K, 3) to M pixels, through the reference's shade_point_light."""
    c = att[:, :, None]
    diffuse, specular = reference.shade_point_light(px, Y[:, None, :], c[:, 0], c[:, 1], c[:, 2])
    return R[:, None, :] * (D * diffuse[..., None] + S * specular[..., None])


class KdTree:
    """Point lights in tree order; node k covers lights [lo[k], hi[k])."""

    def __init__(self, Y):
        self.order = np.arange(len(Y))
        self.lo, self.hi, self.children = [], [], []
        stack = [(0, len(Y), None, 0)]
        while stack:
            lo, hi, parent, side = stack.pop()
            k = len(self.lo)
            self.lo.append(lo)
            self.hi.append(hi)
            self.children.append(None)
            if parent is not None:
                ch = self.children[parent] or [None, None]
                ch[side] = k
                self.children[parent] = ch
            if hi - lo > 1:
                sub = self.order[lo:hi]
                P = Y[sub]
                axis = int(np.argmax(P.max(axis=0) - P.min(axis=0)))
                self.order[lo:hi] = sub[np.argsort(P[:, axis], kind="stable")]
                mid = (lo + hi) // 2
                stack.append((mid, hi, k, 1))
                stack.append((lo, mid, k, 0))


def oracle_cut(contrib, Y, R, tree: KdTree, rep_of, eps: float) -> int:
    """The greedy cut's size for one pixel: ``contrib`` (N, 3) its per-light
    contributions in tree order, ``rep_of(Yc, Rc)`` the representative's (3,). The node
    of largest error (its largest channel's) is split until each channel's errors sum
    to ≤ ``eps``, as the light tree's cuts do."""
    pref = np.vstack([np.zeros(3), np.cumsum(contrib, axis=0)])
    pR = np.vstack([np.zeros(3), np.cumsum(R, axis=0)])
    w = R.sum(axis=1)
    pW = np.concatenate([[0.0], np.cumsum(w)])
    pYW = np.vstack([np.zeros(3), np.cumsum(Y * w[:, None], axis=0)])

    def err(k):
        lo, hi = tree.lo[k], tree.hi[k]
        if hi - lo == 1:
            return np.zeros(3)
        exact = pref[hi] - pref[lo]
        W_ = pW[hi] - pW[lo]
        yc = (pYW[hi] - pYW[lo]) / W_ if W_ > 0 else Y[lo]
        return np.abs(exact - rep_of(yc, pR[hi] - pR[lo]))

    e0 = err(0)
    heap = [(-float(e0.max()), 0, e0)]
    total = e0.copy()
    while (total > eps).any() and heap:
        _, k, e = heapq.heappop(heap)
        total -= e
        if tree.children[k] is None:        # a single light: exact (error 0)
            heapq.heappush(heap, (0.0, k, np.zeros(3)))
            break
        for ch in tree.children[k]:
            ec = err(ch)
            total += ec
            heapq.heappush(heap, (-float(ec.max()), ch, ec))
    return len(heap)


def cut_sizes(scene, gbuffer, eps_list, n_pixels: int, seed: int = 0):
    """{ε: [cut size per sample pixel]} for the scene's point lights (one attenuation)."""
    a = scene.light_arrays
    att_all = a["point_attenuation"]
    if len(np.unique(att_all, axis=0)) != 1 or a["point_is_spot"].any():
        raise ValueError("cut_floor takes point lights that share one attenuation polynomial")
    tree = KdTree(a["point_position"])
    Y = a["point_position"][tree.order]
    R = a["point_radiance"][tree.order]
    att1 = att_all[:1]
    fg = np.flatnonzero(~gbuffer.background_mask().reshape(-1))
    rng = np.random.default_rng(seed)
    idx = rng.choice(fg, size=min(n_pixels, len(fg)), replace=False)
    px, D, S = _pixels_of(scene, gbuffer, idx)
    out = {e: [] for e in eps_list}
    for m in range(len(idx)):
        one = reference.Pixels(p=px.p[m:m + 1], n=px.n[m:m + 1], v=px.v[m:m + 1], k=px.k[m:m + 1],
                               blinn=px.blinn, specular=px.specular)
        contrib = light_contributions(one, D[m:m + 1], S[m:m + 1], Y, R,
                                      np.broadcast_to(att1, (len(Y), 3)))[:, 0, :]

        def rep_of(yc, rc, one=one, m=m):
            return light_contributions(one, D[m:m + 1], S[m:m + 1], yc[None], rc[None], att1)[0, 0]

        for e in eps_list:
            out[e].append(oracle_cut(contrib, Y, R, tree, rep_of, e))
    return out


def _tile_boxes(scene, gbuffer, y, x, tile):
    """TileBoxes of the aligned ``tile`` × ``tile`` block holding pixel (y, x)."""
    y0, x0 = (y // tile) * tile, (x // tile) * tile
    sl = (slice(y0, y0 + tile), slice(x0, x0 + tile))
    fg = ~gbuffer.background_mask()[sl].reshape(-1)
    P = gbuffer.position[sl].reshape(-1, 3).astype(np.float64)[fg]
    N = gbuffer.normal[sl].reshape(-1, 3).astype(np.float64)[fg]
    N /= np.linalg.norm(N, axis=1)[:, None]
    m = scene.material
    D = gbuffer.albedo[sl].reshape(-1, 3).astype(np.float64)[fg] * m.k_d
    return TileBoxes.of_pixels(P, N, D, np.asarray(m.specular_color, np.float64) * m.k_s)


def _entries(tree, used, covered, n_lights):
    """List entries of a cut: its clusters, plus every light no cluster stands for."""
    return int(used.sum()) + n_lights - int(covered.sum())


def node_errors(tree, arrays, px, D, S, j: int, *, magnitude: bool = False):
    """(K, 3) each internal node's true error at sample pixel ``j``: |Σ of its lights'
    contributions − its representative's|, float64 (the reference's shading). With
    ``magnitude``, also (K, 3) Σ|contribution| + |representative's|, which with the
    node's light count bounds the float64 rounding of the error."""
    one = reference.Pixels(p=px.p[j:j + 1], n=px.n[j:j + 1], v=px.v[j:j + 1],
                           k=px.k[j:j + 1], blinn=px.blinn, specular=px.specular)
    leaves = light_contributions(one, D[j:j + 1], S[j:j + 1], arrays["point_position"],
                                 arrays["point_radiance"], arrays["point_attenuation"])[:, 0]
    reps = light_contributions(one, D[j:j + 1], S[j:j + 1], tree.position, tree.radiance,
                               tree.attenuation)[:, 0]
    sums = np.zeros_like(reps)
    mags = np.zeros_like(reps)
    for lv in reversed(tree.levels):              # deepest first: children before parents
        for side in (0, 1):
            c = tree.children[lv, side]
            inner = c >= tree.n_leaves
            sums[lv[~inner]] += leaves[c[~inner]]
            sums[lv[inner]] += sums[c[inner] - tree.n_leaves]
            mags[lv[~inner]] += np.abs(leaves[c[~inner]])
            mags[lv[inner]] += mags[c[inner] - tree.n_leaves]
    err = np.abs(sums - reps)
    return (err, mags + np.abs(reps)) if magnitude else err


#: cluster_bounds' terms, in the order :func:`level_slack` reports their shares.
TERMS = ("diffuse_range", "diffuse_first", "diffuse_second", "specular_range",
         "specular_smooth")


def level_slack(scene, gbuffer, n_pixels: int, seed: int = 0) -> list[dict]:
    """Per depth of the scene's light tree, the proven bound (one-pixel tiles) against
    each node's true error at sample pixels: the median and 10th percentile of bound /
    error, and which term sets the bound. At a node's worst channel, the bound is the
    diffuse term plus the specular term (plus rounding); each is the least of its
    bounds, and a row gives how often each bound is the one taken: the diffuse
    term's range (R·A(d⁻)·(n·u)⁺), first order (Λ·M) or second order (Λ·F + ½H·Q);
    the specular term's range or smooth (first or second order) bound, counted
    where the specular term is the larger; and, where the diffuse second order sets
    it, the median share of its first-moment part Λ·F (F = |Σ R_i (p_i − p_k)|, 0
    for lights of one colour) against its curvature part ½H·Q."""
    tree, a, spec, idx, px, D, S = _sample(scene, gbuffer, n_pixels, seed)
    w = gbuffer.shape[1]
    depth = np.zeros(tree.n_nodes, np.int64)
    for d, lv in enumerate(tree.levels):
        depth[lv] = d
    rows = {d: {"ratio": [], "error": [], "bound": [], "F": [], "spec": 0, **{t: 0 for t in TERMS}}
            for d in range(len(tree.levels))}
    for j, flat in enumerate(idx):
        err = node_errors(tree, a, px, D, S, j)                    # (K, 3)
        y, x = divmod(int(flat), w)
        parts = {}
        b = cluster_bounds(tree, _tile_boxes(scene, gbuffer, y, x, 1), spec, np.zeros(3),
                           parts=parts)[0]
        c = err.argmax(axis=1)                                     # the worst channel
        k = np.arange(tree.n_nodes)
        e = err[k, c]
        ok = (e > 0) & np.isfinite(b) & (b > 0)
        at = {name: np.broadcast_to(v, (1, tree.n_nodes, 3))[0, k, c] for name, v in parts.items()}
        dif = at["diffuse"]
        spc = at.get("specular", np.zeros(tree.n_nodes))
        dterm = np.argmin(np.stack([at["diffuse_range"], at["diffuse_first"],
                                    at["diffuse_second"]]), axis=0)
        sterm = (np.argmin(np.stack([at["specular_range"], at["specular_smooth"]]), axis=0)
                 if "specular" in at else np.zeros(tree.n_nodes, np.int64))
        m2 = ok & (dterm == 2) & (spc <= dif)           # the second order sets it
        fshare = np.where(m2, at["diffuse_second_F"] / np.where(m2, at["diffuse_second"],
                                                                    1.0), np.nan)
        for d, row in rows.items():
            m = ok & (depth == d)
            row["F"].append(fshare[m & m2])
            row["ratio"].append(b[m] / e[m])
            row["error"].append(e[m])
            row["bound"].append(b[m])
            sp = m & (spc > dif)
            row["spec"] += int(sp.sum())
            for i, t in enumerate(TERMS[:3]):
                row[t] += int((m & ~sp & (dterm == i)).sum())
            for i, t in enumerate(TERMS[3:]):
                row[t] += int((sp & (sterm == i)).sum())
    out = []
    for d, row in rows.items():
        r = np.concatenate(row["ratio"])
        if r.size == 0:
            continue
        out.append({"depth": d, "nodes": len(tree.levels[d]), "pairs": int(r.size),
                    "error": float(np.median(np.concatenate(row["error"]))),
                    "bound": float(np.median(np.concatenate(row["bound"]))),
                    "slack": float(np.median(r)), "slack_p10": float(np.percentile(r, 10)),
                    "specular_share": row["spec"] / r.size,
                    "first_moment_share": (float(np.median(np.concatenate(row["F"])))
                                           if sum(len(x) for x in row["F"]) else None),
                    **{t: row[t] / r.size for t in TERMS}})
    return out


def _sample(scene, gbuffer, n_pixels: int, seed: int):
    """The scene's light tree, light arrays and specular model, and ``n_pixels`` shaded
    pixels drawn with ``seed``: (tree, arrays, spec, flat indices, Pixels, D, S)."""
    tree = build_light_tree(scene.light_arrays)
    if tree is None:
        raise ValueError("the scene has too few clusterable point lights for a tree")
    fg = np.flatnonzero(~gbuffer.background_mask().reshape(-1))
    idx = np.random.default_rng(seed).choice(fg, size=min(n_pixels, len(fg)), replace=False)
    px, D, S = _pixels_of(scene, gbuffer, idx)
    return tree, scene.light_arrays, SpecularModel.of_scene(scene), idx, px, D, S


def bound_cut_sizes(scene, gbuffer, eps_list, n_pixels: int, tiles=(1, 16, 128), seed: int = 0):
    """{(what, ε): [list entries per sample pixel]} of the threshold cut
    (:func:`clphong.model.light_tree.choose_cut`) of the scene's light tree: ``what``
    is ``"exact"`` (each node's true error at the pixel, float64) or a tile size
    (the proven :func:`~clphong.model.light_tree.cluster_bounds` on the aligned tile
    holding the pixel). The gap from "exact" to tile 1 is the bound's slack; from
    tile 1 to the super-tiles', the tile's."""
    tree, a, spec, idx, px, D, S = _sample(scene, gbuffer, n_pixels, seed)
    n = len(a["point_position"])
    h, w = gbuffer.shape
    out = {}
    for j, flat in enumerate(idx):
        exact = node_errors(tree, a, px, D, S, j)[None]          # each channel's
        y, x = divmod(int(flat), w)
        for e in eps_list:
            out.setdefault(("exact", e), []).append(_entries(tree, *choose_cut(tree, exact, e), n))
        for t in tiles:
            b = cluster_bounds(tree, _tile_boxes(scene, gbuffer, y, x, t), spec, np.zeros(3),
                               channels=True)
            for e in eps_list:
                out.setdefault((t, e), []).append(_entries(tree, *choose_cut(tree, b, e), n))
    return out


def node_moments(tree, arrays) -> tuple[np.ndarray, np.ndarray]:
    """Each internal node's radiance moments about its representative p_k, per channel
    c: F (K, 3, 3), F_c = Σ_i R_ic·(p_i − p_k), and M (K, 3, 3, 3), M_c = Σ_i
    R_ic·(p_i − p_k)(p_i − p_k)ᵀ. Formed bottom-up by the parallel-axis rule (a child's
    moments moved to its parent's representative), so no large sums cancel. The tree
    keeps |F_c| (``first``) and tr M_c (``quadratic``) only; the bounds use those."""
    P = np.asarray(arrays["point_position"], np.float64)
    R = np.asarray(arrays["point_radiance"], np.float64)
    nl = tree.n_leaves
    F = np.zeros((tree.n_nodes, 3, 3))
    M = np.zeros((tree.n_nodes, 3, 3, 3))
    for lv in reversed(tree.levels):              # deepest first: children before parents
        for side in (0, 1):
            c = tree.children[lv, side]
            inner = c >= nl
            ci = np.where(inner, c - nl, 0)
            cl = np.where(inner, 0, c)
            pos = np.where(inner[:, None], tree.position[ci], P[cl])
            rad = np.where(inner[:, None], tree.radiance[ci], R[cl])
            Fc = np.where(inner[:, None, None], F[ci], 0.0)
            Mc = np.where(inner[:, None, None, None], M[ci], 0.0)
            d = pos - tree.position[lv]                           # (m, 3)
            F[lv] += Fc + rad[:, :, None] * d[:, None, :]
            M[lv] += (Mc + Fc[..., :, None] * d[:, None, None, :]
                      + d[:, None, :, None] * Fc[..., None, :]
                      + rad[:, :, None, None] * (d[:, :, None] * d[:, None, :])[:, None])
    return F, M


def taylor_terms(tree, F, M, one, D, S) -> np.ndarray:
    """(K, 3): each node's second-order Taylor estimate of its error at the one pixel
    ``one`` (a reference Pixels of one pixel, with its D and S (3,)), per channel:
    |∇f_c·F_c| + ½·|tr(∇²f_c·M_c)|, where f_c(L) is the contribution of a light of unit
    radiance at L with the node's falloff (the reference's D_c·diffuse + S_c·specular)
    and the derivatives are taken at the node's representative, by central differences
    (step 10⁻³ of its distance to the pixel, less near the pixel's plane).

    Not a bound: no remainder, and the derivatives at the pixel itself. A bound that
    bounds each term's size (sup|∇f|·|F_c| + ½·sup‖∇²f‖·tr M_c, as
    :func:`~clphong.model.light_tree.cluster_bounds`' second order does, or any split
    of tr(∇²f·M_c)) over boxes holding the pixel and the node is at least this where
    the node's lights are lit; one that keeps the terms' signs may be less.
    """
    att = tree.attenuation

    def f(Y):
        dif, spe = reference.shade_point_light(one, Y[:, None, :], att[:, 0:1], att[:, 1:2],
                                               att[:, 2:3])
        return dif[:, :1] * D + spe[:, :1] * S                  # (K, 3)

    p = tree.position
    # 10⁻³ of the distance, and less than 0.4 of the height above the pixel's plane (the
    # stencil stays on the lit side of the diffuse term's kink)
    h = np.minimum(1e-3 * np.linalg.norm(p - one.p[0], axis=1),
                   0.4 * np.abs((p - one.p[0]) @ one.n[0]))[:, None]     # (K, 1)
    E = np.eye(3)
    f0 = f(p)
    grad = np.stack([(f(p + h * E[a]) - f(p - h * E[a])) / (2 * h) for a in range(3)], -1)
    H = np.empty((len(p), 3, 3, 3))
    for a in range(3):
        H[..., a, a] = ((f(p + 2 * h * E[a]) - 2 * f0 + f(p - 2 * h * E[a])) / (4 * h * h))
        for b in range(a + 1, 3):
            s, t = E[a] + E[b], E[a] - E[b]
            H[..., a, b] = H[..., b, a] = ((f(p + h * s) - f(p + h * t) - f(p - h * t)
                                            + f(p - h * s)) / (4 * h * h))
    first = np.abs(np.einsum("kci,kci->kc", F, grad))
    return first + 0.5 * np.abs(np.einsum("kcij,kcij->kc", M, H))


def third_moments(tree, arrays) -> np.ndarray:
    """(K, 3): each internal node's Σ_i R_ic·|p_i − p_k|³ about its representative, per
    channel (a level's nodes hold disjoint runs of the leaves, :func:`leaf_ranges`)."""
    P = np.asarray(arrays["point_position"], np.float64)
    R = np.asarray(arrays["point_radiance"], np.float64)
    start, end, place = leaf_ranges(tree)
    order = np.argsort(np.where(place < 0, np.iinfo(np.int64).max, place))
    out = np.zeros((tree.n_nodes, 3))
    for lv in tree.levels:
        size = end[lv] - start[lv]
        owner = np.repeat(np.arange(len(lv)), size)
        at = np.repeat(start[lv], size) + np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        lights = order[at]
        d3 = np.linalg.norm(P[lights] - tree.position[lv][owner], axis=1) ** 3
        np.add.at(out, lv[owner], R[lights] * d3[:, None])
    return out


#: Unit directions (13, one of each ± pair) along which :func:`remainder_estimate`
#: samples the third derivative: the axes, the face and the body diagonals.
_DIRS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                  if (i, j, k) > (0, 0, 0)], np.float64)
_DIRS /= np.linalg.norm(_DIRS, axis=1)[:, None]


def remainder_estimate(tree, T3, one, D, S) -> np.ndarray:
    """(K, 3): an estimate of the third-order remainder of :func:`taylor_terms`,
    ⅙·sup‖∇³f_c‖·Σ_i R_ic·|p_i − p_k|³ (``T3``: :func:`third_moments`), with the sup
    taken over samples only: |∂³f_c/∂u³| along 13 directions, by central differences
    (step 10⁻² of the distance, and less than 0.4 of the point's height n·(X − P) above
    the pixel's plane, so that the stencil stays on the lit side of the diffuse term's
    kink; points below it are skipped), at the node's representative, the 8 corners of
    its box and its point nearest the pixel. Not a bound (a sampled sup): it says what
    a proven remainder of this form might give."""
    att = tree.attenuation

    def f(Y):
        dif, spe = reference.shade_point_light(one, Y[:, None, :], att[:, 0:1], att[:, 1:2],
                                               att[:, 2:3])
        return dif[:, :1] * D + spe[:, :1] * S

    sup = np.zeros((tree.n_nodes, 3))
    corners = [np.where(np.array([(c >> i) & 1 for i in range(3)], bool), tree.hi, tree.lo)
               for c in range(8)]
    nearest = np.clip(one.p[0], tree.lo, tree.hi)             # the box's point nearest the pixel
    for X in corners + [tree.position, nearest]:
        height = (X - one.p[0]) @ one.n[0]
        h = np.minimum(1e-2 * np.linalg.norm(X - one.p[0], axis=1), 0.4 * height)[:, None]
        above = (height > 0)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            for u in _DIRS:
                d3 = (f(X + 2 * h * u) - 2 * f(X + h * u) + 2 * f(X - h * u)
                      - f(X - 2 * h * u)) / (2 * h ** 3)
                sup = np.fmax(sup, np.where(above, np.abs(d3), 0.0))
    return sup * T3 / 6.0


def taylor_cut_sizes(scene, gbuffer, eps_list, n_pixels: int, *, relative: bool = False,
                     tile: int = 1, seed: int = 0):
    """{(what, ε): [list entries per sample pixel]} of the threshold cut at each pixel,
    ``what`` one of "exact" (true errors), "taylor" (:func:`taylor_terms` where the
    node is surely lit and smooth, never more than the proven bound, and the true error
    elsewhere: what a bound that adds the two terms' sizes would keep with exact
    derivatives and no remainder), "remainder" (the same with
    :func:`remainder_estimate` added: what a Taylor bound with a third-order remainder
    might keep, an estimate), "remainder, diffuse" (that for the diffuse term only, the
    proven bound's specular term as it is), "bound" (the proven
    :func:`~clphong.model.light_tree.cluster_bounds`, whose diffuse term takes
    :mod:`clphong.model.taylor`'s where that is the least) and "size bound" (the same
    without its Taylor term: the range, first- and second-order size bounds). With
    ``relative`` each channel's budget is ε times the pixel's float64 value (ambient
    and every light), as the relative budget asks. ``tile``: the proven bounds hold for
    the aligned ``tile`` × ``tile`` block holding the pixel (the others are the
    pixel's own)."""
    tree, a, spec, idx, px, D, S = _sample(scene, gbuffer, n_pixels, seed)
    n = len(a["point_position"])
    F, M = node_moments(tree, a)
    T3 = third_moments(tree, a)
    albedo = gbuffer.albedo.reshape(-1, 3)[idx].astype(np.float64)
    w = gbuffer.shape[1]
    out = {}
    for j, flat in enumerate(idx):
        one = reference.Pixels(p=px.p[j:j + 1], n=px.n[j:j + 1], v=px.v[j:j + 1],
                               k=px.k[j:j + 1], blinn=px.blinn, specular=px.specular)
        exact = node_errors(tree, a, px, D, S, j)
        y, x = divmod(int(flat), w)
        parts = {}
        b = cluster_bounds(tree, _tile_boxes(scene, gbuffer, y, x, 1), spec, np.zeros(3),
                           channels=True, parts=parts)[0]
        smooth = np.isfinite(np.broadcast_to(parts["diffuse_second"], (1,) + b.shape)[0])
        box = _tile_boxes(scene, gbuffer, y, x, tile)
        t2 = taylor_terms(tree, F, M, one, D[j], S[j])
        # where the expansion does not hold (a node across the pixel's horizon) the least
        # any bound may charge is the true error
        tay = np.where(smooth, np.fmin(t2, b), exact)
        rem = np.where(smooth, np.fmin(t2 + remainder_estimate(tree, T3, one, D[j], S[j]), b), b)
        # the diffuse term alone by Taylor and the estimated remainder, the proven
        # bound's specular term (and rounding) as it is
        dif = np.broadcast_to(parts["diffuse"], (1,) + b.shape)[0]
        zero = np.zeros(3)
        t2d = (taylor_terms(tree, F, M, one, D[j], zero)
               + remainder_estimate(tree, T3, one, D[j], zero))
        rem_d = b - dif + np.where(smooth, np.fmin(t2d, dif), dif)
        parts = {}
        bt = cluster_bounds(tree, box, spec, np.zeros(3), channels=True, parts=parts)[0]
        # the same bound without its Taylor term (light_tree.cluster_terms before it)
        dif_t = np.broadcast_to(parts["diffuse"], (1,) + bt.shape)[0]
        size = np.fmin(np.fmin(parts["diffuse_range"], parts["diffuse_first"]),
                       parts["diffuse_second"])
        before = bt - dif_t + np.broadcast_to(size, (1,) + bt.shape)[0]
        scale = 1.0
        if relative:
            value = (albedo[j] * reference.ambient_radiance(scene)
                     + light_contributions(one, D[j:j + 1], S[j:j + 1], a["point_position"],
                                           a["point_radiance"], a["point_attenuation"])[:, 0].sum(0))
            scale = 1.0 / value
        for what, e_ in (("exact", exact), ("taylor", tay), ("remainder", rem),
                         ("remainder, diffuse", rem_d), ("bound", bt), ("size bound", before)):
            for e in eps_list:
                used, cov = choose_cut(tree, (e_ * scale)[None], e)
                out.setdefault((what, e), []).append(_entries(tree, used, cov, n))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m clphong.tools.cut_floor", description=__doc__.split("\n\n")[0])
    p.add_argument("--eps", default="1e-3,1e-2,3e-2", help="budgets, relative to white 1.0")
    p.add_argument("--lights", type=int, default=65536, help="lights of the bench 'wide' scene")
    p.add_argument("--pixels", type=int, default=8, help="sample pixels of the 1080p bench G-buffer")
    p.add_argument("--scene", default="wide", choices=("wide", "clusters"),
                   help="bench scene (default wide)")
    p.add_argument("--bound", action="store_true",
                   help="also the threshold cut of the light tree itself: with the true errors, "
                        "and with the proven bound on tiles of 1, 16 and 128 pixels")
    p.add_argument("--taylor", action="store_true",
                   help="only the cut at each sample pixel with the true errors, with the "
                        "second-order Taylor terms at the pixel (taylor_terms), with those plus "
                        "a sampled estimate of a third-order remainder (remainder_estimate), "
                        "with the proven bound (light_tree.cluster_bounds, whose diffuse term "
                        "takes Taylor's, clphong/model/taylor.py, where it is the least) and "
                        "with that bound without its Taylor term")
    p.add_argument("--relative", action="store_true",
                   help="with --taylor: each channel's budget is ε times the pixel's value")
    p.add_argument("--tile", type=int, default=1,
                   help="with --taylor: the proven bounds over the aligned tile of this many "
                        "pixels a side that holds each sample pixel (default 1)")
    p.add_argument("--levels", action="store_true",
                   help="only the bound against the true error per depth of the tree, and "
                        "the terms that set it (level_slack)")
    args = p.parse_args(argv)
    eps = [float(x) for x in args.eps.split(",")]
    if args.taylor:
        got = taylor_cut_sizes(bench_scene(args.scene, args.lights), bench_gbuffer(1920, 1080),
                               eps, args.pixels, relative=args.relative, tile=args.tile)
        rows = []
        for e in eps:
            ex, *more = (np.median(got[(w_, e)]) for w_ in
                         ("exact", "taylor", "remainder", "remainder, diffuse", "bound",
                          "size bound"))
            rows.append([f"{e:g}" + (" relative" if args.relative else ""), args.lights,
                         f"{ex:.0f}"] + [f"{v:.0f} ({v / ex:.1f}×)" for v in more])
        print(markdown_table(["ε", "lights", "true errors", "Taylor terms at the pixel (no remainder)",
                              "with a sampled 3rd-order remainder (estimate)",
                              "the same, diffuse only",
                              f"proven bound, {args.tile} px",
                              f"the same without its Taylor term, {args.tile} px"], rows))
        return 0
    if args.levels:
        got = level_slack(bench_scene(args.scene, args.lights), bench_gbuffer(1920, 1080),
                          args.pixels)
        heads = ["depth", "nodes", "pairs", "median error", "median bound", "bound / error",
                 "10th pct", "specular sets it", "d: range", "d: 1st", "d: 2nd", "s: range",
                 "s: smooth", "Λ·F of d: 2nd"]
        print(markdown_table(heads, [
            [r["depth"], r["nodes"], r["pairs"], f"{r['error']:.2g}", f"{r['bound']:.2g}",
             f"{r['slack']:.3g}", f"{r['slack_p10']:.3g}", f"{r['specular_share']:.0%}"]
            + [f"{r[t]:.0%}" for t in TERMS]
            + ["–" if r["first_moment_share"] is None else f"{r['first_moment_share']:.0%}"]
            for r in got]))
        return 0
    if args.bound:
        scene = bench_scene(args.scene, args.lights)
        got = bound_cut_sizes(scene, bench_gbuffer(1920, 1080), eps, args.pixels)
        whats = ["exact", 1, 16, 128]
        rows = [[f"{e:g}", args.lights] + [f"{np.median(got[(t, e)]):.0f}" for t in whats]
                for e in eps]
        print(markdown_table(["ε", "lights", "true errors", "bound, 1 px", "bound, 16 px",
                              "bound, 128 px"], rows))
        print()
    sizes = cut_sizes(bench_scene("wide", args.lights), bench_gbuffer(1920, 1080), eps, args.pixels)
    rows = [[f"{e:g}", args.lights, f"{np.median(s):.0f}", min(s), max(s),
             f"{np.median(s) / args.lights:.1%}"] for e, s in sizes.items()]
    print(markdown_table(["ε", "lights", "median cut", "min", "max", "median / lights"], rows))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

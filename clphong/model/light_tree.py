"""A light tree over the point lights, and the bound of a cluster's error (issue 16).

Lightcuts (Walter et al. 2005) and the light trees of Cycles and pbrt-v4 replace
the lights under a node by one *representative* that carries their summed
radiance. Here a node's representative is a virtual point light at the
radiance-weighted centroid ``p_k`` of its lights, with their summed radiance
``R_k`` and their shared falloff polynomial (and cone); the representatives join
the point-light records, each light group's after its own lights
(clphong/device/culling.py ``ExtendedLayout``), so a tile's list may name either
(:func:`representative_records`).

Which lights may share a node: point lights with the same falloff coefficients
``c0, c1, c2 ≥ 0`` (so the falloff ``A(d) = 1/p(d)`` decreases in ``d``), finite
non-negative radiance and at least one positive channel, in the same light group (so
each group layer keeps its own guarantee), and the same cone: none, or a spot's axis
and ``(s, o)`` (a rig of spots; the representative is a spot with that cone). Lights
with a falloff or cone of their own and lights with negative radiance are leaves
that are never clustered.

A spot's factor t² (t = clamp(cos θ·s + o, 0, 1)) multiplies each term below: its
largest value t⁺² over the box pair scales the range; |∇t²| ≤ 2t⁺·s/d joins the
gradient by the product rule; ‖∇²t²‖ ≤ (2s² + 6t⁺·s)/d² joins the Hessian, which is
used only where t has no kink over the pair (all inside the inner cone, t ≡ 1, or all
on the ramp) (:func:`spot_factor_bounds`).

The tree is a kd-tree, built level by level with vectorised sorts: a node's lights are
sorted along the longest axis of their box and split where the two sides' weighted sums
of squared distances to their centroids (their Q below) are least, each side keeping a
quarter of the lights or more (:data:`SPLIT`), so that compact groups stay whole;
65 536 lights in about 0.9 s.

The bound (:func:`cluster_bounds`): for a pixel ``x`` and channel ``c``, the
error of the representative is

    e_c = Σ_i R_ic·(f_c(x, p_i) − f_c(x, p_k)),  f_c = D_c·g_d + S_c·g_s,

with ``g_d = max(n·u, 0)·A(d)`` and ``g_s`` the specular power (times the Schlick
weight, ≤ 1) times ``A(d)``, ``u = (p − x)/d``, ``d = |p − x|``. Every ``p_i`` and
``p_k`` lie in the node's box, so the segment between them does; over the box pair
(the tile's box of P and normals × the node's box, ``d ≥ d⁻ > 0``) three bounds
hold, and the smallest is taken, per term:

* **range**: both sums lie in ``[0, R_kc·A(d⁻)·w⁺]``, ``w⁺`` the largest weight: for
  the diffuse term ``(n·u)⁺`` from interval arithmetic, for the specular term
  ``c^K``, ``c`` a bound of its cosine from cones (:func:`specular_cosine`: of the
  normals, of the directions to the node's box, of the view directions);
* **first order**: ``|e_c| ≤ Λ·M_kc`` with ``M_kc = Σ_i R_ic·|p_i − p_k|`` and ``Λ`` a
  bound of the gradient in ``p``;
* **second order** (Taylor about the centroid ``p_k``, where ``Σ_i w_i (p_i − p_k) = 0``):
  ``|e_c| ≤ Λ·F_kc + ½·H·Q_kc`` with ``F_kc = |Σ_i R_ic (p_i − p_k)|`` (0 for lights
  of one colour), ``Q_kc = Σ_i R_ic·|p_i − p_k|²`` and ``H`` a bound of the Hessian;
  only where ``n·u > 0`` over the whole box pair (the terms are smooth there);
* **Taylor** (diffuse, where ``t`` is constant over the pair and ``n·u > 0`` over it):
  the two terms themselves, ``∇g·F_c + ½·tr(∇²g·M_c)`` with ``F_c`` the vector and
  ``M_c`` the tensor, both linear in ``n`` and bounded over the tile's boxes, plus the
  third-order remainder ``⅙·sup‖∇³g‖·Σ_i R_ic |p_i − p_k|³``
  (:mod:`clphong.model.taylor`, :func:`taylor_term`; 2026-12-08). Size bounds cannot
  see that ``∇g·F_c`` and ``tr(∇²g·M_c)`` are far smaller than ``|∇g|·|F_c|`` and
  ``‖∇²g‖·tr M_c`` when the moments and the derivatives point different ways.

The constants, with ``A = A(d⁻)`` and ``d = d⁻`` where a term is decreasing in ``d``,
and the falloff's own slopes ``A₁ = sup |A′|`` and ``A₂ = sup |A″|`` over ``d ≥ d⁻``
(:func:`~clphong.model.falloff.falloff_slopes`: the value at ``d⁻`` or at a turning
point beyond it; ``|A′| ≤ 2A/d`` and ``|A″| ≤ 8A/d²`` always). With ``c = n·u ≥ 0``,
``s = √(1 − c²)`` and ``w`` the unit vector of ``n − c·u``, the diffuse weight ``g =
c·A`` has ``∇g = A·s/d·w + c·A′·u``, so ``|∇g| ≤ Λ_d = max(A/d, A₁)``; its Hessian is,
in the frame (u, w, u × w), ``[[c·A″, −s·m, 0], [−s·m, −c·m, 0], [0, 0, −c·m]]`` with
``m = A/d² + |A′|/d`` (both decreasing in d). ``H_d`` is its spectral norm's largest
value over ``c`` in the pair's range ``[c⁻, c⁺]`` (:func:`diffuse_hessian_sup`, in closed
form): ``2A/(√3·d²)`` without falloff where ``c`` may be ``1/√3``, and ``A/d²`` straight
under the light. Before 2026-12-07 it was the Frobenius bound ``√(m² + max(m, A₂)²)``,
``√2·A/d²`` without falloff (the constants 3A/d and 15A/d², used before 2026-12-06, were
3× and 10× that). Likewise ``Λ_d`` is ``|∇g|``'s largest value over ``[c⁻, c⁺]``
(:func:`diffuse_gradient_sup`), ``max(A/d, A₁)`` when the range is ``[0, 1]``. The specular cosine ``x = cos θ`` (``n·h``, or ``r·v``
for Phong) moves with ``|∇θ| ≤ g``: Phong's ``r = (2nnᵀ − I)u`` is an orthogonal map
of ``u``, so ``g = 1/d``; Blinn-Phong's half vector moves by ``|∇u|/|u + v|``, so
``g = 1/(d·|u + v|⁻)``, ``|u + v|⁻`` from a lower bound of ``u·v``. Then ``|∇x| ≤
sin θ·g``, and with ``J = ∇h`` (``∇r`` for Phong; ``‖J‖ ≤ g``) and ``h·h = 1``,
``∇²x = −x·JᵀJ + n_⊥·∇²h``: a negative semi-definite part of norm ≤ ``cos θ·g²`` and
a part ≤ ``sin θ·b`` from ``∇²h``'s part across ``h``. Along a unit ``a``, ``∇²u(a, a)
= −(2(u·a)·a_⊥ + |a_⊥|²·u)/d²``: across ``u`` at most ``1/d²``, in all at most
``(2/√3)/d²``. So for Phong (``r`` an orthogonal map of ``u``) ``b = g²``; for
Blinn-Phong ``∇²h``'s part across ``h`` is ``−2·∇h·(h·∇u)/|u + v|`` (``|h·∇u| ≤
sin(γ/2)/d``, ``γ ≤ γ⁺`` the angle between ``u`` and ``v``) plus ``∇²u``'s part across
``h`` over ``|u + v|``, so ``b = 2·sin(γ⁺/2)·g² + (2/√3)·g/d`` (before 2026-12-07:
``2g² + 3g/d`` for both). Two facts of the geometry tighten the sums
(2026-12-07): ``x`` depends on ``p`` only through ``u``, so ``∇x ⊥ u`` while ``∇A =
A′·u`` is radial (a gradient's two parts add in quadrature, and the cross term ``∇A ∇Pᵀ
+ ∇P ∇Aᵀ`` has norm ``|∇A|·|∇P|``, not twice it); and for ``S ⪰ 0 ⪰ N``, ``‖S + N‖ ≤ max(‖S‖,
‖N‖)``. So for ``P = x^K`` (``K ≥ 1``; ``K ≥ 2`` for the second order), ``∇²P =
K(K−1)x^(K−2)·∇x∇xᵀ − K·x^K·JᵀJ + K·x^(K−1)·n_⊥·∇²h``, with ``h1, f1`` the
maxima over ``x ∈ [0, c]`` of ``x^(K−1)·√(1 − x²)`` and ``x^(K−2)·(1 − x²)``:
``Λ_s = hypot(A·K·h1·g, c^K·A₁)`` (``A·K·h1·g + 5g·c^K·A`` in the first with
Blinn-Phong's Schlick weight, which depends on ``v·h``) and ``H_s =
A·(max(K(K−1)·f1, K·c^K)·g² + K·h1·b) + K·h1·g·A₁ + c^K·max(A₂, |A′(d⁻)|/d⁻)``
(‖∇²A‖: radially A″, across A′/d; not used with Blinn-Phong's Schlick weight).
Before, ``Λ_s`` and ``H_s`` summed every part (``K(K−1)f1 + K(2h1 + c^K)``,
``2K·h1·g·A₁``): at a highlight's 16×16 tile on ``clusters`` (65 536 lights, 10⁻³)
the cut keeps 9 469 entries now, 14 035 before. A shininess map or ``K < 1`` leaves the
specular term its range ``R·A`` alone.

Where ``n·u ≤ 0`` over the whole box pair both sums are 0 (bound 0); where the
boxes touch (``d⁻ = 0``) there is no bound (+inf: the node is never used there).
The gate tests carry cull.cl's margin for the kernel's error of ``n·l``; the float32
roundings of the representative's record (position ``u·|p|``, radiance ``u``) are
added; the shading arithmetic itself is the float error model's, the same for a
representative as for any light. tests/model/test_light_tree.py holds the bound
against the float64 reference's own contributions (hypothesis, random scenes).

The cut (:func:`choose_cut`): per tile, the largest threshold τ on a grid whose cut
(every topmost node whose bound, its largest channel's, is ≤ τ) has each channel's
bounds summing to ≤ ε. The guarantee is per channel, so the sums are too: a node's
error lies in one colour more than in the others, and a cut of many colours' clusters
holds ε in each channel with fewer entries than Σ max (the greedy cut of 32×32 pixels
on `clusters` at 65 536 lights, absolute 10⁻³: 0.79–0.99 of the entries, median 0.88,
eight sample pixels). :func:`threshold_cut` finds the same cut from the top down, bounding only the nodes above it and their
children, which is what a large tree with a loose budget needs (65 535 nodes at
relative 10⁻¹: 18× fewer seconds than the whole table; docs/bench.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core.floats import U
from ..core.geometry import view_vector
from .falloff import falloff_peaks, falloff_slopes, falloff_third_roots, falloff_third_sup
from .taylor import PAIRS, phi_sups, taylor_diffuse, third_derivative_sup

#: Fewest clusterable lights worth a tree (below it every list is short anyway).
MIN_TREE_LIGHTS = 64


@dataclass(frozen=True)
class LightTree:
    """Internal nodes of a forest over the point lights (see the module docstring).

    Nodes are numbered after the leaves: leaf ``j`` is point light ``j``, internal
    node ``k`` is ``n_leaves + k``. ``levels`` lists the internal nodes depth by
    depth (roots first), for top-down passes; ``children`` (K, 2) holds the
    combined numbers of each internal node's two children.
    """

    n_leaves: int
    lo: np.ndarray          # (K, 3) box of the node's light positions
    hi: np.ndarray
    position: np.ndarray    # (K, 3) the representative: radiance-weighted centroid
    radiance: np.ndarray    # (K, 3) summed radiance
    moment: np.ndarray      # (K, 3) Σ_i R_ic·|p_i − p_k|
    quadratic: np.ndarray   # (K, 3) Σ_i R_ic·|p_i − p_k|²
    first: np.ndarray       # (K, 3) |Σ_i R_ic·(p_i − p_k)| (0 for lights of one colour)
    first_vector: np.ndarray  # (K, 3, 3) Σ_i R_ic·(p_i − p_k), per channel c
    second_moment: np.ndarray  # (K, 3, 6) Σ_i R_ic·(p_i − p_k)(p_i − p_k)ᵀ (taylor.PAIRS)
    third_moment: np.ndarray  # (K, 3) Σ_i R_ic·|p_i − p_k|³
    attenuation: np.ndarray  # (K, 3) the shared c0, c1, c2
    peaks: tuple            # ((K, 2), (K, 3)) where |A′| and |A″| may peak (falloff_peaks)
    third_peaks: np.ndarray  # (K, 4) where |A‴| may peak (falloff_third_roots)
    cone: np.ndarray        # (K, 5) the shared cone: a spot's axis, (s, o); (0, 0, 0, 0, 1)
    group: np.ndarray       # (K,) the light group of the node's lights (0 without groups)
    children: np.ndarray    # (K, 2) combined numbers
    levels: tuple           # tuple of int arrays of internal-node numbers (0-based k)
    clusterable: int        # lights under some internal node
    seconds: float          # build time

    @property
    def n_nodes(self) -> int:
        return len(self.lo)


def group_of(ends, n: int) -> np.ndarray:
    """(n,) the group of each of n records in group order, ``ends`` each group's end
    (empty: one group, 0)."""
    ends = np.asarray(ends, np.int64)
    return np.searchsorted(ends, np.arange(n), side="right") if ends.size else np.zeros(n, np.int64)


def light_groups_of(arrays) -> np.ndarray:
    """(N,) the light group of each point light (0 without groups): the lights are in
    group order, ``point_group_end`` each group's end."""
    return group_of(arrays.get("point_group_end", ()), len(arrays["point_position"]))


def clusterable_classes(arrays) -> list[np.ndarray]:
    """Index arrays of the point lights that may share nodes: one per falloff, cone
    (spots with the same axis and ``(s, o)``, ``s ≥ 0``; a plain point light's is
    ``(0, 1)``) and light group, so that a group's clusters stand for its own lights."""
    pos = arrays["point_position"]
    if len(pos) == 0:
        return []
    R = arrays["point_radiance"]
    att = arrays["point_attenuation"]
    cone = np.asarray(arrays["point_cone"], np.float64)
    ok = (np.isfinite(R).all(axis=1) & (R >= 0).all(axis=1)
          & (R.sum(axis=1) > 0) & np.isfinite(pos).all(axis=1)
          & (att >= 0).all(axis=1) & np.isfinite(att).all(axis=1) & (att.sum(axis=1) > 0)
          & np.isfinite(cone).all(axis=1) & (cone[:, 3] >= 0))
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return []
    key = np.column_stack([att[idx], cone[idx], light_groups_of(arrays)[idx]])
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    return [idx[inv == c] for c in range(inv.max() + 1) if (inv == c).sum() >= 2]


#: How a node's lights are split, after sorting them along the longest axis of their box:
#: "variance", where the two sides' radiance-weighted sums of squared distances to their
#: centroids (the second-order bound's Q) are least, each side holding at least
#: SPLIT_SHARE of the lights; or "median", in halves. Compact groups then stay whole
#: (a median falls inside a group as often as not, and a node holding parts of two
#: groups has the Q of their distance). On `clusters` at 65 536 lights the nodes' Q at
#: depth 10 sum to 0.88 against 4.03 with medians, and whole 1080p frames (Ice Lake,
#: Intel's runtime, second frame) take 18.4 s against 25.4 s at absolute 10⁻³, 2.29 s
#: against 4.14 s at relative 10⁻²; `wide` (uniform lights) keeps its Q (13.07 against
#: 13.29) and its frame (relative 10⁻²: 109 s against 118 s). The build: 0.85 s
#: against 0.57 s.
SPLIT = "variance"
SPLIT_SHARE = 0.25


def _split_points(p, w, starts, ends):
    """Per segment [start, end) of the level (its lights ``p`` (m, 3) in sorted order,
    weights ``w`` (m,)), the split index where the two sides' weighted sums of squared
    distances to their own centroids are least, with at least SPLIT_SHARE of the
    segment's lights (and one) on each side."""
    size = ends - starts
    off = np.r_[0, np.cumsum(size)[:-1]]
    seg = np.repeat(np.arange(size.size), size)
    # inclusive prefix sums within each segment (global cumsums less the segment's base)
    def prefix(x):
        c = np.cumsum(x, axis=0)
        base = np.where(off[:, None] > 0, c[np.maximum(off - 1, 0)], 0.0) if x.ndim > 1 \
            else np.where(off > 0, c[np.maximum(off - 1, 0)], 0.0)
        return c - base[seg]
    W = prefix(w)
    Wp = prefix(w[:, None] * p)
    Wq = prefix(w * (p * p).sum(axis=1))
    last = off + size - 1
    tot_W, tot_Wp, tot_Wq = W[last][seg], Wp[last][seg], Wq[last][seg]
    with np.errstate(divide="ignore", invalid="ignore"):
        left = Wq - (Wp * Wp).sum(axis=1) / W            # lights ≤ j on the left
        rW = tot_W - W
        rWp = tot_Wp - Wp
        right = (tot_Wq - Wq) - (rWp * rWp).sum(axis=1) / rW
        cost = np.nan_to_num(left, nan=0.0) + np.nan_to_num(right, nan=0.0)
    j = np.arange(len(seg)) - off[seg]                   # position within the segment
    least = np.maximum(np.ceil(SPLIT_SHARE * size), 1).astype(np.int64)
    # a split after position j puts j + 1 lights on the left
    ok = (j + 1 >= least[seg]) & (size[seg] - j - 1 >= least[seg])
    cost = np.where(ok, cost, np.inf)
    best = np.lexsort((j, cost, seg))                     # per segment: least cost first
    first = np.r_[0, np.cumsum(size)[:-1]]
    pick = best[first]
    mids = starts + j[pick] + 1
    # no valid split (segments of two or three lights): the middle
    return np.where(np.isfinite(cost[pick]), mids, (starts + ends) // 2)


def build_light_tree(arrays) -> LightTree | None:
    """The forest over ``arrays``' clusterable point lights (:func:`clusterable_classes`),
    or None when fewer than :data:`MIN_TREE_LIGHTS` may be clustered."""
    t0 = time.perf_counter()
    classes = clusterable_classes(arrays)
    if sum(len(c) for c in classes) < MIN_TREE_LIGHTS:
        return None
    n = len(arrays["point_position"])
    P = np.asarray(arrays["point_position"], np.float64)
    R = np.asarray(arrays["point_radiance"], np.float64)
    A = np.asarray(arrays["point_attenuation"], np.float64)
    Cn = np.asarray(arrays["point_cone"], np.float64)
    gid = light_groups_of(arrays)
    los, his, reps, rads, moms, atts, kids = [], [], [], [], [], [], []
    cones, groups = [], []
    quads, fvecs, seconds, thirds = [], [], [], []
    levels: list[list[np.ndarray]] = []
    base = 0                                    # internal nodes numbered so far
    for members in classes:
        order = members.copy()
        # segments of the current level, as [start, end) into `order`, each an internal node
        starts, ends = np.array([0]), np.array([len(order)])
        ids = np.array([base])
        base += 1
        depth = 0
        while starts.size:
            # sort each segment along its longest axis (one lexsort for the level)
            seg = np.repeat(np.arange(starts.size), ends - starts)
            at = np.concatenate([np.arange(s, e) for s, e in zip(starts, ends)])
            p = P[order[at]]
            lo = np.minimum.reduceat(p, np.r_[0, np.cumsum(ends - starts)[:-1]], axis=0)
            hi = np.maximum.reduceat(p, np.r_[0, np.cumsum(ends - starts)[:-1]], axis=0)
            axis = np.argmax(hi - lo, axis=1)
            key = p[np.arange(len(at)), axis[seg]]
            perm = np.lexsort((key, seg))
            order[at] = order[at][perm]
            w = R[order[at]]                    # radiance in the level's (sorted) order
            pp = P[order[at]]
            ww = w.sum(axis=1)
            off = np.r_[0, np.cumsum(ends - starts)[:-1]]
            W = np.add.reduceat(ww, off)
            cent = np.add.reduceat(pp * ww[:, None], off, axis=0) / W[:, None]
            dist = np.sqrt(((pp - cent[seg]) ** 2).sum(axis=1))
            moms.append(np.add.reduceat(w * dist[:, None], off, axis=0))
            quads.append(np.add.reduceat(w * (dist * dist)[:, None], off, axis=0))
            delta = pp - cent[seg]                      # (m, 3) offsets from the centroid
            fvecs.append(np.add.reduceat(w[:, :, None] * delta[:, None, :], off, axis=0))
            pairs = np.stack([delta[:, a] * delta[:, b] for a, b in PAIRS], axis=1)
            seconds.append(np.add.reduceat(w[:, :, None] * pairs[:, None, :], off, axis=0))
            thirds.append(np.add.reduceat(w * (dist ** 3)[:, None], off, axis=0))
            rads.append(np.add.reduceat(w, off, axis=0))
            los.append(lo)
            his.append(hi)
            reps.append(cent)
            atts.append(A[order[starts]])
            cones.append(Cn[order[starts]])
            groups.append(gid[order[starts]])
            while len(levels) <= depth:
                levels.append([])
            levels[depth].append(ids)
            # children: the two sides of the split (a side of one light is a leaf: its
            # light's number)
            mids = _split_points(pp, ww, starts, ends) if SPLIT == "variance" else (starts + ends) // 2
            halves = [(starts, mids), (mids, ends)]
            ch = np.empty((starts.size, 2), np.int64)
            nxt_s, nxt_e, nxt_id = [], [], []
            for side, (s, e) in enumerate(halves):
                leaf = (e - s) == 1
                ch[leaf, side] = order[s[leaf]]
                inner = ~leaf
                new = base + np.arange(inner.sum())
                base += inner.sum()
                ch[inner, side] = n + new
                nxt_s.append(s[inner])
                nxt_e.append(e[inner])
                nxt_id.append(new)
            kids.append((ids, ch))
            # next level in id order, so that ids stay sorted within a level
            s2, e2, i2 = np.concatenate(nxt_s), np.concatenate(nxt_e), np.concatenate(nxt_id)
            o = np.argsort(i2)
            starts, ends, ids = s2[o], e2[o], i2[o]
            depth += 1
    K = base
    cat_ids = np.concatenate([i for i, _ in kids])

    def place(parts):
        out = np.empty((K,) + parts[0].shape[1:], parts[0].dtype)
        out[cat_ids] = np.concatenate(parts)
        return out

    children = place([c for _, c in kids])
    att = place(atts)
    fvec = place(fvecs)
    return LightTree(n_leaves=n, lo=place(los), hi=place(his), position=place(reps),
                     radiance=place(rads), moment=place(moms), quadratic=place(quads),
                     first=np.sqrt(np.sum(fvec * fvec, axis=-1)), first_vector=fvec,
                     second_moment=place(seconds), third_moment=place(thirds),
                     attenuation=att, peaks=falloff_peaks(att),
                     third_peaks=falloff_third_roots(att),
                     cone=place(cones),
                     group=place(groups), children=children, levels=tuple(np.concatenate(lv) for lv in levels),
                     clusterable=sum(len(c) for c in classes),
                     seconds=time.perf_counter() - t0)


def representative_records(tree: LightTree, origin) -> tuple[np.ndarray, np.ndarray]:
    """(float32 rebased, float64 as they are) point records of the representatives,
    in the layout of the scene's own (clphong/device/frame.py pack_lights)."""
    rec = np.zeros((tree.n_nodes, 4, 4))
    rec[:, 0, :3] = tree.position
    rec[:, 0, 3] = tree.attenuation[:, 0]
    rec[:, 1, :3] = tree.radiance
    rec[:, 1, 3] = tree.attenuation[:, 1]
    rec[:, 2, 0] = tree.attenuation[:, 2]
    rec[:, 2, 1:4] = tree.cone[:, :3]           # a spot's axis, and its (s, o); a point
    rec[:, 3, 0:2] = tree.cone[:, 3:5]          # light's (0, 1): no cone
    rec64 = rec.reshape(-1, 4).copy()
    rec[:, 0, :3] -= np.asarray(origin, np.float64)
    return rec.reshape(-1, 4).astype(np.float32), rec64


@dataclass(frozen=True)
class TileBoxes:
    """What a bound needs of a set of screen tiles (arrays of shape (T,) or (T, 3)),
    in the frame's rebased coordinates: boxes of P and of the unit normals, the
    largest |D| and |S| per channel; empty tiles have lo > hi."""

    lo: np.ndarray
    hi: np.ndarray
    nlo: np.ndarray
    nhi: np.ndarray
    D: np.ndarray
    S: np.ndarray

    @classmethod
    def of_pixels(cls, P, N, D, S) -> "TileBoxes":
        """One tile holding the pixels P, N (unit), D, S ((M, 3) each; S may be (3,))."""
        def box(x):
            return np.min(x, axis=0)[None], np.max(x, axis=0)[None]

        (lo, hi), (nlo, nhi) = box(P), box(N)
        return cls(lo=lo, hi=hi, nlo=nlo, nhi=nhi, D=np.abs(D).max(axis=0)[None],
                   S=np.abs(np.atleast_2d(S)).max(axis=0)[None])


@dataclass(frozen=True)
class SpecularModel:
    """The specular term's shape, for its Lipschitz constant."""

    blinn: bool
    exponent: float          # K: h (Phong) or 4h (Blinn-Phong); None with a shininess map
    fresnel: bool            # Schlick's weight on v·h (Blinn-Phong only depends on l)
    eye: np.ndarray          # perspective: eye − origin; orthographic: unit v
    perspective: bool

    @classmethod
    def of_scene(cls, scene, eye=None, *, shininess_map: bool = False) -> "SpecularModel":
        """The scene's material and camera; ``eye`` (rebased, or the unit v) by default
        the camera's own: its position, or the orthographic view vector."""
        m, cam = scene.material, scene.camera
        perspective = cam.type == "perspective"
        if eye is None:
            eye = np.asarray(cam.position, np.float64) if perspective else view_vector(cam)
        return cls(blinn=m.model == "blinn-phong", exponent=None if shininess_map else m.exponent,
                   fresnel=m.fresnel == "schlick", eye=np.asarray(eye, np.float64),
                   perspective=perspective)


def _sum3(x):
    """x[..., 0] + x[..., 1] + x[..., 2]: numpy's sum over a last axis of 3, in its order
    and to the bit, without the reduction's per-row cost."""
    return x[..., 0] + x[..., 1] + x[..., 2]


def _max3(x):
    """The largest of x[..., 0:3] (NaN if any is), as ``x.max(axis=-1)``."""
    return np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2])


def _interval_dot(alo, ahi, blo, bhi):
    """Bounds of a·b for a ∈ [alo, ahi], b ∈ [blo, bhi] (…, 3): (lo, hi)."""
    p, q, r, s = alo * blo, alo * bhi, ahi * blo, ahi * bhi
    lo = np.minimum(np.minimum(p, q), np.minimum(r, s))
    hi = np.maximum(np.maximum(p, q), np.maximum(r, s))
    return _sum3(lo), _sum3(hi)


def _unit(x):
    n = np.sqrt(_sum3(x * x))[..., None]
    with np.errstate(divide="ignore", invalid="ignore"):
        return x / n, n[..., 0]


def _angle(a, b):
    """Angle between unit vectors (…, 3), from atan2 (accurate near 0 and π)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0    # a × b
    return np.arctan2(np.sqrt(c0 * c0 + c1 * c1 + c2 * c2), _sum3(a * b))


def _cone(dirs_center, radius, dist):
    """Half-angle of the directions from a point to a ball of ``radius`` at ``dist``
    (π where the ball holds the point)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(dist > radius, np.arcsin(np.clip(radius / dist, 0, 1)), np.pi)


def specular_cosine(tiles: TileBoxes, blo, bhi, spec: SpecularModel):
    """(T, K) upper bound c of the specular cosine (n·h, or r·v for Phong) over the
    tiles × node boxes, from cones: of the normals (the normal box), of the light
    directions (ball to ball) and of the view directions; the power is ≤ c^K. 1
    where no cone holds. Returns (c, sin(γ⁺/2)), γ⁺ ≤ π the largest angle between
    u and v over the boxes (Blinn-Phong; 1 for Phong, where it is not used)."""
    T = len(tiles.lo)
    # normal cone: axis n0 the box's centre; cos α_n ≥ min over the box's corners of c·n0
    n0, _ = _unit(0.5 * (tiles.nlo + tiles.nhi))
    corner = _sum3(np.minimum(tiles.nlo * n0, tiles.nhi * n0))
    a_n = np.where(corner > 0, np.arccos(np.clip(corner, -1, 1)), np.pi)[:, None]
    ct, rt = 0.5 * (tiles.lo + tiles.hi), 0.5 * _unit(tiles.hi - tiles.lo)[1]
    cb, rb = 0.5 * (blo + bhi), 0.5 * _unit(bhi - blo)[1]
    u0, dist = _unit(cb - ct[:, None])
    a_u = _cone(None, rt[:, None] + rb, dist)
    if spec.perspective:
        v0, de = _unit(np.asarray(spec.eye, np.float64) - ct)
        a_v = _cone(None, rt, de)[:, None]
        v0 = v0[:, None]
    else:
        v0 = np.broadcast_to(np.asarray(spec.eye, np.float64), (T, 1, 3))
        a_v = np.zeros((T, 1))
    n0 = n0[:, None]
    with np.errstate(invalid="ignore"):
        if spec.blinn:
            # the half vector h = (u + v)/|u + v| moves by ≤ (δu + δv)/(2 cos(γ/2)),
            # γ ≤ γ⁺ the angle between u and v
            gamma = _angle(u0, v0) + a_u + a_v
            h0, _ = _unit(u0 + v0)
            d_h = (a_u + a_v) / (2.0 * np.cos(np.minimum(gamma, np.pi) / 2.0))
            beta = np.where(gamma < np.pi, _angle(n0, h0) - a_n - d_h, -1.0)
            # + 1e-5: the kernel's sine errs by a few u
            half = np.minimum(np.sin(np.minimum(gamma, np.pi) / 2.0) + 1e-5, 1.0)
            half = np.nan_to_num(half, nan=1.0)
        else:
            # r = 2n(n·u) − u, the reflection of u: moves by ≤ δu + 2δn
            r0 = 2.0 * n0 * _sum3(n0 * u0)[..., None] - u0
            beta = _angle(r0, v0) - a_u - 2.0 * a_n - a_v
            half = np.ones_like(beta)
    beta = np.nan_to_num(beta, nan=-1.0)
    # + 1e-5: the kernel's cosine errs by a few u
    c = np.minimum(np.cos(np.clip(beta, 0.0, np.pi / 2)) + 1e-5, 1.0)
    return np.where(beta > 0, c, 1.0), half


def cluster_bounds(tree: LightTree, tiles: TileBoxes, spec: SpecularModel,
                   origin, nodes: np.ndarray | None = None, *, pairs: bool = False,
                   parts: dict | None = None, channel_scale=None, terms=None,
                   channels: bool = False) -> np.ndarray:
    """(T, K) upper bounds of the error of using each internal node's representative
    for its lights, for any pixel and channel of each tile (see the module docstring);
    +inf where no bound holds, 0 for empty tiles. ``nodes``: a subset of the
    internal nodes (their 0-based numbers), by default all. ``pairs``: ``tiles`` and
    ``nodes`` (P each) go together row by row, and the result is (P,): the same
    numbers as the (T, K) form's at those pairs. ``parts``: a dict to receive the
    terms, per channel (…, 3), for ``python -m clphong.tools.cut_floor --levels``: the
    diffuse term and its three bounds (range, first and second order; the term is
    their least; ``diffuse_second_F`` is the second order's Λ·F part), and, where the
    tiles have specular, the specular term (× S) and its range and smooth (first or
    second order) bounds. ``channel_scale``: each channel's bound is multiplied by it
    before the largest is taken (broadcast against (T, K, 3), or (P, 1, 3) with
    ``pairs``; +inf: no budget there), so that the bound is in units of each
    channel's own budget (the relative budget's per-channel floors); a channel whose
    bound is 0 stays 0. ``terms``: the per-channel bounds already formed, as
    :func:`cluster_terms` gives them (kernels/node_bound.cl's, read back), for
    ``tiles`` × ``nodes`` as given here. ``channels``: each channel's bound (…, 3), not
    the largest (NaN in any channel: +inf in all), as kernels/node_bound.cl's cut sums
    them."""
    if terms is None:
        terms = cluster_terms(tree, tiles, spec, origin, nodes, pairs=pairs, parts=parts)
    e = np.asarray(terms, np.float64)
    with np.errstate(invalid="ignore", over="ignore"):
        if channel_scale is not None:
            e = np.where(e == 0, 0.0, e * channel_scale)
        b = (e if channels else _max3(e)) * (1 + 1e-6)
    nan = np.isnan(b).any(axis=-1, keepdims=True) if channels else np.isnan(b)
    b = np.where(nan, np.inf, b)
    empty = (tiles.lo > tiles.hi).any(axis=1)
    b = np.where(empty[:, None, None] if channels else empty[:, None], 0.0, b)
    return b[:, 0] if pairs else b


def cluster_terms(tree: LightTree, tiles: TileBoxes, spec: SpecularModel,
                  origin, nodes: np.ndarray | None = None, *, pairs: bool = False,
                  parts: dict | None = None) -> np.ndarray:
    """(T, K, 3) (or (P, 1, 3) with ``pairs``) :func:`cluster_bounds`' bound of each
    channel, before its largest is taken: 0 in every channel where the box pair is
    surely dark, +inf where no bound holds (the boxes touch, d⁻ = 0), NaN where an
    input is not finite. kernels/node_bound.cl ``node_terms`` computes the same in
    double on the device."""
    k = np.arange(tree.n_nodes) if nodes is None else np.asarray(nodes)
    o = np.asarray(origin, np.float64)
    # a node's arrays face the tiles' (T, 1, …) as (1, K, …), or row by row as (P, 1, …)
    side = (lambda x: x[:, None]) if pairs else (lambda x: x[None])
    blo = side(tree.lo[k] - o)                       # (1, K, 3)
    bhi = side(tree.hi[k] - o)
    # the tile boxes widened by the float32 rounding of the positions they hold
    # (an empty tile's box is (+inf, −inf): NaN here, and its bound 0 below)
    pad = 4 * U * (np.abs(tiles.lo) + np.abs(tiles.hi)).max(axis=1, keepdims=True)
    with np.errstate(invalid="ignore"):
        tlo = (tiles.lo - pad)[:, None]              # (T, 1, 3)
        thi = (tiles.hi + pad)[:, None]
    gap = np.maximum(blo - thi, 0) + np.maximum(tlo - bhi, 0)
    d_lo = np.sqrt(_sum3(gap * gap))                 # (T, K)
    c0, c1, c2 = (side(tree.attenuation[k, i]) for i in range(3))
    # a spot's cone factor t² (1 for a point light): t ≤ t⁺ over the box pair
    if (tree.cone[k, 3] > 0).any():
        t_hi, smooth_t, slope = spot_factor_bounds(side(tree.cone[k]), tlo, thi, blo, bhi)
    else:                                           # point lights only: t ≡ 1 (no cost)
        t_hi, smooth_t, slope = np.ones(1), np.ones(1, bool), np.zeros(1)
    t2 = t_hi * t_hi
    D = tiles.D[:, None]                             # (T, 1, 3)
    S = tiles.S[:, None]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        A_lo = 1.0 / (c0 + d_lo * (c1 + d_lo * c2))  # A(d⁻) ≥ A(d) for d ≥ d⁻
        lip = A_lo / d_lo                            # A(d⁻)/d⁻
        # n·(p − x) over the boxes: its sign decides the gate. The kernel's n·l errs
        # by up to u(12 + 2(|P| + |L|)/d) (cull.cl's margin): the boxes are dark, or
        # surely lit, only beyond it; n·u = n·(p − x)/d with d⁻ ≤ d ≤ d⁺
        nl_lo, nl_hi = _interval_dot(tiles.nlo[:, None], tiles.nhi[:, None], blo - thi, bhi - tlo)
        span = np.maximum(bhi, thi) - np.minimum(blo, tlo)
        d_hi = np.sqrt(_sum3(span * span))
        reach = (_max3(np.maximum(np.abs(tlo), np.abs(thi)))
                 + _max3(np.maximum(np.abs(blo), np.abs(bhi))))
        margin = U * (12.0 + 2.0 * reach / d_lo)
        dark = nl_hi / d_hi + margin <= 0
        lit = nl_lo / d_hi - margin > 0              # the gate n·l > 0 surely on
        nu_hi = np.minimum(np.where(nl_hi > 0, nl_hi / d_lo, 0.0) + margin, 1.0)
        Rk = side(tree.radiance[k])
        # the record's float32 roundings: position (u·|p|, its length: each coordinate
        # rounds by ≤ u·|x_i|; the largest coordinate before 2026-12-08, √3 short on a
        # diagonal), added to the moments
        rp = U * side(np.sqrt(_sum3((tree.position[k] - o) ** 2)) + np.abs(o).max())[..., None]
        M = side(tree.moment[k]) + Rk * rp
        F = side(tree.first[k]) + Rk * rp
        Q = side(tree.quadratic[k]) + Rk * rp * (rp + 2 * side(tree.moment[k]) / np.maximum(Rk, 1e-300))
        # the falloff's slopes over d ≥ d⁻: |A′(d⁻)|, sup |A′|, sup |A″|
        a1_lo, a1, a2 = falloff_slopes(c0, c1, c2, d_lo, tuple(side(x[k]) for x in tree.peaks))
        # diffuse g = (n·u)·A: both sums lie in [0, R·A(d⁻)·(n·u)⁺]; |∇g| ≤ Λ_d, its
        # sup over n·u ∈ [c⁻, c⁺] with A/d ≤ A(d⁻)/d⁻ and |A′| ≤ sup|A′|; where surely lit,
        # Taylor to second order: ‖∇²g‖ ≤ H_d, the spectral norm's sup over the same range
        # with m = A/d² + |A′|/d ≤ its value at d⁻ (both decreasing in d) and |A″| ≤
        # sup|A″|, and the first-order term |∇g(p_k)·Σ R_i (p_i − p_k)| ≤ Λ_d·F
        # |∇t²| ≤ 2t⁺·s/d and ‖∇²t²‖ ≤ (2s² + 6t⁺·s)/d² (|∇cos θ| ≤ 1/d, ‖∇²cos θ‖ ≤
        # 3/d²); 0 where t ≡ 1 (slope 0: a point light, or inside the inner cone)
        spot = slope > 0
        spot_lip = np.where(spot, 2.0 * t_hi * slope / d_lo, 0.0)
        spot_hess = np.where(spot, (2.0 * slope * slope + 6.0 * t_hi * slope) / d_lo ** 2, 0.0)
        g_hi = A_lo * nu_hi                          # the diffuse weight's range
        e_rng = Rk * (g_hi * t2)[..., None]
        # the cosine's range over the pair: c ∈ [c⁻, c⁺] (c⁻ = 0 unless surely lit)
        c_lo = np.where(lit, np.clip(nl_lo / d_hi - margin, 0.0, 1.0), 0.0)
        c_hi = nu_hi
        grad_g = diffuse_gradient_sup(c_lo, c_hi, lip, a1)
        m = (lip + a1_lo) / d_lo
        hess_g = diffuse_hessian_sup(c_lo, c_hi, m, a2)
        grad = grad_g * t2 + np.where(spot, g_hi * spot_lip, 0.0)
        e_lip = grad[..., None] * M
        hess = hess_g * t2 + np.where(spot, 2.0 * spot_lip * grad_g + g_hi * spot_hess, 0.0)
        e_two = grad[..., None] * F + 0.5 * hess[..., None] * Q
        smooth = (lit & smooth_t)[..., None]         # the second order: no kink in the pair
        # Taylor's terms themselves, with the remainder (clphong/model/taylor.py), where
        # t is constant over the pair (a point light, or inside a spot's inner cone), about
        # the float64 centroid; the record's float32 position moves g by ≤ |∇g|·rp
        e_tay = np.where((lit & ~spot)[..., None], taylor_term(
            tree, k, side, tiles, tlo, thi, o, d_lo, A_lo, a1, a2, nu_hi, hess_g) * t2[..., None]
            + grad_g[..., None] * Rk * rp, np.inf)
        e = D * np.fmin(np.fmin(np.fmin(e_rng, e_lip), np.where(smooth, e_two, np.inf)), e_tay)
        if parts is not None:
            parts.update(diffuse=e, diffuse_range=D * e_rng, diffuse_first=D * e_lip,
                         diffuse_second=D * np.where(smooth, e_two, np.inf),
                         diffuse_second_F=D * grad[..., None] * F, diffuse_taylor=D * e_tay)
        if tiles.S.any():
            # ‖∇²A‖ = max(|A″|, |A′|/d) (radially and across)
            slopes = (a1, np.maximum(a2, a1_lo / d_lo))
            e = e + S * _specular_bound(tiles, blo, bhi, thi, tlo, d_lo, A_lo, lit, Rk, M, F, Q,
                                        spec, slopes, spot=(t2, spot_lip, spot_hess, smooth_t),
                                        parts=parts, S=S)
        e = e + U * Rk * A_lo[..., None] * (D + S)
    e = np.where((d_lo > 0)[..., None], e, np.inf)       # the boxes touch (or NaN): none
    return np.where(dark[..., None], 0.0, e)


def taylor_term(tree: LightTree, k, side, tiles: TileBoxes, tlo, thi, o, d_lo, A_lo, a1, a2,
                c_hi, hess):
    """:func:`~clphong.model.taylor.taylor_diffuse` for :func:`cluster_terms`' pairs (its
    shapes: the tiles' (T, 1, …) and the nodes' ``side`` (1, K, …), or (P, 1, …)): the
    tiles' widened boxes ``tlo, thi``, the pair's d⁻, A(d⁻), sup|A′|, sup|A″| over d ≥ d⁻,
    the cosine's c⁺ and ``hess`` ≥ sup‖∇²g‖; sup‖∇³g‖ from
    :func:`~clphong.model.falloff.falloff_third_sup`."""
    P0 = 0.5 * (tlo + thi)
    r = 0.5 * np.sqrt(_sum3((thi - tlo) ** 2))
    n0 = 0.5 * (tiles.nlo + tiles.nhi)[:, None]
    dn = 0.5 * np.sqrt(_sum3((tiles.nhi - tiles.nlo) ** 2))[:, None]
    att = side(tree.attenuation[k])
    a3 = falloff_third_sup(att, d_lo, side(tree.third_peaks[k]))
    sup3 = third_derivative_sup(c_hi, d_lo, *phi_sups(A_lo, a1, a2, a3, d_lo))
    x = side(tree.position[k] - o) - P0
    return taylor_diffuse(x, side(tree.first_vector[k]), side(tree.second_moment[k]),
                          side(tree.third_moment[k]), n0, dn, r, hess, sup3,
                          att[..., 0], att[..., 1], att[..., 2])


def diffuse_gradient_sup(c_lo, c_hi, L, A1):
    """sup |∇g| of the diffuse weight g = (n·u)·A over c = n·u ∈ [c_lo, c_hi] ⊂ [0, 1]:
    ∇g = A·s/d·w + c·A′·u has orthogonal parts, so |∇g|² ≤ (1 − c²)·L² + c²·A1² with L ≥
    A/d and A1 ≥ |A′|, linear in c²: its largest value is at c_lo where L ≥ A1, else at
    c_hi (max(L, A1) when the range is all of [0, 1])."""
    c = np.where(L >= A1, c_lo, c_hi)
    return np.sqrt((1.0 - c * c) * L * L + c * c * A1 * A1)


def diffuse_hessian_sup(c_lo, c_hi, M, A2):
    """sup ‖∇²g‖ (spectral norm) of the diffuse weight over c ∈ [c_lo, c_hi] ⊂ [0, 1],
    with 0 ≤ m ≤ M and |A″| ≤ A2 (module docstring). In the frame (u, w, u × w) the
    Hessian is [[c·A″, −s·m, 0], [−s·m, −c·m, 0], [0, 0, −c·m]], s = √(1 − c²): for a
    fixed c it is affine in (A″, m), so its norm, convex, is largest at a vertex of the
    box: m = 0 gives c·|A″|; m = M gives, for the 2×2 block, f(c) = ½(c·|α − M| + √(c²(α
    + M)² + 4(1 − c²)M²)) with α = ±A2, which is ≥ c·|α| and ≥ c·M (the third
    eigenvalue). f(c) = ½(cP + √(4M² + Qc²)), Q = (α + M)² − 4M²: increasing where Q ≥
    0, else concave with its top at c* = 2PM/√(Q(Q − P²)). So the sup is f at c_hi, or at
    c* clipped to [c_lo, c_hi]. Without falloff curvature (A2 = 0) it is 2M/√3 at c =
    1/√3, and M at c = 1 (straight under a light); the Frobenius bound √(m² + max(m,
    A2)²) used before 2026-12-07 was √2·M."""
    best = np.zeros(np.broadcast(c_lo, c_hi, M, A2).shape)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for alpha in (A2, -A2):
            P = np.abs(alpha - M)
            Q = (alpha + M) ** 2 - 4.0 * M * M
            top = 2.0 * P * M / np.sqrt(Q * (Q - P * P))
            c = np.where(Q >= 0, c_hi, np.clip(np.nan_to_num(top, nan=0.0), c_lo, c_hi))
            f = 0.5 * (c * P + np.sqrt(c * c * (alpha + M) ** 2 + 4.0 * (1.0 - c * c) * M * M))
            best = np.fmax(best, f)
    finite = np.isfinite(M) & np.isfinite(A2) & np.isfinite(c_lo) & np.isfinite(c_hi)
    # not finite (boxes that touch, NaN inputs): the Frobenius form, inf or NaN as before
    with np.errstate(invalid="ignore", over="ignore"):
        return np.where(finite, best, np.sqrt(M * M + np.maximum(M, A2) ** 2) + 0.0 * (c_lo + c_hi))


def spot_factor_bounds(cone, tlo, thi, blo, bhi):
    """Bounds of a spot's cone factor t = clamp(cos θ·s + o, 0, 1), cos θ = a·w/|w| with
    w = x − p from the light to the pixel, over the tile boxes ``tlo, thi`` (T, 1, 3) ×
    the node boxes ``blo, bhi`` (1, K, 3) with the nodes' ``cone`` (K, 5) (axis a, s ≥
    0, o). θ lies within the cone of the directions from the node's ball to the tile's
    ball, and cos θ within the interval of a·w over the boxes divided by |w| ∈ [d⁻, d⁺];
    the tighter of the two is taken. Returns (T, K) each:

    * t⁺, the largest t;
    * smooth: t has no kink in the pair (inside the inner cone, t ≡ 1; or on the ramp,
      0 < t = cos θ·s + o ≤ 1, unclamped);
    * the slope: s, or 0 where t ≡ 1.

    A point light's (s, o) = (0, 1) gives t⁺ = 1, smooth, slope 0."""
    cone = cone[None] if cone.ndim == 2 else cone    # (K, 5), or already (…, 5) beside the boxes
    a = cone[..., :3]
    s, o = cone[..., 3], cone[..., 4]
    ct, rt = 0.5 * (tlo + thi), 0.5 * _unit(thi - tlo)[1]
    cb, rb = 0.5 * (blo + bhi), 0.5 * _unit(bhi - blo)[1]
    w0, dist = _unit(ct - cb)                          # (T, K, 3), (T, K)
    half = _cone(None, rt + rb, dist)
    with np.errstate(invalid="ignore"):
        theta = np.nan_to_num(_angle(np.broadcast_to(a, w0.shape), w0), nan=0.0)
    # a point light's axis is 0: s = 0 there, so its θ does not matter
    spot = s > 0
    # and by intervals: a·w over the box of w = x − p, over |w| ∈ [d⁻, d⁺] (better for
    # large tiles far off the axis)
    aw_lo, aw_hi = _interval_dot(tlo - bhi, thi - blo, a, a)
    gap = np.maximum(blo - thi, 0) + np.maximum(tlo - bhi, 0)
    span = np.maximum(bhi, thi) - np.minimum(blo, tlo)
    d_lo, d_hi = _unit(gap)[1], _unit(span)[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        i_hi = np.where(aw_hi > 0, aw_hi / d_lo, aw_hi / d_hi)
        i_lo = np.where(aw_lo < 0, aw_lo / d_lo, aw_lo / d_hi)
    i_hi = np.where(np.isfinite(i_hi), np.minimum(i_hi, 1.0), 1.0)
    i_lo = np.where(np.isfinite(i_lo), np.maximum(i_lo, -1.0), -1.0)
    # 1e-9: the float64 reference's own roundings of cos θ
    cos_hi = np.minimum(np.where(half >= np.pi, 1.0, np.cos(np.clip(theta - half, 0.0, np.pi))),
                        i_hi) + 1e-9
    cos_lo = np.maximum(np.where(half >= np.pi, -1.0, np.cos(np.clip(theta + half, 0.0, np.pi))),
                        i_lo) - 1e-9
    t_hi = np.where(spot, np.clip(cos_hi * s + o, 0.0, 1.0), np.clip(o, 0.0, 1.0))
    inner = np.where(spot, cos_lo * s + o >= 1.0, o >= 1.0)
    ramp = spot & (cos_lo * s + o > 0.0) & (cos_hi * s + o <= 1.0)
    slope = np.where(inner, 0.0, np.broadcast_to(s, t_hi.shape))
    return t_hi, inner | ramp, slope


def _specular_bound(tiles, blo, bhi, thi, tlo, d_lo, A_lo, lit, Rk, M, F, Q, spec, slopes, *,
                    spot=(1.0, 0.0, 0.0, True), parts=None, S=1.0):
    """(T, K, 3) bound of the specular error per unit S (see the module docstring):
    the range R·A(d⁻)·c^K everywhere; where surely lit, also the Lipschitz bound and
    the second-order Taylor bound, with the cosine x = cos θ ≤ c (:func:`specular_cosine`)
    and |∇θ| ≤ g (Phong: g = 1/d, r being an orthogonal map of u; Blinn-Phong: g =
    1/(d·|u + v|⁻)). For P = x^K, with h1 and f1
    the power's slopes at their maxima over [0, c] (:func:`_peak`), ∇P ⊥ ∇A and
    ∇²P's semi-definite parts apart (the module docstring):
    |∇(P·A)| ≤ hypot(A·K·h1·g (+ 5g·c^K·A for Blinn-Phong's Schlick weight), c^K·A₁) and
    ‖∇²(P·A)‖ ≤ A·(max(K(K−1)·f1, K·c^K)·g² + K·h1·b) + K·h1·g·A₁ + c^K·A₂, b (``bend``)
    bounding ∇²x's part across h (r) over sin θ
    (K ≥ 2, and not with Blinn-Phong's Schlick weight), ``slopes`` = (A₁, A₂) the sups
    of |∇A| = |A′| and ‖∇²A‖ = max(|A″|, |A′|/d) over d ≥ d⁻
    (:func:`~clphong.model.falloff.falloff_slopes`; at most 2A/d and 8A/d²). A spot's
    factor: ``spot`` = (t⁺², bounds of |∇t²| and ‖∇²t²‖, smooth): the product rule on
    t²·P·A, the second order only where t is smooth (:func:`spot_factor_bounds`).
    ``parts``: see :func:`cluster_bounds` (its entries × ``S``)."""
    t2, spot_lip, spot_hess, smooth_t = spot
    K = spec.exponent
    if K is None or K < 1:                           # a shininess map, or x^K not Lipschitz
        out = Rk * (A_lo * t2)[..., None]
        if parts is not None:
            parts.update(specular=S * out, specular_range=S * out, specular_smooth=S * np.inf)
        return out
    c, half = specular_cosine(tiles, blo, bhi, spec)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        cK = c ** K
        rng = Rk * (A_lo * cK * t2)[..., None]
        if spec.blinn:
            uv = _view_dot_lower(tiles, blo, bhi, thi, tlo, d_lo, spec)
            huv = np.sqrt(np.maximum(2.0 + 2.0 * uv, 0.0))
            g = 1.0 / (d_lo * huv)                   # |∇h| ≤ |∇u|/|u + v|
            # ∇²h's part across h: 2·∇h·(h·∇u)/|u + v| (h·∇u ≤ sin(γ/2)/d) and the
            # part of ∇²u across h over |u + v| (|∇²u(a, a)| ≤ (2/√3)/d²)
            bend = 2.0 * half * g * g + (2.0 / np.sqrt(3.0)) * g / d_lo
        else:
            g = 1.0 / d_lo                           # r = (2nnᵀ − I)u: |∇r| = |∇u| ≤ 1/d
            bend = g * g                             # ∇²u(a, a) across u: 2(u·a)|a_⊥|/d² ≤ 1/d²
        fres = spec.blinn and spec.fresnel
        # x = cos θ with |∇θ| ≤ g, so |∇x| ≤ sin θ·g: the power's slopes peak away
        # from the highlight's centre: K·x^(K−1)·|∇x| ≤ K·h1·g, K(K−1)x^(K−2)|∇x|² ≤
        # K(K−1)·f1·g², h1 and f1 the maxima over x ∈ [0, c] of x^(K−1)·√(1 − x²)
        # and x^(K−2)·(1 − x²); ∇²x = −x·JᵀJ (⪯ 0, ≤ cos θ·g²) + a part ≤ sin θ·bend.
        # ∇P ⊥ u ∥ ∇A: the gradient's parts add in quadrature, the cross term counts once;
        # K(K−1)x^(K−2)·∇x∇xᵀ ⪰ 0 ⪰ −K·x^K·JᵀJ: the larger of the two norms, not their sum
        h1 = _peak(c, K - 1.0, 0.5)
        A1, A2 = slopes
        grad = np.hypot(A_lo * (K * h1 * g + (5.0 * g * cK if fres else 0.0)), cK * A1)
        g_hi = A_lo * cK                             # the term's range
        grad_t = grad * t2 + np.where(spot_lip > 0, g_hi * spot_lip, 0.0)
        e_lip = grad_t[..., None] * M
        if K >= 2 and not fres:
            f1 = _peak(c, K - 2.0, 1.0)
            hess = (A_lo * (np.maximum(K * (K - 1) * f1, K * cK) * g * g + K * h1 * bend)
                    + K * h1 * g * A1 + cK * A2)
            hess_t = hess * t2 + np.where(spot_hess > 0, 2.0 * spot_lip * grad + g_hi * spot_hess,
                                          0.0)
            e_two = grad_t[..., None] * F + 0.5 * hess_t[..., None] * Q
            e_lip = np.fmin(e_lip, np.where(np.broadcast_to(smooth_t, A_lo.shape)[..., None],
                                            e_two, np.inf))
        out = np.where(lit[..., None], np.fmin(e_lip, rng), rng)
        if parts is not None:
            parts.update(specular=S * out, specular_range=S * rng,
                         specular_smooth=S * np.where(lit[..., None], e_lip, np.inf))
        return out


def _peak(c, a, b):
    """max over x ∈ [0, c] of x^a·(1 − x²)^b (a ≥ 0, b > 0): at x*² = a/(a + 2b), or c."""
    xs = np.sqrt(a / (a + 2.0 * b))
    x = np.minimum(c, xs)
    y = 1.0 - x * x
    # b is 1/2 or 1 here: sqrt and y itself (kernels/node_bound.cl takes them for pow's cost)
    return x ** a * (np.sqrt(y) if b == 0.5 else (y if b == 1.0 else y ** b))


def _view_dot_lower(tiles, blo, bhi, thi, tlo, d_lo, spec):
    """A lower bound of u·v over the boxes (u the light direction, v the view), ≥ −1."""
    if spec.perspective:
        e = np.asarray(spec.eye, np.float64)
        vlo, vhi = e - thi, e - tlo                  # e − x
        num_lo, _ = _interval_dot(blo - thi, bhi - tlo, vlo, vhi)
        far = (np.maximum(vlo, 0) + np.maximum(-vhi, 0))   # distance from the eye to the box
        de_lo = np.sqrt(_sum3(far * far))
        den = d_lo * de_lo
    else:
        v = np.asarray(spec.eye, np.float64)
        num_lo, _ = _interval_dot(blo - thi, bhi - tlo, v, v)
        den = d_lo
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.where(num_lo >= 0, 0.0, num_lo / den)
    return np.clip(np.nan_to_num(uv, nan=-1.0, neginf=-1.0), -1.0, 0.0)


def choose_cut(tree: LightTree, bounds: np.ndarray, budget: float, *, steps: int = 96,
               leaves: bool = True):
    """Per tile, the internal nodes of a cut whose bounds sum to ≤ ``budget`` in each
    channel.

    ``bounds``: (T, K), or each channel's (T, K, 3) (:func:`cluster_bounds` with
    ``channels``); a node's order is its largest channel's bound b_k. A cut for a
    threshold τ takes every topmost node with b_k ≤ τ (leaves have error 0 and end
    every path). Node k is in it for τ ∈ [b_k, a_k), ``a_k`` the smallest order of its
    ancestors. For thresholds τ_m = budget·2^(−m/4) each channel's sums are formed for
    all m at once; the largest τ whose sums all fit is taken.

    Returns (used (T, K) bool: internal nodes used as clusters; covered (T, n_leaves)
    bool: leaves under a used node, or None without ``leaves``: see :func:`leaf_ranges`).
    """
    per = np.asarray(bounds, np.float64)
    per = per if per.ndim == 3 else per[..., None]
    bounds = per.max(axis=-1)
    T, K = bounds.shape
    a = np.full((T, K), np.inf)
    for lv in tree.levels:                           # top-down: a_child = min(a, b) of the parent
        ch = tree.children[lv]
        m = np.minimum(a[:, lv], bounds[:, lv])
        for side in (0, 1):
            c = ch[:, side] - tree.n_leaves
            inner = c >= 0
            a[:, c[inner]] = m[:, inner]
    grid = budget * 2.0 ** (-np.arange(steps)[::-1] / 4.0)     # ascending
    i_lo = np.searchsorted(grid, bounds, side="left")
    i_hi = np.searchsorted(grid, a, side="left")
    contributes = i_lo < i_hi
    sums = np.zeros((T, steps + 1, per.shape[-1]))
    rows = np.broadcast_to(np.arange(T)[:, None], (T, K))
    b_ = per[contributes]
    np.add.at(sums, (rows[contributes], i_lo[contributes]), b_)
    np.add.at(sums, (rows[contributes], i_hi[contributes]), -b_)
    S = np.cumsum(sums, axis=1)[:, :steps]
    fits = (S <= budget * (1 - 1e-9)).all(axis=-1)
    # the largest fitting threshold per tile (−1: none fits; then no cluster at all)
    best = np.where(fits.any(axis=1), steps - 1 - np.argmax(fits[:, ::-1], axis=1), -1)
    tau = np.where(best >= 0, grid[np.maximum(best, 0)], -np.inf)[:, None]
    used = (bounds <= tau) & (tau < a)
    return used, covered_leaves(tree, used) if leaves else None


def covered_leaves(tree: LightTree, used: np.ndarray) -> np.ndarray:
    """(T, n_leaves) bool: the leaves under a used node (``used`` (T, K))."""
    covered = np.zeros((len(used), tree.n_leaves), bool)
    # leaves under a used node: push "covered" down the levels
    cov_inner = used.copy()
    for lv in tree.levels:
        ch = tree.children[lv]
        for side in (0, 1):
            c = ch[:, side]
            inner = c >= tree.n_leaves
            cov_inner[:, c[inner] - tree.n_leaves] |= cov_inner[:, lv[inner]]
            covered[:, c[~inner]] |= cov_inner[:, lv[~inner]]
    return covered


_LEAF_RANGES: dict = {}


def leaf_ranges(tree: LightTree) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An order of the leaves under the tree's nodes in which every internal node's
    leaves are one run: (start (K,), end (K,), each leaf's place (n_leaves,), −1 for
    a light under no node). Formed once per tree (by identity). A cut's uncovered
    leaves are then the gaps between its nodes' runs, found in the time of their
    number (clphong/device/culling.py), not of every leaf's (:func:`covered_leaves`)."""
    hit = _LEAF_RANGES.get(id(tree))
    if hit is not None and hit[0] is tree:
        return hit[1]
    nl, K = tree.n_leaves, tree.n_nodes
    size = np.zeros(K, np.int64)

    def sizes(c):                                    # leaves under a child: 1 for a leaf
        inner = c >= nl
        return np.where(inner, size[np.where(inner, c - nl, 0)], 1)

    for lv in reversed(tree.levels):                 # deepest first
        size[lv] = sizes(tree.children[lv, 0]) + sizes(tree.children[lv, 1])
    start = np.zeros(K, np.int64)
    roots = np.asarray(tree.levels[0]) if tree.levels else np.zeros(0, np.int64)
    if len(roots):
        start[roots] = np.r_[0, np.cumsum(size[roots])[:-1]]
    place = np.full(nl, -1, np.int64)
    for lv in tree.levels:                           # roots first
        ch = tree.children[lv]
        for c, at in ((ch[:, 0], start[lv]), (ch[:, 1], start[lv] + sizes(ch[:, 0]))):
            inner = c >= nl
            start[c[inner] - nl] = at[inner]
            place[c[~inner]] = at[~inner]
    out = (start, start + size, place)
    if len(_LEAF_RANGES) > 8:
        _LEAF_RANGES.clear()
    _LEAF_RANGES[id(tree)] = (tree, out)
    return out


#: Most tile-node pairs bounded at once by :func:`threshold_cut`: its float64
#: temporaries (3 numbers a pair) stay in cache; 2¹⁴ pairs at a time took 0.79 s where
#: (40, 16 383) pairs at once took 1.45 s (Ice Lake, 2 cores), the same bits.
PAIR_CHUNK = 1 << 14


def threshold_cut(tree: LightTree, bound, n_tiles: int, budget: float, *, steps: int = 96,
                  stride: int = 8, leaves: bool = True):
    """:func:`choose_cut`'s cut, found from the top down: only the nodes whose ancestors'
    bounds all exceed the threshold are bounded.

    ``bound(t, k)`` gives the (P,) bounds of tile rows ``t`` with internal nodes ``k``
    (0-based), or each channel's (P, 3), as :func:`cluster_bounds` with ``pairs=True``
    (and ``channels``) does. The thresholds are
    choose_cut's, τ_m = ``budget``·2^(−m/4). A threshold's cut is every topmost node
    with bound ≤ τ, so lowering τ only splits nodes, and every node of the cut of any
    τ ≥ τ_m has been bounded once the cut of τ_m has. So the search lowers τ by
    ``stride`` thresholds at a time (or more: to the next one that splits a node) until
    a cut's bounds sum to ≤ ``budget`` in each channel; then the sums of every threshold above it come
    from the nodes already bounded, as choose_cut forms them, and the largest that
    fits is taken: choose_cut's own choice on the whole (T, K) table. (Its sums run over
    the deeper nodes too, in another order: where a cut's sum lies within a few
    roundings of the budget the two may choose neighbouring thresholds, each within the
    budget. A NaN bound counts as +inf, no bound, where choose_cut drops its subtree.)

    Returns (used (T, K) bool, covered (T, n_leaves) bool), as choose_cut.
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, not {stride}")
    grid = budget * 2.0 ** (-np.arange(steps)[::-1] / 4.0)     # ascending
    limit = budget * (1 - 1e-9)
    nl = tree.n_leaves

    def bounded(t, k):
        """(P, C): each channel's bound (C = 1: one for all), NaN in any: +inf in all"""
        if len(t) <= PAIR_CHUNK:
            b = np.asarray(bound(t, k), np.float64)
        else:
            b = np.concatenate([np.asarray(bound(t[i:i + PAIR_CHUNK], k[i:i + PAIR_CHUNK]),
                                           np.float64) for i in range(0, len(t), PAIR_CHUNK)])
        b = b[:, None] if b.ndim == 1 else b
        return np.where(np.isnan(b).any(axis=1, keepdims=True), np.inf, b)

    # the nodes bounded and not split: tile, node, bound, the least bound of its ancestors;
    # the split ones wait in ``done`` for the sums at the end
    roots = np.asarray(tree.levels[0])
    ct = np.repeat(np.arange(n_tiles), roots.size)
    ck = np.tile(roots, n_tiles)
    cv = bounded(ct, ck)                                   # each channel's
    cb = cv.max(axis=1)                                    # the order
    ca = np.full(cb.shape, np.inf)
    done = []
    m = np.full(n_tiles, steps - 1)
    searching = np.ones(n_tiles, bool)
    fitted = np.zeros(n_tiles, bool)
    while searching.any():
        tau = grid[np.maximum(m, 0)]
        grow = searching[ct] & (cb > tau[ct])             # +inf (no bound) always splits
        if grow.any():
            gt, gk, gb, ga = ct[grow], ck[grow], cb[grow], ca[grow]
            done.append((gt, gk, gb, ga, cv[grow]))
            kids = tree.children[gk] - nl                  # (S, 2): < 0 for leaves (exact)
            kt = np.repeat(gt, 2)
            ka = np.repeat(np.minimum(ga, gb), 2)
            kk = kids.ravel()
            inner = kk >= 0
            kt, kk, ka = kt[inner], kk[inner], ka[inner]
            keep = ~grow
            ct = np.concatenate([ct[keep], kt])
            ck = np.concatenate([ck[keep], kk])
            ca = np.concatenate([ca[keep], ka])
            cv = np.concatenate([cv[keep], bounded(kt, kk)])
            cb = cv.max(axis=1)
            continue
        total = np.stack([np.bincount(ct, weights=cv[:, c], minlength=n_tiles)
                          for c in range(cv.shape[1])], axis=1)
        fits = searching & (total <= limit).all(axis=1)
        fitted |= fits
        searching &= ~fits
        # the next thresholds: ``stride`` down, or further, to the next that splits a node
        top = np.full(n_tiles, -np.inf)
        np.maximum.at(top, ct, cb)
        nxt = np.searchsorted(grid, top, side="left") - 1
        # (never past the lowest threshold: a cut that still changes is tried there)
        m = np.where(searching, np.minimum(np.maximum(m - stride, 0), nxt), m)
        searching &= m >= 0                               # none fits: no cluster at all
    et, ek, eb, ea, ev = (np.concatenate([d[i] for d in done] + [c])
                          for i, c in enumerate((ct, ck, cb, ca, cv)))
    # choose_cut's sums over the thresholds from each fitting tile's m up: node e is in the
    # cut of τ for b_e ≤ τ < a_e
    i_lo = np.searchsorted(grid, eb, side="left")
    i_hi = np.searchsorted(grid, ea, side="left")
    on = fitted[et] & (i_lo < i_hi)
    sums = np.zeros((n_tiles, steps + 1, ev.shape[1]))
    np.add.at(sums, (et[on], i_lo[on]), ev[on])
    np.add.at(sums, (et[on], i_hi[on]), -ev[on])
    S = np.cumsum(sums, axis=1)[:, :steps]
    ok = (S <= limit).all(axis=-1) & (np.arange(steps)[None, :] >= m[:, None])
    ok[np.flatnonzero(fitted), m[fitted]] = True         # fitted there (a direct sum)
    best = steps - 1 - np.argmax(ok[:, ::-1], axis=1)
    tau = np.where(fitted, grid[best], -np.inf)
    pick = fitted[et] & (eb <= tau[et]) & (tau[et] < ea)
    used = np.zeros((n_tiles, tree.n_nodes), bool)
    used[et[pick], ek[pick]] = True
    return used, covered_leaves(tree, used) if leaves else None


def greedy_cut(tree: LightTree, bound, limit: float) -> tuple[np.ndarray, np.ndarray, float]:
    """One tile's cut as kernels/node_bound.cl ``tile_cut`` finds it (Lightcuts'
    order): from the roots, the node with the largest bound (its largest channel's) is
    split until each channel's bounds sum to ≤ ``limit`` or no node is left.
    ``bound(k)``: the bound of internal node k (0-based), each channel's (3,) in units
    of that channel's budget, or one number for all three; NaN in any channel counts as
    +inf in all. Returns (the cut's internal nodes, the leaves reached, the cut's
    largest channel's sum of bounds)."""
    import heapq

    def b_of(k):
        b = np.broadcast_to(np.asarray(bound(k), np.float64), (3,))
        return np.full(3, np.inf) if np.isnan(b).any() else b.copy()

    def entry(k):
        b = b_of(k)
        return (-float(b.max()), int(k), b)

    def sums(heap):
        return np.sum([b for _, _, b in heap], axis=0) if heap else np.zeros(3)

    heap = [entry(k) for k in (tree.levels[0] if tree.levels else [])]
    heapq.heapify(heap)
    leaves = []
    while heap and not (sums(heap) <= limit).all():
        _, k, _ = heapq.heappop(heap)
        for c in tree.children[k]:
            if c < tree.n_leaves:
                leaves.append(int(c))
            else:
                heapq.heappush(heap, entry(c - tree.n_leaves))
    nodes = np.array(sorted(k for _, k, _ in heap), np.int64)
    return nodes, np.array(sorted(leaves), np.int64), float(sums(heap).max())

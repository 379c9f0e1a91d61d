"""The light-tree floor tool (clphong.tools.cut_floor): the oracle cut refines to single
lights at ε = 0, collapses to the root at a budget above the whole image, and grows as ε
falls."""

from __future__ import annotations

import numpy as np

from clphong.tools.bench import bench_gbuffer, bench_scene
from clphong.tools.cut_floor import TERMS, cut_sizes, level_slack


def test_oracle_cut_limits_and_monotone():
    n = 128
    scene = bench_scene("wide", n)
    gb = bench_gbuffer(96, 54)
    sizes = cut_sizes(scene, gb, [0.0, 1e-3, 1e-1, 1e3], n_pixels=3)
    for k in range(3):
        s0, s3, s1, big = (sizes[e][k] for e in (0.0, 1e-3, 1e-1, 1e3))
        assert big == 1                        # the root alone errs by less than 1e3
        assert s0 >= s3 >= s1 >= big
        assert s0 >= 0.9 * n                   # exact: (nearly) every light its own node
    assert np.median(sizes[1e-3]) > np.median(sizes[1e-1])


def test_level_slack_holds_the_bound_and_names_its_terms():
    """Per depth, the bound is never below the true error (bound / error ≥ 1 at the 10th
    percentile and so everywhere it is counted), the term shares cover the pairs, and the
    diffuse term's parts are the bound's: a bound that dropped its curvature part would
    fall below the true error at the deep levels."""
    scene = bench_scene("wide", 256)
    rows = level_slack(scene, bench_gbuffer(96, 54), n_pixels=3)
    assert [r["depth"] for r in rows] == list(range(len(rows))) and len(rows) >= 6
    for r in rows:
        assert r["slack_p10"] >= 1.0 and r["slack"] >= r["slack_p10"]
        shares = sum(r[t] for t in TERMS)
        assert 0.99 <= shares <= 1.0 + 1e-9, shares       # ties go to one term
        assert r["bound"] >= r["error"]


def _pixel(scene, gb, seed=0):
    """One shaded pixel of ``gb``: the reference's Pixels of it, its D and S."""
    from clphong.reference import shading as reference
    from clphong.tools.cut_floor import _pixels_of
    fg = np.flatnonzero(~gb.background_mask().reshape(-1))
    j = np.random.default_rng(seed).choice(fg, size=1)
    px, D, S = _pixels_of(scene, gb, j)
    one = reference.Pixels(p=px.p, n=px.n, v=px.v, k=px.k, blinn=px.blinn, specular=px.specular)
    return one, px, D, S


def test_node_moments_agree_with_the_trees_own():
    """The tensors' trace and the first moment's length are the tree's ``quadratic`` and
    ``first``, and the tensors the tree's ``first_vector`` and ``second_moment`` (formed
    top-down from the lights, a different order of sums)."""
    from clphong.model.light_tree import build_light_tree
    from clphong.tools.cut_floor import node_moments
    scene = bench_scene("wide", 512)
    tree = build_light_tree(scene.light_arrays)
    F, M = node_moments(tree, scene.light_arrays)
    # both sum R_ic·(p_i − p_k) in different orders: they differ by rounding, ~N·2⁻⁵³ of
    # Σ R_ic·|p_i − p_k| (the tree's ``moment``) with N ≤ 512 lights
    assert (np.abs(np.linalg.norm(F, axis=-1) - tree.first) <= 1e-12 * tree.moment).all()
    np.testing.assert_allclose(np.trace(M, axis1=-2, axis2=-1), tree.quadratic, rtol=1e-9)
    # the tree's own vector and six-entry tensor (formed top-down, about each node's centroid)
    assert (np.abs(F - tree.first_vector) <= 1e-12 * tree.moment[..., None]).all()
    from clphong.model.taylor import PAIRS
    six = np.stack([M[..., a, b] for a, b in PAIRS], axis=-1)
    np.testing.assert_allclose(tree.second_moment, six, rtol=1e-9, atol=1e-12 * np.abs(M).max())
    sym = np.abs(M - np.swapaxes(M, -1, -2)).max()
    assert sym <= 1e-12 * np.abs(M).max()
    assert (np.linalg.eigvalsh(M) >= -1e-9 * np.abs(M).max()).all()     # Σ R·ΔΔᵀ is PSD


def _recoloured_clusters(n):
    """``clusters`` with a random colour per light: nodes inside one cluster are small
    against their distance, and their first moment is not 0."""
    import dataclasses
    scene = bench_scene("clusters", n)
    rng = np.random.default_rng(7)
    lights = tuple(dataclasses.replace(l, color=tuple(rng.uniform(0.3, 1.0, 3)))
                   if l.type == "point" else l for l in scene.lights)
    return dataclasses.replace(scene, lights=lights)


def test_taylor_terms_are_the_true_error_of_small_clusters():
    """For a node small against its distance the error is its second-order Taylor
    terms: within 10 % of the float64 true error for nodes under 5 % of their distance,
    whether the first moment is 0 (one colour a cluster: the curvature term alone) or
    not (a colour a light). Half the curvature term, or the gradient taken on the wrong
    side, is off by far more."""
    from clphong.model.light_tree import build_light_tree
    from clphong.tools.cut_floor import node_errors, node_moments, taylor_terms
    gb = bench_gbuffer(96, 54)
    for scene in (bench_scene("clusters", 512), _recoloured_clusters(512)):
        tree = build_light_tree(scene.light_arrays)
        F, M = node_moments(tree, scene.light_arrays)
        for seed in range(3):
            one, px, D, S = _pixel(scene, gb, seed)
            exact = node_errors(tree, scene.light_arrays, px, D, S, 0)
            tay = taylor_terms(tree, F, M, one, D[0], S[0])
            size = np.linalg.norm(tree.hi - tree.lo, axis=1)
            dist = np.linalg.norm(tree.position - one.p[0], axis=1)
            small = (size < 0.05 * dist) & (exact.max(axis=1) > 0)
            assert small.sum() >= 100
            c = exact[small].argmax(axis=1)
            r = exact[small, c] / tay[small][np.arange(small.sum()), c]
            assert 0.9 <= np.median(r) <= 1.1, np.median(r)
            assert np.percentile(r, 10) >= 0.8 and np.percentile(r, 90) <= 1.1


def test_taylor_cut_lies_between_the_true_errors_and_the_bound():
    """At one pixel the cut with the Taylor terms keeps at most the proven bound's entries
    (its terms never exceed the bound's) and not far fewer than the true errors' (it
    omits only the remainder), in absolute and relative budgets; the CLI prints the
    columns."""
    import contextlib
    import io
    from clphong.tools.cut_floor import main, taylor_cut_sizes
    scene = bench_scene("wide", 1024)
    gb = bench_gbuffer(96, 54)
    for relative in (False, True):
        got = taylor_cut_sizes(scene, gb, [1e-2, 1e-1], n_pixels=2, relative=relative)
        for e in (1e-2, 1e-1):
            for k in range(2):
                assert got[("exact", e)][k] <= got[("bound", e)][k]
                assert 0.5 * got[("exact", e)][k] <= got[("taylor", e)][k] <= got[("bound", e)][k]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["--taylor", "--relative", "--lights", "512", "--pixels", "1", "--eps", "1e-1"]) == 0
    assert "Taylor terms at the pixel" in buf.getvalue() and "0.1 relative" in buf.getvalue()


def test_third_moments_sum_over_each_nodes_lights():
    """Σ R·|p − p_k|³ per node, against the node's lights found by walking its children,
    and the tree's ``third_moment`` (formed level by level while it is built)."""
    from clphong.model.light_tree import build_light_tree
    from clphong.tools.cut_floor import third_moments
    scene = bench_scene("wide", 300)
    a = scene.light_arrays
    tree = build_light_tree(a)
    T3 = third_moments(tree, a)
    nl = tree.n_leaves
    for k in range(0, tree.n_nodes, 7):
        stack, lights = [k], []
        while stack:
            for c in tree.children[stack.pop()]:
                (stack if c >= nl else lights).append(c - nl if c >= nl else c)
        d = np.linalg.norm(a["point_position"][lights] - tree.position[k], axis=1)
        np.testing.assert_allclose(T3[k], (a["point_radiance"][lights] * d[:, None] ** 3).sum(0),
                                   rtol=1e-12)
    np.testing.assert_allclose(tree.third_moment, T3, rtol=1e-12)      # the tree's own


def test_the_sampled_remainder_covers_the_true_error():
    """The Taylor terms alone fall below the true error for many nodes (they omit the
    remainder); with the sampled third-order remainder they cover it at nearly every
    node and channel (a sampled sup, so not every one is promised)."""
    from clphong.model.light_tree import build_light_tree
    from clphong.tools.cut_floor import (node_errors, node_moments, remainder_estimate,
                                         taylor_terms, third_moments)
    gb = bench_gbuffer(96, 54)
    for scene in (bench_scene("wide", 512), _recoloured_clusters(512)):
        tree = build_light_tree(scene.light_arrays)
        F, M = node_moments(tree, scene.light_arrays)
        T3 = third_moments(tree, scene.light_arrays)
        one, px, D, S = _pixel(scene, gb, 1)
        exact = node_errors(tree, scene.light_arrays, px, D, S, 0)
        tay = taylor_terms(tree, F, M, one, D[0], S[0])
        rem = remainder_estimate(tree, T3, one, D[0], S[0])
        ok = exact > 0
        assert np.mean(exact[ok] <= tay[ok]) < 0.9
        assert np.mean(exact[ok] <= (tay + rem)[ok] * (1 + 1e-9)) >= 0.995
        # a sampled sup is at most the proven sup of the same derivative over the same box
        # (the diffuse term alone; central differences err by ~1e-4 relative)
        sampled = remainder_estimate(tree, T3, one, D[0], np.zeros(3))
        proven = proven_remainder(tree, one, D[0])
        fin = np.isfinite(proven) & (proven > 0)
        assert fin.mean() > 0.5
        assert (sampled[fin] <= proven[fin] * (1 + 1e-3)).all()


def proven_remainder(tree, one, D):
    """(K, 3): the Taylor term's proven remainder ⅙·sup‖∇³g‖·Σ R|Δ|³ (× D) at one pixel:
    light_tree.cluster_terms' ``diffuse_taylor`` less the same with the third moments 0."""
    import dataclasses
    from clphong.model.light_tree import SpecularModel, TileBoxes, cluster_terms
    tile = TileBoxes(lo=one.p[:1], hi=one.p[:1], nlo=one.n[:1], nhi=one.n[:1], D=D[None],
                     S=np.zeros((1, 3)))
    spec = SpecularModel(blinn=False, exponent=None, fresnel=False, eye=np.zeros(3),
                         perspective=True)

    def term(t):
        parts = {}
        cluster_terms(t, tile, spec, np.zeros(3), parts=parts)
        return np.broadcast_to(parts["diffuse_taylor"], (1, t.n_nodes, 3))[0]

    bare = dataclasses.replace(tree, third_moment=np.zeros_like(tree.third_moment))
    with np.errstate(invalid="ignore"):
        return term(tree) - term(bare)

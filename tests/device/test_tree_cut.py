"""The light tree's clusters in the culled kernel (clphong/device/culling.py _tree_cut).

The claim: with clusters in the lists, every pixel's result is still within ε of
the brute-force sum. Checked two ways, as culling alone is (tests/device/test_culling.py):

* exactly, in float64: per pixel and channel, |Σ over the tile's list (lights and
  representatives, the reference's own contributions) − Σ over all lights| ≤ ε;
* end to end: |kernel − float64 reference| ≤ ε + the brute-force error bound.

Both on scenes where clusters are taken (asserted, so the checks are not vacuous),
and on the bench scenes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import heightfield, make_scene

from clphong.device import culling
from clphong.device.culling import read_tile_lists, tile_of_pixels
from clphong.device.renderer import Renderer, prepare_frame
from clphong.reference import shading as reference
from clphong.tools.bench import bench_gbuffer, bench_scene


@pytest.fixture(autouse=True)
def _shade_through_the_lists(monkeypatch):
    """The lists are used whatever they keep (the brute-force fallback is culling's), and the
    tree's cut is tried on every device (a GPU's frames here are too short for it to pay:
    renderer.tree_can_pay, tested in test_renderer.py)."""
    import clphong.device.renderer as R

    monkeypatch.setattr(culling, "BRUTE_ABOVE", 1.0)
    monkeypatch.setattr(R, "TREE_DEVICE_RATE", float("inf"))


def clustered_scene(rng, *, n_clusters=6, per=40, spread=0.15, height=12.0, grey=False, k_s=0.05,
                    model="phong", **kw):
    lights = [dict(type="ambient", color=(1.0, 1.0, 1.0), intensity=0.2)]
    centres = np.column_stack([rng.uniform(-6, 10, n_clusters), rng.uniform(-6, 10, n_clusters),
                               rng.uniform(height, height * 1.5, n_clusters)])
    for c in centres:
        for _ in range(per):
            col = (1.0, 1.0, 1.0) if grey else tuple(rng.uniform(0.5, 1.0, 3))
            lights.append(dict(type="point", position=tuple(c + rng.normal(0, spread, 3)),
                               color=col, intensity=float(rng.uniform(0.5, 1.5)) * 8.0 / per,
                               attenuation=(1.0, 0.0, 0.005)))
    return make_scene(lights, model=model, k_s=k_s, h=16.0,
                      camera=dict(type="perspective", position=(2.0, 1.5, 8.0)), **kw)


def list_sum_error(scene, gbuffer, renderer, cull):
    """Per shaded pixel and channel: Σ over the tile's list − Σ over all point lights, in
    float64 with the reference's contributions (representatives as point lights)."""
    tree = renderer.light_tree()
    reps = [dict(type="point", position=tuple(tree.position[k]), color=tuple(tree.radiance[k]),
                 intensity=1.0, attenuation=tuple(tree.attenuation[k]))
            for k in range(tree.n_nodes)]
    m = scene.material
    both = make_scene([lt for lt in scene.lights if lt.type != "ambient"] + reps, model=m.model,
                      k_s=m.k_s, h=m.h, camera=dataclasses.asdict(scene.camera))
    px, C, D, S, fg = reference._inputs(both, gbuffer)
    contrib = np.concatenate([L * (D * diffuse[..., None] + S * specular[..., None])
                              for kind, L, _, diffuse, specular in reference._light_terms(both, px)
                              if kind == "point"])                  # (n + K, M, 3)
    n = tree.n_leaves
    full = contrib[:n].sum(axis=0)
    lists = read_tile_lists(renderer.runtime, cull)
    tile = tile_of_pixels(gbuffer.shape, renderer.lanes).reshape(-1)[fg]
    out = np.zeros_like(full)
    for t in np.unique(tile):
        on = tile == t
        idx = lists[t]
        assert np.all(np.diff(idx.astype(np.int64)) > 0), "lists are in record order"
        out[on] = contrib[idx][:, on].sum(axis=0) - full[on]
    return out


def check_tree_budget(scene, gbuffer, eps, *, want_clusters=True):
    r = Renderer(scene, max_error=eps)
    frame = prepare_frame(gbuffer, lanes=r.lanes)
    result = r.shade(frame)
    cull = result.cull
    assert cull is not None and not cull.brute
    if want_clusters:
        assert cull.clusters > 0, "the scene was meant to take clusters"
        assert cull.records is not None
        # 1. exact: the lists' float64 sum is within ε of the full sum
        worst = np.abs(list_sum_error(scene, gbuffer, r, cull)).max()
        assert worst <= eps, f"lists off the full sum by {worst:.3g} > ε = {eps:g}"
    # 2. end to end against the float64 reference
    ref = reference.shade(scene, gbuffer)
    bound, _ = reference.error_bound(scene, gbuffer, origin=frame.origin,
                                     plan=r.plan_for(frame.map_names, culling=False))
    err = np.abs(result.image.astype(np.float64) - ref)
    assert np.all(err <= eps + bound), f"max excess {np.max(err - eps - bound):.3g}"
    return r, cull, err


@pytest.mark.parametrize("seed,eps,grey", [(0, 1e-2, True), (1, 3e-2, False), (2, 1e-1, False)])
def test_clusters_keep_the_budget(seed, eps, grey):
    rng = np.random.default_rng(seed)
    scene = clustered_scene(rng, grey=grey)
    gb = heightfield(rng, 64, 96, bumps=0.1)
    _, cull, _ = check_tree_budget(scene, gb, eps)
    assert cull.covered > cull.clusters          # each cluster stands for ≥ 2 lights


def test_blinn_and_orthographic_clusters_keep_the_budget():
    rng = np.random.default_rng(7)
    scene = clustered_scene(rng, grey=True, model="blinn-phong", k_s=0.2)
    scene = dataclasses.replace(scene, camera=make_scene(
        [], camera=dict(type="orthographic", direction=(0.0, 0.0, -1.0))).camera)
    gb = heightfield(rng, 64, 96, bumps=0.1)
    check_tree_budget(scene, gb, 3e-2)


def test_clusters_shorten_the_lists():
    rng = np.random.default_rng(3)
    scene = clustered_scene(rng, grey=True)
    gb = heightfield(rng, 64, 96, bumps=0.1)
    with_tree = Renderer(scene, max_error=3e-2).render(gb).cull
    without = Renderer(scene, max_error=3e-2, light_tree=False).render(gb).cull
    assert without.clusters == 0 and without.records is None
    assert with_tree.kept < without.kept


def test_zero_budget_takes_no_cluster_and_is_bit_identical():
    rng = np.random.default_rng(4)
    scene = clustered_scene(rng, grey=True)
    gb = heightfield(rng, 40, 48, bumps=0.1)
    culled = Renderer(scene, max_error=0.0).render(gb)
    assert culled.cull.clusters == 0 and culled.cull.records is None
    brute = Renderer(scene).render(gb)
    np.testing.assert_array_equal(culled.image, brute.image)


def test_light_groups_take_no_cluster():
    rng = np.random.default_rng(5)
    scene = clustered_scene(rng, grey=True)
    lights = tuple(dataclasses.replace(lt, group="key" if i % 2 else "fill")
                   for i, lt in enumerate(scene.lights))
    scene = dataclasses.replace(scene, lights=lights)
    gb = heightfield(rng, 40, 48, bumps=0.1)
    cull = Renderer(scene, max_error=3e-2).render(gb).cull
    assert cull.clusters == 0


@pytest.mark.parametrize("kind,n,eps", [("wide", 256, 1e-2), ("wide", 1024, 1e-1),
                                        ("small", 1024, 1e-3)])
def test_bench_scenes_keep_the_budget(kind, n, eps):
    gb = bench_gbuffer(160, 90)
    check_tree_budget(bench_scene(kind, n), gb, eps, want_clusters=False)

"""kernels/node_bound.cl ``tile_cut`` (the light tree's cut per tile, on the device)
against its float64 reference, clphong.model.light_tree.greedy_cut, and in frames.

The kernel and the reference split the node with the largest bound until each
channel's bounds over the cut sum to ≤ the limit. Their bounds agree within 10⁻¹⁰ relative
(tests/device/test_node_bound.py), so they split the same nodes in the same order
unless two bounds, or a sum and the limit, lie within that of each other: the cuts
must be the same on every tile here (random bounds make such ties unlikely; a tie
would show as a failure to look at, not a tolerance to widen). Each cut must also
hold: its bounds, recomputed in numpy, sum to ≤ the limit, and its leaves and its
nodes' lights are each kept light once.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import heightfield
from test_node_bound import tile_boxes
from test_tree_cut import check_tree_budget, clustered_scene, list_sum_error

from clphong.device import culling
from clphong.device.nodebound import CUT_OVERFLOW, DeviceNodeTerms
from clphong.device.renderer import Renderer, prepare_frame
from clphong.model.light_tree import (
    SpecularModel,
    TileBoxes,
    build_light_tree,
    cluster_bounds,
    greedy_cut,
    leaf_ranges,
)
from clphong.reference import shading as reference


@pytest.fixture(autouse=True)
def _shade_through_the_lists(monkeypatch):
    import clphong.device.renderer as R

    monkeypatch.setattr(culling, "BRUTE_ABOVE", 1.0)
    monkeypatch.setattr(R, "TREE_DEVICE_RATE", float("inf"))


def _setup(seed, device, n_tiles=24):
    rng = np.random.default_rng(seed)
    scene = clustered_scene(rng, n_clusters=6, per=30, spread=0.6, height=3.0, k_s=0.2)
    gb = heightfield(rng, 48, 64, bumps=0.3)
    origin = np.array([0.5, -0.25, 0.125])
    tree = build_light_tree(scene.light_arrays)
    tiles = tile_boxes(rng, gb, n_tiles, origin)
    spec = SpecularModel.of_scene(scene)
    spec = SpecularModel(blinn=spec.blinn, exponent=spec.exponent, fresnel=spec.fresnel,
                         eye=spec.eye - origin, perspective=spec.perspective)
    r = Renderer(scene, device=device)
    if not DeviceNodeTerms.usable(r.runtime, tree):
        pytest.skip("the device has no double")
    return rng, tree, tiles, spec, origin, DeviceNodeTerms(r.runtime, tree, spec, origin, tiles)


def _run(dev, tree, scale, kept, *, cap=4096):
    """The kernel's cuts with one super-tile (its culling kept ``kept``), records =
    light j → j, node k → n + k: ((nodes, leaves) per tile, counts, sums)."""
    n = tree.n_leaves
    words = -(-n // 32)
    bits = np.zeros(words * 32, bool)
    bits[kept] = True
    _, _, place = leaf_ranges(tree)
    extra = np.flatnonzero(bits[:n] & (place < 0))
    T = len(scale)
    counts, sums, lists = dev.tile_cut(
        tree, scale, np.zeros(T, np.uint32), np.packbits(bits, bitorder="little").view(np.uint32)[None],
        np.array([[0, extra.size]]), extra, np.arange(n), n + np.arange(tree.n_nodes), cap=cap)
    import pyopencl as cl

    flat = np.empty(T * cap, np.uint32)
    cl.enqueue_copy(dev.runtime.queue, flat, lists).wait()
    cuts = []
    for t in range(T):
        c = int(counts[t, 0])
        got = flat[t * cap:t * cap + c].astype(np.int64) if c != CUT_OVERFLOW else None
        cuts.append(None if got is None else (np.sort(got[got >= n] - n), np.sort(got[got < n])))
    return cuts, counts, sums


def _bound_of(tree, tiles, spec, origin, t, scale):
    part = TileBoxes(*(getattr(tiles, f)[[t]] for f in ("lo", "hi", "nlo", "nhi", "D", "S")))
    return lambda k: cluster_bounds(tree, part, spec, origin, np.array([k]), pairs=True,
                                    channel_scale=scale[t][None, None, :], channels=True)[0]


@pytest.mark.parametrize("seed,budget", [(0, 1e-3), (1, 1e-2), (2, 1e-1)])
def test_device_cut_is_its_reference_cut(seed, budget, device):
    rng, tree, tiles, spec, origin, dev = _setup(seed, device)
    T = len(tiles.lo)
    # per tile and channel budgets over two decades; one channel with none (inf scale)
    share = budget * 10 ** rng.uniform(-1, 1, (T, 3))
    share[0, 1] = 0.0
    scale = np.where(share > 0, (1 + 1e-12) / np.where(share > 0, share, 1), np.inf)
    kept = np.flatnonzero(rng.random(tree.n_leaves) < 0.9)          # culling kept 90 %
    cuts, counts, sums = _run(dev, tree, scale, kept)
    start, end, place = leaf_ranges(tree)
    leaf_at = np.full(int(end.max()), -1)
    leaf_at[place[place >= 0]] = np.flatnonzero(place >= 0)
    limit = 1.0 - 1e-9
    split = 0
    for t in range(T):
        nodes, leaves = cuts[t]
        b = _bound_of(tree, tiles, spec, origin, t, scale)
        want_nodes, want_leaves, want_sum = greedy_cut(tree, b, limit)
        keep = np.isin(want_leaves, kept)
        assert np.array_equal(nodes, want_nodes), t
        outside = np.intersect1d(np.flatnonzero(place < 0), kept)
        assert np.array_equal(leaves, np.unique(np.r_[want_leaves[keep], outside]))
        assert counts[t, 1] == nodes.size
        assert counts[t, 2] == int((end[nodes] - start[nodes]).sum())
        assert sums[t] <= limit and sums[t] == pytest.approx(want_sum, rel=1e-9, abs=0)
        # each channel within its budget, the bounds recomputed in numpy
        got = np.sum([b(k) for k in nodes], axis=0) if nodes.size else np.zeros(3)
        assert np.all(got <= limit * (1 + 1e-9)), (t, got)
        # a cut: every kept light once, as a leaf or under one node
        under = np.zeros(tree.n_leaves, int)
        for k in nodes:
            under[leaf_at[start[k]:end[k]]] += 1
        under[leaves] += 1
        assert np.all(under[kept] == 1) and np.all(under <= 1)
        split += nodes.size > 0 and leaves.size > 0
    print("tiles with both clusters and leaves:", split, "of", T)
    assert split >= T // 3, "most tiles' cuts were meant to take clusters and leaves"


def test_device_cut_overflows_to_none(device):
    """A cut that cap entries cannot hold is marked, never written past its place."""
    rng, tree, tiles, spec, origin, dev = _setup(3, device, n_tiles=6)
    scale = np.full((6, 3), 1e9)                     # a budget of 10⁻⁹: split to the leaves
    cuts, counts, _ = _run(dev, tree, scale, np.arange(tree.n_leaves), cap=16)
    assert np.all(counts[:, 0] == CUT_OVERFLOW) and all(c is None for c in cuts)


def test_a_cap_of_the_lights_holds_any_cut(device):
    """A cut never holds more entries than lights (culling.CUT_CAP's reason to take
    min(cap, lights)): split to the leaves, a cap of exactly n lights holds every list
    (all n lights, no node) and never marks it overflowed."""
    rng, tree, tiles, spec, origin, dev = _setup(3, device, n_tiles=6)
    n = tree.n_leaves
    scale = np.full((6, 3), 1e9)                     # a budget of 10⁻⁹: split to the leaves
    cuts, counts, _ = _run(dev, tree, scale, np.arange(n), cap=n)
    assert np.all(counts[:, 0] == n) and np.all(counts[:, 1] == 0)
    assert all(c is not None and c[0].size == 0 and np.array_equal(c[1], np.arange(n))
               for c in cuts)


@pytest.mark.parametrize("eps,cap,group", [(1e-3, 4096, 1), (1e-3, 4096, 2), (3e-2, 4096, 2),
                                           (3e-2, None, 1), (3e-2, None, 2)])
def test_device_cut_frames_keep_the_budget(eps, cap, group, monkeypatch):
    """Frames through the device's cut (BLOCK_ENTRIES = 0), a cut per tile or per 2×2
    tiles, keep the budget: the lists' float64 sums within ε of the full sums, the
    pixels within ε + the error model; with a cap of the median cut's length (None)
    about half the cuts leave their tiles their super-tile's list."""
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 0)
    monkeypatch.setattr(culling, "CUT_GROUP", group)
    scene, gb = _frame()
    if cap is None:                          # the median of the uncapped cuts' lengths
        sizes = []
        real = DeviceNodeTerms.tile_cut

        def spy(self, *a, **k):
            out = real(self, *a, **k)
            sizes.append(out[0][:, 0][(out[0][:, 0] > 0) & (out[0][:, 0] != CUT_OVERFLOW)])
            return out

        monkeypatch.setattr(culling, "CUT_CAP", 4096)
        with monkeypatch.context() as m:
            m.setattr(DeviceNodeTerms, "tile_cut", spy)
            r = Renderer(scene, max_error=eps)
            r.shade(prepare_frame(gb, lanes=r.lanes))
        cap = int(np.median(np.concatenate(sizes)))
    monkeypatch.setattr(culling, "CUT_CAP", cap)
    cuts = _count_device_cuts(monkeypatch)
    _, cull, _ = check_tree_budget(scene, gb, eps)
    assert cuts and all(c is not None for c in cuts), "the device's cut was made"
    assert cull.tree_blocks and cull.covered > cull.clusters
    if cap < 4096:
        assert any((c[0][:, 1] > cap).any() for c in cuts), "some tile kept its super-tile's list"
    starts = cuts[-1][0][:, 0]
    shared = len(starts) / len(np.unique(starts))
    assert shared > 2.5 if group == 2 else shared < 1.5, "each group's tiles share its list"


def test_a_device_cut_past_its_budget_is_caught(monkeypatch):
    """The frame check above can fail: cuts made with 30× the budget are caught."""
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 0)
    cuts = _count_device_cuts(monkeypatch)
    real = DeviceNodeTerms.tile_cut
    monkeypatch.setattr(DeviceNodeTerms, "tile_cut",
                        lambda self, tree, scale, *a, **k: real(self, tree, scale / 30, *a, **k))
    scene, gb = _frame()
    with pytest.raises(AssertionError, match="off the full sum"):
        check_tree_budget(scene, gb, 1e-3)
    assert cuts and cuts[0] is not None


def _frame():
    rng = np.random.default_rng(21)
    return (clustered_scene(rng, n_clusters=8, per=60, spread=0.4, height=6.0),
            heightfield(rng, 64, 96, bumps=0.1))


def _count_device_cuts(monkeypatch) -> list:
    """The results of culling._device_cut, as the frames make them."""
    out = []
    real = culling._device_cut

    def spy(*a, **k):
        out.append(real(*a, **k))
        return out[-1]

    monkeypatch.setattr(culling, "_device_cut", spy)
    return out


def test_device_cut_keeps_the_relative_budget(monkeypatch):
    """Relative to each pixel, per channel (a colourful scene, so the channels' floors
    differ): the lists' float64 sums within ε·|the pixel's float64 total| of the full
    sums, and the pixels within that plus the error model of the reference."""
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 0)
    cuts = _count_device_cuts(monkeypatch)
    rng = np.random.default_rng(22)
    scene = clustered_scene(rng, n_clusters=8, per=60, spread=0.4, height=6.0, grey=False)
    gb = heightfield(rng, 64, 96, bumps=0.1)
    eps = 3e-2
    r = Renderer(scene, max_error=eps, relative=True, light_tree="always")
    frame = prepare_frame(gb, lanes=r.lanes)
    result = r.shade(frame)
    assert cuts and cuts[-1] is not None and result.cull.tree_blocks and result.cull.clusters > 0
    want = reference.shade(scene, gb)
    _, _, _, _, fg = reference._inputs(scene, gb)
    off = list_sum_error(scene, gb, r, result.cull)
    allowed = eps * np.abs(want.reshape(-1, 3)[fg])
    assert np.all(np.abs(off) <= allowed * (1 + 1e-12)), float(np.max(np.abs(off) / allowed))
    bound, _ = reference.error_bound(scene, gb, origin=frame.origin,
                                     plan=r.plan_for(frame.map_names, culling=False))
    err = np.abs(result.image.astype(np.float64) - want)
    assert np.all(err <= eps * np.abs(want) + bound)

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
from conftest import heightfield, make_scene, record_calls

from clphong.device import culling
from clphong.device.culling import read_tile_lists, tile_of_pixels
from clphong.device.renderer import Renderer, prepare_frame
from clphong.model.light_tree import light_groups_of
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


def representative_lights(scene, tree):
    """The tree's representatives as the scene's lights: a point light (or a spot with
    its members' cone) at the node's centroid with its summed radiance."""
    arrays = scene.light_arrays
    out = []
    for k in range(tree.n_nodes):
        leaf = k + tree.n_leaves
        while leaf >= tree.n_leaves:                 # any member: the first leaf below
            leaf = int(tree.children[leaf - tree.n_leaves][0])
        member = scene.lights[arrays["point_index"][leaf]]
        rep = dict(type=member.type, position=tuple(tree.position[k]),
                   color=tuple(tree.radiance[k]), intensity=1.0,
                   attenuation=tuple(tree.attenuation[k]))
        if member.type == "spot":
            rep.update(direction=member.direction, inner_angle=member.inner_angle,
                       outer_angle=member.outer_angle)
        out.append(rep)
    return out


def list_sum_error(scene, gbuffer, renderer, cull, *, per_group=False):
    """Per shaded pixel and channel: Σ over the tile's list − Σ over all point lights, in
    float64 with the reference's contributions (representatives as the lights they
    are). ``per_group``: (G, pixels, 3), each light group's part of it (its lights and
    its representatives)."""
    tree = renderer.light_tree()
    arrays = scene.light_arrays
    n = tree.n_leaves
    plain = [dataclasses.replace(scene.lights[i], group=None) for i in arrays["point_index"]]
    m = scene.material
    both = make_scene(plain + representative_lights(scene, tree), model=m.model,
                      k_s=m.k_s, h=m.h, camera=dataclasses.asdict(scene.camera))
    px, C, D, S, fg = reference._inputs(both, gbuffer)
    contrib = np.concatenate([L * (D * diffuse[..., None] + S * specular[..., None])
                              for kind, L, _, diffuse, specular in reference._light_terms(both, px)
                              if kind == "point"])                  # (n + K, M, 3)
    group = np.concatenate([light_groups_of(arrays), tree.group])   # of each light, node
    G = max(len(scene.light_groups), 1)
    lists = read_tile_lists(renderer.runtime, cull)
    source = cull.record_source
    tile = tile_of_pixels(gbuffer.shape, renderer.lanes).reshape(-1)[fg]
    out = np.zeros((G,) + contrib.shape[1:])
    for g in range(G):
        out[g] = -contrib[:n][group[:n] == g].sum(axis=0)
    for t in np.unique(tile):
        on = tile == t
        idx = lists[t]
        assert np.all(np.diff(idx.astype(np.int64)) > 0), "lists are in record order"
        src = source[idx]
        for g in range(G):
            out[g, on] += contrib[src[group[src] == g]][:, on].sum(axis=0)
    return out if per_group else out.sum(axis=0)


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


def grouped(scene, fill=1.0):
    """The scene with its point lights dealt alternately to two light groups, the fill's
    intensities scaled by ``fill``."""
    lights = tuple(dataclasses.replace(lt, group="key") if i % 2 else
                   dataclasses.replace(lt, group="fill", intensity=lt.intensity * fill)
                   for i, lt in enumerate(scene.lights))
    return dataclasses.replace(scene, lights=lights)


def check_group_layers(scene, gbuffer, renderer, result, eps, *, relative=False):
    """Each light group's clusters hold its own lights only, and its records follow its
    lights; each group's listed sum is within ε (relative: ε times the group's own
    float64 total) of its full sum, exactly in float64; and each group layer is
    within that plus its error bound of the float64 reference of its own lights."""
    cull, tree = result.cull, renderer.light_tree()
    arrays = scene.light_arrays
    light_group = light_groups_of(arrays)
    for k in range(tree.n_nodes):
        members = light_group[subtree_leaves(tree, k)]
        assert np.all(members == tree.group[k]), f"node {k} mixes groups"
    group = np.concatenate([light_group, tree.group])[cull.record_source]
    at = np.searchsorted(cull.point_end, np.arange(len(group)), side="right")
    assert np.array_equal(group, at), "records out of group order"
    listed = np.concatenate(read_tile_lists(renderer.runtime, cull))
    reps = cull.record_source[listed] >= tree.n_leaves
    used = np.bincount(group[listed][reps], minlength=len(scene.light_groups))
    assert np.all(used > 0), f"clusters used per group: {used}"
    off = list_sum_error(scene, gbuffer, renderer, cull, per_group=True)
    frame_plan = renderer.plan_for(prepare_frame(gbuffer, lanes=renderer.lanes).map_names,
                                   culling=False)
    for g, name in enumerate(scene.light_groups):
        sub = dataclasses.replace(scene, lights=tuple(
            lt for lt in scene.lights if lt.group_name == name))
        want = reference.shade(sub, gbuffer)
        px, _, _, _, fg = reference._inputs(sub, gbuffer)
        allowed = eps * (np.abs(want.reshape(-1, 3)[fg]) if relative else 1.0)
        assert np.all(np.abs(off[g]) <= allowed * (1 + 1e-12)), name
        bound, _ = reference.error_bound(sub, gbuffer, plan=frame_plan)
        err = np.abs(result.layers[name].astype(np.float64) - want)
        extra = eps * np.abs(want) if relative else eps
        assert np.all(err <= extra + bound), f"{name}: max excess {np.max(err - extra - bound):.3g}"


def subtree_leaves(tree, node):
    """Point-light indices under internal node ``node`` (0-based)."""
    out, stack = [], [node]
    while stack:
        for c in tree.children[stack.pop()]:
            if c < tree.n_leaves:
                out.append(int(c))
            else:
                stack.append(int(c) - tree.n_leaves)
    return np.array(sorted(out))


@pytest.mark.parametrize("relative", [False, True], ids=["absolute", "relative"])
def test_each_light_group_takes_clusters_of_its_own(relative):
    """Two light groups dealt from the same clusters (issue 27): each takes clusters of its
    own lights, and each group layer keeps the budget for its own value. Relative: the
    fill 1000x dimmer, held to its own floor, not the key's (the absolute budget would
    drop such a fill whole)."""
    rng = np.random.default_rng(5)
    scene = grouped(clustered_scene(rng, grey=True), fill=1e-3 if relative else 1.0)
    gb = heightfield(rng, 40, 48, bumps=0.1)
    eps = 1e-1 if relative else 3e-2
    r = Renderer(scene, max_error=eps, relative=relative, light_tree="always")
    result = r.shade(prepare_frame(gb, lanes=r.lanes))
    cull = result.cull
    assert cull is not None and not cull.brute
    assert cull.clusters > 0 and cull.point_end is not None
    tree = r.light_tree()
    assert set(tree.group.tolist()) == {0, 1}
    check_group_layers(scene, gb, r, result, eps, relative=relative)


def spot_rig(rng, *, n_clusters=5, per=40, spread=0.15, height=6.0, inner=25.0, outer=40.0,
             tilt=(0.0, 0.0, -1.0)):
    """Clusters of spots sharing one cone (a rig of downlights): every spot in the rig has
    the same axis and angles, so each cluster's spots may share a node."""
    lights = [dict(type="ambient", color=(1.0, 1.0, 1.0), intensity=0.2)]
    centres = np.column_stack([rng.uniform(-4, 8, n_clusters), rng.uniform(-4, 8, n_clusters),
                               rng.uniform(height, height * 1.3, n_clusters)])
    for c in centres:
        for _ in range(per):
            lights.append(dict(type="spot", position=tuple(c + rng.normal(0, spread, 3)),
                               direction=tilt, inner_angle=inner, outer_angle=outer,
                               color=(1.0, 1.0, 1.0), intensity=float(rng.uniform(0.5, 1.5)) * 8.0 / per,
                               attenuation=(1.0, 0.0, 0.02)))
    return lights


@pytest.mark.parametrize("seed,eps,inner,outer,tilt", [(0, 1e-2, 60.0, 75.0, (0.0, 0.0, -1.0)),
                                                       (0, 1e-1, 10.0, 60.0, (0.4, -0.2, -1.0))])
def test_spots_of_one_cone_take_clusters(seed, eps, inner, outer, tilt):
    """A rig of spots with one cone, some pixels inside it, some on its edge and some
    outside: clusters of spots keep the budget (each cluster stands for ≥ 2 spots)."""
    rng = np.random.default_rng(seed)
    scene = make_scene(spot_rig(rng, tilt=tilt, inner=inner, outer=outer), model="phong",
                       k_s=0.05, h=16.0,
                       camera=dict(type="perspective", position=(2.0, 1.5, 8.0)))
    gb = heightfield(rng, 64, 96, bumps=0.1)
    _, cull, _ = check_tree_budget(scene, gb, eps)
    assert cull.covered > cull.clusters
    tree = Renderer(scene, max_error=eps).light_tree()
    assert np.all(tree.cone[:, 3] > 0)                        # every node is a spot's


@pytest.mark.parametrize("case", ["grey", "colour", "blinn", "spots", "groups", "relative",
                                  "grey-host", "blinn-host"])
def test_the_blocks_cut_keeps_the_budget(case, monkeypatch):
    """Where the super-tiles' cuts leave long lists, the cut is made again per block of
    BLOCK_TILES² tiles with all the budget the super-tiles' culling left, and its lists
    are the tiles' own (BLOCK_ENTRIES = 0: every frame here). The lists' float64 sums
    stay within ε of the full sums (per group layer and relative to each pixel where
    asked), and the pixels within ε + the error model of the reference."""
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 0)
    # "-host": the host's cut per block where the device's per tile would be made
    # (tests/device/test_device_cut.py); spots and groups take the host's anyway
    case, host = case.removesuffix("-host"), case.endswith("-host")
    monkeypatch.setattr(culling, "DEVICE_CUT", not host)
    rng = np.random.default_rng(11)
    gb = heightfield(rng, 64, 96, bumps=0.1)
    if case == "spots":
        scene = make_scene(spot_rig(rng, inner=10.0, outer=60.0, tilt=(0.4, -0.2, -1.0)),
                           model="phong", k_s=0.05, h=16.0,
                           camera=dict(type="perspective", position=(2.0, 1.5, 8.0)))
    elif case in ("groups", "relative"):
        scene = grouped(clustered_scene(rng, grey=True), fill=1e-3 if case == "relative" else 1.0)
    else:
        scene = clustered_scene(rng, grey=case == "grey", model="blinn-phong" if case == "blinn"
                                else "phong", k_s=0.2 if case == "blinn" else 0.05)
    eps = 3e-2
    if case in ("groups", "relative"):
        relative = case == "relative"
        r = Renderer(scene, max_error=eps, relative=relative, light_tree="always")
        result = r.shade(prepare_frame(gb, lanes=r.lanes))
        assert result.cull.clusters > 0 and result.cull.tree_blocks
        check_group_layers(scene, gb, r, result, eps, relative=relative)
        return
    _, cull, _ = check_tree_budget(scene, gb, eps)
    assert cull.tree_blocks and cull.covered > cull.clusters


def test_the_blocks_cut_shortens_long_lists(monkeypatch):
    """Blocks of 4×4 tiles take fewer entries than the super-tiles' cut and the tiles'
    culling after it, on a frame whose lists are long (a cut over a smaller box is
    coarser); with BLOCK_ENTRIES above every list, the blocks' cut is not made."""
    rng = np.random.default_rng(12)
    scene = clustered_scene(rng, n_clusters=8, per=150, spread=0.4, height=6.0)
    gb = heightfield(rng, 128, 160, bumps=0.1)
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 10 ** 9)
    supers = Renderer(scene, max_error=1e-3, light_tree="always").render(gb).cull
    monkeypatch.setattr(culling, "BLOCK_ENTRIES", 0)
    blocks = Renderer(scene, max_error=1e-3, light_tree="always").render(gb).cull
    assert not supers.tree_blocks and blocks.tree_blocks
    assert blocks.kept < supers.kept, (blocks.kept, supers.kept)


def test_spots_with_other_cones_never_share_a_node():
    """Spots whose axes or angles differ, points and spots: never in one node."""
    rng = np.random.default_rng(2)
    a = spot_rig(rng, n_clusters=2, per=40)
    b = spot_rig(rng, n_clusters=2, per=40, tilt=(0.3, 0.0, -1.0))
    c = spot_rig(rng, n_clusters=2, per=40, inner=10.0, outer=20.0)
    points = [dict(lt, type="point") for lt in spot_rig(rng, n_clusters=2, per=40)]
    for lt in points:
        for key in ("direction", "inner_angle", "outer_angle"):
            lt.pop(key, None)
    scene = make_scene(a + b[1:] + c[1:] + points[1:], model="phong", k_s=0.05, h=16.0)
    r = Renderer(scene, max_error=1e-2)
    tree = r.light_tree()
    cones = scene.light_arrays["point_cone"]
    for k in range(tree.n_nodes):
        leaves = subtree_leaves(tree, k)
        assert np.all(cones[leaves] == cones[leaves[0]]), f"node {k} mixes cones"
    assert len({tuple(c) for c in tree.cone}) == 4


@pytest.mark.parametrize("kind,n,eps", [("wide", 256, 1e-2), ("wide", 1024, 1e-1),
                                        ("small", 1024, 1e-3)])
def test_bench_scenes_keep_the_budget(kind, n, eps):
    gb = bench_gbuffer(160, 90)
    check_tree_budget(bench_scene(kind, n), gb, eps, want_clusters=False)


def test_representatives_are_marked_out_of_the_floor():
    """The relative budget's floor (cull.cl tile_floor) leaves out records whose F.z is 1:
    the representatives, wherever the layout puts them (their lights' sum is not below
    them), and nothing else of plain lights."""
    rng = np.random.default_rng(8)
    scene = grouped(clustered_scene(rng, grey=True))
    r = Renderer(scene, max_error=1e-2)
    tree = r.light_tree()
    n = tree.n_leaves
    layout = culling.ExtendedLayout.of(tree, n, scene.light_arrays["point_group_end"])
    from clphong.device.frame import pack_lights
    from clphong.model.light_tree import representative_records
    lights = pack_lights(scene, np.zeros(3))
    rec = layout.records(lights.point, representative_records(tree, np.zeros(3))[0])
    packed = culling.pack_cull_lights(rec, len(layout.source),
                                      representative=layout.representative)
    flag = packed.reshape(-1, culling.CULL_RECORD, 4)[:, 4, 2]
    assert np.array_equal(flag == 1, layout.representative)
    assert layout.representative.sum() == tree.n_nodes


@pytest.mark.parametrize("case", ["groups-absolute", "groups-relative", "spots"])
def test_the_top_down_cut_lists_what_the_whole_table_lists(case, monkeypatch):
    """Large trees are cut from the top down (culling.TOP_DOWN_NODES), small ones from their
    whole table of bounds: the two give the same lists and the same pixels, with light
    groups' own floors and with spots' cones."""
    rng = np.random.default_rng(9)
    if case == "spots":
        scene = make_scene(spot_rig(rng, inner=60.0, outer=75.0), model="phong", k_s=0.05,
                           h=16.0, camera=dict(type="perspective", position=(2.0, 1.5, 8.0)))
        eps, relative = 1e-2, False
        gb = heightfield(rng, 64, 96, bumps=0.1)
    else:
        relative = case == "groups-relative"
        scene = grouped(clustered_scene(rng, grey=False), fill=1e-3 if relative else 1.0)
        eps = 1e-1 if relative else 3e-2
        gb = heightfield(rng, 40, 48, bumps=0.1)
    got = []
    for nodes in (0, 1 << 60):
        monkeypatch.setattr(culling, "TOP_DOWN_NODES", nodes)
        r = Renderer(scene, max_error=eps, relative=relative, light_tree="always")
        result = r.shade(prepare_frame(gb, lanes=r.lanes))
        assert result.cull is not None and result.cull.clusters > 0
        got.append((result.image, read_tile_lists(r.runtime, result.cull), result.cull.clusters))
    (a, la, ca), (b, lb, cb) = got
    assert ca == cb
    assert all(np.array_equal(x, y) for x, y in zip(la, lb, strict=True))
    assert np.array_equal(a, b)


def test_a_sample_of_super_tiles_spares_the_pass_the_tree_makes_useless(monkeypatch):
    """Where the tree is given, the tiles' pass without it runs first on one super-tile in
    culling.PROBE_EVERY; where the tree's lists are far shorter than that sample foretells,
    the whole pass never runs, and the lists and pixels are those chosen after it ran."""
    rng = np.random.default_rng(3)
    scene = clustered_scene(rng, grey=True)
    gb = heightfield(rng, 64, 1024, bumps=0.1)
    levels = record_calls(monkeypatch, culling, "_cull_level")
    got = []
    for margin in (culling.PROBE_MARGIN, float("inf")):      # inf: the whole pass always runs
        monkeypatch.setattr(culling, "PROBE_MARGIN", margin)
        levels.clear()
        r = Renderer(scene, max_error=3e-2, light_tree="always")
        result = r.shade(prepare_frame(gb, lanes=r.lanes))
        assert result.cull is not None and result.cull.clusters > 0
        got.append((result.image, read_tile_lists(r.runtime, result.cull),
                    [level[2] for level in levels]))             # each pass's kept entries
    (a, la, spared), (b, lb, whole) = got
    # super-tiles, the sample, the tiles with the tree, and at an infinite margin the
    # whole pass without it, which keeps more than the sample and the tree's lists
    assert len(spared) == 3 and len(whole) == 4 and spared == whole[:3]
    assert spared[1] < whole[3] and whole[2] < whole[3]
    assert all(np.array_equal(x, y) for x, y in zip(la, lb, strict=True))
    assert np.array_equal(a, b)


def test_where_the_sample_keeps_little_but_the_lists_are_too_long_the_tree_is_tried(monkeypatch):
    """The sampled super-tile (culling.PROBE_EVERY) lies far from the lights, so it keeps
    little; the whole pass's lists are too long (MAX_LIST_ENTRIES, lowered to this frame's
    scale): the tree is tried, as without a sample, rather than culling given up. (A
    review found this path returning no lists.)"""
    scene = clustered_scene(np.random.default_rng(3), grey=True)
    gb = heightfield(np.random.default_rng(0), 48, 400, bumps=0.1)
    P = np.array(gb.position)
    P[:, 256:384, 0] += 1000.0                  # super-tile 2 of 4 (the sample): far away
    gb = dataclasses.replace(gb, position=P)
    monkeypatch.setattr(culling, "MAX_LIST_ENTRIES", 12_000)
    got = {}
    for every in (1, culling.PROBE_EVERY):      # 1: no sample (the whole pass first)
        monkeypatch.setattr(culling, "PROBE_EVERY", every)
        r = Renderer(scene, max_error=3e-2, light_tree="always")
        c = r.shade(prepare_frame(gb, lanes=r.lanes)).cull
        assert c is not None and not c.brute and c.clusters > 0
        got[every] = c.kept
    assert got[1] == got[culling.PROBE_EVERY]

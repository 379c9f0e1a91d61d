"""Error-bounded tiled light culling (kernels/cull.cl, clphong/cull.py).

The claim under test: for every pixel and channel, the lights a tile drops
contribute at most ε in total. It is checked two ways, neither tuned to pass:

* exactly, in float64: Σ over the dropped lights of the reference's own
  contribution (clphong.reference.shading, same float32 inputs) ≤ ε, per pixel and
  channel, with the kernel's lists read back;
* end to end: |culled kernel − reference| ≤ ε + the brute-force error bound
  (docs/error-model.md), on top of the first.

ε = 0 must give the brute-force image bit for bit.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import (heightfield, make_gbuffer, make_scene, point_lights, record_calls,
                      skip_unless_lanes)

from clphong.core.floats import U
from clphong.device import culling
from clphong.device.culling import read_tile_lists, tile_of_pixels
from clphong.device.renderer import Renderer, prepare_frame
from clphong.model.options import CullingError
from clphong.reference import shading as reference

#: The real threshold, before the fixture below lifts it.
BRUTE_ABOVE = culling.BRUTE_ABOVE


@pytest.fixture(autouse=True)
def _shade_through_the_lists(monkeypatch):
    """These tests hold the culled kernel itself to its budget: its lists are used
    whatever they keep (the brute-force fallback has tests of its own below), and
    they are culling's alone (the light tree's clusters: tests/device/test_tree_cut.py)."""
    monkeypatch.setattr(culling, "BRUTE_ABOVE", 1.0)
    monkeypatch.setattr(culling, "TREE_ABOVE", 2.0)


def dropped_sum(scene, gbuffer, renderer, cull, members=None):
    """Per pixel and channel, Σ of the float64 contributions of the lights the tile dropped
    (``cull``: the TileLists of the launch); ``members``: only the point lights with these
    indices (scene.light_arrays order), else all."""
    lists = read_tile_lists(renderer.runtime, cull)
    tile = tile_of_pixels(gbuffer.shape, renderer.lanes).reshape(-1)
    px, C, D, S, fg = reference._inputs(scene, gbuffer)
    tile_fg = tile[fg]
    n_point = len(scene.light_arrays["point_position"])        # point and spot lights
    kept = np.zeros((cull.n_tiles, n_point), bool)
    for t, idx in enumerate(lists):
        kept[t, idx] = True
        assert np.all(np.diff(idx.astype(np.int64)) > 0), "lists keep the light order"
    total = np.zeros((len(tile_fg), 3))
    j = 0
    # the reference's per-light weights: batches of K lights of one kind, in scene order
    for kind, L, _, diffuse, specular in reference._light_terms(scene, px):
        if kind != "point":
            continue
        for k in range(len(diffuse)):
            if members is None or j in members:
                contrib = L[k] * (D * diffuse[k][:, None] + S * specular[k][:, None])
                total += np.where(kept[tile_fg, j][:, None], 0.0, contrib)
            j += 1
    assert j == n_point
    return total


def check_budget_holds(scene, gbuffer, eps):
    brute = Renderer(scene)
    r = Renderer(scene, max_error=eps)
    frame = prepare_frame(gbuffer, lanes=r.lanes)
    result = r.shade(frame)
    out = result.image.astype(np.float64)
    assert result.cull is not None
    # 1. exact: the dropped lights' float64 contributions sum to ≤ ε
    dropped = dropped_sum(scene, gbuffer, r, result.cull)
    worst = np.abs(dropped).max(initial=0.0)
    assert worst <= eps, f"dropped lights sum to {worst:.3g} > ε = {eps:g}"
    # 2. end to end against the float64 reference: ε on top of the error model's bound
    ref = reference.shade(scene, gbuffer)
    bound, _ = reference.error_bound(scene, gbuffer, origin=frame.origin,
                                     **_bound_kwargs(brute, frame))
    err = np.abs(out - ref)
    assert np.all(err <= eps + bound), f"max excess {np.max(err - eps - bound):.3g}"
    return r, dropped, result.cull


def _bound_kwargs(renderer, frame):
    """The error_bound options of the brute-force variant that would run (its plan)."""
    return dict(plan=renderer.plan_for(frame.map_names, culling=False))


# ----------------------------------------------------------------------------- ε = 0

@pytest.mark.parametrize("seed", range(2))
def test_zero_budget_is_bit_identical_to_brute_force(seed, device):
    rng = np.random.default_rng(seed)
    gb = heightfield(rng, 29, 51)
    lights = point_lights(rng, 40, att=(1.0, 0.2, 5.0))
    lights.append(dict(type="point", position=(1.0, 1.0, 0.3), color=(0.0, 0.0, 0.0), intensity=0.0))
    scene = make_scene(lights, model=["phong", "blinn-phong"][seed], h=30.0)
    brute = Renderer(scene, device=device).render(gb).image
    r = Renderer(scene, max_error=0.0, device=device)
    assert r.plan_for(()).defines["CULLING"] == 1     # the culling kernels did run
    result = r.render(gb)
    assert result.plan.defines["CULLING"] == 1 and not result.cull.brute   # shaded through the lists
    culled = result.image
    assert np.array_equal(culled, brute)
    # only the black light (bound exactly 0) goes; every other light stays in every
    # tile with shaded pixels (empty and padding tiles keep nothing)
    lists = read_tile_lists(r.runtime, result.cull)
    shaded = tile_of_pixels(gb.shape, r.lanes)[~gb.background_mask()]
    assert {len(lists[t]) for t in np.unique(shaded)} == {40}


# ------------------------------------------------------------------------- the bound holds

@pytest.mark.parametrize("eps", [1e-4, 1e-3, 3e-2])
def test_dropped_lights_sum_to_at_most_the_budget(eps):
    rng = np.random.default_rng(7)
    gb = heightfield(rng)
    scene = make_scene(point_lights(rng, 120), model="blinn-phong", h=40.0,
                       camera=dict(type="perspective", position=(2.2, 1.8, 4.0)))
    r, dropped, cull = check_budget_holds(scene, gb, eps)
    if eps >= 1e-3:
        assert cull.kept_fraction < 1.0   # something was culled
        assert dropped.max() > 0


def test_far_lights_are_culled():
    """Two clusters of 60 lights, one 20 units away from the surface: each far light
    adds at most I·(D + S)/(c2·d²) ≤ 3·1.2/(10⁴·20²) < 10⁻⁶, 60 of them < 10⁻⁴ < ε,
    so every tile must drop the whole far cluster."""
    rng = np.random.default_rng(4)
    gb = heightfield(rng)
    near = point_lights(rng, 60, att=(1.0, 0.0, 1e4))
    far = point_lights(rng, 60, att=(1.0, 0.0, 1e4), offset=(20.0, 0.0, 0.0))
    scene = make_scene(near + far, model="blinn-phong", h=40.0)
    r, _, cull = check_budget_holds(scene, gb, 1e-3)
    for idx in read_tile_lists(r.runtime, cull):
        assert np.all(idx < 60)


@pytest.mark.parametrize("case", ["dipping_polynomial", "lights_on_the_surface", "far_from_origin",
                                  "grazing_and_behind", "maps_and_phong", "bright_and_dim"])
def test_budget_holds_on_adversarial_scenes(case):
    """Cases that break a careless bound: p(d) with c1 < 0 (minimum away from the
    nearest distance), lights inside the tiles' boxes (d⁻ = 0), a scene 10⁴ units
    from the world origin, lights behind and grazing the surface (the n·l bound and
    the specular gate), per-pixel k_d/k_s/C_s maps, and 10⁶ dynamic range."""
    rng = np.random.default_rng(3)
    eps = 2e-3
    kw = dict(model="blinn-phong", h=25.0)
    maps = ()
    offset = np.zeros(3)
    if case == "dipping_polynomial":
        # p(d) = 1 − 1.9d + d² dips to 0.0975 at d = 0.95: the nearest distance is not the worst
        lights = point_lights(rng, 60, att=(1.0, -1.9, 1.0), intensity=(0.01, 0.05))
    elif case == "lights_on_the_surface":
        lights = point_lights(rng, 60, height=(-0.3, 0.3), att=(1.0, 0.0, 200.0))
    elif case == "far_from_origin":
        offset = np.array([1.0e4, -2.0e4, 5.0e3])
        lights = point_lights(rng, 60, offset=offset)
        kw["camera"] = dict(type="perspective", position=tuple(offset + [2.0, 2.0, 4.0]))
    elif case == "grazing_and_behind":
        lights = point_lights(rng, 60, height=(-1.0, 0.02), att=(1.0, 0.0, 100.0))
        kw.update(model="phong", h=3.0)
    elif case == "maps_and_phong":
        lights = point_lights(rng, 60)
        maps = ("k_d", "k_s", "specular_color")
        kw.update(model="phong", h=8.0)
    else:
        lights = point_lights(rng, 60, att=(1e-3, 0.0, 50.0), intensity=(1e-3, 1e3))
    gb = heightfield(rng, offset=offset, maps=maps)
    lights.append(dict(type="directional", direction=(0.3, 0.2, -1.0), intensity=0.5))
    lights.append(dict(type="ambient", intensity=0.2))
    check_budget_holds(make_scene(lights, **kw), gb, eps)


def _spots(rng, n, *, outer=(6.0, 12.0), height=(0.8, 1.5), att=(1.0, 0.0, 1.0)):
    """Spots over the heightfield pointing straight down (axis −z), narrow cones."""
    out = []
    for _ in range(n):
        o = float(rng.uniform(*outer))
        out.append(dict(type="spot", position=(float(rng.uniform(0, 4.4)), float(rng.uniform(0, 3.6)),
                                               float(rng.uniform(*height))),
                        direction=(0.0, 0.0, -1.0), inner_angle=o / 2, outer_angle=o,
                        color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(1, 3)),
                        attenuation=att))
    return out


@pytest.mark.parametrize("eps", [1e-5, 1e-3])
def test_spot_cones_cull_the_tiles_they_miss(eps):
    """Spots pointing down with 6-12° cones light a small disc each. The bound of a
    spot in a tile uses the cone: a tile whose box lies wholly outside the cone
    (cos θ over the box, here (L_z − lo_z)/distance to the box for the axis −z, below
    cos outer by a margin) gets the bound 0 and drops the spot at any budget; without
    the cone the bound is that of a point light, ≈ I·(D + S)/(1 + d²), far above ε.
    The budget holds (both checks), points and spots mixed."""
    rng = np.random.default_rng(11)
    gb = heightfield(rng)
    spots = _spots(rng, 30)
    scene = make_scene(spots + point_lights(rng, 10, att=(1.0, 0.0, 1e3)), model="blinn-phong", h=20.0)
    r, _, cull = check_budget_holds(scene, gb, eps)
    lists = read_tile_lists(r.runtime, cull)
    tile = tile_of_pixels(gb.shape, r.lanes).reshape(-1)
    fg = ~gb.background_mask().reshape(-1)
    P = gb.position.reshape(-1, 3).astype(np.float64)
    outside = 0
    shaded_tiles = np.unique(tile[fg])
    for t in shaded_tiles:
        box = P[fg & (tile == t)]
        lo, hi = box.min(axis=0), box.max(axis=0)
        for j, sp in enumerate(spots):
            L = np.asarray(sp["position"])
            d_lo = np.linalg.norm(np.maximum(lo - L, 0) + np.maximum(L - hi, 0))
            cos_hi = (L[2] - lo[2]) / d_lo
            if cos_hi < np.cos(np.radians(sp["outer_angle"])) - 1e-4:
                outside += 1
                assert j not in lists[t], f"tile {t} keeps spot {j}, whose cone misses its box"
    assert outside > 0.3 * len(spots) * len(shaded_tiles)    # many pairs lie outside the cones


@pytest.mark.parametrize("lanes", [1, 4])
def test_other_lane_widths_and_odd_sizes(lanes, device):
    """Work-items that wrap onto the next row are bounded with the tile that shades them."""
    skip_unless_lanes(lanes, device)
    rng = np.random.default_rng(5)
    gb = heightfield(rng, 23, 35)
    scene = make_scene(point_lights(rng, 50), model="phong", h=10.0)
    brute = Renderer(scene, lanes=lanes, device=device).render(gb).image
    r = Renderer(scene, lanes=lanes, max_error=1e-3, device=device)
    result = r.render(gb)
    out = result.image
    dropped = dropped_sum(scene, gb, r, result.cull)
    assert dropped.max(initial=0.0) <= 1e-3
    # culled vs brute force: the dropped sum plus the two sums' roundings (2·3u·Σ|c|, error model)
    tol = 1e-3 + 6 * U * np.abs(brute).astype(np.float64) + 1e-7
    assert np.all(np.abs(out.astype(np.float64) - brute) <= tol)


# ------------------------------------------------------------------------- what is never culled

def test_directional_and_ambient_lights_are_never_culled(device):
    rng = np.random.default_rng(9)
    gb = heightfield(rng, 20, 20)
    lights = [dict(type="directional", direction=(0.1, 0.0, -1.0), intensity=1e-6),
              dict(type="ambient", intensity=1e-6)]
    scene = make_scene(lights, k_a=1.0)
    r = Renderer(scene, max_error=1.0, device=device)     # a budget far above every term
    assert r.plan_for(()).defines["CULLING"] == 0
    assert np.array_equal(r.render(gb).image, Renderer(scene, device=device).render(gb).image)


# ---------------------------------------------------------------------- options and the cache

def test_negative_or_nonfinite_budget_is_an_error(device):
    scene = make_scene([dict(type="point", position=(0.0, 0.0, 1.0))])
    for bad in (-1e-3, float("nan"), float("inf")):
        with pytest.raises(CullingError, match="--max-error"):
            Renderer(scene, max_error=bad, device=device)
    with pytest.raises(CullingError, match="--reference-white"):
        Renderer(scene, max_error=1e-3, reference_white=0.0, device=device)


def test_plan_says_why_culling_is_on():
    from clphong.device.plan import make_plan

    scene = make_scene([dict(type="point", position=(0.0, 0.0, 1.0))])
    text = str(make_plan(scene, (), lanes=8, max_error=1e-3))
    assert "-DCULLING=1" in text and "ε = 0.001" in text
    assert "-DCULLING=0" in str(make_plan(scene, (), lanes=8))


def test_second_render_builds_nothing(device):
    from clphong.device.selection import get_runtime

    rng = np.random.default_rng(2)
    gb = heightfield(rng, 16, 16)
    scene = make_scene(point_lights(rng, 10), h=5.0)
    Renderer(scene, max_error=1e-3, device=device).render(gb).image
    rt = get_runtime(device=device)
    before = rt.builds
    Renderer(scene, max_error=1e-3, device=device).render(gb).image
    assert rt.builds == before


@pytest.mark.parametrize("case", ["diffuse", "specular", "dipping_polynomial"])
def test_budget_holds_where_the_bound_is_tight(case):
    """100 identical lights stacked above one pixel of a flat, uniform tile, seen from
    above: under the light n·l = 1 and (Blinn, orthographic camera) n·h = 1, so a
    light's contribution there equals its bound, and the culler must stop at ε. The
    dipping polynomial p(d) = 1 − 1.9d + d² is smallest at d = 0.95, which pixels of
    the tile reach while the nearest is 0.5 away. Each light's bound is ε/10, so
    about 9 are dropped and the dropped sum must come close to ε without passing it
    (an under-estimating bound, e.g. p(d⁻) for the dipping polynomial or no specular
    term, fails here)."""
    eps = 1e-3
    h = w = 20
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) * 0.1
    P = np.stack([xs, ys, np.zeros_like(xs)], -1)
    N = np.broadcast_to([0.0, 0.0, 1.0], P.shape)
    gb = make_gbuffer(P, N, np.full(P.shape, 0.5))
    k_d, k_s = (0.01, 1.0) if case == "specular" else (0.8, 0.0)
    att, height = ((1.0, -1.9, 1.0), 0.5) if case == "dipping_polynomial" else ((1.0, 0.0, 4.0), 0.3)
    c0, c1, c2 = att
    p_min = c0 - c1 * c1 / (4 * c2) if c1 < 0 else c0 + c1 * height + c2 * height ** 2
    intensity = eps / 10 * p_min / (0.5 * k_d + k_s)
    lights = [dict(type="point", position=(0.4, 0.4, height), intensity=intensity, attenuation=att)
              for _ in range(100)]
    scene = make_scene(lights, model="blinn-phong", k_a=0.0, k_d=k_d, k_s=k_s, h=10.0,
                       camera=dict(type="orthographic", direction=(0.0, 0.0, -1.0)))
    r, dropped, _ = check_budget_holds(scene, gb, eps)
    # tight: 9 of the 100 go (2 within ε/4 at the super-tile level, 7 within 3ε/4 at
    # the tile level, cull.py), so the dropped sum is ~0.9ε; under the dipping light
    # the worst pixel sees n·l = 0.53
    assert (0.35 if case == "dipping_polynomial" else 0.7) * eps <= dropped.max() <= eps


def test_what_a_level_leaves_unused_is_never_more_than_it_left(monkeypatch):
    """culling._cull_level's unused budget (the light tree's cut adds the super-tiles'
    to its own share) against the exact sum: 100 identical lights above one pixel of a
    flat tile, each contributing exactly ε/10 there (the bound's own value: n·l = 1 at
    the nearest distance); the super-tiles' level, with ε/4, drops 2 of them, so what it
    left is at most ε/4 − 2ε/10 of the budget, and (the bound being tight) not much less."""
    eps = 1e-3
    ys, xs = np.mgrid[0:20, 0:20].astype(np.float64) * 0.1
    P = np.stack([xs, ys, np.zeros_like(xs)], -1)
    gb = make_gbuffer(P, np.broadcast_to([0.0, 0.0, 1.0], P.shape), np.full(P.shape, 0.5))
    p_min = 1.0 + 4.0 * 0.3 ** 2
    lights = [dict(type="point", position=(0.4, 0.4, 0.3), intensity=eps / 10 * p_min / 0.4,
                   attenuation=(1.0, 0.0, 4.0)) for _ in range(100)]
    scene = make_scene(lights, model="blinn-phong", k_a=0.0, k_d=0.8, k_s=0.0, h=10.0,
                       camera=dict(type="orthographic", direction=(0.0, 0.0, -1.0)))
    levels = record_calls(monkeypatch, culling, "_cull_level")
    r = Renderer(scene, max_error=eps)
    r.shade(prepare_frame(gb, lanes=r.lanes))
    c_ranges, unused = levels[0][0], levels[0][5]
    dropped = 100 - int(c_ranges[0, 1])
    share = eps * culling.COARSE_SHARE
    assert dropped == 2
    # each dropped light takes ε/10 from the pixel below it: the rest is all there is
    assert dropped * eps / 10 + unused[0] * share <= share * (1 + 1e-9)
    assert unused[0] * share >= (share - dropped * eps / 10) * 0.999


def test_cli_render_with_a_budget(tmp_path, capsys):
    """--max-error through the CLI: within ε of brute force; a bad budget is one line, exit 1."""
    from conftest import GBUFFERS

    from clphong.console.cli import main
    from clphong.io.gbuffer import read_gbuffer

    args = ["render", str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]
    assert main(args + ["-o", str(tmp_path / "brute.exr")]) == 0
    assert main(args + ["-o", str(tmp_path / "cull.exr"), "--max-error", "1e-3", "--stats"]) == 0
    assert "culling:" in capsys.readouterr().err
    brute = read_gbuffer(str(tmp_path / "brute.exr"), channels={"position": "R,G,B", "normal": "R,G,B",
                                                              "albedo": "R,G,B"}).position
    culled = read_gbuffer(str(tmp_path / "cull.exr"), channels={"position": "R,G,B", "normal": "R,G,B",
                                                               "albedo": "R,G,B"}).position
    assert np.all(np.abs(culled.astype(np.float64) - brute) <= 1e-3 + 6 * U * np.abs(brute))
    assert main(args + ["-o", str(tmp_path / "float.exr"), "--path", "float", "--stats"]) == 0
    assert "-DDIRECTIONS_FP64=0" in capsys.readouterr().err
    assert main(args + ["-o", str(tmp_path / "bad.exr"), "--max-error", "-1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clphong: error: --max-error")
    assert not (tmp_path / "bad.exr").exists()


def test_second_culled_render_process_rebuilds_nothing(tmp_path):
    """`clphong render --max-error` twice: the second process finds the shading and the
    culling programs in clphong's binary store (and, on PoCL, their compiled work-group
    functions in PoCL's disk cache)."""
    import os
    import subprocess
    import sys

    from conftest import GBUFFERS

    from clphong.device.selection import get_runtime

    cache = tmp_path / "pocl-cache"
    env = dict(os.environ, POCL_CACHE_DIR=str(cache), CLPHONG_CACHE_DIR=str(tmp_path / "clphong"))
    cmd = [sys.executable, "-m", "clphong", "render", str(GBUFFERS / "spheres.toml"),
           str(GBUFFERS / "spheres.exr"), "-o", str(tmp_path / "out.exr"), "--max-error", "1e-3"]
    runs = []
    for _ in range(2):
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        # PoCL's built programs are <hash>/<hash>/program.bc, compiled kernels
        # .../<kernel>/*/*.so; clphong's binaries *.poclbin (on PoCL) or *.clbin
        runs.append({str(p.relative_to(tmp_path)): p.stat().st_mtime_ns
                     for pattern in ("program.bc", "*.so", "*.poclbin", "*.clbin")
                     for p in tmp_path.rglob(pattern)})
    kept = [p for p in runs[0] if p.endswith((".poclbin", ".clbin"))]
    assert any("cull" in p for p in kept) and any("shade" in p for p in kept)
    if get_runtime().is_pocl:
        assert len([p for p in runs[0] if p.endswith("program.bc")]) >= 2   # shade.cl and cull.cl
        assert any("cull_write" in p for p in runs[0])
    assert runs[1] == runs[0], "the second process built a program again"


def test_budget_holds_with_negative_albedo():
    """Negative albedo (allowed by the error model, e.g. to cancel a highlight) makes
    contributions negative: the budget bounds |dropped sum|, so |D| enters the bound."""
    rng = np.random.default_rng(12)
    gb = heightfield(rng)
    gb.albedo[...] = rng.uniform(-1.0, 1.0, gb.albedo.shape).astype(np.float32)
    r, dropped, _ = check_budget_holds(make_scene(point_lights(rng, 60), h=12.0), gb, 1e-3)
    assert np.abs(dropped).max() <= 1e-3


# ------------------------------------------------------------------ plan: falloff compiled out

def test_constant_falloff_compiles_the_polynomial_out(device):
    """c1 = c2 = 0 for every point light: HAS_ATTENUATION=0 (1/c0 once per light),
    still within the error model's bound of the float64 reference."""
    from conftest import check_against_reference, random_gbuffer

    rng = np.random.default_rng(21)
    lights = [dict(type="point", position=tuple(rng.uniform(-3, 3, 3) + [0, 0, 3]),
                   intensity=float(rng.uniform(1, 5)), attenuation=(float(c0), 0.0, 0.0))
              for c0 in (1.0, 2.5, 0.3)]
    scene = make_scene(lights, model="blinn-phong", h=20.0)
    assert Renderer(scene, device=device).plan_for(()).defines["HAS_ATTENUATION"] == 0
    check_against_reference(scene, random_gbuffer(rng, 12, 20), device=device)
    lights[0]["attenuation"] = (1.0, 0.0, 1e-3)
    assert Renderer(make_scene(lights), device=device).plan_for(()).defines["HAS_ATTENUATION"] == 1


@pytest.mark.parametrize("maps", [(), ("k_d", "k_s", "h", "specular_color")])
def test_super_tile_bounds_merged_from_tiles_equal_direct_bounds(maps, device):
    """merge_bounds (super-tiles from the tiles' records, one pass over the frame) is
    bit-identical to tile_bounds run on the super-tiles themselves."""
    import pyopencl as cl

    from clphong.device import culling as cull

    rng = np.random.default_rng(21)
    gb = heightfield(rng, 70, 203, maps=maps)           # odd sizes: partial tiles and super-tiles
    scene = make_scene([dict(type="point", position=(1.0, 1.0, 0.5))], k_s=0.3)
    r = Renderer(scene, max_error=1e-3, device=device)
    frame = prepare_frame(gb, lanes=r.lanes)
    plan = r.plan_for(frame.map_names)
    rt = r.runtime
    lanes = max(plan.lanes, 1)
    sup = max(cull.SUPER, lanes)
    defines = {k: v for k, v in plan.defines.items() if k in cull.CULL_DEFINES}
    prog = rt.program("cull.cl", {**defines, "CULL_TILE": cull.TILE, "CULL_SUPER": sup, "LANES": lanes})
    h, w = frame.shape
    tiles_x = -(-(-(-w // cull.TILE)) // sup) * sup
    tiles_y = -(-h // cull.TILE)
    super_x, super_y = tiles_x // sup, -(-tiles_y // sup)
    mf = cl.mem_flags
    g = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=frame.gbuf)
    mp = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=frame.maps)
    k_d, S = 0.7, np.array([0.3, 0.3, 0.3])
    fine, _ = cull._tile_bounds(rt, prog, frame, g, mp, k_d=k_d, S=S, tile_size=cull.TILE,
                                tiles_x=tiles_x, tiles_y=tiles_y, lanes=lanes)
    merged, _ = cull._merge_bounds(rt, prog, fine, fine_tiles_x=tiles_x, fine_tiles_y=tiles_y,
                                   sup=sup, tiles_x=super_x, tiles_y=super_y, lanes=lanes, wait_for=None)
    direct, _ = cull._tile_bounds(rt, prog, frame, g, mp, k_d=k_d, S=S, tile_size=cull.TILE * sup,
                                  tiles_x=super_x, tiles_y=super_y, lanes=lanes)
    n_pad = cull._n_pad(super_x * super_y, lanes)
    a = np.empty(cull.T_PLANES * n_pad, np.float32)
    b = np.empty_like(a)
    cl.enqueue_copy(rt.queue, a, merged)
    cl.enqueue_copy(rt.queue, b, direct)
    rt.queue.finish()
    assert np.isfinite(a[: super_x * super_y]).all()     # at least the lo.x plane of real tiles
    assert np.array_equal(a.view(np.uint32), b.view(np.uint32))


# ------------------------------------------------------------- when culling cannot drop

def test_lists_that_keep_nearly_every_light_fall_back_to_brute_force(monkeypatch, device):
    """Lights that reach everywhere (c2 small against the budget): the lists keep
    more than BRUTE_ABOVE of them, so the frame is shaded brute force, bit-identical
    to a run without a budget, and the result says so (the lists' time and kept
    share stay in result.cull). A small-reach scene still shades through its lists."""
    monkeypatch.setattr(culling, "BRUTE_ABOVE", BRUTE_ABOVE)
    rng = np.random.default_rng(11)
    gb = heightfield(rng, 40, 64)
    wide = make_scene(point_lights(rng, 24, att=(1.0, 0.1, 0.05)), model="blinn-phong", h=20.0)
    r = Renderer(wide, max_error=1e-3, device=device)
    result = r.render(gb)
    assert result.cull is not None and result.cull.kept_fraction > BRUTE_ABOVE
    assert result.cull.brute and result.plan.defines["CULLING"] == 0
    assert result.cull.seconds > 0
    assert np.array_equal(result.image, Renderer(wide, device=device).render(gb).image)

    small = make_scene(point_lights(rng, 24, att=(1.0, 0.0, 1e6)), model="blinn-phong", h=20.0)
    result = Renderer(small, max_error=1e-3, device=device).render(gb)
    assert result.cull.kept_fraction <= BRUTE_ABOVE
    assert not result.cull.brute and result.plan.defines["CULLING"] == 1


@pytest.mark.parametrize("outer", [60.0, 89.99, 90.0])
def test_a_spot_facing_away_is_dropped_at_any_budget(outer):
    """A spot above the surface pointing straight up lights none of it (cos θ < 0 at
    every pixel, even for outer = 90°, whose factor reaches 0 exactly at the plane):
    every tile drops it at ε = 0, where only a bound of exactly 0 may be dropped, and
    the image is the brute-force one bit for bit."""
    rng = np.random.default_rng(12)
    gb = heightfield(rng)
    spot = dict(type="spot", position=(2.0, 1.5, 1.0), direction=(0.0, 0.0, 1.0),
                inner_angle=outer / 2, outer_angle=outer, intensity=3.0)
    scene = make_scene([spot] + point_lights(rng, 5), model="blinn-phong", h=20.0)
    r = Renderer(scene, max_error=0.0)
    result = r.render(gb)
    assert np.array_equal(result.image, Renderer(scene).render(gb).image)
    lists = read_tile_lists(r.runtime, result.cull)
    assert not any(0 in idx for idx in lists)
    assert sum(len(idx) for idx in lists) > 0


def test_culling_that_lost_is_skipped_for_a_few_frames_then_tried_again(monkeypatch):
    """Lists that keep nearly every light fall back to brute force (cull.brute); the
    renderer then shades its next CULL_RETRY frames brute force without building lists
    (cull None, the same pixels), and tries the lists again after them."""
    import clphong.device.renderer as R

    monkeypatch.setattr(R, "CULL_RETRY", 2)
    monkeypatch.setattr(culling, "BRUTE_ABOVE", 0.85)   # the fallback (this file's fixture lifts it)
    rng = np.random.default_rng(8)
    gb = heightfield(rng, 23, 35)
    scene = make_scene(point_lights(rng, 40, att=(1.0, 0.0, 0.01)), model="phong", h=10.0)
    r = Renderer(scene, max_error=0.0)              # 0: drops only lights whose bound is 0
    results = [r.render(gb) for _ in range(4)]
    assert results[0].cull is not None and results[0].cull.brute
    assert results[1].cull is None and results[2].cull is None
    assert results[3].cull is not None and results[3].cull.brute
    assert all(x.plan.defines["CULLING"] == 0 for x in results)
    assert all(np.array_equal(x.image, results[0].image) for x in results)


def test_the_probe_samples_super_tiles_with_shaded_tiles_evenly():
    """culling._probe: one super-tile in PROBE_EVERY (rounded up) among those with shaded
    tiles, spread over them; the others' ranges emptied, offsets kept; None where the sample
    would be every super-tile."""
    PROBE_EVERY, _probe = culling.PROBE_EVERY, culling._probe
    sup, super_x = 2, 10                    # 4 rows of super-tiles
    tiles_x = sup * super_x
    ranges = np.stack([np.arange(40, dtype=np.uint32) * 7, np.full(40, 5, np.uint32)], 1)
    # shaded: every tile of the top three super-tile rows, one tile of the last row's first
    ty, tx = np.mgrid[0:3 * sup, 0:tiles_x]
    shaded = np.concatenate([(ty * tiles_x + tx).ravel(), [(3 * sup) * tiles_x]])
    got, active = _probe(ranges, np.repeat(shaded, 3), tiles_x=tiles_x, sup=sup, super_x=super_x)
    kept = np.flatnonzero(got[:, 1])
    assert len(kept) == -(-31 // PROBE_EVERY)                   # 30 full + 1 with one tile
    assert np.all(np.diff(kept) >= PROBE_EVERY - 1) and kept.max() <= 30
    assert np.array_equal(got[:, 0], ranges[:, 0]) and np.all(got[kept, 1] == 5)
    assert active == sum(sup * sup if k < 30 else 1 for k in kept)
    one = np.arange(sup)                                         # one super-tile's tiles
    assert _probe(ranges, one, tiles_x=tiles_x, sup=sup, super_x=super_x) is None


@pytest.mark.parametrize("shape", [(1080, 1920), (37, 53), (5, 7)])
@pytest.mark.parametrize("lanes", [1, 4, 16])
def test_active_tiles_counts_the_tiles_of_shaded_pixels(shape, lanes):
    """culling.active_tiles (a work-item at a time) counts the tiles that tile_of_pixels
    gives the shaded pixels (a pixel at a time), with rows that split work-items."""
    from types import SimpleNamespace

    from clphong.device.culling import TILE, active_tiles, tile_of_pixels

    rng = np.random.default_rng(lanes)
    tiles_x = -(-shape[1] // TILE)
    for share in (0.0, 0.5, 0.999, 1.0):
        bg = rng.random(shape) < share
        want = np.unique(tile_of_pixels(shape, lanes, tiles_x).reshape(-1)[~bg.reshape(-1)]).size
        assert active_tiles(SimpleNamespace(shape=shape, background=bg), lanes, tiles_x) == want

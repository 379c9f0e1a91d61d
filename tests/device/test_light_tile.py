"""The GPU's kernel shape, run on every device present: light records staged through
local memory a work-group's worth at a time (the plan's LIGHT_TILE) give the same pixels,
to the bit, as each work-item reading them itself, and both match the float64 reference.

The staged loop is what a GPU runs by default (``Runtime.light_tile``); here it is forced
on the CPU platforms, with light counts that are not multiples of the tile, light groups
(whose ranges start and end inside a tile), spots, directional lights, culling beside a
staged directional loop, background work-groups and coverage.
"""

import warnings

import numpy as np
import pytest
from conftest import heightfield, point_lights

from clphong.device.frame import LOCAL_SIZE
from clphong.device.renderer import Renderer
from clphong.model.scene import parse_scene
from clphong.reference import shading as reference


def _scene(rng, n_point, n_dir, *, groups=(), spots=0, model="phong"):
    lights = point_lights(rng, n_point, att=(1.0, 0.2, 2.0))
    for j in range(spots):
        lights.append(dict(type="spot", position=(float(rng.uniform(0, 4)), float(rng.uniform(0, 3.5)),
                                                  float(rng.uniform(0.5, 2.0))),
                           direction=(0.1, -0.1, -1.0), inner_angle=10.0, outer_angle=35.0,
                           intensity=2.0, attenuation=(1.0, 0.0, 0.5)))
    for j in range(n_dir):
        lights.append(dict(type="directional", direction=tuple(rng.normal(size=3) - [0, 0, 2.0]),
                           color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(0.1, 0.5))))
    lights.append(dict(type="ambient", intensity=0.2))
    if groups:
        for k, lt in enumerate(lights):
            lt["group"] = groups[k % len(groups)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return parse_scene({"camera": {"type": "perspective", "position": [2.0, 1.5, 6.0]},
                            "material": {"model": model, "k_a": 0.1, "k_d": 0.6, "k_s": 0.3,
                                         "h": 24.0},
                            "light": lights}, "light-tile.toml")


CASES = {
    # (point, directional, groups, spots, model, max_error)
    "one-tile-and-a-bit": (LOCAL_SIZE + 1, 0, (), 0, "phong", None),
    "fewer-than-a-tile": (5, 3, (), 0, "blinn-phong", None),
    "directional-many": (0, 2 * LOCAL_SIZE + 7, (), 0, "phong", None),
    "groups": (3 * LOCAL_SIZE // 2, 40, ("key", "fill", "rim"), 0, "blinn-phong", None),
    "spots": (70, 0, (), 9, "phong", None),
    "culled-points-staged-directional": (90, 70, (), 0, "phong", 1e-3),
}


@pytest.mark.parametrize("path", ["accurate", "fast"])
@pytest.mark.parametrize("case", list(CASES))
def test_staged_lights_are_bit_identical_and_within_the_bound(case, path, device):
    n_point, n_dir, groups, spots, model, max_error = CASES[case]
    rng = np.random.default_rng(len(case) * 7 + n_point)
    scene = _scene(rng, n_point, n_dir, groups=groups, spots=spots, model=model)
    gb = heightfield(rng, 37, 45)
    kw = dict(device=device, path=path, max_error=max_error)
    plain = Renderer(scene, light_tile=False, **kw).render(gb)
    staged = Renderer(scene, light_tile=True, **kw).render(gb)
    assert plain.plan.defines["LIGHT_TILE"] == 0
    assert staged.plan.defines["LIGHT_TILE"] == LOCAL_SIZE      # the launch's work-group
    assert np.array_equal(plain.image, staged.image)
    for name in plain.layers:
        assert np.array_equal(plain.layers[name], staged.layers[name]), name
    # a tile larger or smaller than the work-group: each work-item loads several, or none
    for tile in (3 * LOCAL_SIZE, 24):
        other = Renderer(scene, light_tile=tile, **kw).render(gb)
        assert other.plan.defines["LIGHT_TILE"] == tile and np.array_equal(other.image, plain.image)
    bound, _ = reference.error_bound(scene, gb, origin=None if staged.plan.defines.get(
        "DIRECTIONS_FP64") else _origin(gb, staged), plan=staged.plan)
    if max_error is None:         # culling adds its budget: the bound above is brute force's
        err = np.abs(staged.image.astype(np.float64) - reference.shade(scene, gb))
        assert (err <= bound).all(), float((err / np.where(bound > 0, bound, 1)).max())


def _origin(gb, result):
    from clphong.device.frame import prepare_frame
    return prepare_frame(gb, lanes=int(result.plan.defines.get("LANES", 1))).origin


def test_the_plan_stages_only_a_loop_that_exists():
    """LIGHT_TILE is 0 when there is nothing to stage: no lights, or only culled point
    lights (the culled loop reads its per-tile lists); the tile otherwise."""
    from clphong.device.plan import make_plan

    rng = np.random.default_rng(3)
    both = _scene(rng, 10, 2)
    points = _scene(rng, 10, 0)
    none = _scene(rng, 0, 0)
    assert make_plan(both, light_tile=64).defines["LIGHT_TILE"] == 64
    assert make_plan(both, light_tile=0).defines["LIGHT_TILE"] == 0
    assert make_plan(points, light_tile=64, max_error=1e-3).defines["LIGHT_TILE"] == 0
    assert make_plan(both, light_tile=64, max_error=1e-3).defines["LIGHT_TILE"] == 64
    assert make_plan(none, light_tile=64).defines["LIGHT_TILE"] == 0

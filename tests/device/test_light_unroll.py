"""The CPU's kernel shape, run on every device present: light loops that take 2, 4 or 8
lights an iteration (the plan's LIGHT_UNROLL) give the same pixels, to the bit, as one
light an iteration, and match the float64 reference within the error bound.

The unrolled loop is what Intel's CPU runtime runs by default (``Runtime.light_unroll``);
here every unroll is forced on every platform, with light counts below, at and past the
unroll and off its multiples (the remainder loop), light groups (whose ranges start and
end mid-iteration), spots, directional lights and the culled loop's per-tile lists.
"""

import numpy as np
import pytest
from test_light_tile import _origin, _scene

from conftest import heightfield

from clphong.device.plan import make_plan
from clphong.device.renderer import Renderer
from clphong.reference import shading as reference

CASES = {
    # (point, directional, groups, spots, model, max_error)
    "one-light": (1, 0, (), 0, "phong", None),
    "three-points-five-directional": (3, 5, (), 0, "blinn-phong", None),
    "off-every-multiple": (19, 11, (), 0, "phong", None),
    "groups": (23, 13, ("key", "fill", "rim"), 0, "blinn-phong", None),
    "spots": (9, 0, (), 7, "phong", None),
    "culled-lists": (45, 6, (), 0, "phong", 1e-3),
}


@pytest.mark.parametrize("path", ["accurate", "fast"])
@pytest.mark.parametrize("case", list(CASES))
def test_unrolled_light_loops_are_bit_identical_and_within_the_bound(case, path, device):
    n_point, n_dir, groups, spots, model, max_error = CASES[case]
    rng = np.random.default_rng(len(case) * 11 + n_point)
    scene = _scene(rng, n_point, n_dir, groups=groups, spots=spots, model=model)
    gb = heightfield(rng, 29, 37)
    kw = dict(device=device, path=path, max_error=max_error, light_tile=False)
    plain = Renderer(scene, light_unroll=0, **kw).render(gb)
    assert plain.plan.defines["LIGHT_UNROLL"] == 0
    for unroll in (2, 4, 8):
        other = Renderer(scene, light_unroll=unroll, **kw).render(gb)
        assert other.plan.defines["LIGHT_UNROLL"] == unroll
        assert np.array_equal(plain.image, other.image), unroll
        for name in plain.layers:
            assert np.array_equal(plain.layers[name], other.layers[name]), (unroll, name)
    if max_error is None:         # culling adds its budget: the bound is brute force's
        bound, _ = reference.error_bound(scene, gb, origin=None if other.plan.defines.get(
            "DIRECTIONS_FP64") else _origin(gb, other), plan=other.plan)
        err = np.abs(other.image.astype(np.float64) - reference.shade(scene, gb))
        assert (err <= bound).all(), float((err / np.where(bound > 0, bound, 1)).max())


def test_the_unroll_is_checked_and_named_in_the_plan():
    """A bad unroll is refused in one line naming the valid ones; the plan says why."""
    scene = _scene(np.random.default_rng(5), 4, 0)
    plan = make_plan(scene, light_unroll=4)
    assert plan.defines["LIGHT_UNROLL"] == 4
    assert "4 lights an iteration" in dict(plan.reasons)["LIGHT_UNROLL"]
    assert make_plan(scene).defines["LIGHT_UNROLL"] == 0
    with pytest.raises(ValueError, match="light_unroll must be one of 0, 2, 4, 8, not 3"):
        make_plan(scene, light_unroll=3)
    with pytest.raises(ValueError, match="light_unroll must be one of"):
        Renderer(scene, light_unroll=16)


def test_the_default_unroll_follows_the_platform(device):
    """Intel's CPU runtime unrolls by 4 on an AVX-512 host (measured there, Zen 5) and by
    2 on an AVX2 host (Zen 3); other platforms keep one light an iteration, as they were
    measured."""
    from clphong.device.hostrule import host

    r = Renderer(_scene(np.random.default_rng(6), 2, 0), device=device)
    expected = (4 if host().avx512 else 2) if r.runtime.kind == "intel-cpu" else 0
    assert r.light_unroll == expected
    assert r.render(heightfield(np.random.default_rng(6), 9, 11)).plan.defines[
        "LIGHT_UNROLL"] == expected

"""clphong.device.plan: which kernel variant (defines) a scene and device get."""

from __future__ import annotations

from conftest import make_scene


def test_plan_forms_the_cosine_and_weights_in_double_where_they_apply():
    """SPEC_COS needs double directions (or the fast path's float power) and the integer
    power (and an even k for Blinn, whose base is (n·h)²); WEIGHTS_FP64 needs double directions and the
    double sum. `clphong plan` says why either is off."""
    from clphong.device.plan import make_plan

    def defines(h, model="phong", **kw):
        scene = make_scene([dict(type="point", position=(0, 0, 3))], h=h, model=model)
        kw.setdefault("fp64_directions", True)
        kw.setdefault("has_fp64", True)
        plan = make_plan(scene, (), lanes=8, **kw)
        return plan.defines["SPEC_COS"], plan.defines["WEIGHTS_FP64"], str(plan)

    assert defines(37.0)[:2] == (1, 1)                       # Phong, any whole k
    assert defines(32.0, "blinn-phong")[:2] == (1, 1)        # k = 128, raised as (n·h)² to 64
    cos, w, text = defines(8.25, "blinn-phong")              # k = 33: odd
    assert (cos, w) == (0, 1) and "odd K = 33" in text
    assert defines(37.5)[:2] == (0, 1)                       # no integer power
    assert defines(37.0, int_pow=False)[:2] == (0, 1)
    cos, w, text = defines(37.0, fp64_directions=False)
    assert (cos, w) == (0, 0) and "directions in float" in text
    # the fast path (all in float, the power too) forms the cosine in float
    cos, w, text = defines(37.0, fp64_directions=False, int_pow="float", compensated=False)
    assert (cos, w) == (1, 0) and "in float" in text and "fast path" in text
    assert defines(32.0, "blinn-phong", fp64_directions=False, int_pow="float")[:2] == (1, 0)
    assert defines(8.25, "blinn-phong", fp64_directions=False, int_pow="float")[0] == 0
    assert defines(37.0, compensated=True)[1] == 0           # a float (Neumaier) sum
    assert defines(37.0, has_fp64=False, compensated=True)[:2] == (0, 0)


def test_plan_uses_the_integer_power_only_where_it_applies():
    from clphong.device.plan import INT_POW_MAX, make_plan

    def flag(h, model="phong", maps=(), **kw):
        scene = make_scene([dict(type="point", position=(0, 0, 3))], h=h, model=model)
        kw.setdefault("fp64_directions", True)
        return make_plan(scene, maps, lanes=8, **kw).defines["SPEC_INT_POW"]

    assert flag(32.0) == 1 and flag(0.0) == 1
    assert flag(0.25, "blinn-phong") == 1                # k = 4h = 1
    assert flag(0.3, "blinn-phong") == 0 and flag(37.5) == 0
    assert flag(INT_POW_MAX) == 1 and flag(INT_POW_MAX + 1.0) == 0
    assert flag(32.0, maps=("h",)) == 0                  # a shininess map: per-pixel k
    assert flag(32.0, fp64_directions=False, has_fp64=True) == 1   # float directions, double powers
    assert flag(32.0, fp64_directions=False, has_fp64=False) == 0  # no cl_khr_fp64
    assert flag(32.0, int_pow=False) == 0
    scene = make_scene([dict(type="point", position=(0, 0, 3))], k_s=0.0)
    assert make_plan(scene, (), lanes=8, fp64_directions=True).defines["SPEC_INT_POW"] == 0
    text = str(make_plan(make_scene([dict(type="point", position=(0, 0, 3))], h=37.5), (), lanes=8,
                         fp64_directions=True))
    assert "k = h = 37.5 is not a whole number" in text


def test_grey_specular_is_formed_once_only_where_the_channels_are_equal():
    """SPEC_GREY (one S·w_s a light for the three sums): a grey specular_color with no
    colour map and no Fresnel weight; any other case keeps three products."""
    from clphong.device.plan import make_plan

    def grey(maps=(), **kw):
        scene = make_scene([dict(type="point", position=(0, 0, 3))], model="blinn-phong", **kw)
        return make_plan(scene, maps, lanes=8).defines["SPEC_GREY"]

    assert grey() == 1                                            # the default, white
    assert grey(specular_color=(0.4, 0.4, 0.4)) == 1
    assert grey(maps=("k_s",)) == 1                               # a k_s map scales all three
    assert grey(specular_color=(0.4, 0.4, 0.4000001)) == 0
    assert grey(maps=("specular_color",)) == 0
    assert grey(fresnel="schlick", f0=(0.04, 0.04, 0.04)) == 0
    assert grey(k_s=0.0) == 0                                     # no specular term at all

"""Tests of clphong.model.scene: parsing, validation messages, warnings, attenuation."""

from __future__ import annotations

import copy
import math
import re
import sys
import warnings
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clphong.core.errors import SceneError
from clphong.model.scene import (
    LIGHT_TYPES,
    Camera,
    Light,
    Material,
    Scene,
    SceneWarning,
    attenuation_problem,
    kernel_falloff_bound,
    largest_falloff,
    load_scene,
    parse_scene,
)

README_TOML = """\
[camera]
type = "perspective"          # eye at `position`; v = normalize(eye − P)
position = [0.0, 2.0, 6.0]
# type = "orthographic"       # viewer at infinity: `direction` is the view direction (eye → scene)
# direction = [0, -0.5, -1]

[material]
model = "phong"               # or "blinn-phong"
k_a = 0.1
k_d = 0.7
k_s = 0.2
h = 32.0                      # shininess (Blinn-Phong uses exponent 4h)
# specular_color = [1,1,1]    # default white, so each highlight takes its light's colour

[render]                      # optional table
# background = [0, 0, 0]      # value written for background pixels (default 0)

[[light]]
type = "point"
position = [3.0, 5.0, 4.0]
color = [1.0, 0.9, 0.8]       # linear RGB in the working colour space
intensity = 25.0
attenuation = [1.0, 0.0, 0.0] # c0, c1, c2 of 1/(c0 + c1·d + c2·d²); default [1, 0, 0] = no falloff

[[light]]
type = "directional"
direction = [-1.0, -1.5, -1.0] # the direction the light TRAVELS; l = −normalize(direction)
color = [1.0, 1.0, 1.0]
intensity = 3.0

[[light]]
type = "ambient"              # E_A = C_d·k_a·color·intensity
color = [1.0, 1.0, 1.0]
intensity = 1.0
"""

SRC = "scene.toml"


def base() -> dict:
    """A valid scene as plain data (no warnings)."""
    return {
        "camera": {"type": "perspective", "position": [0.0, 2.0, 6.0]},
        "material": {"model": "phong", "k_a": 0.1, "k_d": 0.7, "k_s": 0.2, "h": 32.0},
        "light": [
            {"type": "point", "position": [3.0, 5.0, 4.0], "color": [1.0, 0.9, 0.8],
             "intensity": 25.0, "attenuation": [1.0, 0.0, 0.0]},
            {"type": "directional", "direction": [-1.0, -1.5, -1.0], "intensity": 3.0},
            {"type": "ambient", "color": [1.0, 1.0, 1.0], "intensity": 1.0},
        ],
    }


def parse_quietly(data, source=SRC) -> Scene:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SceneWarning)
        return parse_scene(data, source)


def error_of(data, source=SRC) -> str:
    with pytest.raises(SceneError) as info:
        parse_quietly(data, source)
    return str(info.value)


def assert_one_line(msg: str) -> None:
    assert msg and len(msg.splitlines()) == 1 and "\n" not in msg and "\r" not in msg


def set_at(data: dict, path: tuple, value) -> None:
    obj = data
    for p in path[:-1]:
        obj = obj[p]
    obj[path[-1]] = value


def drop_at(data: dict, path: tuple) -> None:
    obj = data
    for p in path[:-1]:
        obj = obj[p]
    del obj[path[-1]]


ORTHO = {"type": "orthographic", "direction": [0, -0.5, -1]}

# (id, mutation, key path the message must name, fragments it must contain)
ERROR_CASES = [
    # wrong types
    ("number-is-string", lambda d: set_at(d, ("light", 2, "intensity"), "bright"),
     "light[2].intensity", ["expected a number, got string 'bright'", "3rd [[light]]"]),
    ("number-is-numeric-string", lambda d: set_at(d, ("material", "k_d"), "0.7"),
     "material.k_d", ["expected a number", "without quotes"]),
    ("number-is-bool", lambda d: set_at(d, ("material", "h"), True),
     "material.h", ["expected a number, got boolean true"]),
    ("number-is-array", lambda d: set_at(d, ("material", "k_s"), [0.2]),
     "material.k_s", ["expected a number, got array"]),
    ("vector-is-number", lambda d: set_at(d, ("camera", "position"), 6.0),
     "camera.position", ["expected an array of 3 numbers", "float 6.0"]),
    ("vector-is-string", lambda d: set_at(d, ("light", 0, "position"), "1,2,3"),
     "light[0].position", ["expected an array of 3 numbers", "string '1,2,3'"]),
    ("vector-element-is-string", lambda d: set_at(d, ("light", 0, "color"), [1, "x", 1]),
     "light[0].color[1]", ["expected a number, got string 'x'"]),
    ("vector-element-is-bool", lambda d: set_at(d, ("camera", "position"), [0, False, 1]),
     "camera.position[1]", ["expected a number, got boolean false"]),
    ("vector-too-short", lambda d: set_at(d, ("light", 0, "color"), [1, 2]),
     "light[0].color", ["expected 3 numbers", "got 2"]),
    ("vector-too-long", lambda d: set_at(d, ("material", "specular_color"), [1, 1, 1, 1]),
     "material.specular_color", ["expected 3 numbers", "got 4"]),
    ("enum-is-number", lambda d: set_at(d, ("camera", "type"), 1),
     "camera.type", ["expected a string", "'perspective', 'orthographic'", "integer 1"]),
    ("light-type-is-array", lambda d: set_at(d, ("light", 1, "type"), ["point"]),
     "light[1].type", ["expected a string", "'point', 'spot', 'directional', 'ambient', 'environment'"]),
    ("camera-not-table", lambda d: set_at(d, ("camera",), "perspective"),
     "camera", ["expected a table"]),
    ("camera-array-of-tables", lambda d: set_at(d, ("camera",), [d["camera"]]),
     "camera", ["not [[camera]]"]),
    ("light-single-table", lambda d: set_at(d, ("light",), d["light"][0]),
     "light", ["not [light]"]),
    ("light-not-array", lambda d: set_at(d, ("light",), 3),
     "light", ["expected an array of tables", "integer 3"]),
    ("light-element-not-table", lambda d: set_at(d, ("light", 1), 3),
     "light[1]", ["expected a table, got integer 3"]),
    ("render-not-table", lambda d: set_at(d, ("render",), [0, 0, 0]),
     "render", ["expected a table"]),
    ("background-is-string", lambda d: set_at(d, ("render",), {"background": "black"}),
     "render.background", ["expected a number or an array of 3 numbers"]),
    # unknown keys, with did-you-mean
    ("unknown-top-table", lambda d: set_at(d, ("materal",), {}),
     "materal", ["unknown key; did you mean 'material'?"]),
    ("unknown-top-plural", lambda d: set_at(d, ("lights",), []),
     "lights", ["expected the name of a lights file", "[[light]], not [[lights]]"]),
    ("lights-file-is-number", lambda d: set_at(d, ("lights",), 3),
     "lights", ["expected the name of a lights file (.csv or .npz", "integer 3"]),
    ("unknown-top-near-lights", lambda d: set_at(d, ("lightss",), "rig.csv"),
     "lightss", ["unknown key; did you mean 'lights'?"]),
    ("unknown-top-far", lambda d: set_at(d, ("zzzz",), 1),
     "zzzz", ["unknown key; valid keys are 'camera', 'material', 'render', 'light'"]),
    ("unknown-material-key", lambda d: set_at(d, ("material", "k_dd"), 0.7),
     "material.k_dd", ["unknown key; did you mean 'k_d'?"]),
    ("unknown-material-far", lambda d: set_at(d, ("material", "roughness"), 0.7),
     "material.roughness", ["unknown key; valid keys are 'model', 'k_a'"]),
    ("unknown-camera-key", lambda d: set_at(d, ("camera", "positon"), [0, 0, 0]),
     "camera.positon", ["did you mean 'position'?"]),
    ("unknown-light-key", lambda d: set_at(d, ("light", 0, "colour"), [1, 1, 1]),
     "light[0].colour", ["did you mean 'color'?", "1st [[light]]"]),
    ("unknown-render-key", lambda d: set_at(d, ("render",), {"backgorund": 0}),
     "render.backgorund", ["did you mean 'background'?"]),
    ("unknown-quoted-key", lambda d: set_at(d, ("material", "k d"), 1),
     "material.'k d'", ["unknown key"]),
    ("unknown-key-with-newline", lambda d: set_at(d, ("material", "k\nd"), 1),
     "material.'k\\nd'", ["unknown key"]),
    # missing required keys
    ("missing-material", lambda d: drop_at(d, ("material",)),
     "material", ["missing required table [material]"]),
    ("missing-camera-type", lambda d: drop_at(d, ("camera", "type")),
     "camera.type", ["missing required key", "'perspective', 'orthographic'"]),
    ("missing-camera-position", lambda d: drop_at(d, ("camera", "position")),
     "camera.position", ["missing", "'perspective' camera"]),
    ("missing-camera-direction", lambda d: set_at(d, ("camera",), {"type": "orthographic"}),
     "camera.direction", ["missing", "'orthographic' camera"]),
    ("missing-material-model", lambda d: drop_at(d, ("material", "model")),
     "material.model", ["missing required key"]),
    ("missing-material-k_a", lambda d: drop_at(d, ("material", "k_a")),
     "material.k_a", ["missing required key"]),
    ("missing-material-k_d", lambda d: drop_at(d, ("material", "k_d")),
     "material.k_d", ["missing required key"]),
    ("missing-material-k_s", lambda d: drop_at(d, ("material", "k_s")),
     "material.k_s", ["missing required key"]),
    ("missing-material-h", lambda d: drop_at(d, ("material", "h")),
     "material.h", ["missing required key"]),
    ("missing-light-type", lambda d: drop_at(d, ("light", 2, "type")),
     "light[2].type", ["missing required key", "'point', 'spot', 'directional', 'ambient', 'environment'"]),
    ("missing-point-position", lambda d: drop_at(d, ("light", 0, "position")),
     "light[0].position", ["missing", "'point' light"]),
    ("missing-directional-direction", lambda d: drop_at(d, ("light", 1, "direction")),
     "light[1].direction", ["missing", "'directional' light"]),
    # keys that do not belong to the type
    ("attenuation-on-directional", lambda d: set_at(d, ("light", 1, "attenuation"), [1, 0, 0]),
     "light[1].attenuation", ["does not apply to a 'directional' light", "'point' and 'spot' lights"]),
    ("attenuation-on-ambient", lambda d: set_at(d, ("light", 2, "attenuation"), [1, 0, 0]),
     "light[2].attenuation", ["does not apply to an 'ambient' light"]),
    ("position-on-directional", lambda d: set_at(d, ("light", 1, "position"), [1, 0, 0]),
     "light[1].position", ["does not apply to a 'directional' light"]),
    ("direction-on-point", lambda d: set_at(d, ("light", 0, "direction"), [1, 0, 0]),
     "light[0].direction", ["does not apply to a 'point' light", "'directional' lights"]),
    ("direction-on-ambient", lambda d: set_at(d, ("light", 2, "direction"), [1, 0, 0]),
     "light[2].direction", ["does not apply to an 'ambient' light"]),
    ("position-on-orthographic", lambda d: set_at(d, ("camera",), dict(ORTHO, position=[0, 0, 1])),
     "camera.position", ["does not apply to an 'orthographic' camera"]),
    ("direction-on-perspective", lambda d: set_at(d, ("camera", "direction"), [0, 0, -1]),
     "camera.direction", ["does not apply to a 'perspective' camera"]),
    # bad enum values
    ("bad-model", lambda d: set_at(d, ("material", "model"), "phong2"),
     "material.model", ["invalid value 'phong2'", "expected one of 'phong', 'blinn-phong'"]),
    ("bad-model-case", lambda d: set_at(d, ("material", "model"), "Blinn-Phong"),
     "material.model", ["did you mean 'blinn-phong'?"]),
    ("bad-camera-type", lambda d: set_at(d, ("camera", "type"), "fisheye"),
     "camera.type", ["invalid value 'fisheye'", "'perspective', 'orthographic'"]),
    ("bad-light-type", lambda d: set_at(d, ("light", 0, "type"), "spotlight"),
     "light[0].type", ["invalid value 'spotlight'", "'point', 'spot', 'directional', 'ambient', 'environment'"]),
    # NaN / Inf anywhere
    ("nan-k_a", lambda d: set_at(d, ("material", "k_a"), float("nan")),
     "material.k_a", ["must be finite, got nan"]),
    ("inf-h", lambda d: set_at(d, ("material", "h"), float("inf")),
     "material.h", ["must be finite, got inf"]),
    ("neg-inf-position", lambda d: set_at(d, ("camera", "position"), [0, -math.inf, 0]),
     "camera.position[1]", ["must be finite, got -inf"]),
    ("nan-intensity", lambda d: set_at(d, ("light", 2, "intensity"), math.nan),
     "light[2].intensity", ["must be finite"]),
    ("nan-light-position", lambda d: set_at(d, ("light", 0, "position"), [math.nan, 0, 0]),
     "light[0].position[0]", ["must be finite"]),
    ("inf-direction", lambda d: set_at(d, ("light", 1, "direction"), [0, 0, math.inf]),
     "light[1].direction[2]", ["must be finite"]),
    ("nan-attenuation", lambda d: set_at(d, ("light", 0, "attenuation"), [1, math.nan, 0]),
     "light[0].attenuation[1]", ["must be finite"]),
    ("inf-background", lambda d: set_at(d, ("render",), {"background": [0, math.inf, 0]}),
     "render.background[1]", ["must be finite"]),
    ("nan-background-scalar", lambda d: set_at(d, ("render",), {"background": math.nan}),
     "render.background", ["must be finite"]),
    ("nan-specular", lambda d: set_at(d, ("material", "specular_color"), [1, 1, math.nan]),
     "material.specular_color[2]", ["must be finite"]),
    ("huge-int", lambda d: set_at(d, ("material", "h"), 10**400),
     "material.h", ["too large for a float64"]),
    # finite in float64 but not in the kernels' float32 (the render gave NaN pixels)
    ("light-position-beyond-float32", lambda d: set_at(d, ("light", 0, "position"), [1e300, 0, 0]),
     "light[0].position[0]", ["1e+300 is beyond the float32 range", "3.40282e+38"]),
    ("camera-position-beyond-float32", lambda d: set_at(d, ("camera", "position"), [0, -4e38, 0]),
     "camera.position[1]", ["-4e+38 is beyond the float32 range"]),
    ("h-beyond-float32", lambda d: set_at(d, ("material", "h"), 10**39),
     "material.h", ["1e+39 is beyond the float32 range"]),
    ("radiance-beyond-float32", lambda d: set_at(d, ("light", 0), dict(
        d["light"][0], color=[1.0, 1e10, 1.0], intensity=1e30)),
     "light[0].intensity", ["color x intensity = 1e+40 is beyond the float32 range"]),
    ("specular-beyond-float32", lambda d: set_at(d, ("material",), dict(
        d["material"], k_s=1e20, specular_color=[1, 1e19, 1])),
     "material.k_s", ["k_s x specular_color = 1e+39"]),
    ("blinn-exponent-beyond-float32", lambda d: set_at(d, ("material",), dict(
        d["material"], model="blinn-phong", h=1e38)),
     "material.h", ["the exponent 4h of 'blinn-phong' = 4e+38 is beyond the float32 range"]),
    ("ambient-sum-beyond-float32", lambda d: set_at(d, ("material", "k_a"), 1.0) or set_at(
        d, ("light",), d["light"] + [{"type": "ambient", "intensity": 3e38}] * 2),
     "material.k_a", ["summed radiance = 6e+38"]),
    # negative coefficients
    ("negative-k_a", lambda d: set_at(d, ("material", "k_a"), -0.1),
     "material.k_a", ["must be >= 0, got -0.1"]),
    ("negative-k_d", lambda d: set_at(d, ("material", "k_d"), -1),
     "material.k_d", ["must be >= 0, got -1.0"]),
    ("negative-k_s", lambda d: set_at(d, ("material", "k_s"), -0.2),
     "material.k_s", ["must be >= 0"]),
    ("negative-h", lambda d: set_at(d, ("material", "h"), -32.0),
     "material.h", ["must be >= 0"]),
    ("negative-intensity", lambda d: set_at(d, ("light", 1, "intensity"), -3.0),
     "light[1].intensity", ["must be >= 0"]),
    ("negative-color", lambda d: set_at(d, ("light", 0, "color"), [1.0, -0.9, 0.8]),
     "light[0].color[1]", ["must be >= 0, got -0.9"]),
    ("negative-specular-color", lambda d: set_at(d, ("material", "specular_color"), [-1, 1, 1]),
     "material.specular_color[0]", ["must be >= 0"]),
    # zero-length directions
    ("zero-camera-direction", lambda d: set_at(d, ("camera",), dict(ORTHO, direction=[0, 0, 0])),
     "camera.direction", ["zero-length vector"]),
    ("zero-light-direction", lambda d: set_at(d, ("light", 1, "direction"), [0.0, -0.0, 0]),
     "light[1].direction", ["zero-length vector"]),
    # attenuation that reaches zero or goes negative
    ("attenuation-c0-zero-negative-c1", lambda d: set_at(d, ("light", 0, "attenuation"), [0, -1, 1]),
     "light[0].attenuation", ["with c0 = 0", "both must be >= 0"]),
    ("power-and-intensity", lambda d: set_at(d, ("light", 0, "power"), 100),
     "light[0].power", ["or intensity, not both"]),
    ("power-and-attenuation", lambda d: (d["light"][0].pop("intensity"),
                                         set_at(d, ("light", 0, "power"), 100)),
     "light[0].power", ["or attenuation, not both"]),
    ("power-on-directional", lambda d: set_at(d, ("light", 1, "power"), 100),
     "light[1].power", ["does not apply to a 'directional' light"]),
    ("power-negative", lambda d: (d["light"][0].pop("intensity"), d["light"][0].pop("attenuation"),
                                  set_at(d, ("light", 0, "power"), -1)),
     "light[0].power", [">= 0"]),
    ("group-not-string", lambda d: set_at(d, ("light", 0, "group"), 3),
     "light[0].group", ["expected a group name"]),
    ("group-bad-name", lambda d: set_at(d, ("light", 0, "group"), "key.light"),
     "light[0].group", ["is not a light-group name", "NAME.R"]),
    ("group-aov-name", lambda d: set_at(d, ("light", 0, "group"), "specular"),
     "light[0].group", ["name of an AOV layer"]),
    ("aovs-unknown", lambda d: d.setdefault("render", {}).update(aovs=["diffuse", "keys"]),
     "render.aovs[1]", ["'keys' is neither a component (diffuse, specular) nor a light group"]),
    ("aovs-not-list", lambda d: d.setdefault("render", {}).update(aovs="diffuse"),
     "render.aovs", ["expected an array of layer names"]),
    ("albedo-space-empty", lambda d: d.setdefault("render", {}).update(albedo_space=" "),
     "render.albedo_space", ["expected a non-empty string (an OCIO colour space name)"]),
    ("attenuation-c0-negative", lambda d: set_at(d, ("light", 0, "attenuation"), [-1, 0, 1]),
     "light[0].attenuation", ["negative at d = 0"]),
    ("attenuation-linear-negative", lambda d: set_at(d, ("light", 0, "attenuation"), [1, -0.4, 0]),
     "light[0].attenuation", ["goes negative for d > 2.5"]),
    ("attenuation-c2-negative", lambda d: set_at(d, ("light", 0, "attenuation"), [1, 0, -0.25]),
     "light[0].attenuation", ["reaches 0 at d = 2 ", "goes negative for d > 2 "]),
    ("attenuation-two-roots", lambda d: set_at(d, ("light", 0, "attenuation"), [1, -3, 1]),
     "light[0].attenuation", ["goes negative for 0.381966 < d < 2.61803"]),
    ("attenuation-double-root", lambda d: set_at(d, ("light", 0, "attenuation"), [1, -2, 1]),
     "light[0].attenuation", ["reaches 0 at d = 1 ", "double root"]),
    ("attenuation-zero", lambda d: set_at(d, ("light", 0, "attenuation"), [0, 0, 0]),
     "light[0].attenuation", ["p(d) = 0 for every d"]),
    # top level
    ("top-not-table", lambda d: d.clear() or None, "material", ["missing required table"]),
]


@pytest.mark.parametrize("mutate, path, fragments",
                         [c[1:] for c in ERROR_CASES], ids=[c[0] for c in ERROR_CASES])
def test_error_names_file_and_key(mutate, path, fragments):
    data = base()
    mutate(data)
    msg = error_of(data)
    assert_one_line(msg)
    assert msg.startswith(f"{SRC}: {path}: "), msg
    for f in fragments:
        assert f in msg, msg


def test_only_products_need_the_float32_range():
    """Light colour and intensity reach the kernels only as their product, and k_a
    only times the ambient radiance: each may be beyond float32 alone."""
    data = base()
    data["light"][0].update(color=[1e-10, 2e-10, 1e-10], intensity=1e39)
    data["material"]["k_a"] = 1e39
    data["light"][2]["intensity"] = 1e-40
    s = parse_quietly(data)
    assert s.lights[0].radiance[1] == pytest.approx(2e29)
    assert s.material.k_a == 1e39


def test_light_messages_say_which_table():
    data = base()
    data["light"][1]["intensity"] = "x"
    assert "(light[1] is the 2nd [[light]])" in error_of(data)
    data = base()
    data["light"] = [{"type": "ambient"}] * 12 + [{"type": "ambient", "color": 1}]
    assert "light[12] is the 13th [[light]]" in error_of(data)


def test_top_level_must_be_a_table():
    msg = error_of([1, 2])
    assert_one_line(msg)
    assert msg.startswith("scene.toml: expected a table")


def test_first_unknown_key_in_order_is_reported():
    data = base()
    data["material"]["zz"] = 1
    data["material"]["k_dd"] = 1
    assert "material.zz:" in error_of(data)


def test_ints_accepted_and_stored_as_float():
    data = base()
    data["material"].update(k_a=0, k_d=1, k_s=0, h=32)
    data["light"][0]["position"] = [3, 5, 4]
    s = parse_quietly(data)
    for x in (s.material.k_a, s.material.k_d, s.material.h, *s.lights[0].position):
        assert type(x) is float
    assert s.material.h == 32.0


def test_numpy_scalars_accepted():
    data = base()
    data["material"]["h"] = np.float32(8.0)
    data["material"]["k_d"] = np.int64(0)
    s = parse_quietly(data)
    assert type(s.material.h) is float and s.material.h == 8.0
    assert type(s.material.k_d) is float


@pytest.mark.parametrize("att", [(0, 0, 1), (0, 1, 0), (0, 0.5, 2)])
def test_physical_attenuation_c0_zero_allowed(att):
    data = base()
    data["light"][0]["attenuation"] = list(att)
    assert parse_quietly(data).lights[0].attenuation == tuple(map(float, att))


def test_power_is_cycles_radiant_intensity_over_pi():
    """power = P watts: L = color·P/(4π²), 1/d² (radiant intensity P/(4π) W/sr times the
    Lambert BRDF's 1/π), computed here from the closed form, not from the module's constant."""
    data = base()
    light = data["light"][0]
    for k in ("intensity", "attenuation"):
        light.pop(k)
    light["power"] = 1000.0
    light["group"] = "key"
    lt = parse_quietly(data).lights[0]
    assert lt.attenuation == (0.0, 0.0, 1.0) and lt.power == 1000.0 and lt.group == "key"
    assert lt.intensity == pytest.approx(1000.0 / (4 * math.pi) / math.pi, rel=1e-15)
    again = parse_quietly({**data, "light": [lt.to_dict(), *data["light"][1:]]}).lights[0]
    assert again == lt


def test_negative_attenuation_coefficients_allowed_when_positive():
    data = base()
    data["light"][0]["attenuation"] = [1, -1, 1]       # discriminant < 0
    assert parse_quietly(data).lights[0].attenuation == (1.0, -1.0, 1.0)


F32_MAX = float(np.finfo(np.float32).max)
F32_MIN = float(np.finfo(np.float32).tiny)          # the smallest normal float32
U = 2.0 ** -24


def test_attenuation_that_float32_rounding_takes_to_zero_is_refused():
    """> 0 in float64 only (before: a warning, and p(d) = 0 in the float path)."""
    data = base()
    data["light"][0]["attenuation"] = [1, -2, 1 + 2**-52]
    msg = error_of(data)
    assert_one_line(msg)
    assert msg.startswith("scene.toml: light[0].attenuation: [1.0, -2.0, 1.0000000000000002]: "
                          "min p(d) = 2.22045e-16 is so close to 0")
    assert "float32" in msg


@pytest.mark.parametrize("att,k", [
    ([1e-40, 0, 0], 0),          # a float32 subnormal: 0 to the kernels (NaN pixels before)
    ([1e-320, 0, 0], 1 and 0),   # a float64 subnormal (only a warning before)
    ([F32_MIN / 2, 0, 0], 0),
    ([1, 1e-40, 0], 1),
    ([1, -1e-40, 1], 1),
    ([1, 0, 1e-50], 2),          # rounds to 0 as a float32
])
def test_attenuation_coefficient_the_kernels_flush_to_zero(att, k):
    data = base()
    data["light"][0]["attenuation"] = att
    msg = error_of(data)
    assert_one_line(msg)
    assert msg.startswith(f"scene.toml: light[0].attenuation[{k}]: {att[k]!r} is nonzero but below "
                          "the smallest normal float32")
    assert ("c0 must be >= 1.17549435e-38" if k == 0 else "write 0, or at least") in msg


def test_attenuation_coefficients_at_the_smallest_normal_float32_are_accepted():
    data = base()
    data["light"][0]["intensity"] = 1.0
    data["light"][0]["attenuation"] = [F32_MIN, 0.0, -F32_MIN]    # c2 < 0 is refused ...
    assert "need c2 >= 0" in error_of(data)
    data["light"][0]["attenuation"] = [F32_MIN, F32_MIN, F32_MIN]
    assert parse_quietly(data).lights[0].attenuation == (F32_MIN, F32_MIN, F32_MIN)
    data["light"][0]["attenuation"] = [float(f"{F32_MIN:.9g}"), 0, 0]   # the message's bound
    parse_quietly(data)


def test_radiance_times_the_largest_falloff_beyond_float32_is_refused():
    """intensity 1e30 over c0 = 1e-10: radiance x 1/p(d) = 1e40 is inf as a float32
    (NaN pixels on the float and fast paths before)."""
    data = base()
    data["light"][0]["intensity"] = 1e30
    data["light"][0]["color"] = [1.0, 0.5, 0.25]
    data["light"][0]["attenuation"] = [1e-10, 0, 0]
    msg = error_of(data)
    assert_one_line(msg)
    assert msg.startswith("scene.toml: light[0].attenuation: color x intensity x the largest "
                          "falloff 1/min p(d) = 1e+40 is beyond the float32 range")
    assert "lower the intensity" in msg
    # the minimum at the vertex d = -c1/(2*c2) = 1 counts, not just p(0) = c0 = 1
    data["light"][0]["intensity"] = 1e38
    data["light"][0]["attenuation"] = [1, -2, 1.25]        # min p(d) = 0.2 at d = 0.8
    assert "= 5e+38 is beyond" in error_of(data)
    data["light"][0]["attenuation"] = [1, 2, 1.25]         # min p(d) = p(0) = 1
    parse_quietly(data)


@pytest.mark.parametrize("c0", [0.1, 1 / 3, 0.7, 0.9, 7e-30, 5e-20, 4.8497015458773895e-12,
                                F32_MIN * 1.5])
def test_radiance_times_falloff_limit_keeps_the_kernels_rounding(c0):
    """At the limit itself the float kernels' 1/fl(c0) x fl(radiance) can round to
    inf (seen for c0 = 4.85e-12): accepted only below it by the error model's margin."""
    data = base()
    data["light"][0]["color"] = [1.0, 1.0, 1.0]
    data["light"][0]["attenuation"] = [c0, 0, 0]
    data["light"][0]["intensity"] = F32_MAX * c0
    assert "beyond the float32 range" in error_of(data)
    data["light"][0]["intensity"] = F32_MAX * c0 * (1 - 16 * U)
    parse_quietly(data)


def test_largest_falloff_is_one_over_the_minimum_of_p():
    assert largest_falloff(0.5, 0.0, 1.0) == 2.0          # min at d = 0
    assert largest_falloff(1.0, -2.0, 2.0) == 2.0         # vertex d = 0.5, p = 0.5
    assert largest_falloff(1.0, -2.0, 1.0 + 2**-52) == 2.0**52 + 1   # exact, not 0 or inf
    assert largest_falloff(5e-324, 0.0, 0.0) == math.inf
    for c in [(1.0, -1.0, 1.0), (3.0, -0.5, 0.03), (1e-30, 0.0, 1.0), (2.0, 1.0, 0.0)]:
        d = np.linspace(0, 100, 200001)
        p = c[0] + c[1] * d + c[2] * d * d
        assert largest_falloff(*c) >= 1 / p.min() * (1 - 1e-12)
        assert largest_falloff(*c) <= 1 / p.min() * (1 + 1e-8)   # the grid's spacing near the vertex
        # the error model: p(d) moves by 4u*(c0 + |c1|*d + |c2|*d^2), kappa times p's minimum
        v = max(0.0, -c[1] / (2 * c[2])) if c[2] else 0.0
        kappa = (c[0] + abs(c[1]) * v + c[2] * v * v) * largest_falloff(*c)
        bound = kernel_falloff_bound(*c)
        assert largest_falloff(*c) * (1 + 4 * kappa * U) < bound
        assert bound <= largest_falloff(*c) * (1 + (4 * kappa + 3) * U) * (1 + 2 * (4 * kappa * U) ** 2)


# --------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------


def test_readme_example_parses(tmp_path):
    f = tmp_path / "scene.toml"
    f.write_text(README_TOML, encoding="utf-8")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = load_scene(f)
    assert s.source == str(f)
    assert s.warnings == ()
    assert s.camera == Camera("perspective", position=(0.0, 2.0, 6.0))
    assert s.material == Material("phong", 0.1, 0.7, 0.2, 32.0)
    assert [lt.type for lt in s.lights] == ["point", "directional", "ambient"]
    p, d, a = s.lights
    assert p.position == (3.0, 5.0, 4.0) and p.attenuation == (1.0, 0.0, 0.0)
    assert p.radiance == pytest.approx((25.0, 22.5, 20.0))
    n = math.sqrt(1 + 2.25 + 1)
    assert d.direction == pytest.approx((-1 / n, -1.5 / n, -1 / n), rel=1e-15)
    assert a.radiance == (1.0, 1.0, 1.0)
    assert s.background == (0.0, 0.0, 0.0)
    assert s.lights_of("point") == (p,)
    assert s.lights_of("directional") == (d,)
    assert s.lights_of("ambient") == (a,)


def test_readme_orthographic_variant(tmp_path):
    text = README_TOML.replace('type = "perspective"', 'type = "orthographic"')
    text = text.replace("position = [0.0, 2.0, 6.0]", "direction = [0, -0.5, -1]")
    f = tmp_path / "ortho.toml"
    f.write_text(text, encoding="utf-8")
    s = load_scene(str(f))
    assert s.camera.type == "orthographic" and s.camera.position is None
    assert s.camera.direction == pytest.approx((0, -0.5 / math.sqrt(1.25), -1 / math.sqrt(1.25)))


def test_toml_keys_checked_from_file(tmp_path):
    f = tmp_path / "scene.toml"
    f.write_text(README_TOML.replace("[material]", "[materal]"), encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg == f"{f}: materal: unknown key; did you mean 'material'?"


def test_toml_nan_and_inf_rejected(tmp_path):
    f = tmp_path / "scene.toml"
    f.write_text(README_TOML.replace("h = 32.0", "h = nan"), encoding="utf-8")
    with pytest.raises(SceneError, match=r"material\.h: must be finite, got nan"):
        load_scene(f)
    f.write_text(README_TOML.replace("intensity = 3.0", "intensity = +inf"), encoding="utf-8")
    with pytest.raises(SceneError, match=r"light\[1\]\.intensity: must be finite, got inf"):
        load_scene(f)


def test_missing_file(tmp_path):
    f = tmp_path / "nope.toml"
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg == f"{f}: cannot read scene file: no such file"


def test_directory_is_not_a_scene(tmp_path):
    with pytest.raises(SceneError, match="cannot read scene file"):
        load_scene(tmp_path)


def test_invalid_toml_gives_line_and_column(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[camera]\ntype = perspective\n', encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg.startswith(f"{f}:2:8: invalid TOML: ")
    assert "(at line" not in msg


def test_duplicate_key_is_a_toml_error(tmp_path):
    f = tmp_path / "dup.toml"
    f.write_text('[material]\nk_a = 1\nk_a = 2\n', encoding="utf-8")
    with pytest.raises(SceneError, match=r"dup\.toml:3:\d+: invalid TOML"):
        load_scene(f)


@pytest.mark.parametrize("text,where", [
    ('[camera]\nposition = [0, 2,\n', "3:1"),        # after the last newline
    ('[camera]\nposition = [0.0, 2.0', "2:21"),      # no newline at the end
    ('x = "abc', "1:9"),
])
def test_invalid_toml_at_end_of_document(tmp_path, text, where):
    """tomllib says "(at end of document)" instead of a position: the message still
    gives the line and column, as tomllib counts them."""
    f = tmp_path / "bad.toml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg.startswith(f"{f}:{where}: invalid TOML: ")
    assert "end of document" not in msg


def test_fuzzing_dictionary_has_every_scene_key():
    """tests/scene.dict (libFuzzer format, for tests/fuzz_atheris.py) stays in step
    with the format: every line is a comment or one quoted entry, and every table
    and key name the parser knows is an entry."""
    import ast
    from pathlib import Path

    from clphong.model import scene, scene_types

    lines = (Path(__file__).resolve().parent.parent / "scene.dict").read_text(encoding="ascii").splitlines()
    entries = set()
    for ln in lines:
        if ln.strip() and not ln.startswith("#"):
            assert re.fullmatch(r'"(?:[^"\\]|\\.)*"', ln), ln
            entries.add(ast.literal_eval(ln))
    keys = {*scene_types._TOP_KEYS, *scene_types._CAMERA_ALL, *scene_types._MATERIAL_KEYS,
            *scene_types._RENDER_KEYS, *scene_types._LIGHT_ALL}
    assert keys <= entries
    assert {"[camera]", "[material]", "[render]", "[[light]]"} <= entries
    assert {f'"{v}"' for v in (*scene.LIGHT_TYPES, *scene.CAMERA_TYPES, *scene.MATERIAL_MODELS)} <= entries


def test_non_utf8_file(tmp_path):
    f = tmp_path / "latin1.toml"
    f.write_bytes(b'[camera]\ntype = "caf\xe9"\n')
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg.startswith(f"{f}:2: invalid TOML: not UTF-8")


@pytest.mark.parametrize("name, data, kind", [
    ("frame.exr", b"\x76\x2f\x31\x01\x02\x00\x00\x00channels\x00chlist\x00", "an OpenEXR"),
    ("frame.bin", b"\x76\x2f\x31\x01\x02\x00\x00\x00", "an OpenEXR"),   # by its magic bytes
    ("beauty.png", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "a PNG"),
    ("broken.exr", b"\x00\xff\xfe garbage", "an OpenEXR"),            # not UTF-8, named .exr
])
def test_an_image_given_as_the_scene_is_named_as_such(tmp_path, name, data, kind):
    f = tmp_path / name
    f.write_bytes(data)
    with pytest.raises(SceneError) as info:
        load_scene(f)
    msg = str(info.value)
    assert_one_line(msg)
    assert msg == (f"{f}: this is {kind} image, not a scene file; give the scene .toml first: "
                   "clphong render SCENE.toml GBUFFER.exr ...")


def test_a_text_scene_named_like_an_image_is_still_parsed(tmp_path):
    f = tmp_path / "scene.exr"
    from conftest import GBUFFERS
    f.write_text((GBUFFERS / "spheres.toml").read_text())
    assert load_scene(f).material.k_d == 0.7


def test_empty_file_reports_missing_material(tmp_path):
    # [camera] is optional (taken from the EXR's worldToCamera); [material] is not.
    f = tmp_path / "empty.toml"
    f.write_text("", encoding="utf-8")
    with pytest.raises(SceneError) as info:
        load_scene(f)
    assert str(info.value) == f"{f}: material: missing required table [material]"


# --------------------------------------------------------------------------
# defaults, lights list, background
# --------------------------------------------------------------------------


def test_defaults():
    data = {
        "camera": {"type": "perspective", "position": [0, 0, 5]},
        "material": {"model": "blinn-phong", "k_a": 0, "k_d": 1, "k_s": 0, "h": 0},
        "light": [{"type": "point", "position": [1, 1, 1]},
                  {"type": "directional", "direction": [0, 0, -2]},
                  {"type": "ambient"}],
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = parse_scene(data)
    assert s.source == "<scene>" and s.warnings == ()
    assert s.material.specular_color == (1.0, 1.0, 1.0)
    assert s.background == (0.0, 0.0, 0.0)
    p, d, a = s.lights
    for lt in s.lights:
        assert lt.color == (1.0, 1.0, 1.0) and lt.intensity == 1.0
        assert lt.attenuation == (1.0, 0.0, 0.0)
    assert p.direction is None and d.position is None
    assert a.position is None and a.direction is None
    assert d.direction == (0.0, 0.0, -1.0)


@pytest.mark.parametrize("lights", [None, []], ids=["absent", "empty"])
def test_no_lights_allowed(lights):
    data = base()
    data["material"]["k_a"] = 0.0
    if lights is None:
        del data["light"]
    else:
        data["light"] = lights
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = parse_scene(data, SRC)
    assert s.lights == () and s.lights_of("point") == ()


def test_lights_of_rejects_unknown_type():
    s = parse_quietly(base())
    with pytest.raises(ValueError, match="'point', 'spot', 'directional', 'ambient', 'environment'"):
        s.lights_of("spotlight")


def test_background_vector_and_scalar():
    data = base()
    data["render"] = {"background": [0.1, 0.2, -1]}
    assert parse_quietly(data).background == (0.1, 0.2, -1.0)
    data["render"] = {"background": 1}
    assert parse_quietly(data).background == (1.0, 1.0, 1.0)
    data["render"] = {}
    assert parse_quietly(data).background == (0.0, 0.0, 0.0)


def test_h_zero_with_specular_allowed_without_warning():
    data = base()
    data["material"].update(k_s=0.2, h=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse_scene(data).material.h == 0.0


def test_radiance():
    lt = Light("point", color=(1.0, 0.5, 0.0), intensity=4.0, position=(0.0, 0.0, 0.0))
    assert lt.radiance == (4.0, 2.0, 0.0)


# --------------------------------------------------------------------------
# warnings
# --------------------------------------------------------------------------


def test_warning_coefficient_sum():
    data = base()
    data["material"].update(k_a=0.2, k_d=0.8, k_s=0.5)
    with pytest.warns(SceneWarning) as rec:
        s = parse_scene(data, SRC)
    assert len(s.warnings) == 1
    msg = s.warnings[0]
    assert_one_line(msg)
    assert msg.startswith("scene.toml: material: k_a + k_d + k_s = 1.5 > 1")
    assert [str(w.message) for w in rec] == [msg]
    assert rec[0].filename == __file__          # points at the caller


@pytest.mark.parametrize("ks", [(0.1, 0.7, 0.2), (0.3, 0.3, 0.4), (0.2, 0.6, 0.2), (0, 1, 0)])
def test_no_warning_when_sum_is_one_in_decimal(ks):
    data = base()
    data["material"].update(k_a=ks[0], k_d=ks[1], k_s=ks[2])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse_scene(data, SRC).warnings == ()


def test_warning_ambient_without_ambient_light():
    data = base()
    del data["light"][2]
    with pytest.warns(SceneWarning, match="no ambient light"):
        s = parse_scene(data, SRC)
    (msg,) = s.warnings
    assert_one_line(msg)
    assert msg.startswith("scene.toml: material.k_a: ")
    assert "the ambient term is 0" in msg
    assert 'add a [[light]] of type = "ambient"' in msg


def test_no_ambient_warning_when_k_a_is_zero():
    data = base()
    del data["light"][2]
    data["material"]["k_a"] = 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse_scene(data).warnings == ()


def test_load_scene_emits_warnings(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text(README_TOML.replace("k_s = 0.2", "k_s = 0.9"), encoding="utf-8")
    with pytest.warns(SceneWarning, match=re.escape(f"{f}: material: k_a + k_d + k_s")) as rec:
        load_scene(f)
    assert rec[0].filename == __file__


# --------------------------------------------------------------------------
# directions
# --------------------------------------------------------------------------

finite = st.floats(allow_nan=False, allow_infinity=False)
vectors = st.tuples(finite, finite, finite).filter(lambda v: any(c != 0 for c in v))


def _dir_scene(v):
    data = base()
    data["camera"] = {"type": "orthographic", "direction": list(v)}
    data["light"][1]["direction"] = list(v)
    return parse_quietly(data)


@settings(max_examples=300, deadline=None)
@given(vectors)
def test_directions_normalised(v):
    s = _dir_scene(v)
    for u in (s.camera.direction, s.lights[1].direction):
        assert all(type(c) is float for c in u)
        assert abs(math.hypot(*u) - 1.0) <= 4 * sys.float_info.epsilon
        # same direction: u is a positive multiple of v (compare in exact arithmetic
        # after scaling v by its largest component)
        m = max(abs(c) for c in v)
        w = [c / m for c in v]
        nw = math.hypot(*w)
        for a, b in zip(u, w):
            assert a == pytest.approx(b / nw, rel=1e-12, abs=1e-300)
    # normalising is idempotent, so a round trip is exact
    assert _dir_scene(s.camera.direction).camera.direction == s.camera.direction


def test_direction_examples():
    s = _dir_scene((0.0, 3.0, -4.0))
    assert s.camera.direction == (0.0, 0.6, -0.8)
    assert _dir_scene((5e-324, 5e-324, 0.0)).camera.direction == pytest.approx(
        (math.sqrt(0.5), math.sqrt(0.5), 0.0))
    big = sys.float_info.max
    assert _dir_scene((big, -big, big)).camera.direction == pytest.approx(
        (1 / math.sqrt(3), -1 / math.sqrt(3), 1 / math.sqrt(3)))


# --------------------------------------------------------------------------
# attenuation condition vs brute force
# --------------------------------------------------------------------------

# Coefficients on a grid of 1/4 in [-4, 4]: every real root is then below 17,
# every negative interval is wider than 1/16, and p(d) is computed exactly in
# float64 on the sample grid d = k/256, so a dense sample decides positivity
# except at a double root, which is added to the samples.
quarter = st.integers(-16, 16).map(lambda k: k / 4)
D_GRID = np.arange(0, 100 * 256 + 1, dtype=np.float64) / 256.0


def brute_force_positive(c0, c1, c2) -> bool:
    """p(d) > 0 on the grid's d > 0 (c0 = 0 is allowed: p(0) = 0 adds no light, the
    d = 0 guard), and near 0, where the grid is coarse: the sign of p's lowest term."""
    d = D_GRID[1:]
    p = c0 + c1 * d + c2 * d * d
    if p.min() <= 0:
        return False
    if c0 == 0 and (c1 < 0 or (c1 == 0 and c2 <= 0)):
        return False
    if c0 < 0:
        return False
    if c2 > 0 and c1 < 0:  # the vertex, where a double root would touch 0
        v = Fraction(-c1) / (2 * Fraction(c2))
        if Fraction(c0) + Fraction(c1) * v + Fraction(c2) * v * v <= 0:
            return False
    return True


def reported_points(msg: str) -> list[float]:
    """The distances where a message says p(d) = 0: 'at d = X', 'd > X', 'X < d < Y'."""
    pat = r"reaches 0 at d = ([0-9.e+-]+)|d > ([0-9.e+-]+)|([0-9.e+-]+) < d < ([0-9.e+-]+)"
    return [float(x) for m in re.findall(pat, msg) for x in m if x]


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(quarter, quarter, quarter)
def test_attenuation_condition_matches_brute_force(c0, c1, c2):
    problem = attenuation_problem(c0, c1, c2)
    assert (problem is None) == brute_force_positive(c0, c1, c2), (c0, c1, c2, problem)
    # the closed form of the brief
    exact = ((c0 > 0 and ((c2 > 0 and (c1 >= 0 or c1 * c1 < 4 * c0 * c2)) or (c2 == 0 and c1 >= 0)))
             or (c0 == 0 and c1 >= 0 and c2 >= 0 and (c1 > 0 or c2 > 0)))
    assert (problem is None) == exact
    if problem is not None:
        assert "\n" not in problem
        scale = abs(c0) + abs(c1) + abs(c2)
        for d in reported_points(problem):   # where it says p reaches 0, it does
            assert d >= 0
            assert abs(c0 + c1 * d + c2 * d * d) <= 1e-5 * scale * (1 + d * d)


def p_exact(c, d: Fraction) -> Fraction:
    return Fraction(c[0]) + Fraction(c[1]) * d + Fraction(c[2]) * d * d


wide = st.one_of(st.floats(-1e6, 1e6), st.sampled_from([0.0, -0.0, 1.0, -1.0, 2.0, 4.0]),
                 st.floats(-1e-6, 1e-6), st.floats(-1e300, 1e300))


@settings(max_examples=600, deadline=None)
@given(wide, wide, wide)
def test_attenuation_condition_exact_witnesses(c0, c1, c2):
    """Accepted: p > 0 at its minimum over d > 0; rejected: a d > 0 with p <= 0, or
    p(0) < 0, or p = 0 everywhere. (c0 = 0 is accepted when p > 0 for every d > 0.)"""
    c = (c0, c1, c2)
    problem = attenuation_problem(*c)
    if c0 == 0:
        tiny = Fraction(1, 10**700)              # p's sign for small d > 0 is that of c1 (else c2)
        if problem is None:
            assert c1 >= 0 and c2 >= 0 and (c1 > 0 or c2 > 0)
            assert p_exact(c, tiny) > 0 and p_exact(c, 1 + abs(Fraction(c1)) + 10**400) > 0
        else:
            assert c1 < 0 or c2 < 0 or (c1 == 0 and c2 == 0), (c, problem)
        return
    # candidate minimisers / witnesses, exact
    cands = [Fraction(0)]
    if c2 != 0 and -c1 / c2 >= 0:
        cands.append(Fraction(-c1) / (2 * Fraction(c2)))
    big = 1 + 2 * (abs(Fraction(c0)) + abs(Fraction(c1))) / max(abs(Fraction(c2)), Fraction(1, 10**400))
    if c2 == 0 and c1 != 0:
        big = 1 + 2 * abs(Fraction(c0)) / abs(Fraction(c1))
    cands.append(big)
    values = [p_exact(c, d) for d in cands]
    if problem is None:
        # convex or linear with c1 >= 0: the minimum over d >= 0 is at 0 or the vertex
        assert c2 >= 0 and all(v > 0 for v in values[:2])
        if c2 == 0:
            assert c1 >= 0
    else:
        assert min(values) <= 0, (c, problem)


def test_attenuation_exact_at_the_boundary():
    # c1^2 - 4 c0 c2 is 2^-104 > 0 in exact arithmetic but rounds to 0 in float64
    c0, c1, c2 = 1.0, -2.0 * (1 + 2**-52), 1.0
    assert attenuation_problem(c0, c1, c2) is not None
    # and the other way round: a hair inside
    assert attenuation_problem(1.0, -2.0, 1.0 + 2**-52) is None
    # coefficients whose squares overflow float64
    assert attenuation_problem(1e300, -1e200, 1e300) is None
    msg = attenuation_problem(1e300, -1e200, 1e-100)        # roots near 1e100 and 1e300
    assert msg is not None and "1e+100" in msg and "1e+300" in msg
    msg = attenuation_problem(1e300, -1e-300, 0.0)           # root at 1e600
    assert msg is not None and "d > 1e+600" in msg
    msg = attenuation_problem(1e300, 1e300, -5e-324)         # root beyond float64
    assert msg is not None and "e+6" in msg


# --------------------------------------------------------------------------
# round trip
# --------------------------------------------------------------------------

nonneg = st.floats(0, 1e6)
anyf = st.floats(-1e6, 1e6)
vec = st.lists(anyf, min_size=3, max_size=3)
nonneg_vec = st.lists(nonneg, min_size=3, max_size=3)
direction = vec.filter(lambda v: any(v))
good_att = st.sampled_from([[1, 0, 0], [1, -1, 1], [0.5, 0.1, 0.01], [2, 0, 3]])

light_st = st.one_of(
    st.fixed_dictionaries({"type": st.just("point"), "position": vec},
                          optional={"color": nonneg_vec, "intensity": nonneg,
                                    "attenuation": good_att}),
    st.fixed_dictionaries({"type": st.just("directional"), "direction": direction},
                          optional={"color": nonneg_vec, "intensity": nonneg}),
    st.fixed_dictionaries({"type": st.just("ambient")},
                          optional={"color": nonneg_vec, "intensity": nonneg}),
)
scene_st = st.fixed_dictionaries(
    {
        "camera": st.one_of(
            st.fixed_dictionaries({"type": st.just("perspective"), "position": vec}),
            st.fixed_dictionaries({"type": st.just("orthographic"), "direction": direction})),
        "material": st.fixed_dictionaries(
            {"model": st.sampled_from(["phong", "blinn-phong"]), "k_a": nonneg, "k_d": nonneg,
             "k_s": nonneg, "h": nonneg}, optional={"specular_color": nonneg_vec}),
    },
    optional={"light": st.lists(light_st, max_size=5),
              "render": st.fixed_dictionaries({}, optional={"background": vec})},
)


@settings(max_examples=200, deadline=None)
@given(scene_st)
def test_to_dict_round_trip(data):
    s = parse_quietly(data, "x.toml")
    d = s.to_dict()
    s2 = parse_quietly(copy.deepcopy(d), "x.toml")
    assert s2 == s
    assert s2.to_dict() == d
    assert [lt["type"] for lt in d["light"]] == [lt.type for lt in s.lights]


def test_to_dict_layout():
    d = parse_quietly(base()).to_dict()
    assert set(d) == {"camera", "material", "render", "light"}
    assert d["camera"] == {"type": "perspective", "position": [0.0, 2.0, 6.0]}
    assert set(d["light"][0]) == {"type", "color", "intensity", "position", "attenuation"}
    assert set(d["light"][1]) == {"type", "color", "intensity", "direction"}
    assert set(d["light"][2]) == {"type", "color", "intensity"}


# --------------------------------------------------------------------------
# scale
# --------------------------------------------------------------------------


def test_many_lights_parse_and_a_late_error_is_named():
    n = 100_000
    kinds = [
        {"type": "point", "position": [1, 2, 3], "color": [1, 1, 1], "intensity": 2,
         "attenuation": [1, 0.1, 0.01]},
        {"type": "directional", "direction": [0, -1, 0], "intensity": 0.5},
        {"type": "ambient", "intensity": 0.1},
    ]
    data = base()
    data["light"] = [kinds[i % 3] for i in range(n)]
    s = parse_quietly(data)          # (speed is for `clphong bench`, not a timed test)
    assert len(s.lights) == n
    assert len(s.lights_of("point")) == (n + 2) // 3
    # an error at the very end is still found and named
    data["light"][-1] = {"type": "point", "position": [0, 0, 0], "intensity": -1}
    msg = error_of(data)
    assert msg.startswith(f"scene.toml: light[{n - 1}].intensity: must be >= 0")
    assert f"the {n}th [[light]]" in msg


def test_light_types_constant():
    assert LIGHT_TYPES == ("point", "spot", "directional", "ambient", "environment")


def test_light_arrays_are_cached_read_only_and_not_pickled():
    """Scene.light_arrays is computed once per scene (the renderer asks every frame),
    cannot be changed by a caller, and does not travel in pickles to workers."""
    import pickle

    import numpy as np

    from clphong.tools.hardcases import make_scene

    scene = make_scene([dict(type="point", position=(0, 0, 3), intensity=2.0),
                        dict(type="directional", direction=(0, 0, -1)), dict(type="ambient")])
    a = scene.light_arrays
    assert a is scene.light_arrays
    assert np.array_equal(a["point_position"], [[0.0, 0.0, 3.0]])
    assert np.array_equal(a["point_radiance"], [scene.lights_of("point")[0].radiance])
    with pytest.raises(ValueError):
        a["point_position"][0, 0] = 1.0
    with pytest.raises(TypeError):
        a["point_position"] = None
    copy = pickle.loads(pickle.dumps(scene))
    assert copy == scene and "light_arrays" not in copy.__dict__
    assert np.array_equal(copy.light_arrays["point_attenuation"], a["point_attenuation"])


def test_render_aovs_and_albedo_space_round_trip():
    data = base()
    data["light"][0]["group"] = "key"
    data.setdefault("render", {}).update(aovs=["specular", "key", "specular"],
                                         albedo_space="sRGB Encoded Rec.709 (sRGB)")
    sc = parse_quietly(data)
    assert sc.aovs == ("specular", "key") and sc.color.albedo_space == "sRGB Encoded Rec.709 (sRGB)"
    assert parse_quietly(sc.to_dict()) == sc


# ------------------------------------------------------------------ spots, environment, Fresnel

def _with_light(light, material=None):
    data = base()
    data["light"] = [light]
    if material:
        data["material"].update(material)
    return data


_SPOT = {"type": "spot", "position": [0, 2, 0], "direction": [0, -1, 0],
         "inner_angle": 10.0, "outer_angle": 20.0}


@pytest.mark.parametrize("change, path, fragment", [
    ({"inner_angle": 20.0}, "light[0].inner_angle", "not less than outer_angle = 20.0"),
    ({"inner_angle": 30.0}, "light[0].inner_angle", "not less than outer_angle"),
    ({"outer_angle": 91.0}, "light[0].outer_angle", "out of range"),
    ({"inner_angle": -1.0}, "light[0].inner_angle", "out of range"),
    ({"outer_angle": float("nan")}, "light[0].outer_angle", "must be finite"),
    ({"inner_angle": 10.0, "outer_angle": 10.0001}, "light[0].outer_angle", "too sharp"),
    ({"direction": [0, 0, 0]}, "light[0].direction", "zero-length"),
    ({"direction": None}, "light[0].direction", "missing"),
    ({"file": "x.exr"}, "light[0].file", "does not apply to a 'spot' light"),
])
def test_spot_errors_name_the_key(change, path, fragment):
    lt = dict(_SPOT, **change)
    lt = {k: v for k, v in lt.items() if v is not None}
    msg = error_of(_with_light(lt))
    assert_one_line(msg)
    assert msg.startswith(f"{SRC}: {path}: "), msg
    assert fragment in msg, msg


def test_spot_defaults_and_cone_constants():
    """glTF's defaults (inner 0, outer 45°) and s, o from the half-angles: s·cos inner + o = 1
    and s·cos outer + o = 0, the two ends of the fade."""
    lt = parse_quietly(_with_light({"type": "spot", "position": [0, 2, 0], "direction": [0, -2, 0]})).lights[0]
    assert (lt.inner_angle, lt.outer_angle, lt.direction) == (0.0, 45.0, (0.0, -1.0, 0.0))
    s, o = lt.spot_scale_offset()
    assert s * 1.0 + o == pytest.approx(1.0, abs=1e-15)
    assert s * math.cos(math.radians(45.0)) + o == pytest.approx(0.0, abs=1e-15)
    s90, o90 = parse_quietly(_with_light(dict(_SPOT, outer_angle=90.0))).lights[0].spot_scale_offset()
    assert o90 == 0.0          # the horizon exactly: cos 90° taken as 0, not 6e-17


def test_spot_power_is_cycles_point_intensity():
    """power: the point light's convention (the cone does not concentrate it)."""
    sp = parse_quietly(_with_light(dict(_SPOT, power=100.0))).lights[0]
    pt = parse_quietly(_with_light({"type": "point", "position": [0, 2, 0], "power": 100.0})).lights[0]
    assert (sp.intensity, sp.attenuation) == (pt.intensity, pt.attenuation)


@pytest.mark.parametrize("light, path, fragment", [
    ({"type": "environment"}, "light[0].file", "missing"),
    ({"type": "environment", "file": ""}, "light[0].file", "expected a file name"),
    ({"type": "environment", "file": 3}, "light[0].file", "expected a file name"),
    ({"type": "environment", "file": "a.exr", "rotation": float("inf")}, "light[0].rotation",
     "must be finite"),
    ({"type": "environment", "file": "a.exr", "color": [1, 1, 1]}, "light[0].color",
     "does not apply to an 'environment' light"),
])
def test_environment_errors_name_the_key(light, path, fragment):
    msg = error_of(_with_light(light))
    assert msg.startswith(f"{SRC}: {path}: "), msg
    assert fragment in msg, msg


def test_environment_file_is_relative_to_the_scene(tmp_path):
    (tmp_path / "s.toml").write_text(
        '[material]\nmodel = "phong"\nk_a = 0\nk_d = 1\nk_s = 0\nh = 1\n'
        '[[light]]\ntype = "environment"\nfile = "sky.exr"\nrotation = 90\nintensity = 2\n')
    lt = load_scene(tmp_path / "s.toml").lights[0]
    assert (lt.file, lt.rotation, lt.intensity) == (str(tmp_path / "sky.exr"), 90.0, 2.0)


@pytest.mark.parametrize("material, path, fragment", [
    ({"fresnel": "fresnel"}, "material.fresnel", "invalid value"),
    ({"fresnel": "schlick"}, "material.f0", "missing"),
    ({"fresnel": "schlick", "f0": 1.5}, "material.f0", "above 1"),
    ({"fresnel": "schlick", "f0": [0.1, 2, 0.1]}, "material.f0[1]", "above 1"),
    ({"fresnel": "schlick", "f0": -0.1}, "material.f0", "must be >= 0"),
    ({"f0": 0.04}, "material.f0", "applies only with fresnel"),
    ({"fresnel": "schlick", "f0": 0.04, "specular_color": [1, 1, 1]}, "material.specular_color",
     "does not apply with fresnel"),
])
def test_fresnel_errors_name_the_key(material, path, fragment):
    msg = error_of(_with_light({"type": "ambient"}, material))
    assert msg.startswith(f"{SRC}: {path}: "), msg
    assert fragment in msg, msg


def test_fresnel_round_trips():
    s = parse_quietly(_with_light({"type": "ambient"}, {"fresnel": "schlick", "f0": [0.9, 0.6, 0.2]}))
    assert (s.material.fresnel, s.material.f0) == ("schlick", (0.9, 0.6, 0.2))
    assert parse_quietly(s.to_dict()) == s
    sp = parse_quietly(_with_light(_SPOT))
    assert parse_quietly(sp.to_dict()) == sp


# ------------------------------------------------------------------ loading many lights (issue 16)

def _reference_light_arrays(scene: Scene) -> dict:
    """light_arrays as the per-light loops of the first version formed them (the
    reference the vectorised one is held to)."""
    def table(lights, attr):
        return np.array([getattr(lt, attr) for lt in lights], np.float64).reshape(-1, 3)

    groups = scene.light_groups
    rank = {g: k for k, g in enumerate(groups)}

    def in_group_order(types):
        idx = [i for i, lt in enumerate(scene.lights) if lt.type in types]
        idx.sort(key=lambda i: rank.get(scene.lights[i].group_name, 0))
        return idx, [scene.lights[i] for i in idx]

    pi, pts = in_group_order(("point", "spot"))
    di, dirs = in_group_order(("directional",))
    cone = np.zeros((len(pts), 5))
    cone[:, 4] = 1.0
    spot = np.array([lt.type == "spot" for lt in pts], bool)
    for k in np.flatnonzero(spot):
        cone[k, :3] = pts[k].direction
        cone[k, 3:] = pts[k].spot_scale_offset()
    ends = {}
    for name, lts in (("point", pts), ("directional", dirs)):
        gid = np.array([rank.get(lt.group_name, 0) for lt in lts], int)
        ends[name] = np.searchsorted(gid, np.arange(len(groups)), side="right")
    amb_g = np.zeros((len(groups), 3))
    for lt in scene.lights_of("ambient") if groups else ():
        amb_g[rank[lt.group_name]] += lt.radiance
    return {"point_position": table(pts, "position"), "point_radiance": table(pts, "radiance"),
            "point_attenuation": table(pts, "attenuation"), "point_cone": cone,
            "point_is_spot": spot, "directional_direction": table(dirs, "direction"),
            "directional_radiance": table(dirs, "radiance"),
            "ambient_radiance": table(scene.lights_of("ambient"), "radiance").sum(axis=0),
            "point_index": np.array(pi, int), "directional_index": np.array(di, int),
            "point_group_end": ends["point"], "directional_group_end": ends["directional"],
            "ambient_group_radiance": amb_g}


_MIXED = [
    {"type": "point", "position": [1, 2, 3], "color": [0.3, 0.7, 0.9], "intensity": 3.0,
     "attenuation": [1, 0.1, 0.05], "group": "key"},
    {"type": "spot", "position": [0, 4, 0], "direction": [0, -1, 0.2], "inner_angle": 5.0,
     "outer_angle": 30.0, "power": 40.0},
    {"type": "directional", "direction": [-1, -1, -1], "intensity": 2.0, "group": "fill"},
    {"type": "ambient", "color": [0.1, 0.2, 0.3], "intensity": 0.5, "group": "key"},
    {"type": "point", "position": [-1, 0, 2], "power": 10.0, "group": "fill"},
    {"type": "ambient", "intensity": 0.25},
    {"type": "spot", "position": [2, 2, 2], "direction": [0, 0, -1], "group": "key"},
    {"type": "directional", "direction": [0, -1, 0], "color": [1, 0.5, 0.5]},
]


@pytest.mark.parametrize("grouped", [True, False])
def test_light_arrays_equal_the_per_light_reference(grouped):
    lights = copy.deepcopy(_MIXED)
    if not grouped:
        for lt in lights:
            lt.pop("group", None)
    s = parse_quietly({**base(), "light": lights})
    ref = _reference_light_arrays(s)
    assert set(s.light_arrays) == set(ref)
    for k, v in ref.items():
        got = s.light_arrays[k]
        assert got.shape == v.shape and got.dtype.kind == v.dtype.kind and np.array_equal(got, v), k
        assert not got.flags.writeable
    empty = parse_quietly({**base(), "light": []})
    for k, v in _reference_light_arrays(empty).items():
        assert empty.light_arrays[k].shape == v.shape, k


def test_new_light_is_the_dataclass():
    from clphong.model.scene import new_light

    kw = dict(type="spot", color=(0.5, 0.25, 1.0), intensity=2.0, position=(1.0, 2.0, 3.0),
              direction=(0.0, -1.0, 0.0), attenuation=(1.0, 0.0, 0.5), group="g",
              inner_angle=10.0, outer_angle=20.0)
    a, b = new_light(**kw), Light(**kw)
    assert type(a) is Light and a == b and hash(a) == hash(b) and vars(a) == vars(b)
    assert new_light(type="ambient") == Light("ambient")
    with pytest.raises(Exception):
        a.intensity = 3.0                    # still frozen


@pytest.mark.parametrize("group", [None, "sky"])
def test_directional_lights_from_columns_are_the_dataclass(group):
    """scene.directional_lights (an environment's lights, its probes' sums): each light is
    Light(...) of its row, travelling along −l, and the collector is left as it was."""
    import gc

    from clphong.model.scene import directional_lights

    rng = np.random.default_rng(5)
    l = rng.normal(size=(7, 3))
    l /= np.linalg.norm(l, axis=1)[:, None]
    rad = rng.uniform(0, 2, (7, 3)).astype(np.float32)       # any float dtype, as float64
    for enabled in (True, False):
        (gc.enable if enabled else gc.disable)()
        try:
            got = directional_lights(l, rad, group)
            assert gc.isenabled() == enabled
        finally:
            gc.enable()
        want = tuple(Light(type="directional", color=tuple(float(c) for c in r), intensity=1.0,
                           direction=tuple(float(-x) for x in d), group=group)
                     for r, d in zip(rad, l))
        assert got == want and [vars(a) for a in got] == [vars(b) for b in want]
        assert all(type(x) is float for a in got for x in (*a.color, *a.direction))
    assert directional_lights(np.zeros((0, 3)), np.zeros((0, 3))) == ()


def test_shared_attenuation_still_checks_every_lights_radiance():
    """The polynomial's checks run once per distinct polynomial; each light's own
    radiance x falloff is still checked, and the message names that light."""
    lt = {"type": "point", "position": [0, 0, 1], "attenuation": [1e-30, 0, 1]}
    data = {**base(), "light": [dict(lt, intensity=1.0), dict(lt, intensity=1.0),
                                dict(lt, intensity=1e10)]}
    msg = error_of(data)
    assert msg.startswith(f"{SRC}: light[2].attenuation: color x intensity x the largest falloff"), msg
    bad = {**base(), "light": [dict(lt, attenuation=[1, -3, 1], intensity=1.0)] * 2}
    assert error_of(bad).startswith(f"{SRC}: light[0].attenuation: p(d) = c0 + c1*d + c2*d^2 reaches 0")


def test_vectors_just_beyond_float32_max_round_to_it():
    """The fast path for three floats hands the edge cases to the exact checks: a value
    that rounds to FLT_MAX as a float32 is legal, 2^128 is not."""
    flt_max = float(np.finfo(np.float32).max)
    near = flt_max * (1 + 2.0 ** -26)
    s = parse_quietly({**base(), "camera": {"type": "perspective", "position": [near, 0.0, -near]}})
    assert s.camera.position == (near, 0.0, -near)
    msg = error_of({**base(), "camera": {"type": "perspective", "position": [0.0, 2.0 ** 128, 0.0]}})
    assert msg.startswith(f"{SRC}: camera.position[1]: 3.40282e+38 is beyond the float32 range"), msg
    assert error_of({**base(), "camera": {"type": "perspective", "position": [0.0, math.nan, 0.0]}}) \
        .startswith(f"{SRC}: camera.position[1]: must be finite, got nan")
    assert "must be >= 0, got -0.5" in error_of(
        {**base(), "light": [{"type": "ambient", "color": [1.0, -0.5, 1.0]}]})
    assert parse_quietly({**base(), "light": [{"type": "ambient", "color": [-0.0, 0.0, 1.0]}]}
                         ).lights[0].color == (-0.0, 0.0, 1.0)


@pytest.mark.parametrize("fails", [False, True])
def test_parsing_leaves_the_garbage_collector_as_it_was(fails):
    import gc

    data = base() if not fails else {**base(), "material": 3}
    for enabled in (True, False):
        (gc.enable if enabled else gc.disable)()
        try:
            try:
                parse_quietly(data)
            except SceneError:
                assert fails
            assert gc.isenabled() == enabled
        finally:
            gc.enable()


def test_spot_with_angles_equal_in_float64_cosines_is_refused():
    """inner 0 and outer 1e-40 have the same float64 cosine (a division by zero once)."""
    msg = error_of(_with_light(dict(_SPOT, inner_angle=0.0, outer_angle=1e-40)))
    assert msg.startswith(f"{SRC}: light[0].outer_angle: the edge from inner_angle = 0.0 to "
                          "outer_angle = 1e-40 is too sharp"), msg
    assert "cos inner - cos outer = 0 <" in msg


def test_lights_file_rows_follow_the_tables(tmp_path):
    (tmp_path / "rig.csv").write_text("type,x,y,z,intensity\npoint,1,2,3,4\nambient,,,,0.5\n")
    (tmp_path / "s.toml").write_text('lights = "rig.csv"\n[material]\nmodel = "phong"\nk_a = 0.1\n'
                                     'k_d = 0.7\nk_s = 0.2\nh = 32.0\n[[light]]\ntype = "ambient"\n'
                                     'intensity = 1.0\n')
    s = load_scene(tmp_path / "s.toml")
    assert [(lt.type, lt.intensity) for lt in s.lights] == [("ambient", 1.0), ("point", 4.0),
                                                            ("ambient", 0.5)]
    assert list(s.light_arrays["ambient_radiance"]) == [1.5, 1.5, 1.5]
    assert parse_quietly(s.to_dict()) == dataclasses_replace_source(s)


def dataclasses_replace_source(s: Scene) -> Scene:
    import dataclasses

    return dataclasses.replace(s, source=SRC, warnings=())


@pytest.mark.parametrize("text", ['a = ', 'a = [1,', '[material\n', 'a = 1\na = 2\n', 'a = "x',
                                  'a = 1e', 'x = {a=1', '[[light]]\ntype = "point"\n[light]\n',
                                  'a = tru', 'a = 0x', "[a]\n[a]\n", "a.b = 1\na = 2\n", "a = 1 2",
                                  "= 1", 'a = {b = 1, b = 2}', 'a = "\\q"', 'a = """x'])
def test_toml_messages_are_tomllibs(text):
    """load_scene parses with tomli where it is installed (tomllib's own parser, compiled):
    an invalid document gets the message tomllib's error gives."""
    import tomllib

    from clphong.model import scene

    def message(mod):
        with pytest.raises(mod.TOMLDecodeError) as info:
            mod.loads(text)
        return scene._toml_message(SRC, info.value, text)

    assert message(scene._toml) == message(tomllib)
    assert re.match(rf"{re.escape(SRC)}:\d+:\d+: invalid TOML: \S", message(tomllib))


def test_a_top_level_key_after_a_table_says_where_it_belongs():
    """TOML files a key written after [[light]] into that light: say it is a top-level key."""
    msg = error_of(_with_light({"type": "ambient", "lights": "rig.csv"}))
    assert msg.startswith(f"{SRC}: light[0].lights: unknown key; 'lights' is a top-level key"), msg


def test_a_large_scene_file_parses_with_rtoml_to_the_same_scene_and_errors(tmp_path, monkeypatch):
    """Files of BIG_TOML bytes or more go through rtoml (1.9x faster at 65,536 lights): the
    scene is the same as tomli's, and a broken file says tomli's words, line and column."""
    from clphong.model import scene as scene_module
    from clphong.model.scene import load_scene

    rng = np.random.default_rng(5)
    body = ['[camera]\ntype = "perspective"\nposition = [0.0, 2.0, 6.0]\n',
            '[material]\nmodel = "phong"\nk_a = 0.1\nk_d = 0.7\nk_s = 0.2\nh = 32.0\n',
            '[[light]]\ntype = "ambient"\nintensity = 0.25 # a comment\n']
    for x, y, z in rng.uniform(-3, 3, (300, 3)):
        body.append(f'[[light]]\ntype = "point"\nposition = [{float(x)!r}, {float(y)!r}, {z + 4:.17g}]\n'
                    f"intensity = 1e-1\nattenuation = [1.0, 0, 0.5]\n")
    good = tmp_path / "big.toml"
    good.write_text("".join(body))
    bad = tmp_path / "bad.toml"
    bad.write_text("".join(body[:200]) + "[[light]]\ntype = 'point\n" + "".join(body[200:]))
    assert scene_module._rtoml is not None
    with_tomli = load_scene(good)
    with pytest.raises(SceneError) as e:
        load_scene(bad)
    tomli_error = str(e.value)
    monkeypatch.setattr(scene_module, "BIG_TOML", 1)            # every file through rtoml
    calls = []
    real = scene_module._rtoml.loads
    monkeypatch.setattr(scene_module._rtoml, "loads", lambda t: calls.append(1) or real(t))
    assert load_scene(good) == with_tomli and calls
    with pytest.raises(SceneError) as e:
        load_scene(bad)
    assert str(e.value) == tomli_error and ": invalid TOML: " in tomli_error


def test_a_scene_of_columns_is_the_scene_of_light_objects():
    """scene.directional_scene (an environment's probe sums): the caches it fills from the
    columns are those a Scene of the same Light objects computes, to the bit, and its
    lights are those objects when asked for."""
    from clphong.model.scene import Camera, LightColumns, Scene, directional_lights, directional_scene

    rng = np.random.default_rng(8)
    l = rng.normal(size=(9, 3))
    l /= np.linalg.norm(l, axis=1)[:, None]
    rad = rng.uniform(0, 3, (9, 3))
    cam = Camera(type="perspective", position=(0.0, 0.0, 0.0))
    mat = Material(model="phong", k_a=0.0, k_d=0.7, k_s=0.2, h=32.0)
    got = directional_scene(cam, mat, l, rad, source="probes")
    want = Scene(camera=cam, material=mat, lights=directional_lights(l, rad), source="probes")
    assert isinstance(got.lights, LightColumns) and len(got.lights) == 9
    a, b = got.light_arrays, want.light_arrays
    assert a.keys() == b.keys()
    for k in a:
        assert np.asarray(a[k]).dtype == np.asarray(b[k]).dtype, k
        assert np.array_equal(a[k], b[k]) and np.shape(a[k]) == np.shape(b[k]), k
        assert not np.asarray(a[k]).flags.writeable, k
    assert got.light_groups == want.light_groups == ()
    for t in ("point", "spot", "ambient", "environment"):
        assert tuple(got.lights_of(t)) == want.lights_of(t) == ()
    assert tuple(got.lights_of("directional")) == want.lights_of("directional") == want.lights
    assert got.lights[3] == want.lights[3] and tuple(got.lights[2:5]) == want.lights[2:5]
    assert isinstance(got.lights[2:5], LightColumns)
    with pytest.raises(ValueError, match="9 directions but 8 radiances"):
        directional_scene(cam, mat, l, rad[:8], source="probes")

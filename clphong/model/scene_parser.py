"""The scene file's tables checked one by one: camera, material, render, lights
(:class:`_Parser`); :mod:`clphong.model.scene` is its public face."""

from __future__ import annotations

import difflib
import math
import numbers
import os
from collections.abc import Mapping
from typing import Any, NoReturn

from ..core.errors import SceneError, ToneMapError
from ..core.floats import FLT_MAX, FLT_MIN, U
from .falloff import (
    SPOT_MAX_SCALE,
    Vec3,
    _f32,
    attenuation_problem,
    kernel_falloff_bound,
    largest_falloff,
    radiance_problem,
    spot_scale_offset,
)
from .light_table import read_light_table
from .options import check_exposure
from .scene_messages import (
    _describe,
    _g,
    _join,
    _message,
    _quoted_list,
    _short,
)
from .scene_types import (
    _CAMERA_ALL,
    _CAMERA_ALL_ORDERED,
    _CAMERA_KEYS,
    _EPS,
    _F64_MAX,
    _GROUP_NAME,
    _LIGHT_ALL,
    _LIGHT_ALL_ORDERED,
    _LIGHT_KEYS,
    _LIGHT_SETS,
    _MATERIAL_KEYS,
    _MATERIAL_REQUIRED,
    _NO_FALLOFF,
    _RENDER_KEYS,
    _SUM_TOLERANCE,
    _TOP_KEYS,
    _WHITE,
    AOV_NAMES,
    CAMERA_TYPES,
    CAMERA_UP_AXES,
    FRESNEL_MODELS,
    INVERSE_SQUARE,
    LIGHT_TYPES,
    MATERIAL_MODELS,
    POINT_TYPES,
    SPOT_INNER_DEFAULT,
    SPOT_OUTER_DEFAULT,
    WATTS_TO_RADIANCE,
    WORKING_SPACE_NAMES,
    Camera,
    ColorSettings,
    Light,
    Material,
    Scene,
    new_light,
)
from .tonemap import operator, operator_params

# --------------------------------------------------------------------------
# the validator
# --------------------------------------------------------------------------


class _Parser:
    """Validates plain data against the scene schema; raises on the first problem."""

    def __init__(self, source: str, base_dir: str = "", table_parser: type | None = None):
        self.source = source
        self.base_dir = base_dir      # the scene file's folder: relative file names start there
        # what checks a lights file's columns (scene_table._TableParser, a subclass of this
        # one: given by clphong.model.scene, which imports both)
        self.table_parser = table_parser
        self.warnings: list[str] = []
        self._falloffs: dict[Vec3, float] = {}   # attenuation -> falloff bound, once checked

    # -- reporting --------------------------------------------------------

    def fail(self, path: str, problem: str) -> NoReturn:
        raise SceneError(_message(self.source, path, problem))

    def warn(self, path: str, problem: str) -> None:
        self.warnings.append(_message(self.source, path, problem))

    def unknown(self, path: str, key: Any, valid: tuple[str, ...]) -> NoReturn:
        close = difflib.get_close_matches(key, valid, n=1) if isinstance(key, str) else []
        if path and key in _TOP_KEYS:
            # TOML puts a key written after a [table] header into that table
            self.fail(_join(path, key), f"unknown key; {key!r} is a top-level key: write it "
                                        "before the first [table] or [[light]] of the file")
        if close:
            hint = f"did you mean {close[0]!r}?"
        else:
            hint = f"valid keys are {_quoted_list(valid)}"
        self.fail(_join(path, key), f"unknown key; {hint}")

    # -- structure --------------------------------------------------------

    def table(self, v: Any, path: str) -> Mapping:
        if not isinstance(v, Mapping):
            if isinstance(v, list) and v and all(isinstance(x, Mapping) for x in v):
                self.fail(path, f"expected a table [{path}], got an array of tables "
                                f"(write [{path}], not [[{path}]])")
            self.fail(path, f"expected a table, got {_describe(v)}")
        return v

    def check_keys(self, t: Mapping, path: str, valid: frozenset, ordered: tuple[str, ...]):
        if not valid.issuperset(t.keys()):
            for k in t:
                if k not in valid:
                    self.unknown(path, k, ordered)

    # -- values -----------------------------------------------------------

    def num(self, v: Any, path: str, index: int | None = None, f32: bool = True) -> float:
        """A finite number as float; ``index`` extends ``path`` lazily; ``f32``: it must
        also be finite as the float32 the kernels take (not for directions, which
        are normalised first)."""
        t = type(v)
        if t is float:
            x = v
        elif t is int:
            x = self._int_to_float(v, path, index)
        elif isinstance(v, bool) or not isinstance(v, numbers.Real):
            hint = ""
            if isinstance(v, str):
                try:
                    float(v)
                    hint = " (write the number without quotes)"
                except ValueError:
                    pass
            self.fail(self._at(path, index), f"expected a number, got {_describe(v)}{hint}")
        elif isinstance(v, int):
            x = self._int_to_float(v, path, index)
        else:
            try:
                x = float(v)
            except (OverflowError, ValueError, TypeError):
                self.fail(self._at(path, index), f"{_describe(v)} is not a float64 number")
        if not math.isfinite(x):
            self.fail(self._at(path, index), f"must be finite, got {x!r}")
        if f32 and abs(x) > FLT_MAX:
            self.fits_f32(x, self._at(path, index))
        return x

    def fits_f32(self, x: float, path: str, what: str = "") -> None:
        """Fail unless ``x`` (named ``what`` in the message, if given) is finite as a float32."""
        if -FLT_MAX <= x <= FLT_MAX:          # the common case, without packing (NaN is not)
            return
        if not math.isfinite(_f32(x)):
            self.fail(path, f"{what + ' = ' if what else ''}{_g(x)} is beyond the float32 range "
                            f"the kernels compute in (|x| <= {_g(FLT_MAX)})")

    def _int_to_float(self, v: int, path: str, index: int | None) -> float:
        try:
            return float(v)
        except OverflowError:
            self.fail(self._at(path, index),
                      f"integer {_short(str(v), 30)} is too large for a float64")

    @staticmethod
    def _at(path: str, index: int | None) -> str:
        return path if index is None else f"{path}[{index}]"

    def nonneg(self, v: Any, path: str, index: int | None = None, f32: bool = True) -> float:
        x = self.num(v, path, index, f32)
        if x < 0:
            self.fail(self._at(path, index), f"must be >= 0, got {x!r}")
        return x

    def vec3(self, v: Any, path: str, nonneg: bool = False, f32: bool = True) -> Vec3:
        # The common case first: three floats that every check below accepts as
        # they are (finite, within float32 if ``f32``, >= 0 if ``nonneg``; -0.0 is).
        if type(v) is list and len(v) == 3:
            a, b, c = v
            if type(a) is float and type(b) is float and type(c) is float:
                hi = FLT_MAX if f32 else _F64_MAX
                lo = 0.0 if nonneg else -hi
                if lo <= a <= hi and lo <= b <= hi and lo <= c <= hi:
                    return (a, b, c)
        if not isinstance(v, (list, tuple)):
            self.fail(path, f"expected an array of 3 numbers [x, y, z], got {_describe(v)}")
        if len(v) != 3:
            self.fail(path, f"expected 3 numbers [x, y, z], got {len(v)}: "
                            f"{_short(repr(list(v)))}")
        f = self.nonneg if nonneg else self.num
        return (f(v[0], path, 0, f32), f(v[1], path, 1, f32), f(v[2], path, 2, f32))

    def unit(self, v: Any, path: str) -> Vec3:
        """A non-zero 3-vector, normalised in float64.

        A vector already unit to within 4 ulp is kept as it is, so that
        normalising is idempotent and ``to_dict`` round-trips exactly.
        """
        x, y, z = self.vec3(v, path, f32=False)
        n = math.hypot(x, y, z)
        if n == 0.0:
            self.fail(path, f"zero-length vector {[x, y, z]!r} has no direction")
        if abs(n - 1.0) <= 4 * _EPS:
            return (x, y, z)
        if not (1e-150 < n < 1e150):  # rescale to avoid overflow/subnormal loss
            m = max(abs(x), abs(y), abs(z))
            x, y, z = x / m, y / m, z / m
            n = math.hypot(x, y, z)
        return (x / n, y / n, z / n)

    def enum(self, v: Any, path: str, choices: tuple[str, ...]) -> str:
        if not isinstance(v, str):
            self.fail(path, f"expected a string, one of {_quoted_list(choices)}, "
                            f"got {_describe(v)}")
        if v not in choices:
            close = difflib.get_close_matches(v.lower(), choices, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            self.fail(path, f"invalid value {_short(repr(v))}; expected one of "
                            f"{_quoted_list(choices)}{hint}")
        return v

    def not_for_type(self, path: str, key: str, kind: str, type_: str,
                     keys_of: dict[str, tuple[str, ...]]) -> NoReturn:
        owners = [t for t, ks in keys_of.items() if key in ks]
        an = "an" if type_[0] in "aeiou" else "a"
        self.fail(_join(path, key),
                  f"does not apply to {an} {type_!r} {kind} (only to "
                  f"{' and '.join(repr(t) for t in owners)} {kind}s); "
                  f"{an} {type_!r} {kind} takes {_quoted_list(keys_of[type_])}")

    # -- sections ---------------------------------------------------------

    def scene(self, data: Any) -> Scene:
        if not isinstance(data, Mapping):
            self.fail("", f"expected a table of scene settings, got {_describe(data)}")
        self.check_keys(data, "", frozenset(_TOP_KEYS), _TOP_KEYS)
        if "material" not in data:
            self.fail("material", "missing required table [material]")
        # No [camera]: each frame's worldToCamera header attribute gives it.
        camera = self.camera(data["camera"]) if "camera" in data else Camera("metadata", up="y")
        material = self.material(data["material"])
        background: Vec3 = (0.0, 0.0, 0.0)
        color = ColorSettings()
        if "render" in data:
            background = self.render(data["render"])
            color = self.color_settings(data["render"])
        lights = self.lights(data.get("light", []))
        if "lights" in data:                          # a lights file: its rows after the tables
            lights += self.lights_file(data["lights"])
        self.check_scene(material, lights)
        aovs = self.aovs(data["render"]["aovs"], lights) if "aovs" in data.get("render", {}) else ()
        max_error, relative = self.budget(data.get("render", {}))
        return Scene(camera=camera, material=material, lights=lights, background=background,
                     source=self.source, warnings=tuple(self.warnings), color=color, aovs=aovs,
                     max_error=max_error, relative=relative)

    def budget(self, t: Mapping) -> tuple[float | None, bool]:
        """``render.max_error`` (≥ 0, as ``--max-error``) and ``render.relative`` (a bool
        that needs max_error, as ``--relative``)."""
        max_error = None
        if "max_error" in t:
            max_error = self.num(t["max_error"], "render.max_error")
            if max_error < 0:
                self.fail("render.max_error", f"expected a finite number ≥ 0, got {max_error!r}")
        relative = False
        if "relative" in t:
            relative = t["relative"]
            if type(relative) is not bool:
                self.fail("render.relative", f"expected true or false, got {_describe(relative)}")
            if relative and max_error is None:
                self.fail("render.relative", "needs render.max_error (a fraction of each "
                                             "pixel's own value, e.g. max_error = 1e-2)")
        return max_error, relative

    def aovs(self, v: Any, lights: tuple[Light, ...]) -> tuple[str, ...]:
        """``render.aovs``: AOV_NAMES and the lights' group names, each once."""
        if not isinstance(v, (list, tuple)) or not all(type(x) is str for x in v):
            self.fail("render.aovs", f"expected an array of layer names, e.g. "
                                     f"[\"diffuse\", \"specular\"], got {_describe(v)}")
        groups = dict.fromkeys(lt.group_name for lt in lights) if any(
            lt.group is not None for lt in lights) else {}
        for k, name in enumerate(v):
            if name not in AOV_NAMES and name not in groups:
                have = f"light groups {', '.join(groups)}" if groups else "no light groups"
                self.fail(f"render.aovs[{k}]", f"{_short(repr(name))} is neither a component "
                                               f"({', '.join(AOV_NAMES)}) nor a light group ({have})")
        return tuple(dict.fromkeys(v))

    def camera(self, v: Any) -> Camera:
        t = self.table(v, "camera")
        self.check_keys(t, "camera", _CAMERA_ALL, _CAMERA_ALL_ORDERED)
        if "type" not in t:
            self.fail("camera.type", f"missing required key; one of {_quoted_list(CAMERA_TYPES)}")
        type_ = self.enum(t["type"], "camera.type", CAMERA_TYPES)
        allowed = _CAMERA_KEYS[type_]
        for k in t:
            if k not in allowed:
                self.not_for_type("camera", k, "camera", type_, _CAMERA_KEYS)
        if type_ == "perspective":
            if "position" not in t:
                self.fail("camera.position", "missing; a 'perspective' camera needs the eye "
                                             "position, e.g. position = [0.0, 2.0, 6.0]")
            return Camera(type_, position=self.vec3(t["position"], "camera.position"))
        if type_ == "metadata":
            up = self.enum(t["up"], "camera.up", CAMERA_UP_AXES) if "up" in t else "y"
            return Camera(type_, up=up)
        if "direction" not in t:
            self.fail("camera.direction", "missing; an 'orthographic' camera needs the view "
                                          "direction (eye -> scene), e.g. direction = [0, 0, -1]")
        return Camera(type_, direction=self.unit(t["direction"], "camera.direction"))

    def material(self, v: Any) -> Material:
        t = self.table(v, "material")
        self.check_keys(t, "material", frozenset(_MATERIAL_KEYS), _MATERIAL_KEYS)
        for k in _MATERIAL_REQUIRED:
            if k not in t:
                self.fail(f"material.{k}", "missing required key")
        model = self.enum(t["model"], "material.model", MATERIAL_MODELS)
        k_a = self.nonneg(t["k_a"], "material.k_a", f32=False)   # only k_a·Σ ambient reaches the kernels
        k_d = self.nonneg(t["k_d"], "material.k_d")
        k_s = self.nonneg(t["k_s"], "material.k_s")
        h = self.nonneg(t["h"], "material.h")
        cs = _WHITE
        fresnel = self.enum(t["fresnel"], "material.fresnel", FRESNEL_MODELS) if "fresnel" in t \
            else "none"
        if fresnel == "none":
            if "f0" in t:
                self.fail("material.f0", "applies only with fresnel = \"schlick\" (Schlick's "
                                         "W = f0 + (1 - f0)(1 - cos a)^5)")
            if "specular_color" in t:
                cs = self.vec3(t["specular_color"], "material.specular_color", nonneg=True)
            return Material(model, k_a, k_d, k_s, h, cs)
        if "specular_color" in t:
            self.fail("material.specular_color", "does not apply with fresnel = \"schlick\": "
                                                 "W(a) replaces the constant C_s (f0 gives "
                                                 "its colour at normal incidence)")
        if "f0" not in t:
            self.fail("material.f0", "missing; fresnel = \"schlick\" needs the reflectance "
                                     "at normal incidence, e.g. f0 = 0.04 (scalar or [r, g, b])")
        f = t["f0"]
        f0 = self.vec3(f, "material.f0", nonneg=True) if isinstance(f, (list, tuple)) else \
            (self.nonneg(f, "material.f0"),) * 3
        for k, x in enumerate(f0):
            if x > 1.0:
                self.fail("material.f0" + (f"[{k}]" if isinstance(f, (list, tuple)) else ""),
                          f"{x!r} is above 1: f0 is a reflectance at normal incidence, in [0, 1]")
        return Material(model, k_a, k_d, k_s, h, fresnel=fresnel, f0=f0)

    def render(self, v: Any) -> Vec3:
        t = self.table(v, "render")
        self.check_keys(t, "render", frozenset(_RENDER_KEYS), _RENDER_KEYS)
        if "background" not in t:
            return (0.0, 0.0, 0.0)
        b = t["background"]
        if isinstance(b, (list, tuple)):
            return self.vec3(b, "render.background")
        if isinstance(b, (str, bool)) or not isinstance(b, numbers.Real):
            self.fail("render.background", "expected a number or an array of 3 numbers "
                                           f"[r, g, b], got {_describe(b)}")
        x = self.num(b, "render.background")
        return (x, x, x)

    def color_settings(self, t: Mapping) -> "ColorSettings":
        """Tone mapping and colour keys of [render] (the table is already checked)."""
        ws = "lin_rec709"
        if "working_space" in t:
            ws = self.enum(t["working_space"], "render.working_space", WORKING_SPACE_NAMES)
        exposure = 0.0
        if "exposure" in t:
            exposure = self.num(t["exposure"], "render.exposure")
            try:
                check_exposure(exposure, "render.exposure")
            except ToneMapError as exc:
                self.fail("render.exposure", exc.problem)
        op_name = "none"
        if "tonemap" in t:
            v = t["tonemap"]
            if not isinstance(v, str):
                self.fail("render.tonemap", f"expected a string, got {_describe(v)}")
            try:
                op_name = operator(v).name
            except ToneMapError as exc:
                self.fail("render.tonemap", str(exc))
        white = None
        if "white_point" in t:
            white = self.num(t["white_point"], "render.white_point")
            if white <= 0:
                self.fail("render.white_point", f"must be > 0, got {white!r}")
            if not operator(op_name).uses_white:
                self.warn("render.white_point", f"{op_name!r} has no white point; only "
                                                "'reinhard-extended' and 'hable' use it")
            try:
                # here, naming the file and key, not at the first frame (1e-300 with Hable)
                operator_params(op_name, white)
            except ToneMapError as exc:
                self.fail("render.white_point", exc.problem)
        names = {}
        for key, what in (("display", "display"), ("view", "view"), ("look", "look"),
                          ("albedo_space", "colour space")):
            if key in t:
                v = t[key]
                if not isinstance(v, str) or not v.strip():
                    self.fail(f"render.{key}", f"expected a non-empty string (an OCIO {what} "
                                               f"name), got {_describe(v)}")
                names[key] = v
        return ColorSettings(working_space=ws, exposure=exposure, tonemap=op_name,
                             white_point=white, **names)

    def lights(self, v: Any) -> tuple[Light, ...]:
        if not isinstance(v, (list, tuple)):
            if isinstance(v, Mapping):
                self.fail("light", "expected an array of tables, got a single table "
                                   "(write [[light]], not [light])")
            self.fail("light", f"expected an array of tables [[light]], got {_describe(v)}")
        one = self.light
        return tuple([one(lt, i) for i, lt in enumerate(v)])

    def lights_file(self, v: Any) -> tuple[Light, ...]:
        """``lights = "FILE"``: the rows of a .csv or .npz lights file (light_table)."""
        if type(v) is not str or not v.strip() or "\0" in v:
            tables = isinstance(v, (list, tuple, Mapping))
            self.fail("lights", "expected the name of a lights file (.csv or .npz, one light a "
                                f"row), got {_describe(v)}" +
                      ("; light tables are [[light]], not [[lights]]" if tables else ""))
        f = os.path.join(self.base_dir, v) if self.base_dir and not os.path.isabs(v) else v
        if self.table_parser is None:     # pragma: no cover - scene.py always gives one
            self.fail("lights", "lights files are not read by this parser")
        return self.table_parser(self, read_light_table(f, f"{self.source}: lights")).rows()

    def light(self, v: Any, i: int) -> Light:
        path = f"light[{i}]"
        if type(v) is not dict and not isinstance(v, Mapping):   # (an ABC check is slow)
            self.fail(path, f"expected a table, got {_describe(v)}")
        self.check_keys(v, path, _LIGHT_ALL, _LIGHT_ALL_ORDERED)
        if "type" not in v:
            self.fail(path + ".type", f"missing required key; one of "
                                      f"{_quoted_list(LIGHT_TYPES)}")
        type_ = v["type"]
        if type(type_) is not str or type_ not in _LIGHT_KEYS:
            self.enum(type_, path + ".type", LIGHT_TYPES)
        if not _LIGHT_SETS[type_].issuperset(v.keys()):
            allowed = _LIGHT_KEYS[type_]
            for k in v:
                if k not in allowed:
                    self.not_for_type(path, k, "light", type_, _LIGHT_KEYS)
        # color and intensity reach the kernels only as their product (checked
        # below), so either may be beyond float32 alone
        color = _WHITE
        if "color" in v:
            color = self.vec3(v["color"], path + ".color", nonneg=True, f32=False)
        group = self.group(v["group"], path + ".group") if "group" in v else None
        power = None
        if "power" in v:
            for other in ("intensity", "attenuation"):
                if other in v:
                    self.fail(path + ".power", f"give power (watts, with Cycles' 1/d^2 falloff) "
                                               f"or {other}, not both")
            power = self.nonneg(v["power"], path + ".power", f32=False)
            intensity = power * WATTS_TO_RADIANCE
            self.fits_f32(max(color) * intensity, path + ".power", "color x power/(4 pi^2)")
        else:
            intensity = 1.0
            if "intensity" in v:
                intensity = self.nonneg(v["intensity"], path + ".intensity", f32=False)
            self.fits_f32(max(color) * intensity, path + ".intensity", "color x intensity")
        if type_ == "environment":
            return self.environment(v, path, intensity, group)
        if type_ in POINT_TYPES:
            if "position" not in v:
                self.fail(path + ".position", f"missing; a {type_!r} light needs a position, "
                                              "e.g. position = [3.0, 5.0, 4.0]")
            position = self.vec3(v["position"], path + ".position")
            att = INVERSE_SQUARE if power is not None else _NO_FALLOFF
            if "attenuation" in v:
                apath = path + ".attenuation"
                att = self.vec3(v["attenuation"], apath)
                if att != _NO_FALLOFF:
                    falloff = self._falloffs.get(att)
                    if falloff is None:           # a rig's lights share a few polynomials
                        falloff = self._falloffs[att] = self.falloff(att, apath)
                    # The kernels form radiance x 1/p(d) in float32: an infinite
                    # one (times a weight of 0) is a NaN pixel.
                    radiance = max(color) * intensity           # rounded once to float32
                    peak = radiance * falloff * (1 + U)
                    if not -FLT_MAX <= peak <= FLT_MAX and not math.isfinite(_f32(peak)):
                        self.fail(apath, radiance_problem(radiance, att))
            if type_ == "spot":
                return new_light(type=type_, color=color, intensity=intensity, position=position,
                                 attenuation=att, power=power, group=group, **self.cone(v, path))
            return new_light(type=type_, color=color, intensity=intensity, position=position,
                             attenuation=att, power=power, group=group)
        if type_ == "directional":
            if "direction" not in v:
                self.fail(path + ".direction", "missing; a 'directional' light needs the "
                                               "direction it travels, e.g. "
                                               "direction = [-1.0, -1.5, -1.0]")
            return Light(type_, color, intensity,
                         direction=self.unit(v["direction"], path + ".direction"), group=group)
        return new_light(type=type_, color=color, intensity=intensity, group=group)

    def falloff(self, att: Vec3, apath: str) -> float:
        """The checks of an attenuation polynomial other than (1, 0, 0) on its own (the
        same for every light that has it): > 0 for d >= 0, normal float32 coefficients
        and a float32 p(d) that cannot round to 0; :func:`kernel_falloff_bound`, or 0
        with c0 = 0, where the falloff is unbounded as d -> 0 and its float32 range is
        checked per frame instead, at the nearest shaded pixel (clphong.device.frame)."""
        problem = attenuation_problem(*att)
        if problem is not None:
            self.fail(apath, f"{problem}; got {list(att)!r}")
        a32 = (_f32(att[0]), _f32(att[1]), _f32(att[2]))
        for k, (c, c32) in enumerate(zip(att, a32)):
            if c != 0 and abs(c32) < FLT_MIN:
                least = f"{FLT_MIN:.9g}"
                self.fail(f"{apath}[{k}]", f"{c!r} is nonzero but below the smallest "
                          "normal float32, so the kernels (which flush subnormals) "
                          "take it as 0; " + (f"c0 must be >= {least}" if k == 0 else
                                             f"write 0, or at least {least} in magnitude"))
        falloff = kernel_falloff_bound(*att) if att[0] != 0 else 0.0
        if math.isinf(falloff):
            self.fail(apath, f"{list(att)!r}: min p(d) = "
                             f"{_g(1 / largest_falloff(*att))} is so close to 0 "
                             "that p(d) = c0 + c1*d + c2*d^2 can round to 0 or "
                             "below in the kernels' float32 arithmetic (and the "
                             "float path and culling store the coefficients as "
                             "float32); keep it further from the limit")
        return falloff

    def cone(self, v: Mapping, path: str) -> dict:
        """A spot's axis and half-angles (degrees), 0 <= inner < outer <= 90."""
        if "direction" not in v:
            self.fail(path + ".direction", "missing; a 'spot' light needs the axis it points "
                                           "along, e.g. direction = [0.0, -1.0, 0.0]")
        axis = self.unit(v["direction"], path + ".direction")
        angles = {}
        for key, default in (("inner_angle", SPOT_INNER_DEFAULT),
                             ("outer_angle", SPOT_OUTER_DEFAULT)):
            x = self.num(v[key], path + "." + key, f32=False) if key in v else default
            if not 0.0 <= x <= 90.0:
                self.fail(path + "." + key, f"{x!r} is out of range: a spot's half-angle from "
                                            "its axis is in degrees, 0 <= inner < outer <= 90")
            angles[key] = x
        inner, outer = angles["inner_angle"], angles["outer_angle"]
        if inner >= outer:
            given = "" if "outer_angle" in v else " (the default)"
            self.fail(path + ".inner_angle", f"{inner!r} is not less than outer_angle = "
                                             f"{outer!r}{given}; the cone fades from inner to "
                                             "outer, so 0 <= inner < outer <= 90 (degrees)")
        s, _ = spot_scale_offset(inner, outer)
        if s > SPOT_MAX_SCALE:
            self.fail(path + ".outer_angle", f"the edge from inner_angle = {inner!r} to "
                      f"outer_angle = {outer!r} is too sharp for the kernels' float32 cone "
                      f"factor (cos inner - cos outer = {_g(1 / s)} < {_g(1 / SPOT_MAX_SCALE)}); "
                      "widen it")
        return {"direction": axis, "inner_angle": inner, "outer_angle": outer}

    def environment(self, v: Mapping, path: str, intensity: float, group: str | None) -> Light:
        """An environment light: its map (read and checked when the scene is
        rendered, clphong.io.envmap), intensity and rotation about +y."""
        if "file" not in v:
            self.fail(path + ".file", "missing; an 'environment' light needs a "
                                      "latitude-longitude map, e.g. file = \"sky.exr\"")
        f = v["file"]
        if type(f) is not str or not f or "\0" in f:
            self.fail(path + ".file", f"expected a file name (a non-empty string), got "
                                      f"{_describe(f)}")
        if self.base_dir and not os.path.isabs(f):
            f = os.path.join(self.base_dir, f)
        rotation = 0.0
        if "rotation" in v:
            rotation = self.num(v["rotation"], path + ".rotation", f32=False)
            if not abs(rotation) <= 1e6:
                self.fail(path + ".rotation", f"{rotation!r} degrees: give the rotation about "
                                              "the up axis in degrees, |rotation| <= 1e6")
        return Light("environment", intensity=intensity, file=f, rotation=rotation, group=group)

    def group(self, v: Any, path: str) -> str:
        if type(v) is not str:
            self.fail(path, f"expected a group name (a string), got {_describe(v)}")
        if not _GROUP_NAME.match(v):
            self.fail(path, f"{_short(repr(v))} is not a light-group name: it names EXR layers "
                            "(NAME.R, NAME.G, NAME.B), so use 1-63 letters, digits, '_' or '-', "
                            "starting with a letter or '_'")
        if v in AOV_NAMES:
            self.fail(path, f"{v!r} is the name of an AOV layer ({', '.join(AOV_NAMES)}); "
                            "choose another group name")
        return v

    def check_scene(self, m: Material, lights: tuple[Light, ...]) -> None:
        # The products the host forms before the kernels see them as float32.
        self.fits_f32(m.exponent, "material.h", "the exponent 4h of 'blinn-phong'")
        self.fits_f32(m.k_s * max(m.specular_color), "material.k_s", "k_s x specular_color")
        ambients = [lt.radiance for lt in lights if lt.type == "ambient"]
        amb = [math.fsum(rad[c] for rad in ambients) for c in range(3)]
        self.fits_f32(m.k_a * max(amb), "material.k_a", "k_a x the ambient lights' summed radiance")
        total = math.fsum((m.k_a, m.k_d, m.k_s))
        if total > 1.0 + _SUM_TOLERANCE:
            self.warn("material", f"k_a + k_d + k_s = {_g(total)} > 1: the surface reflects "
                                  "more light than it receives (the consistency rule); "
                                  "allowed, e.g. for HDR scenes")
        if m.k_a > 0 and not ambients:
            self.warn("material.k_a", f"k_a = {_g(m.k_a)} but the scene has no ambient light, "
                                      "so the ambient term is 0; add a [[light]] of "
                                      "type = \"ambient\"")

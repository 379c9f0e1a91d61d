"""Scene files: camera, material and lights, read from TOML and validated.

A scene file looks like this::

    [camera]
    type = "perspective"          # eye at `position`; v = normalize(eye - P)
    position = [0.0, 2.0, 6.0]
    # type = "orthographic"       # viewer at infinity: `direction` is the
    # direction = [0, -0.5, -1]   # view direction (eye -> scene)

    [material]
    model = "phong"               # or "blinn-phong" (exponent 4h)
    k_a = 0.1
    k_d = 0.7
    k_s = 0.2
    h = 32.0
    # specular_color = [1, 1, 1]  # default white

    [render]                      # optional table
    # background = [0, 0, 0]      # value written for background pixels

    [[light]]
    type = "point"
    position = [3.0, 5.0, 4.0]
    color = [1.0, 0.9, 0.8]
    intensity = 25.0
    attenuation = [1.0, 0.0, 0.0] # 1/(c0 + c1*d + c2*d^2); default no falloff

    [[light]]
    type = "directional"
    direction = [-1.0, -1.5, -1.0] # the direction the light TRAVELS
    color = [1.0, 1.0, 1.0]
    intensity = 3.0

    [[light]]
    type = "ambient"
    color = [1.0, 1.0, 1.0]
    intensity = 1.0

Rules
-----
* ``[material]`` is required; ``[camera]`` and ``[render]`` are optional.
* Without ``[camera]`` (or with ``type = "metadata"``) each frame's camera
  is its EXR header's standard ``worldToCamera`` matrix (see
  :mod:`clphong.io.camera`); ``up = "y"`` (default) or ``"z"`` names the
  up axis of the world that matrix is written in.
* The ``[[light]]`` list may be empty or absent: the image is then black
  except for the background (no light, no shading).
* ``lights = "rig.csv"`` (or ``"rig.npz"``), a top-level key before any table,
  names a lights file, relative to the scene file's folder: one light a row,
  in columns (``type, x, y, z, dx, dy, dz, r, g, b, intensity, power, c0, c1,
  c2, inner_angle, outer_angle, group``; :mod:`clphong.model.light_table`
  describes them), after the ``[[light]]`` tables in ``Scene.lights``. Each row
  gets every check a ``[[light]]`` table gets (vectorised over the columns, a
  row they cannot clear checked again as the table it stands for), and the
  messages name the file, the row (from 0) and the column:
  ``rig.csv: row 12 (line 14): intensity: must be >= 0, got -1.0``.
* Numbers may be written as TOML integers or floats; booleans and strings are
  not numbers. Every number is stored as a Python ``float`` (float64) and must
  be finite (no ``nan``, no ``inf``).
* ``k_a``, ``k_d``, ``k_s``, ``h``, light ``intensity`` and the components of
  ``color`` and ``specular_color`` must be >= 0. ``h = 0`` is allowed
  (``0^0 := 1``).
* Direction vectors (orthographic ``camera.direction``, directional
  ``light.direction``) must not have zero length; they are stored normalised.
* ``render.background`` is a 3-vector of finite numbers, or a single number
  used for all three channels; it defaults to ``[0, 0, 0]``.
* A point light's attenuation ``p(d) = c0 + c1*d + c2*d^2`` must be > 0 for
  every distance ``d >= 0`` (see :func:`attenuation_problem`); a nonzero
  coefficient must be a normal float32 (``|c| >= 1.17549435e-38``: the kernels
  flush smaller ones to 0), and the light's brightest radiance, ``color x
  intensity`` times the largest falloff ``1 / min p(d)`` (see
  :func:`largest_falloff`), must be within the float32 range.

Error messages
--------------
Every problem raises :class:`~clphong.core.errors.SceneError` with a single-line
message ``"<file>: <key path>: <problem>"``. Key paths are dotted TOML paths;
array elements are indexed **0-based**, like TOML arrays, so ``light[2]`` is
the third ``[[light]]`` table and ``light[2].color[0]`` its red component.
Messages about a light add a reminder such as
``(light[2] is the 3rd [[light]])``. Keys that are not TOML bare keys are
quoted. For example::

    scene.toml: light[2].intensity: expected a number, got string 'bright' (light[2] is the 3rd [[light]])
    scene.toml: material.k_dd: unknown key; did you mean 'k_d'?
    scene.toml:4:9: invalid TOML: Invalid value

Findings that are suspicious but legal are collected in ``Scene.warnings`` and
emitted with :func:`warnings.warn` as :class:`SceneWarning`.
"""

from __future__ import annotations

import contextlib
import difflib
import gc
import math
import numbers
import os
import re
import struct
import sys
import warnings as _warnings
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, fields
from decimal import MAX_EMAX, MIN_EMIN, Context, Decimal, localcontext
from fractions import Fraction
from functools import cached_property
from itertools import chain
from operator import attrgetter
from types import MappingProxyType
from typing import Any, NoReturn

import numpy as np

try:    # tomllib's own parser (tomllib is tomli), as a mypyc-compiled wheel: 2.3x faster
    import tomli as _toml
except ImportError:  # pragma: no cover - a platform without the compiled wheel
    import tomllib as _toml

from ..core.errors import SceneError, ToneMapError
from ..core.files import image_kind, open_regular
from ..core.floats import FLT_MAX, FLT_MIN, U
from ..core.memory import format_size, require_memory
from .light_table import VECTOR_COLUMNS, LightTable, column_of, read_light_table
from .options import check_exposure
from .tonemap import operator, operator_params

__all__ = [
    "Camera",
    "Material",
    "Light",
    "Scene",
    "SceneWarning",
    "load_scene",
    "parse_scene",
    "attenuation_problem",
    "largest_falloff",
    "kernel_falloff_bound",
    "CAMERA_TYPES",
    "CAMERA_UP_AXES",
    "MATERIAL_MODELS",
    "LIGHT_TYPES",
    "ColorSettings",
    "WORKING_SPACE_NAMES",
    "MATERIAL_MAPS",
    "MAP_KEYS",
    "INVERSE_SQUARE",
    "WATTS_TO_RADIANCE",
    "DEFAULT_GROUP",
    "AOV_NAMES",
]

Vec3 = tuple[float, float, float]

#: The per-pixel material maps (G-buffer ``maps``) and their channels, in the
#: order the kernels read them (kernels/shade.cl MAP_* rows): each overrides
#: the scene material's value of the same name.
MATERIAL_MAPS: Mapping[str, int] = MappingProxyType({"k_d": 1, "k_s": 1, "h": 1, "specular_color": 3})
MAP_KEYS: tuple[str, ...] = tuple(MATERIAL_MAPS)

#: Valid ``camera.type`` values.
CAMERA_TYPES: tuple[str, ...] = ("perspective", "orthographic", "metadata")
#: Valid ``camera.up`` values of a ``"metadata"`` camera (world up axis of worldToCamera).
CAMERA_UP_AXES: tuple[str, ...] = ("y", "z")
#: Valid ``material.model`` values.
MATERIAL_MODELS: tuple[str, ...] = ("phong", "blinn-phong")
#: Valid ``light.type`` values.
LIGHT_TYPES: tuple[str, ...] = ("point", "spot", "directional", "ambient", "environment")
#: Light types the kernels shade as point lights (a spot is a point light with a cone).
POINT_TYPES: tuple[str, ...] = ("point", "spot")
#: ``material.fresnel`` values: none (the constant k_s·C_s) or Schlick's W(α).
FRESNEL_MODELS: tuple[str, ...] = ("none", "schlick")

_TOP_KEYS = ("camera", "material", "render", "light", "lights")
_CAMERA_KEYS = {"perspective": ("type", "position"), "orthographic": ("type", "direction"),
                "metadata": ("type", "up")}
_CAMERA_ALL = frozenset(k for ks in _CAMERA_KEYS.values() for k in ks)
_CAMERA_ALL_ORDERED = ("type", "position", "direction", "up")
_MATERIAL_KEYS = ("model", "k_a", "k_d", "k_s", "h", "specular_color", "fresnel", "f0")
_MATERIAL_REQUIRED = ("model", "k_a", "k_d", "k_s", "h")
_RENDER_KEYS = ("background", "working_space", "exposure", "tonemap", "white_point",
                "display", "view", "look", "albedo_space", "aovs")
#: Valid ``render.working_space`` values (clphong.color.ocio.WORKING_SPACES).
WORKING_SPACE_NAMES: tuple[str, ...] = ("lin_rec709", "acescg")
_LIGHT_KEYS = {
    "point": ("type", "color", "intensity", "power", "position", "attenuation", "group"),
    "spot": ("type", "color", "intensity", "power", "position", "direction", "inner_angle",
             "outer_angle", "attenuation", "group"),
    "directional": ("type", "color", "intensity", "direction", "group"),
    "ambient": ("type", "color", "intensity", "group"),
    "environment": ("type", "file", "intensity", "rotation", "group"),
}
_LIGHT_SETS = {t: frozenset(ks) for t, ks in _LIGHT_KEYS.items()}
_LIGHT_ALL_ORDERED = ("type", "color", "intensity", "power", "position", "direction",
                      "inner_angle", "outer_angle", "attenuation", "file", "rotation", "group")
_LIGHT_ALL = frozenset(_LIGHT_ALL_ORDERED)
_LIGHT_REQUIRED = {"point": ("position",), "spot": ("position", "direction"),
                   "directional": ("direction",), "ambient": (), "environment": ("file",)}
#: A spot's cone half-angles (degrees) when not given: glTF KHR_lights_punctual's
#: defaults (inner 0, outer π/4).
SPOT_INNER_DEFAULT = 0.0
SPOT_OUTER_DEFAULT = 45.0

_WHITE: Vec3 = (1.0, 1.0, 1.0)
_NO_FALLOFF: Vec3 = (1.0, 0.0, 0.0)
#: A point light given by its ``power`` falls off as 1/d² (Cycles' convention).
INVERSE_SQUARE: Vec3 = (0.0, 0.0, 1.0)
#: Radiance per watt of a point light given by ``power`` (Cycles): radiant
#: intensity P/(4π) W/sr, times the Lambert BRDF's 1/π, so that k_d = 1 and the
#: albedo reproduce Cycles' direct diffuse light.
WATTS_TO_RADIANCE = 1.0 / (4.0 * math.pi ** 2)
#: Name of the light-group layer of lights without a ``group``.
DEFAULT_GROUP = "default"
#: Layer names the outputs use for their own passes: not light-group names.
AOV_NAMES = ("diffuse", "specular")
_GROUP_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,62}\Z")
_EPS = sys.float_info.epsilon
_F64_MAX = sys.float_info.max
#: k_a + k_d + k_s may exceed 1 by this much (decimal rounding) without a warning.
_SUM_TOLERANCE = 1e-9
_DEC_CTX = Context(prec=40, Emax=MAX_EMAX, Emin=MIN_EMIN)


class SceneWarning(UserWarning):
    """A scene is valid but probably not what was meant (see ``Scene.warnings``)."""


# --------------------------------------------------------------------------
# data model
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Camera:
    """Where the viewer is.

    Attributes
    ----------
    type : str
        ``"perspective"`` or ``"orthographic"``.
    position : tuple of 3 float or None
        Eye position of a perspective camera (``v = normalize(eye - P)``);
        None for an orthographic camera.
    direction : tuple of 3 float or None
        Unit view direction (eye -> scene) of an orthographic camera, so that
        ``v = -direction``; None for a perspective camera. Normalised in
        float64 when parsed.
    up : str or None
        For ``type = "metadata"`` (the camera comes from each frame's
        ``worldToCamera``): ``"y"`` or ``"z"``, the up axis of the world that
        matrix is written in; None for other types.
    """

    type: str
    position: Vec3 | None = None
    direction: Vec3 | None = None
    up: str | None = None

    def to_dict(self) -> dict:
        """The ``[camera]`` table as a dict that :func:`parse_scene` accepts."""
        d: dict[str, Any] = {"type": self.type}
        if self.type == "perspective":
            d["position"] = list(self.position) if self.position is not None else None
        elif self.type == "metadata":
            d["up"] = self.up or "y"
        else:
            d["direction"] = list(self.direction) if self.direction is not None else None
        return d


@dataclass(frozen=True)
class Material:
    """The uniform surface material.

    Attributes
    ----------
    model : str
        ``"phong"`` (``(r.v)^h``) or ``"blinn-phong"`` (``(n.h)^(4h)``).
    k_a, k_d, k_s : float
        Ambient, diffuse and specular coefficients, each >= 0.
    h : float
        Shininess, >= 0 (``0^0 := 1``).
    specular_color : tuple of 3 float
        Colour of the highlights, components >= 0; white by default, so each
        highlight takes its light's colour.
    fresnel : str
        ``"none"`` (the constant ``k_s·C_s``) or ``"schlick"``: Phong's weight
        W(α) in place of ``C_s`` (the seed's note 2), Schlick's
        ``W = f0 + (1 − f0)(1 − cos α)^5`` per channel, scaled by ``k_s``; α is
        the angle between v and the half vector h (Blinn-Phong) or the normal n
        (Phong).
    f0 : tuple of 3 float or None
        W at normal incidence (``"schlick"`` only), each in [0, 1].
    """

    model: str
    k_a: float
    k_d: float
    k_s: float
    h: float
    specular_color: Vec3 = _WHITE
    fresnel: str = "none"
    f0: Vec3 | None = None

    @property
    def exponent(self) -> float:
        """The specular exponent the kernels raise to: h for Phong, 4h for Blinn-Phong."""
        return 4.0 * self.h if self.model == "blinn-phong" else self.h

    def to_dict(self) -> dict:
        """The ``[material]`` table as a dict that :func:`parse_scene` accepts."""
        d = {"model": self.model, "k_a": self.k_a, "k_d": self.k_d, "k_s": self.k_s,
             "h": self.h}
        if self.fresnel == "schlick":
            d.update(fresnel=self.fresnel, f0=list(self.f0))
        else:
            d["specular_color"] = list(self.specular_color)
        return d


@dataclass(frozen=True)
class Light:
    """One ``[[light]]``.

    Attributes
    ----------
    type : str
        One of :data:`LIGHT_TYPES`: ``"point"``, ``"spot"``, ``"directional"``,
        ``"ambient"`` or ``"environment"``.
    color : tuple of 3 float
        Linear RGB in the working colour space, components >= 0.
    intensity : float
        Scale of ``color``, >= 0.
    position : tuple of 3 float or None
        Position of a point or spot light; None otherwise.
    direction : tuple of 3 float or None
        Unit direction a directional light travels (``l = -direction``), or
        the axis a spot light points along; None otherwise. Normalised in
        float64 when parsed.
    inner_angle, outer_angle : float or None
        A spot's cone half-angles in degrees from its axis, ``0 <= inner <
        outer <= 90``: full intensity inside ``inner``, none outside ``outer``,
        and glTF KHR_lights_punctual's ``t²`` between (:meth:`spot_scale_offset`);
        None for other types.
    file : str or None
        An environment light's latitude-longitude map (a relative path in a
        scene file is resolved against the file's folder); None otherwise.
    rotation : float
        An environment light's rotation about the up axis (+y), degrees.
    attenuation : tuple of 3 float
        ``(c0, c1, c2)`` of ``1/(c0 + c1*d + c2*d^2)`` for a point light;
        ``(1, 0, 0)`` (no falloff) by default and for other types. ``c0 = 0``
        (e.g. pure inverse-square ``(0, 0, 1)``) is allowed: the falloff is then
        unbounded as d -> 0, and its float32 range is checked per frame, at the
        nearest shaded pixel (:mod:`clphong.device.frame`).
    power : float or None
        The point light's power in watts as given (Cycles' convention); then
        ``intensity = power / (4*pi^2)`` and ``attenuation = (0, 0, 1)``.
    group : str or None
        Light-group name (``None``: the ``"default"`` group).
    """

    type: str
    color: Vec3 = _WHITE
    intensity: float = 1.0
    position: Vec3 | None = None
    direction: Vec3 | None = None
    attenuation: Vec3 = _NO_FALLOFF
    power: float | None = None
    group: str | None = None
    inner_angle: float | None = None
    outer_angle: float | None = None
    file: str | None = None
    rotation: float = 0.0

    def spot_scale_offset(self) -> tuple[float, float]:
        """``(s, o)`` of the cone factor ``t² , t = clamp(cos θ·s + o, 0, 1)``
        (glTF KHR_lights_punctual: ``s = 1/(cos inner − cos outer)``, ``o = −cos
        outer·s``), in float64; ``(0, 1)`` (factor 1) for a point light."""
        if self.type != "spot":
            return (0.0, 1.0)
        return spot_scale_offset(self.inner_angle, self.outer_angle)

    @property
    def group_name(self) -> str:
        """The light-group layer this light adds to: its ``group`` or ``"default"``."""
        return self.group if self.group is not None else DEFAULT_GROUP

    @property
    def radiance(self) -> Vec3:
        """``color * intensity``, per channel, as float64."""
        i = self.intensity
        c = self.color
        return (c[0] * i, c[1] * i, c[2] * i)

    def to_dict(self) -> dict:
        """The ``[[light]]`` table as a dict, with only the keys of its type."""
        d: dict[str, Any] = {"type": self.type, "color": list(self.color)}
        if self.power is not None:
            d["power"] = self.power
        else:
            d["intensity"] = self.intensity
        if self.type in POINT_TYPES:
            d["position"] = list(self.position) if self.position is not None else None
            if self.power is None:
                d["attenuation"] = list(self.attenuation)
            if self.type == "spot":
                d.update(direction=list(self.direction), inner_angle=self.inner_angle,
                         outer_angle=self.outer_angle)
        elif self.type == "environment":
            d = {"type": self.type, "file": self.file, "intensity": self.intensity,
                 "rotation": self.rotation}
        elif self.type == "directional":
            d["direction"] = list(self.direction) if self.direction is not None else None
        if self.group is not None:
            d["group"] = self.group
        return d


#: Light's fields and their defaults, for :func:`new_light`.
_LIGHT_FIELDS = {f.name: f.default for f in fields(Light)}
#: Whether a Light is nothing but its fields (no __post_init__, __slots__ or
#: default factory), so that :func:`new_light` may fill its __dict__ directly.
_LIGHT_PLAIN = (not hasattr(Light, "__post_init__") and "__slots__" not in vars(Light)
                and all(f.init and (f.default is not MISSING or f.name == "type")
                        for f in fields(Light)))


def new_light(**values: Any) -> Light:
    """``Light(**values)`` for values already validated, about 3x faster: the frozen
    dataclass's ``__init__`` sets each field through ``object.__setattr__`` (5 µs a
    light on the 2-core test machine, 0.3 s of loading 65 536 lights)."""
    if not _LIGHT_PLAIN:
        return Light(**values)
    lt = object.__new__(Light)
    d = _LIGHT_FIELDS.copy()
    d.update(values)
    object.__setattr__(lt, "__dict__", d)
    return lt


@dataclass(frozen=True)
class ColorSettings:
    """Tone mapping and colour management keys of ``[render]``.

    Attributes
    ----------
    working_space : str
        ``"lin_rec709"`` (default) or ``"acescg"``: the space albedo, light
        colours and the scene-linear EXR are in.
    exposure : float
        Stops; display outputs see the scene-linear value times 2^exposure.
    tonemap : str
        Operator of the fused display path (:data:`clphong.model.tonemap.OPERATORS`).
    white_point : float or None
        White point of ``reinhard-extended`` / ``hable`` (operator default if None).
    display, view, look : str or None
        OCIO display, view and look(s); any of them selects the OCIO path.
    albedo_space : str or None
        OCIO colour space the G-buffer's albedo is in, converted to the working
        space before shading (None: it is in the working space).
    """

    working_space: str = "lin_rec709"
    exposure: float = 0.0
    tonemap: str = "none"
    white_point: float | None = None
    display: str | None = None
    view: str | None = None
    look: str | None = None
    albedo_space: str | None = None

    def to_dict(self) -> dict:
        """The keys of ``[render]`` that are set (None has no TOML form)."""
        d: dict[str, Any] = {"working_space": self.working_space, "exposure": self.exposure,
                             "tonemap": self.tonemap}
        for k in ("white_point", "display", "view", "look", "albedo_space"):
            if getattr(self, k) is not None:
                d[k] = getattr(self, k)
        return d


@dataclass(frozen=True)
class Scene:
    """A validated scene.

    Attributes
    ----------
    camera : Camera
    material : Material
    lights : tuple of Light
        In file order; may be empty.
    background : tuple of 3 float
        Value written for background pixels.
    source : str
        Where the scene came from (a file path), used in messages.
    warnings : tuple of str
        Non-fatal findings, each a single line naming ``source``.
    aovs : tuple of str
        ``render.aovs``: extra output layers (``diffuse``, ``specular``, light-group
        names), as ``--aov`` (which replaces them).
    """

    camera: Camera
    material: Material
    lights: tuple[Light, ...] = ()
    background: Vec3 = (0.0, 0.0, 0.0)
    source: str = "<scene>"
    warnings: tuple[str, ...] = ()
    color: "ColorSettings" = None  # type: ignore[assignment]  # set in __post_init__
    aovs: tuple[str, ...] = ()

    def __post_init__(self):
        if self.color is None:
            object.__setattr__(self, "color", ColorSettings())

    def lights_of(self, type: str) -> tuple[Light, ...]:  # noqa: A002 - API name
        """The lights of one type, in file order.

        Parameters
        ----------
        type : str
            One of :data:`LIGHT_TYPES`.

        Returns
        -------
        tuple of Light

        Raises
        ------
        ValueError
            If ``type`` is not a light type (a typo would otherwise silently
            select no lights).
        """
        if type not in LIGHT_TYPES:
            raise ValueError(f"unknown light type {type!r}; expected one of "
                             f"{_quoted_list(LIGHT_TYPES)}")
        return self._lights_by_type[type]

    # The scene is immutable, so what is derived from its lights is computed once
    # (a renderer asks for it every frame and band; 65 536 lights took ~0.25 s a
    # frame in Python loops). dataclasses.replace() makes a new scene, and new caches.
    _CACHED = ("_lights_by_type", "light_arrays")

    def __getstate__(self):
        # Pickles (process pools, Dask) carry the fields only: the caches are
        # rebuilt where they are used (5 MB more at 65 536 lights otherwise).
        return {k: v for k, v in self.__dict__.items() if k not in self._CACHED}

    @cached_property
    def _lights_by_type(self) -> dict[str, tuple[Light, ...]]:
        by: dict[str, list[Light]] = {t: [] for t in LIGHT_TYPES}
        for lt in self.lights:
            by[lt.type].append(lt)
        return {t: tuple(v) for t, v in by.items()}

    @cached_property
    def light_arrays(self) -> Mapping[str, Any]:
        """The lights as read-only float64 numpy arrays, computed once (a read-only mapping).

        Keys: ``point_position``, ``point_radiance``, ``point_attenuation``
        (N, 3) each (c0, c1, c2), over the point and spot lights (a spot is a
        point light with a cone); ``point_cone`` (N, 5): a spot's unit axis and
        the ``(s, o)`` of :meth:`Light.spot_scale_offset` (a point light's: 0 axis,
        ``(0, 1)``, a factor of exactly 1); ``point_is_spot`` (N,) bool;
        ``directional_direction``,
        ``directional_radiance`` (M, 3); ``ambient_radiance`` (3,), the sum of
        the ambient lights' radiance (before k_a).

        With light groups (:attr:`light_groups`) the point and directional
        lights are in group order (stable: file order within a group), as the
        kernels sum them group by group; ``point_index`` and
        ``directional_index`` give each one's index in :attr:`lights`;
        ``point_group_end`` and ``directional_group_end`` (G,) the end of each
        group's run, and ``ambient_group_radiance`` (G, 3) each group's summed
        ambient radiance.
        """
        # Whole columns at once: per-light Python is only the attribute reads (the
        # radiance c·i is numpy's float64 product, the same rounding as Light.radiance).
        lights = self.lights

        def frozen(a):
            a = np.asarray(a)
            a.setflags(write=False)
            return a

        def triples(lts, attr):              # (twice as fast as np.array of the tuples)
            return np.fromiter(chain.from_iterable(map(attrgetter(attr), lts)), np.float64,
                               3 * len(lts)).reshape(-1, 3)

        def vectors(lts, attr):
            return frozen(triples(lts, attr))

        def radiance(lts):
            intensity = np.fromiter(map(attrgetter("intensity"), lts), np.float64, len(lts))
            return triples(lts, "color") * intensity[:, None]

        groups = self.light_groups
        rank = {g: k for k, g in enumerate(groups)}
        types = [lt.type for lt in lights]
        gid = (np.array([rank[lt.group_name] for lt in lights], np.intp) if groups
               else np.zeros(len(lights), np.intp))

        def in_group_order(kinds):
            idx = np.array([i for i, t in enumerate(types) if t in kinds], np.intp)
            if groups:
                idx = idx[np.argsort(gid[idx], kind="stable")]
            return idx, [lights[i] for i in idx.tolist()]

        pi, pts = in_group_order(POINT_TYPES)
        di, dirs = in_group_order(("directional",))
        cone = np.zeros((len(pts), 5))
        cone[:, 4] = 1.0
        spot = np.array([lt.type == "spot" for lt in pts], bool)
        so: dict[tuple, tuple[float, float]] = {}       # a rig's spots share a few cones
        for k in np.flatnonzero(spot).tolist():
            lt = pts[k]
            cone[k, :3] = lt.direction
            key = (lt.inner_angle, lt.outer_angle)
            if key not in so:
                so[key] = lt.spot_scale_offset()
            cone[k, 3:] = so[key]
        ambients = self.lights_of("ambient")
        amb = frozen(radiance(ambients).sum(axis=0))
        ends = {name: frozen(np.searchsorted(gid[idx], np.arange(len(groups)), side="right"))
                for name, idx in (("point", pi), ("directional", di))}
        amb_g = np.zeros((len(groups), 3))
        for lt in ambients if groups else ():
            amb_g[rank[lt.group_name]] += lt.radiance
        return MappingProxyType({
            "point_position": vectors(pts, "position"), "point_radiance": frozen(radiance(pts)),
            "point_attenuation": vectors(pts, "attenuation"), "point_cone": frozen(cone),
            "point_is_spot": frozen(spot),
            "directional_direction": vectors(dirs, "direction"),
            "directional_radiance": frozen(radiance(dirs)), "ambient_radiance": amb,
            "point_index": frozen(pi.astype(int)), "directional_index": frozen(di.astype(int)),
            "point_group_end": ends["point"], "directional_group_end": ends["directional"],
            "ambient_group_radiance": frozen(amb_g)})

    @cached_property
    def light_groups(self) -> tuple[str, ...]:
        """The light-group layers, in first-appearance order: () unless some light
        has a ``group``; then every light's :attr:`Light.group_name` (``"default"``
        for a light without one)."""
        if not any(lt.group is not None for lt in self.lights):
            return ()
        return tuple(dict.fromkeys(lt.group_name for lt in self.lights))

    def to_dict(self) -> dict:
        """The scene as plain dicts, lists, floats and strings.

        The result has the layout of a scene file and round-trips:
        ``parse_scene(s.to_dict(), s.source) == s``. Every optional key is
        written out explicitly.

        Returns
        -------
        dict
        """
        return {
            "camera": self.camera.to_dict(),
            "material": self.material.to_dict(),
            "render": {"background": list(self.background), **self.color.to_dict(),
                       **({"aovs": list(self.aovs)} if self.aovs else {})},
            "light": [lt.to_dict() for lt in self.lights],
        }


# --------------------------------------------------------------------------
# spot cones
# --------------------------------------------------------------------------

#: The largest cone scale s = 1/(cos inner − cos outer) a spot may have: the
#: kernels form t = cos θ·s + o in float32 (|o| ≤ s), which errs by about 4u·s,
#: so this keeps the cone factor's rounding error ≤ 2⁻⁴ at the sharpest edge
#: allowed (cos inner − cos outer ≥ 3.8e-6, e.g. 10° and 10.0013°).
SPOT_MAX_SCALE = 2.0 ** 18


def spot_scale_offset(inner: float, outer: float) -> tuple[float, float]:
    """``(s, o)`` of glTF KHR_lights_punctual's spot factor for half-angles in
    degrees: ``t = clamp(cos θ·s + o, 0, 1)``, factor ``t²``, with
    ``s = 1/(cos inner − cos outer)`` and ``o = −cos outer·s`` (float64); ``s = ∞``
    where the cosines are equal in float64 (e.g. 0 and 1e-40), an edge no scene
    accepts (:data:`SPOT_MAX_SCALE`)."""
    ci, co = math.cos(math.radians(inner)), math.cos(math.radians(outer))
    if outer == 90.0:
        co = 0.0                   # cos(π/2) is 6e-17 in float64: the horizon exactly
    if ci <= co:
        return (math.inf, -math.inf)
    s = 1.0 / (ci - co)
    return (s, -co * s)


#: The ratio of glTF's fade width to Cycles' in cos θ that minimises the largest
#: difference between t² and Cycles' smoothstep: 0.107 (docs/lighting.md, "Spot lights").
BLENDER_SPOT_FIT = 1.255


def spot_angles_from_blender(spot_size: float, spot_blend: float) -> tuple[float, float]:
    """``(inner_angle, outer_angle)`` in degrees for a Blender spot: ``spot_size`` the
    full cone in **radians** as bpy gives it (Blender's interface shows degrees),
    0 < spot_size <= π, and ``spot_blend`` in [0, 1]. outer = spot_size/2 and
    cos inner = cos outer + spot_blend·(1 − cos outer)/:data:`BLENDER_SPOT_FIT`, so
    that t² follows Cycles' smoothstep fade within 0.107; a blend of 0 (Cycles' hard
    edge) gives the sharpest edge the scene allows (:data:`SPOT_MAX_SCALE`).

    Raises
    ------
    ValueError
        For a size or blend out of range (a size in degrees, e.g. 45, is one).
    """
    if not (0.0 < spot_size <= math.pi):
        raise ValueError(f"spot_size {spot_size!r} is not in (0, pi]: Blender's spot_size is the "
                         "full cone in radians (bpy's value; the interface shows degrees)")
    if not (0.0 <= spot_blend <= 1.0):
        raise ValueError(f"spot_blend {spot_blend!r} is not in [0, 1]")
    outer = math.degrees(spot_size / 2)
    co = 0.0 if outer == 90.0 else math.cos(spot_size / 2)
    width = max(spot_blend * (1.0 - co) / BLENDER_SPOT_FIT, 1.0001 / SPOT_MAX_SCALE)
    return math.degrees(math.acos(min(co + width, 1.0))), outer


# --------------------------------------------------------------------------
# attenuation
# --------------------------------------------------------------------------


def attenuation_problem(c0: float, c1: float, c2: float) -> str | None:
    """Why ``p(d) = c0 + c1*d + c2*d^2`` is not > 0 for all ``d > 0``, if it is not.

    ``p(d) > 0`` for every ``d > 0`` exactly when either ``c0 = 0``, ``c1 >= 0``,
    ``c2 >= 0`` and not both are 0 (physical falloffs such as pure inverse-square
    ``(0, 0, 1)``: ``p(0) = 0``, where a light adds nothing, the kernels' d = 0
    guard), or ``c0 > 0`` and

    * ``c2 > 0`` and (``c1 >= 0`` or ``c1^2 < 4*c0*c2``), or
    * ``c2 == 0`` and ``c1 >= 0``.

    (``c2 < 0`` always fails: the ``d^2`` term wins at large ``d``.) The
    discriminant is compared exactly, in rational arithmetic on the float64
    values, so there is no rounding at the boundary.

    Parameters
    ----------
    c0, c1, c2 : float
        Finite coefficients.

    Returns
    -------
    str or None
        None when the polynomial stays positive; otherwise a one-line
        description of where it reaches zero or goes negative, e.g.
        ``"p(d) = c0 + c1*d reaches 0 at d = 2.5 and goes negative for d > 2.5
        (c1 = -0.4 < 0 with c2 = 0); need c1 >= 0"``.
    """
    if c0 == 0:
        if c1 == 0 and c2 == 0:
            return "p(d) = 0 for every d (c0 = c1 = c2 = 0): no finite falloff"
        if c1 < 0 or c2 < 0:
            return (f"with c0 = 0, p(d) = d*(c1 + c2*d) is negative for small or large d "
                    f"(c1 = {_g(c1)}, c2 = {_g(c2)}); with c0 = 0 both must be >= 0")
        return None
    if c0 < 0:
        return (f"p(d) = c0 + c1*d + c2*d^2 is negative at d = 0 (c0 = {_g(c0)}); "
                "c0 must be >= 0")
    if c2 < 0:
        r = _gd(max(_roots(c0, c1, c2)))
        return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r} and goes negative for "
                f"d > {r} (c2 = {_g(c2)} < 0, so the d^2 term wins at large d); "
                "need c2 >= 0")
    if c1 >= 0:
        return None
    if c2 == 0:
        r = _gd(_quotient(c0, -c1))
        return (f"p(d) = c0 + c1*d reaches 0 at d = {r} and goes negative for "
                f"d > {r} (c1 = {_g(c1)} < 0 with c2 = 0); need c1 >= 0")
    # c0 > 0, c1 < 0, c2 > 0: both roots (if real) are positive.
    f0, f1, f2 = Fraction(c0), Fraction(c1), Fraction(c2)
    disc = f1 * f1 - 4 * f0 * f2
    if disc < 0:
        return None
    if disc == 0:
        r = _gd(_half(_quotient(-c1, c2)))
        return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r} (a double root: "
                "c1^2 = 4*c0*c2); need c1 >= 0 or c1^2 < 4*c0*c2")
    r1, r2 = (_gd(r) for r in sorted(_roots(c0, c1, c2)))
    return (f"p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = {r1} and goes negative for "
            f"{r1} < d < {r2} (c1 < 0 and c1^2 > 4*c0*c2); "
            "need c1 >= 0 or c1^2 < 4*c0*c2")


def largest_falloff(c0: float, c1: float, c2: float) -> float:
    """``1 / min p(d)`` over ``d >= 0``, for a ``p(d) = c0 + c1*d + c2*d^2`` that
    :func:`attenuation_problem` accepts: ``1/c0`` when ``c1 >= 0``, else the
    vertex value ``1 / (c0 - c1^2/(4*c2))`` (exact rational arithmetic); ``inf``
    beyond float64.

    >>> largest_falloff(0.5, 0.0, 1.0), largest_falloff(1.0, -2.0, 2.0)
    (2.0, 2.0)
    """
    if c1 >= 0:
        return 1.0 / c0            # inf, not an error, beyond float64
    # c2 > 0: the minimum is at d = -c1/(2*c2) > 0
    p = Fraction(c0) - Fraction(c1) ** 2 / (4 * Fraction(c2))
    try:
        return float(1 / p)
    except OverflowError:
        return math.inf


def kernel_falloff_bound(c0: float, c1: float, c2: float) -> float:
    """An upper bound of the falloff ``1/p(d)`` the float32 kernels compute at any
    ``d >= 0``; ``inf`` where their ``p(d)`` may round to 0 or below.

    docs/error-model.md, row "attenuation 1/p(d)": Horner's roundings (and the
    coefficients' own) move ``p(d)`` by at most ``4u*(c0 + |c1|*d + |c2|*d^2)``,
    the reciprocal and the rest add ``3u`` relative (``u = 2^-24``). So the bound
    is ``(1 + 3u) * largest_falloff`` of ``p(d) - 4u*(c0 + |c1|*d + c2*d^2)``.
    (A changed ``d``, from the directions' errors, is still some ``d >= 0``.)
    """
    k = 4 * U
    lo = (c0 * (1 - k), c1 - k * abs(c1), c2 * (1 - k))
    if attenuation_problem(*lo) is not None:
        return math.inf
    return largest_falloff(*lo) * (1 + 3 * U)


def radiance_problem(radiance: float, att: Vec3) -> str:
    """The message for a light whose ``max(color) x intensity`` (``radiance``) times
    the largest falloff of ``att`` is beyond float32 (see :func:`kernel_falloff_bound`)."""
    return ("color x intensity x the largest falloff 1/min p(d) = "
            f"{_g(radiance * largest_falloff(*att))} is beyond the "
            "float32 range the kernels compute in (|x| <= "
            f"{_g(FLT_MAX)}, less their rounding error); lower the "
            "intensity or raise the minimum of p(d)")


def _roots(c0: float, c1: float, c2: float) -> tuple[Decimal, Decimal]:
    """Both real roots of ``c2*d^2 + c1*d + c0`` (``c2 != 0``, ``c0 != 0``).

    Only used for messages. Computed with the numerically stable form of the
    quadratic formula in 40-digit decimal arithmetic, whose exponent range
    covers any float64 coefficients (their squares and quotients included).
    """
    with localcontext(_DEC_CTX):
        a, b, c = Decimal(c2), Decimal(c1), Decimal(c0)
        disc = max(b * b - 4 * a * c, Decimal(0))
        root = disc.sqrt()
        q = -(b + root if b >= 0 else b - root) / 2
        return (q / a, c / q)


def _quotient(n: float, d: float) -> Decimal:
    """``n / d`` without overflow or underflow (for messages)."""
    with localcontext(_DEC_CTX):
        return Decimal(n) / Decimal(d)


def _half(x: Decimal) -> Decimal:
    with localcontext(_DEC_CTX):
        return x / 2


def _gd(x: Decimal) -> str:
    """A short form of a (possibly out-of-float-range) root for messages."""
    if x == 0 or Decimal("1e-300") < abs(x) < Decimal("1e300"):
        return _g(float(x))
    return re.sub(r"\.?0+e", "e", f"{x:.5e}")


def _f32(x: float) -> float:
    """``x`` rounded to float32 (as the kernels store it), back as a float."""
    try:
        return struct.unpack("f", struct.pack("f", x))[0]
    except OverflowError:
        return math.copysign(math.inf, x)


# --------------------------------------------------------------------------
# message helpers
# --------------------------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+\Z")
_LIGHT_PATH = re.compile(r"light\[(\d+)\]")


def _g(x: float) -> str:
    """A short human form of a float for messages."""
    return f"{x:.6g}"


def _ordinal(n: int) -> str:
    if 10 <= n % 100 <= 20:
        suffix = "th"
    else:
        suffix = {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def _short(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _quoted_list(items) -> str:
    return ", ".join(repr(i) for i in items)


def _key(k: Any) -> str:
    """A key as it appears in a path: bare if TOML allows it, else quoted."""
    if isinstance(k, str) and _BARE_KEY.match(k):
        return k
    return _short(repr(k), 40)


def _join(path: str, key: Any) -> str:
    return f"{path}.{_key(key)}" if path else _key(key)


def _describe(v: Any) -> str:
    """What a value is, for 'expected X, got Y' messages."""
    if isinstance(v, bool):
        return f"boolean {'true' if v else 'false'}"
    if isinstance(v, int):
        return f"integer {_short(str(v), 30)}"
    if isinstance(v, float):
        return f"float {v!r}"
    if isinstance(v, str):
        return f"string {_short(repr(v))}"
    if isinstance(v, Mapping):
        return f"table {{{_short(', '.join(_key(k) for k in v), 50)}}}"
    if isinstance(v, (list, tuple)):
        return f"array {_short(repr(list(v)))}"
    if v is None:
        return "nothing (None)"
    return f"{type(v).__name__} {_short(repr(v))}"


def _one_line(text: str) -> str:
    """Escape anything that could break a message over several lines."""
    if text.isprintable():
        return text
    return "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text)


def _message(source: str, path: str, problem: str) -> str:
    head = f"{source}: {path}: " if path else f"{source}: "
    m = _LIGHT_PATH.match(path)
    note = ""
    if m:
        i = int(m.group(1))
        note = f" (light[{i}] is the {_ordinal(i + 1)} [[light]])"
    return _one_line(head + problem + note)


# --------------------------------------------------------------------------
# the validator
# --------------------------------------------------------------------------


class _Parser:
    """Validates plain data against the scene schema; raises on the first problem."""

    def __init__(self, source: str, base_dir: str = ""):
        self.source = source
        self.base_dir = base_dir      # the scene file's folder: relative file names start there
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
        return Scene(camera=camera, material=material, lights=lights, background=background,
                     source=self.source, warnings=tuple(self.warnings), color=color, aovs=aovs)

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
        return _TableParser(self, read_light_table(f, f"{self.source}: lights")).rows()

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


#: Light types a lights file's rows may have (an environment light needs a map file).
TABLE_TYPES: tuple[str, ...] = ("point", "spot", "directional", "ambient")
#: The key each column of a lights file gives.
_KEY_OF_COLUMN = {**{c: key for key, cols in VECTOR_COLUMNS.items() for c in cols},
                  **{c: c for c in ("type", "intensity", "power", "inner_angle", "outer_angle",
                                    "group")}}
_ROW_PATH = re.compile(r"light\[(\d+)\]\.?(.*)\Z", re.S)


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(a, axis=0, return_inverse=True)`` of a (k, m) float array without
    NaN, at once where every row is the first (a rig's lights share one falloff)."""
    if (a == a[0]).all():
        return a[:1], np.zeros(len(a), np.intp)
    uniq, inv = np.unique(a, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1)


class _TableParser(_Parser):
    """The rows of a lights file (:mod:`clphong.model.light_table`) checked as
    ``[[light]]`` tables are, vectorised: each check runs on whole columns, and a
    row that any check cannot clear is checked again by :meth:`_Parser.light`
    itself (as the table ``{"type": ..., "position": [x, y, z], ...}`` it stands for),
    which raises the message a ``[[light]]`` would get, naming the file, the row and
    the column (``light[i].color[1]`` -> ``<file>: row i: g``). Structural problems
    (a cell a row's type does not take, an empty cell it needs) have messages of
    their own. The first row with a problem is reported."""

    def __init__(self, parent: _Parser, table: LightTable):
        super().__init__(parent.source, parent.base_dir)
        self.table = table
        self.warnings = parent.warnings
        self._falloffs = parent._falloffs           # shared: the same polynomials

    def fail(self, path: str, problem: str) -> NoReturn:
        m = _ROW_PATH.match(path)
        if m is None:
            raise self.table.error(None, path, problem)
        raise self.table.error(int(m.group(1)), column_of(m.group(2)), problem)

    def warn(self, path: str, problem: str) -> None:
        m = _ROW_PATH.match(path)
        self.warnings.append(self.table.message(int(m.group(1)) if m else None,
                                                column_of(m.group(2)) if m else path, problem))

    def _clears(self, check, *args) -> bool:
        try:
            check(*args)
            return True
        except SceneError:
            return False

    def rows(self) -> tuple[Light, ...]:
        t, n = self.table, self.table.rows
        num, txt = t.numbers, t.text
        given = {c: ~np.isnan(a) for c, a in num.items()}
        none = np.zeros(n, bool)
        problems: list[tuple[np.ndarray, Any]] = []   # (rows, fn(row) -> raises), in check order

        # -- the type of each row
        if "type" in txt:
            index = {x: k for k, x in enumerate(TABLE_TYPES)}
            code = np.array([index.get(x, -1) for x in txt["type"].tolist()], np.int8).reshape(n)
            problems.append((code < 0, lambda r: self.type_problem(str(txt["type"][r]), r)))
        else:
            code = np.zeros(n, np.int8)                           # every row a point light
        is_t = {x: code == k for k, x in enumerate(TABLE_TYPES)}
        type_names = np.array(TABLE_TYPES + ("?",))

        def takes(key: str) -> np.ndarray:
            m = none.copy()
            for x in TABLE_TYPES:
                if key in _LIGHT_KEYS[x]:
                    m |= is_t[x]
            return m

        def ty(r: int) -> str:
            return str(type_names[code[r]])

        # -- structure: cells a type does not take, cells it needs, keys it needs
        pg = given.get("power", none)
        ig = given.get("intensity", none)
        point = is_t["point"] | is_t["spot"]
        for c in num:
            key = _KEY_OF_COLUMN[c]
            applies = takes(key)
            problems.append((given[c] & ~applies, lambda r, c=c, key=key: self.not_taken(r, c, key, ty(r))))
            if key == "power":
                problems.append((given[c] & ig, lambda r: self.fail(
                    f"light[{r}].power", "give power (watts, with Cycles' 1/d^2 falloff) or "
                                         "intensity, not both")))
                needed = applies & ~ig if "intensity" in num else applies
            elif key == "intensity":
                needed = applies & ~(point & pg) if "power" in num else applies
            elif key == "attenuation":
                problems.append((given[c] & pg, lambda r: self.fail(
                    f"light[{r}].power", "give power (watts, with Cycles' 1/d^2 falloff) or "
                                         "attenuation, not both")))
                needed = applies & ~pg
            else:
                needed = applies
            missing = needed & ~given[c]
            problems.append((missing, lambda r, c=c, key=key, m=missing:
                             self.empty(r, c, key, ty(r), int(m.sum()))))
        for key, types_ in (("position", point), ("direction", is_t["spot"] | is_t["directional"])):
            cols = VECTOR_COLUMNS[key]
            if cols[0] not in num:
                problems.append((types_, lambda r, key=key, cols=cols: self.table_fail(
                    r, ", ".join(cols), f"missing; a {ty(r)!r} light needs a {key}: give the "
                                        f"columns {', '.join(cols)}")))
        bad = none.copy()
        for rows, _ in problems:
            bad |= rows

        # -- values: every check _Parser.light makes, on whole columns; a row not
        #    cleared is checked again by _Parser.light itself (the exact check)
        def col(c: str, default: float) -> np.ndarray:
            return np.where(given[c], num[c], default) if c in num else np.full(n, default)

        ok = ~bad
        if "group" in txt:                  # each name once (a rig has a few)
            names = txt["group"].tolist()
            valid = {x: x == "" or self._clears(self.group, x, "light[0].group") for x in set(names)}
            ok &= np.array([valid[x] for x in names], bool).reshape(n)
        with np.errstate(over="ignore", invalid="ignore"):    # beyond float64: not cleared
            self.values(ok, col, given, is_t, point, pg)
        intensity = np.where(pg, col("power", 0.0) * WATTS_TO_RADIANCE, col("intensity", 1.0))

        # -- the first row with a problem raises; a row only not cleared is a light
        exact: dict[int, Light] = {}
        for r in np.flatnonzero(~ok).tolist():
            if bad[r]:
                for rows, raise_for in problems:
                    if rows[r]:
                        raise_for(r)
                raise AssertionError(f"row {r} flagged but no check raised")  # pragma: no cover
            exact[r] = _Parser.light(self, self.row(r, code), r)
        return self.build(code, intensity, exact)

    def values(self, ok, col, given, is_t, point, pg) -> None:
        """Clear, in ``ok``, the rows that pass every value check of _Parser.light
        (conservatively: a row not cleared is checked again by _Parser.light itself)."""
        num, none = self.table.numbers, np.zeros(self.table.rows, bool)
        r_, g_, b_ = col("r", 1.0), col("g", 1.0), col("b", 1.0)
        ok &= (r_ >= 0) & (g_ >= 0) & (b_ >= 0)
        power = col("power", 0.0)
        ok &= col("intensity", 0.0) >= 0
        ok &= power >= 0
        intensity = np.where(pg, power * WATTS_TO_RADIANCE, col("intensity", 1.0))
        radiance = np.maximum(np.maximum(r_, g_), b_) * intensity
        ok &= np.abs(radiance) <= FLT_MAX
        if "x" in num:
            x, y, z = col("x", 0.0), col("y", 0.0), col("z", 0.0)
            ok &= ~point | ((np.abs(x) <= FLT_MAX) & (np.abs(y) <= FLT_MAX) & (np.abs(z) <= FLT_MAX))
        with_dir = is_t["spot"] | is_t["directional"]
        if "dx" in num:
            dx, dy, dz = col("dx", 0.0), col("dy", 0.0), col("dz", 0.0)
            ok &= ~with_dir | (dx != 0) | (dy != 0) | (dz != 0)
        ag = given.get("c0", none) & point
        if ag.any():
            c = np.stack([num["c0"], num["c1"], num["c2"]], axis=1)
            ok &= ~ag | (np.abs(c) <= FLT_MAX).all(axis=1)         # each a float32, too
            falls = (c[:, 0] != 1) | (c[:, 1] != 0) | (c[:, 2] != 0)
            rows = np.flatnonzero(ag & falls & ok)
            if rows.size:
                uniq, inv = _unique_rows(c[rows])
                bound = np.empty(len(uniq))
                for k, att in enumerate(map(tuple, uniq.tolist())):
                    f = self._falloffs.get(att)
                    if f is None:
                        try:
                            f = self._falloffs[att] = self.falloff(att, "light[0].attenuation")
                        except SceneError:
                            f = math.nan                    # the row's own check says why
                    bound[k] = f
                peak = radiance[rows] * bound[inv.reshape(-1)] * (1 + U)
                ok[rows] &= np.abs(peak) <= FLT_MAX           # NaN: a polynomial not cleared
        spot = is_t["spot"]
        inner, outer = col("inner_angle", SPOT_INNER_DEFAULT), col("outer_angle", SPOT_OUTER_DEFAULT)
        rows = np.flatnonzero(spot & ok)
        if rows.size:
            uniq, inv = _unique_rows(np.stack([inner[rows], outer[rows]], axis=1))
            cok = np.array([self._clears(self.cone, {"direction": [0.0, 0.0, 1.0],
                                                     "inner_angle": a, "outer_angle": b},
                                         "light[0]") for a, b in uniq.tolist()], bool)
            ok[rows] &= cok[inv.reshape(-1)]

    # -- messages of the structural checks

    def table_fail(self, r: int, column: str, problem: str) -> NoReturn:
        raise self.table.error(r, column, problem)

    def type_problem(self, value: str, r: int) -> NoReturn:
        if value == "":
            self.table_fail(r, "type", f"empty; one of {_quoted_list(TABLE_TYPES)}")
        if value == "environment":
            self.table_fail(r, "type", "an 'environment' light needs a map file: give it as a "
                                       "[[light]] table in the scene")
        self.enum(value, f"light[{r}].type", TABLE_TYPES)
        raise AssertionError(value)  # pragma: no cover

    def not_taken(self, r: int, c: str, key: str, type_: str) -> NoReturn:
        owners = [x for x in TABLE_TYPES if key in _LIGHT_KEYS[x]]
        an = "an" if type_[0] in "aeiou" else "a"
        self.table_fail(r, c, f"{_g(float(self.table.numbers[c][r]))} but {an} {type_!r} light "
                              f"takes no {key} (only {' and '.join(map(repr, owners))} lights "
                              "do); leave the cell empty" +
                        (" (NaN in .npz)" if self.table.lines is None else ""))

    def empty(self, r: int, c: str, key: str, type_: str, count: int) -> NoReturn:
        an = "an" if type_[0] in "aeiou" else "a"
        if key in ("intensity", "power") and type_ in POINT_TYPES:
            need = "gives intensity or power"
        else:
            need = f"takes {key} and the file has the column"
        what = "empty" if self.table.lines is not None else "NaN (an empty cell)"
        self.table_fail(r, c, f"{what}; {an} {type_!r} light {need} ({count} such cell(s) in "
                              f"column {c})")

    # -- the lights

    def row(self, r: int, code: np.ndarray) -> dict:
        """Row ``r`` as the ``[[light]]`` table it stands for (its cells that are there)."""
        t = self.table
        d: dict[str, Any] = {"type": TABLE_TYPES[code[r]]}
        for key, cols in VECTOR_COLUMNS.items():
            if cols[0] in t.numbers and not math.isnan(t.numbers[cols[0]][r]):
                d[key] = [float(t.numbers[c][r]) for c in cols]
        for c in ("intensity", "power", "inner_angle", "outer_angle"):
            if c in t.numbers and not math.isnan(t.numbers[c][r]):
                d[c] = float(t.numbers[c][r])
        if "group" in t.text and t.text["group"][r]:
            d["group"] = str(t.text["group"][r])
        return d

    def build(self, code: np.ndarray, intensity: np.ndarray, exact: dict[int, Light]) -> tuple[Light, ...]:
        """The Light of each row that every check cleared (and ``exact``'s own), made
        as :func:`new_light` makes them: a tight loop over the columns as lists."""
        t, n = self.table, self.table.rows
        num = t.numbers

        def vectors(key, default):
            c = VECTOR_COLUMNS[key]
            if c[0] not in num:
                return [default] * n
            return [None if v[0] != v[0] else v for v in zip(*(num[x].tolist() for x in c))]

        def scalars(c, default):
            if c not in num:
                return [default] * n
            return [default if v != v else v for v in num[c].tolist()]

        colors = vectors("color", _WHITE)
        pos, dirs, atts = vectors("position", None), vectors("direction", None), vectors("attenuation", None)
        powers = scalars("power", None)
        inner = scalars("inner_angle", SPOT_INNER_DEFAULT)
        outer = scalars("outer_angle", SPOT_OUTER_DEFAULT)
        groups = [g or None for g in t.text["group"].tolist()] if "group" in t.text else [None] * n
        proto = _LIGHT_FIELDS.copy()
        unit, new, set_dict, plain = self.unit, object.__new__, object.__setattr__, _LIGHT_PLAIN
        out = []
        for r, k, c, i, g, p, w, a in zip(range(n), code.tolist(), colors, intensity.tolist(),
                                          groups, pos, powers, atts):
            lt = exact.get(r) if exact else None
            if lt is None:
                d = proto.copy()
                d["type"], d["color"], d["intensity"], d["group"] = TABLE_TYPES[k], c, i, g
                if k <= 1:                                          # point, spot
                    d["position"], d["power"] = p, w
                    d["attenuation"] = a if a is not None else \
                        INVERSE_SQUARE if w is not None else _NO_FALLOFF
                    if k == 1:
                        d["direction"] = unit(list(dirs[r]), f"light[{r}].direction")
                        d["inner_angle"], d["outer_angle"] = inner[r], outer[r]
                elif k == 2:                                        # directional
                    d["direction"] = unit(list(dirs[r]), f"light[{r}].direction")
                if plain:
                    lt = new(Light)
                    set_dict(lt, "__dict__", d)
                else:                                               # pragma: no cover
                    lt = Light(**d)
            out.append(lt)
        return tuple(out)


# --------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------


def _emit(scene: Scene, stacklevel: int) -> None:
    for w in scene.warnings:
        _warnings.warn(w, SceneWarning, stacklevel=stacklevel + 1)


def _parse(data: Mapping, source: str, base_dir: str = "") -> Scene:
    with _gc_paused():
        return _Parser(source, base_dir).scene(data)


@contextlib.contextmanager
def _gc_paused():
    """The cyclic garbage collector off for a while (if it was on): parsing makes
    objects by the million and no cycles, and each of the collector's passes over
    the growing heap took 20-50% of validating 65 536 lights."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def parse_scene(data: Mapping, source: str = "<scene>") -> Scene:
    """Validate scene data (as :func:`tomllib.load` returns it) into a :class:`Scene`.

    Parameters
    ----------
    data : Mapping
        The top-level table: ``camera``, ``material``, optional ``render``
        and optional ``light`` (a list of tables).
    source : str, optional
        Name of where the data came from, used in messages.

    Returns
    -------
    Scene
        With ``source`` set and any warnings in ``Scene.warnings``; each
        warning is also emitted with :func:`warnings.warn` as
        :class:`SceneWarning`.

    Raises
    ------
    SceneError
        On the first problem found, with a one-line message
        ``"<source>: <key path>: <problem>"``.
    """
    source = _one_line(str(source))
    scene = _parse(data, source)
    _emit(scene, stacklevel=2)
    return scene


_TOML_POS = re.compile(r"\s*\(at line (\d+), column (\d+)\)\s*$")
#: What tomllib (before Python 3.14) says instead of a line and column at the end.
_TOML_END = re.compile(r"\s*\(at end of document\)\s*$")


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a TOML scene file.

    Parameters
    ----------
    path : str or os.PathLike
        The scene file (UTF-8 TOML).

    Returns
    -------
    Scene
        ``Scene.source`` is ``path`` as given.

    Raises
    ------
    SceneError
        If the file cannot be read (``"<path>: cannot read scene file: ..."``),
        is not UTF-8, is not valid TOML (``"<path>:<line>:<col>: invalid
        TOML: ..."``), or fails validation (see :func:`parse_scene`).
    """
    source = _one_line(os.fspath(path) if not isinstance(path, bytes)
                       else os.fsdecode(path))
    try:
        # only a regular file: a FIFO would block forever, /dev/zero read until out of memory
        with open_regular(path, SceneError, "scene file") as f:
            _check_scene_memory(source, os.fstat(f.fileno()).st_size)
            raw = f.read()
    except FileNotFoundError:
        raise SceneError(f"{source}: cannot read scene file: no such file") from None
    except IsADirectoryError:
        raise SceneError(f"{source}: cannot read scene file: it is a directory") from None
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise SceneError(_one_line(f"{source}: cannot read scene file: {reason}")) from None
    image = image_kind(source, raw)
    if image:
        raise SceneError(f"{source}: this is {image} image, not a scene file; give the scene "
                         ".toml first: clphong render SCENE.toml GBUFFER.exr ...")
    try:
        # utf-8-sig: a byte-order mark (Windows editors write one) is read past, as the
        # lights CSV's is; TOML itself has no place for it ("Invalid statement" at 1:1)
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise SceneError(f"{source}:{line}: invalid TOML: not UTF-8 (byte {exc.start}); "
                         "save the file as UTF-8") from None
    try:
        data = _toml.loads(text)
    except _toml.TOMLDecodeError as exc:
        raise SceneError(_toml_message(source, exc, text)) from None
    except RecursionError:
        # tomllib parses nested arrays and inline tables recursively: a few
        # hundred levels exhaust the interpreter's stack (found by fuzzing).
        raise SceneError(f"{source}: invalid TOML: arrays or inline tables nested too deeply "
                         "for the parser (a scene needs at most 2 levels)") from None
    except MemoryError:
        raise SceneError(f"{source}: out of memory parsing a {len(raw)}-byte scene file") from None
    scene = _parse(data, source, os.path.dirname(os.fspath(path) if not isinstance(path, bytes)
                                                 else os.fsdecode(path)))
    _emit(scene, stacklevel=2)
    return scene


#: Peak bytes of memory per byte of TOML while parsing (tomllib and the scene
#: objects), an upper bound from tracemalloc measurements: 14-39 for scene-like
#: documents (50 000 lights as [[light]] tables 18, as inline tables 23-26),
#: 102 for the worst found, a document of empty [tN] tables.
SCENE_BYTES_PER_BYTE = 128


def _check_scene_memory(source: str, size: int) -> None:
    """Refuse a scene file whose parse could exhaust memory (instead of being killed)."""
    require_memory(SCENE_BYTES_PER_BYTE * size,
                   f"{source}: parsing a {format_size(size)} scene file", SceneError,
                   "use fewer lights, or set CLPHONG_MAX_MEMORY (e.g. 16G) if you know "
                   "there is more memory")


def _toml_message(source: str, exc: _toml.TOMLDecodeError, text: str = "") -> str:
    msg = str(exc.args[0]) if exc.args else str(exc)
    line = getattr(exc, "lineno", None)
    col = getattr(exc, "colno", None)
    if getattr(exc, "msg", None):  # Python >= 3.14 keeps the bare message
        msg = exc.msg
    m = _TOML_POS.search(msg)
    end = _TOML_END.search(msg)
    if m:
        line, col = int(m.group(1)), int(m.group(2))
        msg = msg[: m.start()]
    elif end:                     # the position len(text), counted as tomllib counts
        line = text.count("\n") + 1
        col = len(text) - text.rfind("\n") if line > 1 else len(text) + 1
        msg = msg[: end.start()]
    where = f"{source}:{line}:{col}" if line is not None else source
    return _one_line(f"{where}: invalid TOML: {msg}")

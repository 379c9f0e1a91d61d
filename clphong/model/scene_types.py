"""The scene's types: camera, material, lights, colour settings and the scene itself, with
their names and constants (:mod:`clphong.model.scene` reads them from TOML)."""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, fields
from functools import cached_property
from itertools import chain
from operator import attrgetter
from types import MappingProxyType
from typing import Any

import numpy as np

from ..core.memory import gc_paused
from .falloff import (
    Vec3,
    spot_scale_offset,
)
from .scene_messages import (
    _quoted_list,
)

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
                "display", "view", "look", "albedo_space", "aovs", "max_error", "relative")
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


def directional_lights(l, radiance, group: str | None = None) -> tuple[Light, ...]:
    """Directional lights from columns: each shines from the unit direction ``l`` (N, 3)
    (so travels along ``direction = −l``) with ``color`` its row of ``radiance`` (N, 3)
    and intensity 1, in ``group``: an environment's lights (clphong.io.envmap), a few
    hundred thousand at a time, with the garbage collector paused
    (:func:`~clphong.core.memory.gc_paused`)."""
    columns = LightColumns(-np.asarray(l, np.float64).reshape(-1, 3),
                           np.array(radiance, np.float64).reshape(-1, 3), group)
    with gc_paused():
        return tuple(columns)


def directional_scene(camera: "Camera", material: "Material", l, radiance, *,
                      source: str) -> "Scene":
    """A scene of directional lights only, no groups, made from columns: the same scene
    as ``Scene(camera, material, directional_lights(l, radiance), source=source)`` to the
    bit (each light's direction −l and radiance its row of ``radiance``, intensity 1),
    without a Light object a light. An environment conversion's probe sums
    (clphong.device.envprobe) shade a few hundred thousand lights this way: the objects
    took 1.6 s of a 4.5 s conversion (the 1024 × 512 sky with the spheres' material).

    Its ``lights`` is a :class:`LightColumns`, which makes a Light only when one is
    asked for; :attr:`Scene.light_arrays` and :meth:`Scene.lights_of` are filled from
    the columns at once."""
    lights = LightColumns(-np.asarray(l, np.float64).reshape(-1, 3),
                          np.array(radiance, np.float64).reshape(-1, 3))
    scene = Scene(camera=camera, material=material, lights=lights, source=source)
    empty = np.zeros((0, 3))

    def frozen(a):
        a = np.asarray(a)
        a.setflags(write=False)
        return a

    cone = np.zeros((0, 5))
    none = np.zeros(0, np.intp)
    arrays = MappingProxyType({
        "point_position": frozen(empty), "point_radiance": frozen(empty.copy()),
        "point_attenuation": frozen(empty.copy()), "point_cone": frozen(cone),
        "point_is_spot": frozen(np.zeros(0, bool)),
        "directional_direction": lights.direction, "directional_radiance": lights.radiance,
        "ambient_radiance": frozen(np.zeros(3)), "point_index": frozen(none.astype(int)),
        "directional_index": frozen(np.arange(len(lights))),
        "point_group_end": frozen(none), "directional_group_end": frozen(none.copy()),
        "ambient_group_radiance": frozen(np.zeros((0, 3)))})
    # the caches Scene computes from its lights (cached_property: the instance's
    # __dict__ entry is what it reads), filled from the columns
    scene.__dict__["light_arrays"] = arrays
    scene.__dict__["_lights_by_type"] = {t: (lights if t == "directional" else ())
                                         for t in LIGHT_TYPES}
    scene.__dict__["light_groups"] = ()
    return scene


class LightColumns(Sequence):
    """Directional lights held as columns (:func:`directional_scene`): ``direction`` (N, 3)
    each light's direction of travel, ``radiance`` (N, 3), both read-only float64,
    intensity 1, in ``group``. Indexing makes the Light (:func:`new_light`); a slice is
    columns again."""

    __slots__ = ("direction", "radiance", "group")

    def __init__(self, direction: np.ndarray, radiance: np.ndarray, group: str | None = None):
        if len(direction) != len(radiance):
            raise ValueError(f"{len(direction)} directions but {len(radiance)} radiances")
        for a in (direction, radiance):
            a.setflags(write=False)
        self.direction = direction
        self.radiance = radiance
        self.group = group

    def __len__(self) -> int:
        return len(self.direction)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return LightColumns(self.direction[i].copy(), self.radiance[i].copy(), self.group)
        return self._light(self.radiance[i].tolist(), self.direction[i].tolist())

    def __iter__(self):
        return map(self._light, self.radiance.tolist(), self.direction.tolist())

    def _light(self, color: list, direction: list) -> Light:
        return new_light(type="directional", color=tuple(color), intensity=1.0,
                         direction=tuple(direction), group=self.group)

    def __repr__(self) -> str:
        return f"LightColumns({len(self)} directional lights)"


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
    max_error : float or None
        ``render.max_error``: the culling budget, as ``--max-error`` (which replaces
        it, with ``--relative``); None: brute force.
    relative : bool
        ``render.relative``: ``max_error`` is a fraction of each pixel's own value,
        as ``--relative``.
    env_tables : tuple of (EnvTables, str or None)
        Environment lights resolved into the kernels' tables
        (:class:`clphong.model.env_table.EnvTables`) and their light group; their suns are
        directional lights in :attr:`lights`. Set by
        :func:`clphong.io.envmap.resolve_environment`, never by a scene file.
    """

    camera: Camera
    material: Material
    lights: tuple[Light, ...] = ()
    background: Vec3 = (0.0, 0.0, 0.0)
    source: str = "<scene>"
    warnings: tuple[str, ...] = ()
    color: "ColorSettings" = None  # type: ignore[assignment]  # set in __post_init__
    aovs: tuple[str, ...] = ()
    max_error: float | None = None
    relative: bool = False
    env_tables: tuple = ()

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
                       **({"aovs": list(self.aovs)} if self.aovs else {}),
                       **({"max_error": self.max_error} if self.max_error is not None else {}),
                       **({"relative": True} if self.relative else {})},
            "light": [lt.to_dict() for lt in self.lights],
        }

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

import os
import re
import warnings as _warnings
from collections.abc import Mapping

try:    # Rust's toml crate: large scene files (BIG_TOML) parse 1.9x faster than with tomli
    import rtoml as _rtoml
except ImportError:  # pragma: no cover - a dependency; tomli alone then
    _rtoml = None
try:    # tomllib's own parser (tomllib is tomli), as a mypyc-compiled wheel: 2.3x faster
    import tomli as _toml
except ImportError:  # pragma: no cover - a platform without the compiled wheel
    import tomllib as _toml

from ..core.errors import SceneError
from ..core.files import image_kind, open_regular
from ..core.memory import format_size, gc_paused, require_memory
from .falloff import (
    attenuation_problem,
    kernel_falloff_bound,
    largest_falloff,
    spot_angles_from_blender,
    spot_scale_offset,
)
from .scene_messages import (
    _one_line,
)
from .scene_parser import (
    _Parser,
)
from .scene_table import (
    _TableParser,
)
from .scene_types import (
    AOV_NAMES,
    CAMERA_TYPES,
    CAMERA_UP_AXES,
    DEFAULT_GROUP,
    INVERSE_SQUARE,
    LIGHT_TYPES,
    MAP_KEYS,
    MATERIAL_MAPS,
    MATERIAL_MODELS,
    WATTS_TO_RADIANCE,
    WORKING_SPACE_NAMES,
    Camera,
    ColorSettings,
    Light,
    Material,
    Scene,
    SceneWarning,
    LightColumns,
    directional_lights,
    directional_scene,
    new_light,
)

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
    "new_light",
    "directional_lights",
    "directional_scene",
    "LightColumns",
    "spot_angles_from_blender",
    "spot_scale_offset",
]


# --------------------------------------------------------------------------
# public entry points
# --------------------------------------------------------------------------


def _emit(scene: Scene, stacklevel: int) -> None:
    for w in scene.warnings:
        _warnings.warn(w, SceneWarning, stacklevel=stacklevel + 1)


def _parse(data: Mapping, source: str, base_dir: str = "") -> Scene:
    with gc_paused():
        return _Parser(source, base_dir, table_parser=_TableParser).scene(data)


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
        with gc_paused():          # the parsers make dicts and lists by the million, no cycles
            data = _loads(text)
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


#: Scene files from this size on (about 3,700 lights as [[light]] tables) are parsed by
#: rtoml (Rust's toml crate): 0.72 s against tomli's 1.34 s for 65,536 lights, the same
#: dictionary. A file rtoml refuses is parsed by tomli again, so every error reads as before.
BIG_TOML = 1 << 20


def _loads(text: str) -> dict:
    """The TOML document ``text`` as tomllib returns it (see BIG_TOML)."""
    if len(text) >= BIG_TOML and _rtoml is not None:
        try:
            return _rtoml.loads(text)
        except Exception:     # rtoml.TomlParsingError, or anything else it says: tomli's words
            pass
    return _toml.loads(text)


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

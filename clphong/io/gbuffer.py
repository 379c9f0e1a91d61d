"""Reading (and writing) G-buffers from OpenEXR files, by channel NAME.

A G-buffer holds, per pixel, the world-space position ``P``, the world-space
normal ``N`` (as stored, not normalised) and the diffuse albedo ``C_d``;
optionally a coverage (alpha) and per-pixel material maps. Channels are always
looked up by their names in the EXR header (``spec.channelnames``), never by
their index, so the channel order in the file does not matter.

Accepted channel names
----------------------
A *vector layer* ``L`` matches the channels ``L.X, L.Y, L.Z``, else
``L.x, L.y, L.z``, else ``L.R, L.G, L.B``, else ``L.r, L.g, L.b``. A
*scalar* ``S`` matches the channel ``S`` itself, or the only channel of a
one-channel layer ``S.*`` (e.g. Blender's value AOV ``k_s.X``).

The conventions are tried in this order; the first one that has all of
position, normal and albedo wins:

``generic``
    position ``P``, normal ``N``, albedo ``albedo`` (all vector layers).
``arnold``
    Arnold AOVs: position ``P``, normal ``N``, albedo ``albedo`` or
    ``diffuse_albedo``. Reported as ``arnold`` rather than ``generic`` when
    the albedo is ``diffuse_albedo``, when ``P`` or ``N`` use R/G/B
    components, or when the header has ``arnold/*`` attributes.
``mitsuba``
    Mitsuba 3's ``aov`` integrator: position ``pos``, normal ``sh_normal``
    (else ``geo_normal``), albedo ``albedo``.
``blender``
    Cycles/EEVEE multilayer EXR: ``<ViewLayer>.Position``,
    ``<ViewLayer>.Normal`` and ``<ViewLayer>.DiffCol`` or (newer Blender)
    ``<ViewLayer>.Diffuse Color``. ``<ViewLayer>`` is any view-layer name
    (``ViewLayer``, ``RenderLayer``, ...) and may be absent (compositor File
    Output). With several view layers the first complete one, in channel
    order, is used; ``GBuffer.sources`` names it.
``rgb-files``
    Separate files, one per buffer (``position=``, ``normal=``,
    ``albedo=``), each holding just that buffer as plain ``R, G, B`` (or
    ``X, Y, Z``, ``x, y, z``, ``r, g, b``). A separate file may also hold the
    buffer as a layer of any convention above, which is preferred.
``explicit``
    Position, normal and albedo all named through ``channels=``.

Coverage (``0`` = background), first found of: for Blender
``<ViewLayer>.Combined.A`` and ``<ViewLayer>.Alpha``; then ``A``,
``RGBA.A``, ``rgba.A`` (a multi-part beauty part named ``rgba``) and the
albedo layer's ``.A`` (e.g. ``albedo.A``).

Material maps (optional; Blender names may carry the view-layer prefix):
``k_d`` (scalar) -> ``maps["k_d"]``; ``k_s`` (scalar) -> ``maps["k_s"]``;
``shininess`` (scalar) -> ``maps["h"]``; ``specular_color`` or ``Cs``
(vector layer) -> ``maps["specular_color"]``.

``channels=`` (or ``--channels KEY=VALUE`` on the command line) overrides
detection per buffer; keys are ``position``, ``normal``, ``albedo``,
``coverage``, ``k_d``, ``k_s``, ``h`` and ``specular_color``. A value is a
layer prefix (``"Pworld"`` -> ``Pworld.X/Y/Z``, ``.x/y/z`` or ``.R/G/B``;
for a scalar key the exact channel name or a one-channel layer) or an explicit
list, or comma-separated string, of exact channel names (3 for vector
buffers, 1 for scalars).

Half and float pixels, scanline and tiled files are read; the result is
always float32. Multi-part files (Blender 5's default multilayer output, Nuke,
Arnold, Karma, RenderMan) are read as one set of channels: the channels of
every part are gathered by their full names, and in a part named by its layer
(``ViewLayer.Position``) a bare channel name (``X``) gets that prefix
(``ViewLayer.Position.X``). A channel name found in two parts is an error. The
parts must share one display window; each may have its own data window. Deep
files are rejected. If the data
window differs from the display window the pixels are placed in the display
window and the rest is zero (background). Separate files may have different
data windows: a pixel is shaded only where position, normal and albedo all
have data (elsewhere it is background); data windows that do not overlap at
all are an error. Reading is refused, with the sizes, when the channels would
not fit in memory (see :mod:`clphong.device.bands`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import sys
import tempfile
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import OpenImageIO as oiio

from ..core.errors import GBufferError, InputWarning
from ..core.files import image_signature, not_regular
from ..core.memory import require_memory
from ..model.scene import MAP_KEYS, MATERIAL_MAPS
from .atomic import _one_line, check_pixel_type, write_exr
from .nonfinite import all_finite

__all__ = ["GBuffer", "read_gbuffer", "write_gbuffer", "parse_channel_mapping",
           "CHANNEL_KEYS", "VECTOR_KEYS", "SCALAR_KEYS", "WRITE_CONVENTIONS"]

#: The three buffers every G-buffer needs.
REQUIRED = ("position", "normal", "albedo")
#: Keys of ``channels=`` that name 3-channel buffers.
VECTOR_KEYS = REQUIRED + tuple(k for k, c in MATERIAL_MAPS.items() if c == 3)
#: Keys of ``channels=`` that name 1-channel buffers.
SCALAR_KEYS = ("coverage",) + tuple(k for k, c in MATERIAL_MAPS.items() if c == 1)
#: Optional buffers: coverage and the material maps (clphong.model.scene.MAP_KEYS).
OPTIONAL = ("coverage", *MAP_KEYS)
#: Every valid key of ``channels=``, in a stable order.
CHANNEL_KEYS = REQUIRED + OPTIONAL
#: Rows per band of a G-buffer read (:meth:`_ExrFile.read_stacked`), rounded to whole
#: chunks of the file: 64 rows of 1920 pixels and 10 float channels are 4.9 MB.
BAND_ROWS = 64
#: Conventions :func:`write_gbuffer` can write.
WRITE_CONVENTIONS = ("generic", "blender", "blender-new", "arnold", "mitsuba")

_COMPONENTS = (("X", "Y", "Z"), ("x", "y", "z"), ("R", "G", "B"), ("r", "g", "b"))

_LOOKED_FOR = {
    "position": "P.X/Y/Z (or .x/y/z, .R/G/B), pos.*, <ViewLayer>.Position.*",
    "normal": "N.*, sh_normal.*, geo_normal.*, <ViewLayer>.Normal.*",
    "albedo": "albedo.*, diffuse_albedo.*, <ViewLayer>.DiffCol.*, <ViewLayer>.Diffuse Color.*",
}

# Layer names of each required buffer per convention (single-file detection).
_GENERIC_LAYERS = {"position": ("P",), "normal": ("N",), "albedo": ("albedo", "diffuse_albedo")}
_MITSUBA_LAYERS = {"position": ("pos",), "normal": ("sh_normal", "geo_normal"), "albedo": ("albedo",)}
_BLENDER_PASSES = {"position": ("Position",), "normal": ("Normal",), "albedo": ("DiffCol", "Diffuse Color")}


# --------------------------------------------------------------------------- GBuffer


@dataclass
class GBuffer:
    """A G-buffer: per-pixel world-space position, normal and albedo.

    Attributes
    ----------
    position : numpy.ndarray
        (H, W, 3) float32, C-contiguous, world-space position ``P``.
    normal : numpy.ndarray
        (H, W, 3) float32, world-space normal ``N`` as stored (not
        normalised).
    albedo : numpy.ndarray
        (H, W, 3) float32 diffuse colour ``C_d``.
    coverage : numpy.ndarray or None
        (H, W) float32 alpha/coverage if the file has it; 0 is background.
    maps : dict of str to numpy.ndarray
        Optional per-pixel material maps, only those present: ``"k_d"``,
        ``"k_s"``, ``"h"`` (shininess), each (H, W), and
        ``"specular_color"`` (H, W, 3); float32.
    convention : str
        Detected naming convention: ``"generic"``, ``"blender"``,
        ``"arnold"``, ``"mitsuba"``, ``"rgb-files"`` or ``"explicit"``.
    sources : dict of str to str
        Buffer name -> ``"file.exr: P.X,P.Y,P.Z"`` (for messages and
        ``inspect``).
    attributes : dict of str to object
        Header attributes of the (first) file, e.g. ``"worldToCamera"``.
    """

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    coverage: np.ndarray | None = None
    maps: dict[str, np.ndarray] = field(default_factory=dict)
    convention: str = "explicit"
    sources: dict[str, str] = field(default_factory=dict)
    attributes: dict[str, object] = field(default_factory=dict)

    def __post_init__(self):
        shp = np.shape(self.position)
        if len(shp) != 3 or shp[2] != 3:
            raise GBufferError(f"position must be an (H, W, 3) array, got shape {shp}")
        for name in ("normal", "albedo"):
            if np.shape(getattr(self, name)) != shp:
                raise GBufferError(f"{name} has shape {np.shape(getattr(self, name))} "
                                   f"but position has {shp}")
        if self.coverage is not None and np.shape(self.coverage) != shp[:2]:
            raise GBufferError(f"coverage has shape {np.shape(self.coverage)}, expected {shp[:2]}")
        for key, arr in self.maps.items():
            want = shp if key == "specular_color" else shp[:2]
            if np.shape(arr) != want:
                raise GBufferError(f"material map {key} has shape {np.shape(arr)}, expected {want}")

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W): the image size in pixels."""
        return (int(self.position.shape[0]), int(self.position.shape[1]))

    def partly_covered(self) -> bool:
        """Whether some pixel has ``0 < coverage < 1``: then every output is
        premultiplied by coverage (the kernels' COVERAGE, and its reference twin)."""
        cov = self.coverage
        return cov is not None and bool(((cov > 0) & (cov < 1)).any())

    def background_mask(self) -> np.ndarray:
        """Pixels that are background and must not be shaded.

        Returns
        -------
        numpy.ndarray
            (H, W) bool, True where the coverage is 0 or not finite, where
            the normal has zero length (``|N|^2`` is computed in float64, so
            a denormal normal is *not* background), or where any normal
            component is not finite.
        """
        n = np.asarray(self.normal)
        x, y, z = n[..., 0], n[..., 1], n[..., 2]
        # |N|² = 0 in float64 exactly where every component is 0 (the square of
        # the smallest float32 or half denormal, about 2e-90, is a normal float64).
        if n.dtype == np.float32:
            # ±0 is the float32 whose bits are 0 but for the sign: the same test, 1.5x faster
            u = n.view(np.uint32)
            mask = ((u[..., 0] | u[..., 1] | u[..., 2]) & np.uint32(0x7FFFFFFF)) == 0
        else:
            mask = (x == 0) & (y == 0) & (z == 0)

        if not all_finite(n):                              # the common case, cheaply
            mask |= ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(z))
        if self.coverage is not None:
            cov = np.asarray(self.coverage)
            mask |= cov == 0
            if not all_finite(cov):
                # no coverage, as the EXR writer takes a NaN: its alpha, and so the
                # pixel's output and its A, would be NaN (a damaged file decodes so)
                mask |= ~np.isfinite(cov)
        return mask


# --------------------------------------------------------------------------- channel mapping


def _show(name: str) -> str:
    """A channel name for a message: escaped when it has control or undecodable
    characters (a newline, found by fuzzing), so that the message stays one line."""
    return name if name.isprintable() else repr(name)


def _short(names: Sequence[str], limit: int = 16) -> str:
    names = [_show(n) for n in names]
    if not names:
        return "(no channels)"
    if len(names) <= limit:
        return ", ".join(names)
    return ", ".join(names[:limit]) + f", ... (+{len(names) - limit} more)"


def _normalise_mapping(channels) -> dict[str, tuple[str, object]]:
    """Validate ``channels=``; return key -> ("prefix"|"name"|"list", value)."""
    if channels is None:
        return {}
    if not isinstance(channels, Mapping):
        raise GBufferError(f"channels must be a mapping of key to channel names, "
                           f"got {type(channels).__name__}")
    out: dict[str, tuple[str, object]] = {}
    for key, value in channels.items():
        if key not in CHANNEL_KEYS:
            raise GBufferError(f"unknown channel mapping key {key!r}; valid keys: {', '.join(CHANNEL_KEYS)}")
        want = 3 if key in VECTOR_KEYS else 1
        if isinstance(value, str):
            parts = [p.strip() for p in value.split(",")] if "," in value else None
            if parts is None:
                if not value.strip():
                    raise GBufferError(f"channel mapping {key}= is empty; give a layer prefix or "
                                       f"{want} channel name(s)")
                out[key] = ("prefix" if want == 3 else "name", value.strip())
                continue
        elif isinstance(value, Sequence):
            parts = [str(p).strip() for p in value]
        else:
            raise GBufferError(f"channel mapping {key}: expected a string or a list of channel "
                               f"names, got {type(value).__name__}")
        if any(not p for p in parts):
            raise GBufferError(f"channel mapping {key}={','.join(map(_show, parts))} has an empty channel name")
        if len(parts) != want:
            raise GBufferError(f"channel mapping {key}={','.join(map(_show, parts))}: {key} needs {want} "
                               f"channel name{'s' if want > 1 else ''}, got {len(parts)}")
        out[key] = ("list", parts)
    return out


def parse_channel_mapping(items: Sequence[str]) -> dict[str, str | list[str]]:
    """Parse the command-line form ``--channels KEY=VALUE`` (repeatable).

    Parameters
    ----------
    items : sequence of str
        Items like ``"position=P.X,P.Y,P.Z"`` or ``"normal=Nw"``.

    Returns
    -------
    dict
        Key -> layer prefix (str) or list of channel names, suitable for
        ``read_gbuffer(..., channels=...)``.

    Raises
    ------
    GBufferError
        Naming the bad item: no ``=``, an unknown key, an empty value, a
        wrong number of channel names, or a key given twice.

    Examples
    --------
    >>> parse_channel_mapping(["position=P.X,P.Y,P.Z", "normal=Nw"])
    {'position': ['P.X', 'P.Y', 'P.Z'], 'normal': 'Nw'}
    """
    if isinstance(items, str):
        items = [items]
    result: dict[str, str | list[str]] = {}
    for item in items:
        if "=" not in item:
            raise GBufferError(f"--channels {item!r}: expected KEY=CHANNELS, e.g. position=P.X,P.Y,P.Z")
        key, value = (s.strip() for s in item.split("=", 1))
        if key not in CHANNEL_KEYS:
            raise GBufferError(f"--channels {item!r}: unknown key {key!r}; valid keys: {', '.join(CHANNEL_KEYS)}")
        if key in result:
            raise GBufferError(f"--channels {item!r}: {key} is given more than once")
        if not value:
            raise GBufferError(f"--channels {item!r}: no channels after '='")
        parsed: str | list[str] = [p.strip() for p in value.split(",")] if "," in value else value
        try:
            _normalise_mapping({key: parsed})
        except GBufferError as exc:
            raise GBufferError(f"--channels {item!r}: {exc}") from None
        result[key] = parsed
    return result


# --------------------------------------------------------------------------- channel lookup


class _Channels:
    """Channel names of one file, with name lookup helpers."""

    def __init__(self, names: Sequence[str]):
        self.names = list(names)
        self.set = set(self.names)
        self.layers: dict[str, list[str]] = {}
        for n in self.names:
            if "." in n:
                self.layers.setdefault(n.rsplit(".", 1)[0], []).append(n)

    def vector(self, layer: str) -> list[str] | None:
        """Channels of vector layer ``layer`` ("" = plain R,G,B / X,Y,Z)."""
        for comps in _COMPONENTS:
            chans = [f"{layer}.{c}" if layer else c for c in comps]
            if all(c in self.set for c in chans):
                return chans
        return None

    def scalar(self, name: str, path: str, key: str) -> list[str] | None:
        """The channel ``name`` or the only channel of layer ``name``."""
        if name in self.set:
            return [name]
        chans = self.layers.get(name)
        if not chans:
            return None
        if len(chans) == 1:
            return chans
        raise GBufferError(f"{path}: layer {name!r} has {len(chans)} channels ({_short(chans, 6)}) "
                           f"but {key} needs one; choose it with --channels {key}={chans[0]}")

    def blender_prefixes(self) -> list[str]:
        """View-layer prefixes ("ViewLayer." or "") of Blender passes, in channel order."""
        prefixes: list[str] = []
        passes = tuple(p for names in _BLENDER_PASSES.values() for p in names)
        for layer in self.layers:
            for p in passes:
                if layer == p or layer.endswith("." + p):
                    prefix = layer[: len(layer) - len(p)]
                    if prefix not in prefixes:
                        prefixes.append(prefix)
        return prefixes


@dataclass
class _Layout:
    """How one file names its buffers: convention, Blender prefix, found channels."""

    convention: str
    prefix: str = ""                                   # Blender view layer + "." (or "")
    found: dict[str, list[str]] = field(default_factory=dict)
    albedo_layer: str | None = None

    @property
    def view_layer(self) -> str | None:
        return self.prefix[:-1] if self.prefix else None


def _layer_of(chans: list[str]) -> str | None:
    return chans[0].rsplit(".", 1)[0] if "." in chans[0] else None


def _is_rgb(chans: list[str] | None) -> bool:
    return bool(chans) and chans[0].rsplit(".", 1)[-1] in ("R", "r")


def _candidate_layouts(ch: _Channels, attributes: Mapping[str, object]) -> list[_Layout]:
    """Every convention's view of a multichannel file, in detection order."""
    def first_present(candidates: Mapping[str, Sequence[str]]) -> dict:
        """For each buffer, the channels of the first candidate layer present."""
        found = {}
        for key, layers in candidates.items():
            for layer in layers:
                chans = ch.vector(layer)
                if chans:
                    found[key] = chans
                    break
        return found

    layouts = []
    # generic / arnold
    found = first_present(_GENERIC_LAYERS)
    arnold = (found.get("albedo", [""])[0].startswith("diffuse_albedo.")
              or _is_rgb(found.get("position")) or _is_rgb(found.get("normal"))
              or any(str(k).startswith("arnold/") for k in attributes))
    layouts.append(_Layout("arnold" if arnold else "generic", "", found,
                           _layer_of(found["albedo"]) if "albedo" in found else None))
    # mitsuba
    found = first_present(_MITSUBA_LAYERS)
    layouts.append(_Layout("mitsuba", "", found, "albedo" if "albedo" in found else None))
    # blender, one layout per view layer
    for prefix in ch.blender_prefixes():
        found = {}
        for key, passes in _BLENDER_PASSES.items():
            for p in passes:
                chans = ch.vector(prefix + p)
                if chans:
                    found[key] = chans
                    break
        layouts.append(_Layout("blender", prefix, found,
                               _layer_of(found["albedo"]) if "albedo" in found else None))
    return layouts


def _detect_single(ch: _Channels, key: str, attributes: Mapping[str, object]) -> _Layout | None:
    """Find one required buffer in a file given for that buffer alone."""
    for layout in _candidate_layouts(ch, attributes):
        if key in layout.found:
            return _Layout(layout.convention, layout.prefix, {key: layout.found[key]},
                           layout.albedo_layer if key == "albedo" else None)
    chans = ch.vector("")
    if chans:
        return _Layout("rgb-files", "", {key: chans}, None)
    return None


def _find_optional(ch: _Channels, key: str, layout: _Layout, path: str) -> list[str] | None:
    """Detect coverage or a material map in a file described by ``layout``."""
    prefixes = [layout.prefix, ""] if layout.prefix else [""]
    if key == "coverage":
        if layout.convention == "blender":
            for pre in prefixes:
                for name in (pre + "Combined.A", pre + "Alpha"):
                    chans = ch.scalar(name, path, key)
                    if chans:
                        return chans
        for name in ("A", "RGBA.A", "rgba.A"):          # rgba.A: Nuke's multi-part beauty
            if name in ch.set:
                return [name]
        if layout.albedo_layer and f"{layout.albedo_layer}.A" in ch.set:
            return [f"{layout.albedo_layer}.A"]
        return None
    if key == "specular_color":
        for pre in prefixes:
            for layer in ("specular_color", "Cs"):
                chans = ch.vector(pre + layer)
                if chans:
                    return chans
        return None
    name = "shininess" if key == "h" else key
    for pre in prefixes:
        chans = ch.scalar(pre + name, path, key)
        if chans:
            return chans
    return None


def _explicit(ch: _Channels, key: str, spec: tuple[str, object], path: str,
              required: bool = True) -> list[str] | None:
    """Resolve an explicit ``channels=`` entry in one file (None if absent and not required)."""
    kind, value = spec
    if kind == "list":
        missing = [c for c in value if c not in ch.set]
        if not missing:
            return list(value)
        if not required:
            return None
        raise GBufferError(f"{path}: channel {missing[0]!r} ({key}, from channels "
                           f"{key}={','.join(map(_show, value))}) not found; the file has: {_short(ch.names)}")
    if kind == "prefix":
        chans = ch.vector(value)
        if chans or not required:
            return chans
        raise GBufferError(f"{path}: no layer {value!r} with .X/.Y/.Z, .x/.y/.z or .R/.G/.B "
                           f"channels ({key}, from channels {key}={value}); the file has: {_short(ch.names)}")
    chans = ch.scalar(value, path, key)
    if chans or not required:
        return chans
    raise GBufferError(f"{path}: channel {value!r} ({key}, from channels {key}={value}) not found; "
                       f"the file has: {_short(ch.names)}")


# --------------------------------------------------------------------------- file access


def oiio_message(geterror) -> str:
    """OpenImageIO's pending error as one line; its binding fails on non-UTF-8 text."""
    try:
        text = geterror()             # reading it clears it: call once
    except UnicodeDecodeError:
        return "OpenImageIO's message is not UTF-8 text (a corrupt file?)"
    return _one_line(text) if text else ""


def _signature_format(path: str) -> str | None:
    """The other image format ('a PNG', …) whose magic number ``path`` starts with,
    if any. Such a file is refused before OpenImageIO opens it: its PNG reader,
    given a broken PNG, prints libpng's complaint on stderr beside clphong's line."""
    try:
        with open(path, "rb") as f:
            kind = image_signature(f.read(16))
    except OSError:
        return None           # OpenImageIO says why
    return None if kind == "an OpenEXR" else kind


@contextlib.contextmanager
def _c_stderr_captured():
    """Send what C libraries write on file descriptor 2 to a temporary file (yielded)
    for the duration, so that it can join a one-line message instead of preceding it."""
    with tempfile.TemporaryFile() as tmp:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(tmp.fileno(), 2)
        try:
            yield tmp
        finally:
            os.dup2(saved, 2)
            os.close(saved)


def open_image(path: str, *, what: str = "an EXR file", verb: str = "read as EXR"):
    """``oiio.ImageInput.open(path)`` with one-line errors naming the file.

    Raises :class:`GBufferError` for a missing path, a folder (``"is a
    directory, not {what}"``), for an EXR, a file with another format's
    signature, or a file OpenImageIO cannot open (``"cannot {verb}: …"``).
    Shared by the G-buffer reader and ``clphong inspect``; for the latter (any
    format) what a C library prints while opening joins the message.
    """
    if not os.path.exists(path):
        raise GBufferError(f"{path}: file not found")
    if os.path.isdir(path):
        raise GBufferError(f"{path}: is a directory, not {what}")
    kind = not_regular(path)
    if kind is not None:        # a FIFO would block the open forever, a device read forever
        raise GBufferError(f"{path}: cannot {verb}: it is {kind}, not {what}; give a regular file")
    exr = what == "an EXR file"
    fmt = _signature_format(path) if exr else None
    if fmt is not None:
        raise GBufferError(f"{path}: not an OpenEXR file (it is {fmt} file)")
    if exr:
        inp = oiio.ImageInput.open(path)
        noise = ""
    else:
        with _c_stderr_captured() as tmp:
            inp = oiio.ImageInput.open(path)
            tmp.seek(0)
            noise = tmp.read().decode("utf-8", "replace")
    if inp is None:
        message = oiio_message(oiio.geterror) or _one_line(noise) or "unknown error"
        raise GBufferError(f"{path}: cannot {verb}: {message}")
    return inp


def _window(x, y, w, h) -> str:
    return f"({x},{y})-({x + w - 1},{y + h - 1})"


def _check_windows(path, s, part=None) -> None:
    """The data window against the display window of one part: never a silent crop
    or a black frame. OpenEXR falls back to a 64x64 display window at (0, 0) when the
    displayWindow attribute is missing or damaged (one flipped byte in its name):
    data outside that is an error; data outside any other display window (overscan,
    or an edited header) is a warning with both windows, and data with no pixel
    inside it an error."""
    fw = int(s.full_width) or int(s.width)
    fh = int(s.full_height) or int(s.height)
    fx, fy = int(s.full_x), int(s.full_y)
    x0, y0, x1, y1 = int(s.x), int(s.y), int(s.x) + int(s.width), int(s.y) + int(s.height)
    if fx <= x0 and fy <= y0 and x1 <= fx + fw and y1 <= fy + fh:
        return
    where = f"{path}" + (f" part {part}" if part is not None else "")
    data = _window(x0, y0, x1 - x0, y1 - y0)
    display = _window(fx, fy, fw, fh)
    if (fx, fy, fw, fh) == (0, 0, 64, 64):
        raise GBufferError(f"{where}: the data window {data} lies outside the display window "
                           f"{display}, which is OpenEXR's default when the header's displayWindow "
                           "is missing or damaged; repair the header (e.g. oiiotool IN.exr "
                           "--fullpixels -o OUT.exr)")
    inside_w = min(x1, fx + fw) - max(x0, fx)
    inside_h = min(y1, fy + fh) - max(y0, fy)
    if inside_w <= 0 or inside_h <= 0:
        raise GBufferError(f"{where}: the data window {data} has no pixel in the display window "
                           f"{display}; the header looks edited or damaged")
    outside = (x1 - x0) * (y1 - y0) - inside_w * inside_h
    warnings.warn(InputWarning(f"{where}: the data window {data} extends beyond the display "
                               f"window {display}: {outside} pixel(s) of data outside it are not "
                               "shaded"), stacklevel=4)


@dataclass
class _Part:
    """One part (OpenImageIO subimage) of an EXR file."""

    index: int
    spec: object
    name: str
    full_names: list[str]                               # channel names as gathered


def _gathered_names(part_name: str, names: Sequence[str], multipart: bool) -> list[str]:
    """The full channel names of one part.

    In a multi-part file a part named by its layer (``ViewLayer.Position``)
    may store bare channel names (``X, Y, Z``): they get the part name as
    prefix. A name that already carries a layer (``ViewLayer.Position.X``,
    ``diffuse.R``) is kept as it is, and so is every name of a single-part file.
    """
    if not multipart or not part_name:
        return list(names)
    return [n if "." in n or n.startswith(part_name + ".") else f"{part_name}.{n}" for n in names]


def _by_type(names: Sequence[str], types: Sequence[str]) -> str:
    """Channels grouped by pixel type, the rarest first: ``P.X as half and P.Y, P.Z as float``."""
    by: dict[str, list[str]] = {}
    for n, t in zip(names, types):
        by.setdefault(t, []).append(_show(n))
    return " and ".join(f"{', '.join(ns)} as {t}" for t, ns in sorted(by.items(), key=lambda kv: len(kv[1])))


def _part_name(index: int, name: str) -> str:
    """"part N" or "part N (NAME)" for messages."""
    return f"part {index} ({_show(name)})" if name else f"part {index}"


class _ExrFile:
    """One opened EXR file, single- or multi-part: validated specs, the channel
    names of every part gathered by their full names, pixel reads."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        p = self.path
        inp = open_image(p)
        self.inp = inp
        try:
            fmt = inp.format_name()
            if fmt != "openexr":
                raise GBufferError(f"{p}: not an OpenEXR file (OpenImageIO reads it as {fmt})")
            specs = []
            while inp.seek_subimage(len(specs), 0):
                specs.append(inp.spec())
            if not specs:
                raise GBufferError(f"{p}: cannot read as EXR: "
                                   f"{oiio_message(inp.geterror) or 'no readable part'}")
            multipart = len(specs) > 1
            self.parts = []
            owner: dict[str, int] = {}
            for i, spec in enumerate(specs):
                part = f"part {i}" if multipart else ""
                where = f"{p}: {part}: " if multipart else f"{p}: "
                if spec.deep:
                    raise GBufferError(f"{where}deep EXR files are not supported; flatten it first "
                                       "(e.g. oiiotool --flatten)")
                if spec.depth > 1:
                    raise GBufferError(f"{where}volume images (depth {spec.depth}) are not supported")
                if spec.width <= 0 or spec.height <= 0 or spec.nchannels <= 0:
                    raise GBufferError(f"{where}empty image ({spec.width}x{spec.height}, "
                                       f"{spec.nchannels} channels)")
                # OpenImageIO's binding decodes header text as UTF-8 (found by fuzzing).
                try:
                    names = list(spec.channelnames)
                    name = spec.get_string_attribute("name", "") if multipart else ""
                    if i == 0:
                        attributes = {a.name: a.value for a in spec.extra_attribs}
                except UnicodeDecodeError:
                    raise GBufferError(f"{where}cannot read as EXR: the header has channel or attribute "
                                       "names that are not UTF-8 text (a corrupt file?)") from None
                full = _gathered_names(name, names, multipart)
                for n in full:
                    if n in owner:
                        raise GBufferError(
                            f"{p}: channel {_show(n)!r} is in {_part_name(owner[n], self.parts[owner[n]].name)} "
                            f"and in {_part_name(i, name)}: a channel name must be unique across "
                            "parts; split the file (oiiotool --subimage N) and pass the parts with "
                            "--position, --normal and --albedo")
                    owner[n] = i
                self.parts.append(_Part(i, spec, name, full))
        except BaseException:
            inp.close()
            raise
        first = self.parts[0].spec
        self.size = (int(first.full_width) or int(first.width), int(first.full_height) or int(first.height))
        for part in self.parts[1:]:
            s = part.spec
            size = (int(s.full_width) or int(s.width), int(s.full_height) or int(s.height))
            if size != self.size or (s.full_x, s.full_y) != (first.full_x, first.full_y):
                inp.close()
                raise GBufferError(f"{p}: part {part.index} has a {size[0]}x{size[1]} display window "
                                   f"but part 0 has {self.size[0]}x{self.size[1]}: the parts must share "
                                   "one display window")
        try:
            for part in self.parts:
                _check_windows(p, part.spec, part.index if len(self.parts) > 1 else None)
        except BaseException:
            inp.close()
            raise
        self.spec = first
        self.channels = _Channels([n for part in self.parts for n in part.full_names])
        self._where = {n: (part, k) for part in self.parts for k, n in enumerate(part.full_names)}
        self.attributes = attributes
        self._data: dict[str, np.ndarray] = {}
        self._mixed = ""                       # _mixed_types of the groups being read
        # channel -> (the run read, its index there), for channels read in the display window
        self._run_of: dict[str, tuple[np.ndarray, int]] = {}

    @property
    def multipart(self) -> bool:
        return len(self.parts) > 1

    def close(self):
        if self.inp is not None:
            self.inp.close()
            self.inp = None

    def runs(self, names: Sequence[str]) -> list[tuple[_Part, list[int]]]:
        """(part, channel indices) of ``names`` not yet loaded, grouped in runs read together."""
        wanted = sorted({(self._where[n][0].index, self._where[n][1]) for n in names if n not in self._data})
        runs: list[tuple[_Part, list[int]]] = []
        for part, i in wanted:
            if runs and runs[-1][0].index == part and i - runs[-1][1][-1] <= 8:
                runs[-1][1].append(i)
            else:
                runs.append((self.parts[part], [i]))
        return runs

    def window(self, names: Sequence[str] | None = None) -> tuple[int, int, int, int]:
        """The data window (of the part holding ``names[0]``; else part 0) in
        display-window pixels, clipped: (x0, y0, x1, y1), x1/y1 exclusive."""
        s = self._where[names[0]][0].spec if names else self.spec
        fw, fh = self.size
        x0, y0 = s.x - s.full_x, s.y - s.full_y
        return (min(max(x0, 0), fw), min(max(y0, 0), fh),
                max(min(x0 + s.width, fw), 0), max(min(y0 + s.height, fh), 0))

    def load_bytes(self, names: Sequence[str]) -> int:
        """Peak bytes :meth:`load` allocates for ``names`` (see ``_check_read_memory``)."""
        total = 0
        display_px = self.size[0] * self.size[1]
        by_part: dict[int, list[list[int]]] = {}
        for part, run in self.runs(names):
            by_part.setdefault(part.index, []).append(run)
        for index, runs in by_part.items():
            s = self.parts[index].spec
            data_px = int(s.width) * int(s.height)
            lengths = [run[-1] + 1 - run[0] for run in runs]
            # OpenImageIO reads whole tiles, all channels, in the file's type and in
            # float: a header claiming 10560x16384 tiles on a 4x3 image made it
            # allocate 9 GB (found by fuzzing with atheris).
            total += 8 * max(int(s.tile_width), 0) * max(int(s.tile_height), 0) * max(int(s.nchannels), 1)
            if (s.x, s.y, s.width, s.height) == (s.full_x, s.full_y, *self.size):
                total += 4 * data_px * sum(lengths)     # planes stay views of the runs read
            else:                                       # planes are copied into the display window
                total += 4 * (display_px * sum(len(r) for r in runs) + data_px * max(lengths))
        return total

    def load(self, names: Sequence[str]) -> None:
        """Read channels ``names`` (in runs of nearby channels of one part) into the cache."""
        for part, run in self.runs(names):
            s = part.spec
            lo, hi = run[0], run[-1] + 1
            pix = self.inp.read_image(part.index, 0, lo, hi, oiio.TypeDesc("float"))
            if pix is None:
                self._read_failed(part, lo, hi)
            pix = np.asarray(pix, dtype=np.float32).reshape(s.height, s.width, hi - lo)
            for i in run:
                view = pix[:, :, i - lo]
                plane = self._data[part.full_names[i]] = self._fit(view, s)
                if plane is view:                    # in the display window: stack slices pix
                    self._run_of[part.full_names[i]] = (pix, i - lo)

    def _pixel_type(self, name: str) -> str:
        """The pixel type of channel ``name`` as the header gives it: "half", "float", "uint"."""
        part, k = self._where[name]
        s = part.spec
        return str(s.channelformats[k] if len(s.channelformats) else s.format)

    def _mixed_types(self, groups: Mapping[str, Sequence[str]]) -> str:
        """The buffers whose channels the header gives different pixel types, as text
        (``position: P.X as half and P.Y, P.Z as float``), or "".

        A renderer writes one type per layer (Blender all half or all float; half
        albedo beside float position, in different layers, is normal and not
        looked at). One channel of a vector in another type is what a flipped
        pixel-type byte makes: if its chunks still decode (a file written so) the
        values are the writer's, read as stored, so it is a warning; if they do not
        (the chunk sizes no longer match), the read error names it
        (:meth:`_read_failed`)."""
        mixed = []
        for key, chans in groups.items():
            types = [self._pixel_type(n) for n in chans]
            if len(set(types)) > 1:
                mixed.append(f"{key}: {_by_type(chans, types)}")
        return "; ".join(mixed)

    def _check_pixel_types(self, names) -> None:
        """A G-buffer channel is half or float: a uint one (a flipped pixel-type byte,
        FLOAT -> UINT, decoded as garbage: ±3.4e38 and negatives, exit 0) is an error."""
        for n in names:
            part, k = self._where[n]
            s = part.spec
            fmt = s.channelformats[k] if len(s.channelformats) else s.format
            if str(fmt).startswith("uint"):
                others = sorted({str(f) for f in (s.channelformats if len(s.channelformats)
                                                  else [s.format])} - {str(fmt)})
                raise GBufferError(
                    f"{self.path}: channel {_show(n)} is stored as {fmt}"
                    + (f" (the others as {', '.join(others)})" if others else "")
                    + ": a G-buffer channel must be half or float; the header looks damaged "
                    "or the channel is an ID (map it with --channels)")

    def read_stacked(self, groups: Mapping[str, Sequence[str]]) -> dict[str, np.ndarray]:
        """:meth:`stack` of each group of channels (key -> names), read from the file.

        Where each group is a run of side-by-side channels of one scanline part that
        fills the display window (every G-buffer clphong or a renderer writes), the
        file is read a band of rows at a time straight into the groups' arrays, so
        no interleaved copy of the whole frame is made (1080p, 10 channels: an 83 MB
        buffer and its page faults; the copies work on a band in cache). Otherwise
        :meth:`load` then :meth:`stack`. The same values either way.
        """
        names = [n for chans in groups.values() for n in chans]
        self._check_pixel_types(names)
        self._mixed = mixed = self._mixed_types(groups)
        out = self._read_groups(groups, names)
        if mixed:
            warnings.warn(InputWarning(
                f"{self.path}: channels of one buffer stored as different pixel types ({mixed}): "
                "a renderer writes one type per layer, a flipped pixel-type byte in the header "
                "gives this; read as stored (a half channel holds 11 significant bits, at most "
                "65504); check the file (oiiotool --info -v)"), stacklevel=3)
        return out

    def _read_groups(self, groups: Mapping[str, Sequence[str]], names: Sequence[str]) -> dict[str, np.ndarray]:
        """The reading of :meth:`read_stacked`: in bands where it can, else :meth:`load`."""
        runs = self.runs(names)
        if not self._bandable(groups, runs):
            self.load(names)
            return {k: self.stack(chans) for k, chans in groups.items()}
        fw, fh = self.size
        out = {k: np.empty((fh, fw, len(chans)), np.float32) for k, chans in groups.items()}
        for part, run in runs:
            s = part.spec
            lo, hi = run[0], run[-1] + 1
            targets = [(out[k], self._where[chans[0]][1] - lo, len(chans))
                       for k, chans in groups.items()
                       if self._where[chans[0]][0] is part and lo <= self._where[chans[0]][1] < hi]
            chunk = max(1, s.get_int_attribute("oiio:RowsPerChunk", 16))
            rows = chunk * max(1, BAND_ROWS // chunk)          # whole chunks: each decoded once
            for y in range(0, fh, rows):
                y1 = min(fh, y + rows)
                pix = self.inp.read_scanlines(part.index, 0, s.y + y, s.y + y1, s.z, lo, hi,
                                              oiio.TypeDesc("float"))
                if pix is None:
                    self._read_failed(part, lo, hi)
                pix = np.asarray(pix, dtype=np.float32).reshape(y1 - y, fw, hi - lo)
                for arr, j, k in targets:
                    arr[y:y1] = pix[:, :, j:j + k]
        return out

    def _bandable(self, groups: Mapping[str, Sequence[str]], runs) -> bool:
        """Whether :meth:`read_stacked` can read ``groups`` in bands: each group side-by-side
        channels, in order, of one part, and every part read a scanline image filling the
        display window."""
        if not runs or any(n in self._data for chans in groups.values() for n in chans):
            return False
        fw, fh = self.size
        for part, _ in runs:
            s = part.spec
            if s.tile_width or s.deep or (s.x, s.y, s.width, s.height) != (s.full_x, s.full_y, fw, fh):
                return False
        for chans in groups.values():
            if not chans:
                return False
            part, first = self._where[chans[0]]
            if any(self._where[n] != (part, first + k) for k, n in enumerate(chans)):
                return False
        return True

    def _read_failed(self, part: _Part, lo: int, hi: int):
        msg = (oiio_message(self.inp.geterror) or oiio_message(oiio.geterror)
               or "unknown error")
        where = f" of part {part.index}" if self.multipart else ""
        raise GBufferError(f"{self.path}: reading channels "
                           f"{','.join(map(_show, part.full_names[lo:hi]))}{where} failed: {msg}"
                           f"{self._odd_types(part)}")

    def _odd_types(self, part: _Part) -> str:
        """A hint for a failed read: a flipped pixel-type byte (FLOAT -> HALF) changes the
        size of every chunk, which then no longer decodes. Named when one buffer's
        channels have different types, or one channel of the part differs from all
        the others (a whole layer in another type, half albedo beside float
        position, is normal and not named)."""
        if self._mixed:
            return (f"; the header gives one buffer's channels different pixel types "
                    f"({self._mixed}): a flipped pixel-type byte?")
        names = part.full_names
        types = [self._pixel_type(n) for n in names]
        odd = [k for k, t in enumerate(types) if types.count(t) == 1]
        if len(names) < 3 or len(set(types)) != 2 or len(odd) != 1:
            return ""
        k = odd[0]
        common = types[1 - k] if k < 2 else types[0]
        return (f"; the header gives {_show(names[k])} as {types[k]} but the other "
                f"{len(names) - 1} channels as {common}: a flipped pixel-type byte?")

    def _fit(self, plane: np.ndarray, s) -> np.ndarray:
        """Place a data-window plane of a part with spec ``s`` in the display window (zeros outside)."""
        fw, fh = self.size
        if (s.x, s.y, s.width, s.height) == (s.full_x, s.full_y, fw, fh):
            return plane
        out = np.zeros((fh, fw), np.float32)
        x0, y0 = s.x - s.full_x, s.y - s.full_y
        dx0, dy0 = max(x0, 0), max(y0, 0)
        dx1, dy1 = min(x0 + s.width, fw), min(y0 + s.height, fh)
        if dx1 > dx0 and dy1 > dy0:
            out[dy0:dy1, dx0:dx1] = plane[dy0 - y0:dy1 - y0, dx0 - x0:dx1 - x0]
        return out

    def stack(self, names: Sequence[str]) -> np.ndarray:
        """(H, W, len(names)) float32 array of loaded channels, C-contiguous, a new array.

        Channels that lie side by side, in order, in one run read are copied as one
        slice of it (3.5x faster than stacking their planes: 1080p, 4 buffers, 190 -> 55 ms).
        """
        pix, j = self._run_of.get(names[0], (None, 0))
        if pix is not None and all(self._run_of.get(n, (None, -1))[0] is pix
                                   and self._run_of[n][1] == j + k for k, n in enumerate(names)):
            out = np.empty((*pix.shape[:2], len(names)), np.float32)
            out[...] = pix[:, :, j:j + len(names)]
            return out
        return np.ascontiguousarray(np.stack([self._data[n] for n in names], axis=-1), dtype=np.float32)

    def part_of(self, names: Sequence[str]) -> str:
        """" (part N)" naming the part that holds ``names`` in a multi-part file, else ""."""
        if not self.multipart or not names:
            return ""
        part = self._where[names[0]][0]
        return f" (part {part.index}{f' {_show(part.name)}' if part.name else ''})"


def _source(f: _ExrFile, chans: list[str], layout: _Layout | None) -> str:
    text = f"{f.path}: {','.join(chans)}{f.part_of(chans)}"
    if layout is not None and layout.view_layer:
        text += f" (view layer {layout.view_layer!r})"
    return text


def _detect_main(f: _ExrFile, needed: Sequence[str]) -> _Layout:
    """Pick the first convention of the main file that has every needed buffer."""
    layouts = _candidate_layouts(f.channels, f.attributes)
    for layout in layouts:
        if all(k in layout.found for k in needed):
            return layout
    best = max(layouts, key=lambda lo: sum(k in lo.found for k in needed))
    missing = [k for k in needed if k not in best.found]
    where = f" in view layer {best.view_layer!r}" if best.view_layer and len(missing) < len(needed) else ""
    looked = "; ".join(f"{k}: {_LOOKED_FOR[k]}" for k in missing)
    hint = f"name them with --channels {missing[0]}=LAYER or {missing[0]}=CH1,CH2,CH3"
    if not any(lo.found for lo in layouts) and f.channels.vector(""):
        hint = ("a plain R,G,B file holds one buffer: pass such files with --position, --normal "
                "and --albedo (position=, normal=, albedo=)")
    raise GBufferError(f"{f.path}: no {', '.join(missing)} channels found{where} (looked for {looked}); "
                       f"the file has: {_short(f.channels.names)}; {hint}")


# --------------------------------------------------------------------------- read_gbuffer


def read_gbuffer(path: str | os.PathLike | None = None, *, position: str | os.PathLike | None = None,
                 normal: str | os.PathLike | None = None, albedo: str | os.PathLike | None = None,
                 channels: Mapping[str, str | Sequence[str]] | None = None,
                 premultiplied: bool | None = None) -> GBuffer:
    """Read a G-buffer from one multichannel EXR or from separate files.

    Partly covered pixels are made shadeable by :func:`resolve_coverage`:
    ``premultiplied`` (default: by convention, True for
    :data:`PREMULTIPLIED_CONVENTIONS`) divides albedo and maps by coverage there.

    Parameters
    ----------
    path : str or os.PathLike, optional
        A multichannel EXR holding the buffers (and optionally coverage and
        material maps). May be omitted when all of ``position``, ``normal``
        and ``albedo`` are given.
    position, normal, albedo : str or os.PathLike, optional
        A file holding just that buffer (a layer of any convention, or plain
        R,G,B / X,Y,Z), overriding ``path`` for that buffer.
    channels : mapping, optional
        Explicit channel names per key (``position``, ``normal``,
        ``albedo``, ``coverage``, ``k_d``, ``k_s``, ``h``,
        ``specular_color``): a layer prefix, or a list / comma-separated
        string of exact channel names (3 for vectors, 1 for scalars). See
        :func:`parse_channel_mapping` for the command-line form.

    Returns
    -------
    GBuffer
        float32 arrays; coverage and maps when present; the detected
        ``convention``, the ``sources`` of each buffer and the header
        ``attributes`` of the first file (``path``, else ``position``).

    Raises
    ------
    GBufferError
        One line naming the file (and channel): a missing, unreadable,
        non-EXR or deep file, a channel name in two parts of one file; missing position, normal or albedo
        channels (with what was looked for and what the file has); separate
        files of different sizes; a bad or unknown ``channels`` entry.

    Notes
    -----
    Coverage and maps are searched in ``path`` first, then in the position,
    normal and albedo files; the first file that has one provides it. The
    accepted names of each convention are listed in the module docstring.
    """
    mapping = _normalise_mapping(channels)
    overrides = {"position": position, "normal": normal, "albedo": albedo}
    lacking = [k for k in REQUIRED if path is None and overrides[k] is None]
    if lacking:
        raise GBufferError(f"no G-buffer file for {', '.join(lacking)}: give a multichannel EXR, "
                           "or --position, --normal and --albedo files")
    main = os.fspath(path) if path is not None else None
    src = {k: os.fspath(overrides[k]) if overrides[k] is not None else main for k in REQUIRED}

    order: list[str] = []
    for p in [main, *src.values()]:
        if p is not None and p not in order:
            order.append(p)
    files: dict[str, _ExrFile] = {}
    try:
        for p in order:
            files[p] = _ExrFile(p)
        _check_sizes(files, src, main)
        resolved: dict[str, tuple[_ExrFile, list[str], _Layout | None]] = {}
        layouts: dict[str, _Layout] = {}          # file path -> layout for optional lookups
        conventions: dict[str, str] = {}

        for key in REQUIRED:
            if key in mapping:
                f = files[src[key]]
                resolved[key] = (f, _explicit(f.channels, key, mapping[key], f.path), None)
                conventions[key] = "explicit"
        if main is not None:
            f = files[main]
            needed = [k for k in REQUIRED if k not in resolved and src[k] == main]
            layout = _detect_main(f, needed) if needed else _fallback_layout(f)
            layouts[main] = layout
            for key in needed:
                resolved[key] = (f, layout.found[key], layout)
                conventions[key] = layout.convention
        for key in REQUIRED:
            if key in resolved:
                continue
            f = files[src[key]]
            layout = _detect_single(f.channels, key, f.attributes)
            if layout is None:
                raise GBufferError(
                    f"{f.path}: no {key} channels found (looked for {_LOOKED_FOR[key]}, "
                    f"or plain R,G,B / X,Y,Z); the file has: {_short(f.channels.names)}; "
                    f"name them with --channels {key}=LAYER or {key}=CH1,CH2,CH3")
            layouts.setdefault(f.path, layout)
            resolved[key] = (f, layout.found[key], layout)
            conventions[key] = layout.convention

        # Optional buffers: first file (main, position, normal, albedo) that has them.
        optional: dict[str, tuple[_ExrFile, list[str], _Layout | None]] = {}
        for key in OPTIONAL:
            for p in order:
                f = files[p]
                layout = layouts.get(p)
                if key in mapping:
                    chans = _explicit(f.channels, key, mapping[key], f.path, required=False)
                else:
                    if layout is None:
                        layout = _fallback_layout(f)
                        layouts[p] = layout
                    chans = _find_optional(f.channels, key, layout, f.path)
                if chans:
                    optional[key] = (f, chans, layout)
                    break
            else:
                if key in mapping:
                    kind, value = mapping[key]
                    shown = ",".join(map(_show, value)) if kind == "list" else _show(value)
                    raise GBufferError(f"{', '.join(order)}: channel(s) {shown!r} for {key} "
                                       f"(from channels {key}={shown}) not found in any file")

        wanted: dict[str, list[str]] = {}
        for f, chans, _ in (*resolved.values(), *optional.values()):
            wanted.setdefault(f.path, []).extend(chans)
        _check_read_memory(files, wanted)
        groups: dict[str, dict[str, list[str]]] = {}
        for k, (f, chans, _) in (*resolved.items(), *optional.items()):
            groups.setdefault(f.path, {})[k] = chans
        stacked: dict[str, np.ndarray] = {}
        for p, group in groups.items():
            stacked.update(files[p].read_stacked(group))

        arrays = {k: stacked[k] for k in resolved}
        _background_outside_data_windows(arrays, {k: (f, chans) for k, (f, chans, _) in resolved.items()})
        coverage = None
        maps: dict[str, np.ndarray] = {}
        for key in optional:
            arr = stacked[key]
            if key == "coverage":
                coverage = np.ascontiguousarray(arr[..., 0])
            elif key == "specular_color":
                maps[key] = arr
            else:
                maps[key] = np.ascontiguousarray(arr[..., 0])
        sources = {k: _source(f, chans, lo) for k, (f, chans, lo) in (*resolved.items(), *optional.items())}
        non_explicit = [conventions[k] for k in REQUIRED if conventions[k] != "explicit"]
        convention = non_explicit[0] if non_explicit else "explicit"
        attributes = dict(files[order[0]].attributes)
    finally:
        for f in files.values():
            f.close()
    gb = GBuffer(position=arrays["position"], normal=arrays["normal"], albedo=arrays["albedo"],
                 coverage=coverage, maps={k: maps[k] for k in MAP_KEYS if k in maps},
                 convention=convention, sources=sources, attributes=attributes)
    if premultiplied is None:
        premultiplied = convention in PREMULTIPLIED_CONVENTIONS
    if coverage is None and convention == "blender":
        warnings.warn(f"{order[0]}: no coverage channel (<ViewLayer>.Combined.A or .Alpha), so "
                      "partly covered edge pixels cannot be told from covered ones: they are "
                      "shaded as stored and written with A = 1; keep the Combined pass, or name "
                      "the coverage with --channels coverage=CHANNEL", InputWarning, stacklevel=2)
    return resolve_coverage(gb, premultiplied=premultiplied)


#: Conventions whose renderers filter every pass over the pixel's samples, so
#: that a partly covered pixel's albedo and maps are premultiplied by coverage
#: (background samples add 0): Cycles/EEVEE, Arnold, Mitsuba 3's aov integrator.
PREMULTIPLIED_CONVENTIONS = ("blender", "arnold", "mitsuba")
#: How far (in pixels, Chebyshev) :func:`resolve_coverage` looks for a covered
#: neighbour whose position stands in for an edge pixel's missing one.
EDGE_SEARCH = 2


def resolve_coverage(gb: GBuffer, *, premultiplied: bool) -> GBuffer:
    """Make a partly covered pixel shadeable: straight albedo, a real position.

    * ``premultiplied``: albedo and the colour and weight maps (``k_d``,
      ``k_s``, ``specular_color``; not ``shininess``, an exponent) are divided
      by the coverage where ``0 < coverage < 1``. The normal needs nothing: it
      is normalised anyway.
    * A partly covered pixel whose position is exactly (0, 0, 0) holds no
      surface point: Blender writes Position from the pixel's first sample
      only, and a background first sample gives 0. It is never shaded there:
      it takes the position of the nearest covered pixel that has one (its
      own first sample hit a surface) within :data:`EDGE_SEARCH` pixels (the
      nearest first, ties in row order, among those whose normal faces the
      same way, n·n' > 0); with none, the pixel is background (not shaded).

    Both are counted in ``attributes["clphong:coverage"]`` (for ``inspect``).
    """
    cov = gb.coverage
    if cov is None:
        return gb
    partial = (cov > 0) & (cov < 1)
    if not partial.any():
        return gb
    albedo, maps, position, normal = gb.albedo, dict(gb.maps), gb.position, gb.normal
    ys, xs = np.nonzero(partial)
    counts = {"partial": int(ys.size), "unpremultiplied": 0, "edge_positions": 0, "edge_background": 0}
    if premultiplied:
        a = cov[ys, xs][:, None]
        albedo = albedo.copy()
        with np.errstate(all="ignore"):          # non-finite inputs: the nonfinite policy's
            albedo[ys, xs] = albedo[ys, xs] / a
            for key in ("k_d", "k_s", "specular_color"):
                if key in maps:
                    m = maps[key].copy()
                    m[ys, xs] = m[ys, xs] / (a if m.ndim == 3 else a[:, 0])
                    maps[key] = m
        counts["unpremultiplied"] = int(ys.size)
    hole = ~position[ys, xs].any(axis=1)
    if hole.any():
        position, normal = position.copy(), normal.copy()
        h, w = cov.shape
        hit = (cov > 0) & position.any(axis=-1)          # the pixel's centre ray hit a surface
        by, bx = ys[hole], xs[hole]
        todo = np.ones(by.size, bool)
        rings = sorted(((dy, dx) for dy in range(-EDGE_SEARCH, EDGE_SEARCH + 1)
                        for dx in range(-EDGE_SEARCH, EDGE_SEARCH + 1) if dy or dx),
                       key=lambda o: (max(abs(o[0]), abs(o[1])), o[0] * o[0] + o[1] * o[1]))
        for dy, dx in rings:
            ny, nx = by + dy, bx + dx
            inside = todo & (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
            ny, nx = np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)
            facing = (normal[by, bx].astype(np.float64) * normal[ny, nx]).sum(axis=1) > 0
            take = inside & hit[ny, nx] & facing
            position[by[take], bx[take]] = position[ny[take], nx[take]]
            todo &= ~take
        normal[by[todo], bx[todo]] = 0.0                     # no stand-in: background
        counts["edge_positions"] = int((~todo).sum())
        counts["edge_background"] = int(todo.sum())
    attributes = {**gb.attributes, "clphong:coverage": counts}
    return dataclasses.replace(gb, position=position, normal=normal, albedo=albedo, maps=maps,
                               attributes=attributes)


def _check_read_memory(files: Mapping[str, _ExrFile], wanted: Mapping[str, list[str]]) -> None:
    """Refuse to read channels that would not fit in memory (instead of being killed).

    Peak bytes: what :meth:`_ExrFile.load` keeps (the runs of channels read, or
    display-window copies of them plus one run when the data window differs)
    plus the float32 (H, W, k) arrays stacked from them.
    """
    need = 0
    channels = 0
    for p, names in wanted.items():
        f = files[p]
        need += f.load_bytes(names)
        need += 4 * f.size[0] * f.size[1] * len(names)
        channels += len(names)
    first = files[next(iter(wanted))]
    w, h = first.size
    d = first.spec
    window = f" (data window {d.width}x{d.height})" if (d.width, d.height) != (w, h) else ""
    if d.tile_width * d.tile_height > d.width * d.height:
        window += f" (tiles of {d.tile_width}x{d.tile_height})"
    require_memory(need, f"{', '.join(wanted)}: reading {channels} channels of a {w}x{h} "
                         f"image{window}", GBufferError,
                   "crop the image (e.g. oiiotool --crop) or free memory")


def _background_outside_data_windows(arrays: dict[str, np.ndarray],
                                     sources: Mapping[str, tuple[_ExrFile, list[str]]]) -> None:
    """Pixels outside the data window of any required buffer are background.

    Within one part every channel shares the data window, and the zeros
    outside it make a zero normal, so background. Separate files, and the parts
    of one multi-part file, may have different data windows (e.g. auto-cropped
    AOVs): a pixel is shaded only
    where position, normal and albedo all have data, so elsewhere the normal
    is set to 0. Windows that do not overlap at all leave nothing to shade:
    an error.
    """
    windows = {k: f.window(chans) for k, (f, chans) in sources.items()}
    if len(set(windows.values())) <= 1:
        return
    x0 = max(w[0] for w in windows.values())
    y0 = max(w[1] for w in windows.values())
    x1 = min(w[2] for w in windows.values())
    y1 = min(w[3] for w in windows.values())
    if x1 <= x0 or y1 <= y0:
        shown = "; ".join(f"{k} {sources[k][0].path}{sources[k][0].part_of(sources[k][1])} "
                          f"({w[0]},{w[1]})-({w[2] - 1},{w[3] - 1})"
                          for k, w in windows.items())
        raise GBufferError(f"the data windows of the separate buffers do not overlap, so no pixel "
                           f"has position, normal and albedo: {shown}; render them with the same "
                           "data window (or oiiotool --fullpixels)")
    inside = np.zeros(arrays["normal"].shape[:2], bool)
    inside[y0:y1, x0:x1] = True
    arrays["normal"][~inside] = 0.0


def _fallback_layout(f: _ExrFile) -> _Layout:
    """Layout of a file only used through explicit mappings: its best-matching convention."""
    layouts = _candidate_layouts(f.channels, f.attributes)
    return max(layouts, key=lambda lo: len(lo.found))


def _check_sizes(files: Mapping[str, _ExrFile], src: Mapping[str, str], main: str | None) -> None:
    """All files must have the same (display window) size; name two that differ."""
    role = {}
    if main is not None:
        role[main] = "G-buffer"
    for key in REQUIRED:
        role.setdefault(src[key], key)
    items = list(files.values())
    first = items[0]
    for f in items[1:]:
        if f.size != first.size:
            raise GBufferError(
                f"{role[first.path]} {first.path} is {first.size[0]}x{first.size[1]} but "
                f"{role[f.path]} {f.path} is {f.size[0]}x{f.size[1]}: separate buffers must have "
                "the same size")


# --------------------------------------------------------------------------- write_gbuffer


def _channel_layout(convention: str, layer: str, has_cov: bool, maps: Mapping[str, np.ndarray]):
    """(buffer key, channel names) pairs of ``convention``, for write_gbuffer."""
    xyz, rgb = ("X", "Y", "Z"), ("R", "G", "B")
    if convention in ("blender", "blender-new"):
        pre = f"{layer}." if layer else ""
        diff = "DiffCol" if convention == "blender" else "Diffuse Color"
        out = [("position", [f"{pre}Position.{c}" for c in xyz]),
               ("normal", [f"{pre}Normal.{c}" for c in xyz]),
               ("albedo", [f"{pre}{diff}.{c}" for c in rgb])]
        if has_cov:
            out.append(("combined", [f"{pre}Combined.{c}" for c in "RGBA"]))
        scal = {"k_d": f"{pre}k_d.X", "k_s": f"{pre}k_s.X", "h": f"{pre}shininess.X"}
        spec_names = [f"{pre}specular_color.{c}" for c in rgb]
    else:
        p, n, a = {"generic": ("P", "N", "albedo"), "arnold": ("P", "N", "diffuse_albedo"),
                   "mitsuba": ("pos", "sh_normal", "albedo")}[convention]
        comps = rgb if convention == "arnold" else xyz
        out = [("position", [f"{p}.{c}" for c in comps]),
               ("normal", [f"{n}.{c}" for c in comps]),
               ("albedo", [f"{a}.{c}" for c in rgb])]
        if convention == "mitsuba":
            out.append(("image", ["R", "G", "B"]))
        if has_cov:
            out.append(("coverage", ["A"]))
        scal = {"k_d": "k_d", "k_s": "k_s", "h": "shininess"}
        spec_names = [f"specular_color.{c}" for c in rgb]
    for key in ("k_d", "k_s", "h"):
        if key in maps:
            out.append((key, [scal[key]]))
    if "specular_color" in maps:
        out.append(("specular_color", spec_names))
    return out


def write_gbuffer(path: str | os.PathLike, position: np.ndarray, normal: np.ndarray, albedo: np.ndarray,
                  *, coverage: np.ndarray | None = None, maps: Mapping[str, np.ndarray] | None = None,
                  convention: str = "generic", pixel_type: str = "float", tiled: bool = False,
                  compression: str = "zip", layer: str = "ViewLayer",
                  attributes: Mapping[str, object] | None = None) -> None:
    """Write a G-buffer as one multichannel EXR, named after a convention.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file, written atomically (via
        :func:`clphong.io.atomic.atomic_path`).
    position, normal, albedo : numpy.ndarray
        (H, W, 3) arrays.
    coverage : numpy.ndarray, optional
        (H, W) coverage/alpha.
    maps : mapping, optional
        Material maps ``"k_d"``, ``"k_s"``, ``"h"`` (H, W) and
        ``"specular_color"`` (H, W, 3).
    convention : {"generic", "blender", "blender-new", "arnold", "mitsuba"}
        Channel names to use:

        - generic: ``P.X/Y/Z``, ``N.X/Y/Z``, ``albedo.R/G/B``, ``A``,
          ``k_d``, ``k_s``, ``shininess``, ``specular_color.R/G/B``;
        Partly covered pixels' albedo and colour/weight maps are written
        premultiplied by coverage in the conventions that store them so
        (:data:`PREMULTIPLIED_CONVENTIONS`).

        - blender / blender-new: ``<layer>.Position.X/Y/Z``,
          ``<layer>.Normal.X/Y/Z``, ``<layer>.DiffCol.R/G/B`` (blender-new:
          ``<layer>.Diffuse Color.R/G/B``), coverage as
          ``<layer>.Combined.R/G/B/A`` (RGB = albedo x coverage), maps as
          value AOVs ``<layer>.k_d.X``, ``<layer>.k_s.X``,
          ``<layer>.shininess.X`` and ``<layer>.specular_color.R/G/B``;
        - arnold: ``P.R/G/B``, ``N.R/G/B``, ``diffuse_albedo.R/G/B``, ``A``,
          maps as generic;
        - mitsuba: ``pos.X/Y/Z``, ``sh_normal.X/Y/Z``, ``albedo.R/G/B``, an
          ``R, G, B`` image (albedo x coverage) and ``A``, maps as generic.
    pixel_type : {"float", "half"}
        Pixel type of every channel.
    tiled : bool
        Write 64x64 tiles instead of scanlines.
    compression : str
        EXR compression.
    layer : str
        Blender view-layer name (``""`` for none).
    attributes : mapping, optional
        Extra header attributes (see :func:`clphong.io.atomic.set_attribute`).

    Raises
    ------
    GBufferError
        Bad convention, pixel type, array shape or map name.
    OutputError
        The file cannot be written (nothing is left behind).
    """
    if convention not in WRITE_CONVENTIONS:
        raise GBufferError(f"{os.fspath(path)}: unknown convention {convention!r}; "
                           f"choose one of {', '.join(WRITE_CONVENTIONS)}")
    check_pixel_type(pixel_type, os.fspath(path), GBufferError)
    maps = dict(maps or {})
    unknown = [k for k in maps if k not in MAP_KEYS]
    if unknown:
        raise GBufferError(f"{os.fspath(path)}: unknown material map {unknown[0]!r}; "
                           f"valid maps: {', '.join(MAP_KEYS)}")
    P = np.asarray(position, np.float32)
    gb = GBuffer(position=P, normal=np.asarray(normal, np.float32), albedo=np.asarray(albedo, np.float32),
                 coverage=None if coverage is None else np.asarray(coverage, np.float32),
                 maps={k: np.asarray(v, np.float32) for k, v in maps.items()})
    planes = {"position": gb.position, "normal": gb.normal, "albedo": gb.albedo}
    cov = gb.coverage
    if cov is not None:
        planes["coverage"] = cov[..., None]
        planes["combined"] = np.concatenate([gb.albedo * cov[..., None], cov[..., None]], axis=-1)
    planes["image"] = gb.albedo * (cov[..., None] if cov is not None else np.float32(1))
    for k, v in gb.maps.items():
        planes[k] = v if v.ndim == 3 else v[..., None]
    read_as = "blender" if convention == "blender-new" else convention
    if cov is not None and read_as in PREMULTIPLIED_CONVENTIONS:
        # as those renderers store them (read_gbuffer divides them by coverage again)
        partial = ((cov > 0) & (cov < 1))[..., None]
        for k in ("albedo", "k_d", "k_s", "specular_color"):
            if k in planes:
                planes[k] = np.where(partial, planes[k] * cov[..., None], planes[k])
    names: list[str] = []
    data: list[np.ndarray] = []
    for key, chans in _channel_layout(convention, layer, cov is not None, gb.maps):
        names.extend(chans)
        data.append(planes[key])
    write_exr(path, np.concatenate(data, axis=-1), pixel_type=pixel_type, compression=compression,
              attributes=attributes, channel_names=names, tiled=tiled)


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

import dataclasses
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import GBufferError, InputWarning
from ..core.memory import require_memory
from ..model.scene import MAP_KEYS
from .atomic import check_pixel_type, write_exr
from .channels import (
    _LOOKED_FOR,
    CHANNEL_KEYS,
    OPTIONAL,
    REQUIRED,
    SCALAR_KEYS,
    VECTOR_KEYS,
    WRITE_CONVENTIONS,
    _candidate_layouts,
    _detect_single,
    _explicit,
    _find_optional,
    _Layout,
    _normalise_mapping,
    _short,
    _show,
    parse_channel_mapping,
)
from .exrfile import _detect_main, _ExrFile, _source
from .nonfinite import all_finite

__all__ = ["GBuffer", "read_gbuffer", "write_gbuffer", "parse_channel_mapping",
           "CHANNEL_KEYS", "VECTOR_KEYS", "SCALAR_KEYS", "WRITE_CONVENTIONS"]

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

    def pixels(self, idx) -> "GBuffer":
        """The pixels ``idx`` (flat indices, row-major) as a 1 × len(idx) G-buffer: the same
        buffers, maps, convention, sources and attributes, only those pixels."""
        h, w = self.shape
        idx = np.asarray(idx)

        def take(a):
            a = np.asarray(a)
            return a.reshape((h * w,) + a.shape[2:])[idx].reshape((1, len(idx)) + a.shape[2:])

        return dataclasses.replace(
            self, position=take(self.position), normal=take(self.normal),
            albedo=take(self.albedo), coverage=None if self.coverage is None else take(self.coverage),
            maps={k: take(v) for k, v in self.maps.items()})

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


"""Every output of one frame, in one run: scene-linear EXR, SDR, HDR and the contact sheet.

This is the one per-frame output step of ``clphong render``, ``clphong
relight`` and :class:`clphong.Relighter`: :func:`render_outputs` shades a
G-buffer once and writes every file asked for, choosing the path for each:

* scene-linear EXR: float or half, zip or piz, tagged with the working space
  (``chromaticities`` and ``oiio:ColorSpace``, :func:`exr_attributes`);
* SDR without an OCIO display, view or look: exposure, the tone-mapping
  operator and sRGB encoding run fused in the shading kernel's store
  (``Renderer.render(gbuffer, display=...)``), no round trip through the host;
* SDR with a display/view/look: scene-linear → ``ImageBufAlgo.ociodisplay``
  (the view does the tone mapping, as in oiiotool, Blender and Nuke);
* HDR: Rec.2100 PQ through the 1000-nit view (``HDR_DISPLAY``/``HDR_VIEW``);
* contact sheet: every operator and every view of the SDR display.

Two small frozen (hashable, picklable) values describe the work:
:class:`OutputOptions`, *how* (formats and colour settings; a colour setting
left ``None`` is taken from the scene's ``[render]`` table by
:meth:`OutputOptions.for_scene`), and :class:`OutputPaths`, *where* (the files
of one frame, by kind). Every file is written atomically
(:func:`clphong.io.atomic.atomic_path`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from ..color import ocio as color
from ..core.errors import OutputError, OutputWarning
from ..core.memory import output_bytes, require_memory
from ..device.display import DisplayTransform, display_matrix
from ..device.renderer import straight_of
from ..io.atomic import check_pixel_type, same_file
from ..model import tonemap
from ..model.options import check_exposure, finished
from .contact import write_contact_sheet
from .writers import (
    HDR_EXTENSIONS,
    SDR_EXTENSIONS,
    check_bits,
    check_compression,
    check_sdr,
    jpegxl_available,
    write_hdr,
    write_scene_linear,
    write_sdr,
)

__all__ = ["OutputOptions", "OutputPaths", "render_outputs", "write_output", "exr_attributes",
           "check_outputs", "check_distinct", "OUTPUT_KINDS"]

#: The kinds of file one frame can be delivered as (fields of :class:`OutputPaths`).
OUTPUT_KINDS = ("exr", "sdr", "hdr", "contact_sheet")
#: The extensions each kind accepts.
EXTENSIONS = {"exr": (".exr",), "sdr": SDR_EXTENSIONS, "hdr": HDR_EXTENSIONS,
              "contact_sheet": SDR_EXTENSIONS}
#: Each kind in messages.
_WHAT = {"exr": "scene-linear", "sdr": "SDR", "hdr": "HDR", "contact_sheet": "contact-sheet"}
#: The display colour space (interop ID) a TIFF can be tagged with: OpenImageIO's TIFF
#: writer records only sRGB (EXIF ColorSpace = 1); TIFF has no cICP.

#: OutputOptions fields taken from the scene's [render] table when None (field -> ColorSettings key).
_FROM_SCENE = {"working_space": "working_space", "exposure": "exposure", "tonemap": "tonemap",
               "white": "white_point", "display": "display", "view": "view", "look": "look",
               "albedo_space": "albedo_space"}


def exr_attributes(working_space: str) -> dict:
    """Header tags of a scene-linear EXR in ``working_space``: chromaticities and colour space."""
    ws = color.working_space(working_space)
    return {"chromaticities": ws.chromaticities, "oiio:ColorSpace": ws.interop_id}


@dataclass(frozen=True)
class OutputOptions:
    """How each relit frame is written (the same for every frame of a rig).

    Attributes
    ----------
    pixel_type : {"float", "half"}
        EXR pixel type.
    compression : {"zip", "piz"}
        EXR compression.
    attributes : tuple of (str, object) pairs
        Extra EXR header attributes, after the colour-space tags.
    bits : {8, 16}
        SDR bit depth.
    dither : bool
        Dither before 8-bit quantisation.
    working_space, exposure, tonemap, white, display, view, look
        Colour settings, as the scene's ``[render]`` keys (``white`` is
        ``white_point``); ``None`` takes the scene's value
        (:meth:`for_scene`).
    hdr_view : str, optional
        OCIO view of the HDR output (default :data:`clphong.color.ocio.HDR_VIEW`).
    ocio_config : str, optional
        OCIO config (default ``$OCIO``, else the built-in one).
    alpha : bool
        Give the SDR and HDR outputs a straight (un-premultiplied) alpha channel
        (``--alpha``); the EXR always has ``A``, with RGB premultiplied.
    albedo_space : str, optional
        OCIO colour space of the G-buffer's albedo (``--albedo-space``, else
        ``render.albedo_space``): converted to the working space before shading.
    from_scene : tuple of str
        The colour settings :meth:`for_scene` took from the scene (for messages;
        not compared).
    scene_source : str, optional
        That scene's file (for messages; not compared).
    """

    pixel_type: str = "float"
    compression: str = "zip"
    attributes: tuple = ()
    bits: int = 8
    dither: bool = True
    working_space: str | None = None
    exposure: float | None = None
    tonemap: str | None = None
    white: float | None = None
    display: str | None = None
    view: str | None = None
    look: str | None = None
    hdr_view: str | None = None
    ocio_config: str | None = None
    alpha: bool = False
    albedo_space: str | None = None
    from_scene: tuple = field(default=(), compare=False, repr=False)
    scene_source: str | None = field(default=None, compare=False, repr=False)
    #: Set by :meth:`checked` on the instance it returns; any change (``replace``) makes
    #: an unchecked one again, so a checked value is checked once and never again.
    _checked: bool = field(default=False, init=False, compare=False, repr=False)
    #: The OutputPaths :func:`check_outputs` checked these options with (None: none).
    _checked_for: object = field(default=None, init=False, compare=False, repr=False)

    def for_scene(self, scene) -> "OutputOptions":
        """These options with every colour setting left ``None`` taken from ``scene.color``, checked.

        Raises
        ------
        ToneMapError, ColorError, OutputError
            A bad operator, working space, exposure, white point, pixel type,
            compression or bit depth (one line; no OCIO config is opened).
        """
        c = scene.color
        fill = {k: getattr(c, key) for k, key in _FROM_SCENE.items() if getattr(self, k) is None}
        given = tuple(k for k, v in fill.items() if v is not None)
        if self._checked and not given:
            return self                    # finished already: nothing of the scene's to add
        if given:
            fill.update(from_scene=self.from_scene + given, scene_source=getattr(scene, "source", None))
        return dataclasses.replace(self, **fill).checked()

    def origin(self, name: str) -> str:
        """Where colour setting ``name`` came from: ``--name`` or the scene key (for messages)."""
        if name in self.from_scene:
            return f"the scene key render.{_FROM_SCENE[name]} in {self.scene_source or 'the scene'}"
        return f"--{name.replace('_', '-')}"

    def checked(self) -> "OutputOptions":
        """Validate names and values; normalise operator and working-space names (once:
        a checked instance is returned as it is)."""
        if self._checked:
            return self
        check_pixel_type(self.pixel_type)
        check_compression(self.compression)
        check_bits(self.bits)
        changes = {}
        if self.tonemap is not None:
            op = tonemap.operator(self.tonemap)
            tonemap.operator_params(op.name, self.white)          # validates the white point
            changes["tonemap"] = op.name
        if self.working_space is not None:
            changes["working_space"] = color.working_space(self.working_space).name
        if self.exposure is not None:
            changes["exposure"] = check_exposure(self.exposure, self.origin("exposure"))
        out = dataclasses.replace(self, **changes)
        object.__setattr__(out, "_checked", True)
        return out

    @property
    def resolved(self) -> bool:
        """Whether the scene's settings have been filled in (:meth:`for_scene`)."""
        return self.working_space is not None and self.exposure is not None and self.tonemap is not None

    @property
    def ocio_view(self) -> bool:
        """Whether SDR goes through an OCIO view (any of display, view, look given)."""
        return bool(self.display or self.view or self.look)


def _paths(value) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, (str, os.PathLike)):
        return (os.fspath(value),)
    return tuple(os.fspath(v) for v in value)


@dataclass(frozen=True)
class OutputPaths:
    """The files of one frame, by kind (each a tuple of paths; any may be empty).

    The constructor accepts, for each kind, None, one path or a sequence of paths.
    """

    exr: tuple = ()
    sdr: tuple = ()
    hdr: tuple = ()
    contact_sheet: tuple = ()

    def __post_init__(self):
        for kind in OUTPUT_KINDS:
            object.__setattr__(self, kind, _paths(getattr(self, kind)))

    def items(self) -> list[tuple[str, str]]:
        """(kind, path) of every file, EXR first."""
        return [(kind, p) for kind in OUTPUT_KINDS for p in getattr(self, kind)]

    @property
    def files(self) -> tuple[str, ...]:
        return tuple(p for _, p in self.items())

    def __bool__(self) -> bool:
        return bool(self.files)

    def __len__(self) -> int:
        return len(self.files)

    def map(self, fn) -> "OutputPaths":
        """A copy with ``fn(kind, path)`` applied to every path."""
        return OutputPaths(**{k: tuple(fn(k, p) for p in getattr(self, k)) for k in OUTPUT_KINDS})

    def only(self, keep: Iterable[str]) -> "OutputPaths":
        """A copy keeping only the paths in ``keep``."""
        keep = set(keep)
        return OutputPaths(**{k: tuple(p for p in getattr(self, k) if p in keep) for k in OUTPUT_KINDS})


def check_extensions(paths: OutputPaths) -> None:
    """Each path ends in an extension its kind can be written as (before any work)."""
    for kind, path in paths.items():
        ext = os.path.splitext(path)[1].lower()
        allowed = EXTENSIONS[kind]
        what = _WHAT[kind]
        if ext not in allowed:
            raise OutputError(f"{path}: a {what} output must end in {' or '.join(allowed)}")
        if ext == ".jxl" and not jpegxl_available():
            raise OutputError(f"{path}: this OpenImageIO cannot write JPEG XL; write a .png instead")


def check_distinct(paths: OutputPaths) -> None:
    """No two outputs name the same file (one would silently replace the other)."""
    items = paths.items()
    for i, (kind, path) in enumerate(items):
        for kind0, path0 in items[:i]:
            if same_file(path0, path):
                twice = (f"twice as the {_WHAT[kind]} output" if kind == kind0
                         else f"as both the {_WHAT[kind0]} and the {_WHAT[kind]} output")
                raise OutputError(f"{path}: given {twice}; one would replace the other, "
                                  "give each output its own name")


@functools.lru_cache(maxsize=16)
def _config(path: str | None, env: str | None, stamp) -> color.ColorConfig:
    # ``env`` and ``stamp`` (the file's mtime) key the cache only.
    return color.load_config(path)


def _load_config(path: str | None) -> color.ColorConfig:
    """:func:`clphong.color.ocio.load_config`, opened once per process (a batch reuses it every frame)."""
    env = os.environ.get("OCIO")
    where = path if path is not None else env
    try:
        stamp = os.stat(where).st_mtime_ns if where and not where.startswith("ocio://") else None
    except OSError:
        stamp = None
    return _config(path, env, stamp)


@functools.lru_cache(maxsize=16)
def _to_rec709(cfg: color.ColorConfig, ws_name: str):
    m = cfg.working_to_rec709(color.working_space(ws_name))
    return None if m is None else tuple(map(tuple, np.asarray(m, np.float64)))


def _needs_config(options: OutputOptions, paths: OutputPaths, ws: color.WorkingSpace) -> bool:
    return bool(paths.hdr or paths.contact_sheet or options.albedo_space
                or (paths.sdr and (options.ocio_view or ws.name != "lin_rec709")))


def _check_display_files(cfg: color.ColorConfig, display: str, view: str, paths,
                         options: OutputOptions) -> None:
    """The SDR files of ``paths`` can hold what (display, view) encodes
    (:func:`~clphong.deliver.writers.check_sdr`: TIFF and JPEG name only sRGB)."""
    space = cfg.interop_id(cfg.display_colorspace(display, view))
    for path in paths:
        check_sdr(path, bits=options.bits, alpha=options.alpha, colorspace=space)


def _display_view(cfg, options, display, view, look):
    """``cfg.check_display_view``, its error naming the scene file and key where the
    bad name came from the scene (``render.display = "nope"``), not only the name."""
    try:
        return cfg.check_display_view(display, view, look)
    except color.ColorError as exc:
        msg = str(exc)
        for name in ("display", "view", "look"):
            if msg.startswith(f"{name} ") and name in options.from_scene:
                raise color.ColorError(f"{options.origin(name)}: {msg}") from None
        raise


def check_outputs(options: OutputOptions, paths: OutputPaths, *, warn: bool = True) -> OutputOptions:
    """Check everything about ``paths`` that can be checked before shading; return the options.

    Extensions, that no two outputs name the same file, names and values of
    ``options`` (which must be resolved: :meth:`OutputOptions.for_scene`), and,
    whenever a config, display, view, look or HDR view is given or an output
    goes through OCIO, that the config loads and has them (whether or not an
    output uses them: a bad name is never silently ignored). With ``warn``, an
    OutputWarning for a command-line ``--tonemap`` or ``--white`` no output uses.

    Raises
    ------
    OutputError, ToneMapError, ColorError
        One line naming the file, option or OCIO name at fault.
    """
    if not options.resolved:
        raise OutputError("output options lack the scene's colour settings; "
                          "call OutputOptions.for_scene(scene) first")
    options = options.checked()
    check_extensions(paths)
    check_distinct(paths)
    for path in paths.sdr:              # bits and alpha a file can hold (its colour space: below)
        check_sdr(path, bits=options.bits, alpha=options.alpha, colorspace=None)
    if options.ocio_view and options.tonemap != "none" and paths.sdr:
        views = [options.origin(k) for k in ("display", "view", "look") if getattr(options, k)]
        raise color.ColorError(
            f"tone-mapping operator {options.tonemap!r} ({options.origin('tonemap')}) and an OCIO "
            f"view ({', '.join(views)}) both tone-map the SDR output; drop one of them")
    if warn:
        _warn_unused(options, paths)
    ws = color.working_space(options.working_space)
    if (_needs_config(options, paths, ws) or options.ocio_config is not None or options.ocio_view
            or options.hdr_view):
        cfg = _load_config(options.ocio_config)
        if options.ocio_view:
            display, view, _ = _display_view(cfg, options, options.display, options.view, options.look)
            _check_display_files(cfg, display, view, paths.sdr, options)
        if paths.hdr or options.hdr_view:
            _display_view(cfg, options, color.HDR_DISPLAY, options.hdr_view or color.HDR_VIEW, options.look)
        if paths.contact_sheet or (paths.sdr and not options.ocio_view):
            _to_rec709(cfg, ws.name)
        if options.albedo_space:
            cfg.check_colorspace(options.albedo_space, options.origin("albedo_space"))
            cfg.space_name(ws)
        if paths.contact_sheet:          # encoded for --display (default: the config's own)
            display, view, _ = _display_view(cfg, options, options.display, None, options.look)
            _check_display_files(cfg, display, view, paths.contact_sheet,
                                 dataclasses.replace(options, bits=8, alpha=False))
    out = copy.copy(options)                # checked with these paths: not again (render_outputs)
    object.__setattr__(out, "_checked_for", paths)
    return out


def _warn_unused(options: OutputOptions, paths: OutputPaths) -> None:
    """Warn (one line) about a command-line colour option no output will use."""
    import warnings

    fused = bool(paths.sdr) and not options.ocio_view
    if options.tonemap != "none" and "tonemap" not in options.from_scene and not fused:
        warnings.warn(OutputWarning(
            f"--tonemap {options.tonemap} applies to the SDR output (--sdr) only; "
            + ("the HDR output is tone-mapped by its OCIO view" if paths.hdr
               else "no SDR output is written")), stacklevel=3)
    if (options.white is not None and "white" not in options.from_scene
            and not tonemap.operator(options.tonemap).uses_white):
        warnings.warn(OutputWarning(
            f"--white {options.white:g} has no effect: {options.tonemap!r} has no white point; "
            "only 'reinhard-extended' and 'hable' use it"), stacklevel=3)
    if options.alpha and not (paths.sdr or paths.hdr):
        warnings.warn(OutputWarning(
            "--alpha applies to the --sdr and --hdr outputs only, and none is written "
            "(the EXR always has A)"), stacklevel=3)


def write_output(rgb: np.ndarray, path: str | os.PathLike, options: OutputOptions | None = None,
                 *, alpha: np.ndarray | None = None, layers: dict | None = None) -> None:
    """Write a scene-linear (H, W, 3) frame as an EXR tagged with the options' working space.

    Parameters
    ----------
    rgb : numpy.ndarray
        (H, W, 3) float32 scene-linear RGB.
    path : str or os.PathLike
        Destination ``.exr``; replaced only when the write succeeds.
    options : OutputOptions, optional
        Pixel type, compression, extra attributes and working space (default:
        float32, zip, linear Rec.709).
    alpha : numpy.ndarray, optional
        (H, W) coverage, written as ``A`` (``rgb`` premultiplied by it).
    layers : dict, optional
        Name -> (H, W, 3) layers (light groups, AOVs), written as ``NAME.R/G/B``.

    Raises
    ------
    OutputError
        A name not ending in ``.exr``, or the file cannot be written (nothing
        is left behind).
    """
    options = (options or OutputOptions()).checked()
    ws = color.working_space(options.working_space or "lin_rec709")
    write_scene_linear(path, rgb, ws, pixel_type=options.pixel_type,
                       compression=options.compression, attributes=dict(options.attributes),
                       alpha=alpha, layers=layers)


def convert_albedo(gbuffer, cfg: color.ColorConfig, space: str, ws: color.WorkingSpace):
    """``gbuffer`` with its albedo converted from OCIO colour space ``space`` to the
    working space ``ws`` (OpenImageIO's colorconvert); background pixels are not shaded,
    so their albedo does not matter."""
    src = cfg.check_colorspace(space)
    dst = cfg.space_name(ws)
    if cfg.oiio.resolve(src) == cfg.oiio.resolve(dst):
        return gbuffer
    return dataclasses.replace(gbuffer, albedo=np.ascontiguousarray(
        cfg.convert(gbuffer.albedo, src, dst), np.float32))


def shading_albedo(gbuffer, options: OutputOptions):
    """``gbuffer`` as the kernels shade it: its albedo converted from ``options.albedo_space``
    to the working space (as :func:`render_outputs` does), or itself."""
    if not options.albedo_space:
        return gbuffer
    ws = color.working_space(options.working_space or "lin_rec709")
    return convert_albedo(gbuffer, _load_config(options.ocio_config), options.albedo_space, ws)


def coverage_of(gbuffer) -> np.ndarray:
    """The frame's coverage as written in ``A``: the G-buffer's, 0 on background
    pixels (not shaded), 1 on every other pixel of a G-buffer without one."""
    background = gbuffer.background_mask()
    if gbuffer.coverage is None:
        return np.logical_not(background).astype(np.float32)
    alpha = np.asarray(np.clip(gbuffer.coverage, 0, 1), np.float32)     # a new array
    np.copyto(alpha, 0, where=background)
    return alpha


def _check_output_memory(shape, paths: OutputPaths) -> None:
    """Refuse, before shading, a frame whose output files would not fit in memory
    (clphong.core.memory.output_bytes): one line with both figures, not the OOM killer."""
    kinds = [k for k in ("exr", "sdr", "contact_sheet") if getattr(paths, k)]
    kinds += ["hdr_jxl" if str(p).lower().endswith(".jxl") else "hdr" for p in paths.hdr]
    h, w = shape
    names = ", ".join(sorted(set(kinds))) or "no files"
    require_memory(output_bytes(shape, kinds), f"writing the outputs ({names}) of a {w}x{h} frame",
                   OutputError, "write the display outputs in separate runs, crop the frame, "
                   "or raise CLPHONG_MAX_MEMORY if more memory is free")


def render_outputs(renderer, gbuffer, options: OutputOptions,
                   paths: OutputPaths) -> tuple[np.ndarray, dict[str, float]]:
    """Shade ``gbuffer`` once and write every file of ``paths``.

    Parameters
    ----------
    renderer : clphong.Renderer
        Not modified (the fused display path shades on a shallow copy), so
        several threads may share it.
    gbuffer : clphong.GBuffer
    options : OutputOptions
        Unresolved colour settings are taken from ``renderer.scene``.
    paths : OutputPaths
        May be empty: the frame is then only shaded.

    Returns
    -------
    (clphong.device.renderer.RenderResult, dict)
        The shading's result (``.image``: the scene-linear (H, W, 3) float32
        frame; ``.stats``, ``.plan``, ``.cull``), and seconds spent: ``"shade"``
        (the shading, with the fused SDR path's tone mapping, which is inside the
        shading launch and is not separable), then per output kind written
        (``"exr"``, ``"sdr"``, ``"hdr"``, ``"contact_sheet"``: tone mapping +
        encoding + writing).
    """
    if not options.resolved:
        options = options.for_scene(renderer.scene)
    if options._checked_for != paths:
        options = check_outputs(options, paths, warn=False)   # the caller's check warned
    _check_output_memory(gbuffer.shape, paths)
    ws = color.working_space(options.working_space)
    cfg = _load_config(options.ocio_config) if _needs_config(options, paths, ws) else None
    times: dict[str, float] = {}
    t_shade = time.perf_counter()
    if paths.sdr and not options.ocio_view:
        matrix = _to_rec709(cfg, ws.name) if cfg is not None else None
        # the operator, exposure and white point were checked with the options: handed
        # down as they are; the matrix, from the OCIO config, is checked here
        dt = finished(DisplayTransform, operator=options.tonemap, exposure=options.exposure,
                      white=options.white, matrix=display_matrix(matrix), encoding="srgb")
    else:
        dt = None
    if options.alpha and not renderer.straight_alpha:
        # the fused display output takes the straight shade (DISPLAY_STRAIGHT)
        renderer = copy.copy(renderer)
        renderer.straight_alpha = True
    if options.albedo_space:
        gbuffer = convert_albedo(gbuffer, cfg, options.albedo_space, ws)
    result = renderer.render(gbuffer, display=dt)
    rgb, shown = result.image, result.display
    times["shade"] = time.perf_counter() - t_shade
    alpha = coverage_of(gbuffer)
    straight = None
    if options.alpha:
        # the display outputs' straight colour: un-premultiplied (the fused path has it)
        straight = straight_of(rgb, alpha, renderer.scene.background)
    if paths.exr:
        t0 = time.perf_counter()
        for path in paths.exr:
            write_output(rgb, path, options, alpha=alpha, layers=result.layers)
        times["exr"] = time.perf_counter() - t0
    if paths.sdr:
        t0 = time.perf_counter()
        if shown is not None:
            space, cicp = color.SRGB_DISPLAY_INTEROP, color.SRGB_CICP
        else:
            display, view, looks = cfg.check_display_view(options.display, options.view, options.look)
            shown = cfg.display_view(rgb if straight is None else straight, ws, display, view, looks,
                                     exposure=options.exposure)
            cs = cfg.display_colorspace(display, view)
            space, cicp = cfg.interop_id(cs), cfg.cicp(cs)
        for path in paths.sdr:
            write_sdr(path, shown, bits=options.bits, dither=options.dither, colorspace=space, cicp=cicp,
                      alpha=alpha if options.alpha else None)
        times["sdr"] = time.perf_counter() - t0
    if paths.hdr:
        t0 = time.perf_counter()
        hdr_view = options.hdr_view or color.HDR_VIEW
        pq = cfg.display_view(rgb if straight is None else straight, ws, color.HDR_DISPLAY,
                              hdr_view, options.look, exposure=options.exposure)
        space = cfg.display_colorspace(color.HDR_DISPLAY, hdr_view)
        for path in paths.hdr:
            write_hdr(path, pq, colorspace=cfg.interop_id(space), cicp=color.PQ_CICP,
                      alpha=alpha if options.alpha else None)
        times["hdr"] = time.perf_counter() - t0
    if paths.contact_sheet:
        t0 = time.perf_counter()
        for path in paths.contact_sheet:
            write_contact_sheet(path, rgb, ws, cfg, exposure=options.exposure, white=options.white,
                                look=options.look,
                                display=options.display)
        times["contact_sheet"] = time.perf_counter() - t0
    return result, times

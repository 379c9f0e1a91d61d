"""The pipeline-stage API: build a :class:`Relighter` once, relight many frames.

>>> import clphong
>>> relighter = clphong.Relighter("gbuffers/spheres.toml")      # compiles once
>>> rgb = relighter.relight("gbuffers/spheres.exr")              # (H, W, 3) float32
>>> relighter.relight("gbuffers/spheres.exr", out="lit.exr")     # doctest: +SKIP

A frame is a path to a multichannel EXR G-buffer, a
:class:`~clphong.gbuffer.GBuffer`, a mapping ``{"position": P, "normal": N,
"albedo": C}`` (optionally ``"coverage"`` and material maps) or a tuple
``(P, N, C)`` of (H, W, 3) float32 or float16 numpy arrays. The result is an
(H, W, 3) float32 scene-linear array, and, with ``out=``, a file written by
:func:`write_output` (atomically: temporary name, then rename).

A scene without a ``[camera]`` (or with ``type = "metadata"``) takes each
frame's camera from its ``worldToCamera`` header attribute
(:mod:`clphong.camera_meta`); numpy input passes the matrix as
``world_to_camera=``.

A :class:`Relighter` may be shared by several threads: frame preparation runs
in parallel and kernel launches are serialised by the renderer's lock. The
``clphong render`` and ``clphong relight`` commands go through this class.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from .camera_meta import resolve_camera
from .errors import GBufferError, OutputError
from .gbuffer import MAP_KEYS, GBuffer, read_gbuffer
from .output import write_exr

__all__ = ["Relighter", "OutputOptions", "write_output", "as_gbuffer", "OUTPUT_KINDS",
           "REC709_CHROMATICITIES", "SCENE_LINEAR_COLORSPACE"]

#: Rec.709 primaries and D65 white: the working space of scene-linear output.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: OCIO name of that space, stored as ``oiio:ColorSpace``.
SCENE_LINEAR_COLORSPACE = "Linear Rec.709 (sRGB)"
#: Output kinds :func:`write_output` can write today. Tone-mapped and
#: display-referred outputs (SDR PNG/TIFF, PQ) dispatch from the same function.
OUTPUT_KINDS = ("exr",)
#: Pixel types accepted for numpy G-buffer input (anything else is an error).
_INPUT_DTYPES = (np.float16, np.float32, np.float64)


@dataclass(frozen=True)
class OutputOptions:
    """How each relit frame is written.

    Attributes
    ----------
    kind : {"exr"}
        ``"exr"``: scene-linear Rec.709 RGB OpenEXR.
    pixel_type : {"float", "half"}
        EXR pixel type.
    compression : str
        EXR compression.
    attributes : tuple of (str, object) pairs
        Extra header attributes, after the colour-space tags.
    """

    kind: str = "exr"
    pixel_type: str = "float"
    compression: str = "zip"
    attributes: tuple = ()


def write_output(rgb: np.ndarray, path: str | os.PathLike, options: OutputOptions | None = None) -> None:
    """Write one relit frame: the single per-frame output step of the API, CLI and batch.

    Parameters
    ----------
    rgb : numpy.ndarray
        (H, W, 3) float32 scene-linear RGB.
    path : str or os.PathLike
        Destination; replaced only when the write succeeds.
    options : OutputOptions, optional
        Output kind and format (default: float32 scene-linear EXR).

    Raises
    ------
    OutputError
        Unknown output kind, or the file cannot be written (nothing is left
        behind).
    """
    options = options or OutputOptions()
    if options.kind not in OUTPUT_KINDS:
        raise OutputError(f"{os.fspath(path)}: unknown output kind {options.kind!r}; "
                          f"valid kinds: {', '.join(OUTPUT_KINDS)}")
    attributes = {"chromaticities": REC709_CHROMATICITIES,
                  "oiio:ColorSpace": SCENE_LINEAR_COLORSPACE,
                  "Software": "clphong"}
    attributes.update(dict(options.attributes))
    write_exr(path, rgb, pixel_type=options.pixel_type, compression=options.compression,
              attributes=attributes)


def _array(value, name: str, want_channels: int | None) -> np.ndarray:
    arr = np.asarray(value)
    if arr.dtype.type not in _INPUT_DTYPES:
        raise GBufferError(f"{name}: expected a float32 or float16 array, got dtype {arr.dtype}")
    if want_channels is None:
        ok = arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 1)
        shape = "(H, W)"
    else:
        ok = arr.ndim == 3 and arr.shape[2] == want_channels
        shape = f"(H, W, {want_channels})"
    if not ok:
        raise GBufferError(f"{name}: expected an {shape} array, got shape {arr.shape}")
    if want_channels is None and arr.ndim == 3:
        arr = arr[..., 0]
    return np.ascontiguousarray(arr, dtype=np.float32)


def as_gbuffer(frame, *, channels: Mapping | None = None) -> GBuffer:
    """Turn any accepted frame form into a :class:`~clphong.gbuffer.GBuffer`.

    Parameters
    ----------
    frame : str, os.PathLike, GBuffer, mapping or (P, N, C) tuple
        See the module docstring.
    channels : mapping, optional
        Channel overrides for file input (see :func:`clphong.read_gbuffer`).

    Raises
    ------
    GBufferError
        An unreadable file, or an array of the wrong shape or dtype (naming
        the buffer).
    """
    if isinstance(frame, GBuffer):
        return frame
    if isinstance(frame, (str, os.PathLike)):
        return read_gbuffer(frame, channels=channels)
    if isinstance(frame, Mapping):
        missing = [k for k in ("position", "normal", "albedo") if k not in frame]
        if missing:
            raise GBufferError(f"frame mapping lacks {', '.join(missing)}; give position, normal "
                               "and albedo (H, W, 3) arrays")
        unknown = [k for k in frame if k not in ("position", "normal", "albedo", "coverage", *MAP_KEYS)]
        if unknown:
            raise GBufferError(f"frame mapping: unknown key {unknown[0]!r}; valid keys: position, "
                               f"normal, albedo, coverage, {', '.join(MAP_KEYS)}")
        maps = {k: _array(frame[k], k, 3 if k == "specular_color" else None)
                for k in MAP_KEYS if k in frame}
        cov = frame.get("coverage")
        return GBuffer(position=_array(frame["position"], "position", 3),
                       normal=_array(frame["normal"], "normal", 3),
                       albedo=_array(frame["albedo"], "albedo", 3),
                       coverage=None if cov is None else _array(cov, "coverage", None),
                       maps=maps, convention="explicit")
    if isinstance(frame, Sequence) and len(frame) == 3:
        P, N, C = frame
        return GBuffer(position=_array(P, "position", 3), normal=_array(N, "normal", 3),
                       albedo=_array(C, "albedo", 3), convention="explicit")
    raise GBufferError(f"cannot relight a {type(frame).__name__}: give an EXR path, a GBuffer, "
                       "a mapping of position/normal/albedo arrays or a (P, N, C) tuple")


def _hashable_channels(channels) -> tuple:
    if not channels:
        return ()
    return tuple(sorted((k, v if isinstance(v, str) else tuple(v)) for k, v in dict(channels).items()))


@dataclass(frozen=True)
class RelighterSpec:
    """Everything needed to rebuild an identical :class:`Relighter` elsewhere.

    Picklable and hashable, so worker processes (local pools, Dask workers)
    can build their relighter once and reuse it (:func:`cached_relighter`).
    """

    scene: object
    device: str | None = None
    kernel: str = "lanes"
    lanes: int | None = None
    channels: tuple = ()
    output: OutputOptions = field(default_factory=OutputOptions)

    def build(self) -> Relighter:
        return Relighter(self.scene, device=self.device, kernel=self.kernel, lanes=self.lanes,
                         channels=dict(self.channels) or None, output=self.output)


_CACHE: dict = {}


def cached_relighter(spec: RelighterSpec) -> Relighter:
    """This process's relighter for ``spec``: built (and compiled) on first use, then reused."""
    import threading

    lock = _CACHE.setdefault("__lock__", threading.Lock())
    with lock:
        r = _CACHE.get(spec)
        if r is None:
            r = spec.build()
            _CACHE[spec] = r
        return r


class Relighter:
    """A scene compiled once, relighting many frames.

    Parameters
    ----------
    scene : clphong.scene.Scene or str or os.PathLike
        The scene (camera, material, lights), or its TOML file.
    device, kernel, lanes
        As for :class:`clphong.Renderer`.
    channels : mapping, optional
        Channel overrides used when reading frames from files.
    output : OutputOptions, optional
        How :meth:`relight` writes ``out=`` files.

    Notes
    -----
    The kernel variant is compiled at construction (a bad device or kernel
    fails here, not on the first frame). Thread-safe: several threads may
    call :meth:`relight` on one instance.
    """

    def __init__(self, scene, *, device: str | None = None, kernel: str = "lanes",
                 lanes: int | None = None, channels: Mapping | None = None,
                 output: OutputOptions | None = None):
        from .render import Renderer
        from .scene import Scene, load_scene

        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        self.scene = scene
        self.channels = dict(channels) if channels else None
        self.output = output or OutputOptions()
        self.renderer = Renderer(scene, device=device, kernel=kernel, lanes=lanes)
        self.spec = RelighterSpec(scene=scene, device=device, kernel=kernel, lanes=lanes,
                                  channels=_hashable_channels(channels), output=self.output)

    @property
    def camera_from_metadata(self) -> bool:
        """True when each frame's camera comes from its ``worldToCamera``."""
        return self.scene.camera.type == "metadata"

    def read(self, frame) -> GBuffer:
        """The frame as a :class:`~clphong.gbuffer.GBuffer` (reads files; validates arrays)."""
        return as_gbuffer(frame, channels=self.channels)

    def renderer_for(self, gbuffer: GBuffer, *, world_to_camera=None, source: str | None = None):
        """The renderer for one frame: ours, or, for a metadata camera, a view of it with the frame's camera.

        The view is a shallow copy: it shares the compiled programs and the
        launch lock, and only its ``scene`` (the eye position, a kernel
        argument) differs, so nothing is recompiled.
        """
        if not self.camera_from_metadata:
            return self.renderer
        where = source or gbuffer.sources.get("position", "<frame>").split(":")[0]
        scene = resolve_camera(self.scene, gbuffer.attributes, world_to_camera_matrix=world_to_camera,
                               source=where)
        view = copy.copy(self.renderer)
        view.scene = scene
        return view

    def relight(self, frame, out: str | os.PathLike | None = None, *,
                world_to_camera=None) -> np.ndarray:
        """Relight one frame.

        Parameters
        ----------
        frame : str, os.PathLike, GBuffer, mapping or tuple
            The G-buffer (see the module docstring).
        out : str or os.PathLike, optional
            Also write the result there with :func:`write_output`.
        world_to_camera : array_like, optional
            (4, 4) world-to-camera matrix for a metadata-camera scene when the
            frame has no header (numpy input); overrides the header otherwise.

        Returns
        -------
        numpy.ndarray
            (H, W, 3) float32 scene-linear RGB.
        """
        if out is not None and isinstance(frame, (str, os.PathLike)) and _same_file(frame, out):
            raise OutputError(f"{os.fspath(out)}: output would overwrite the input {os.fspath(frame)}")
        gbuffer = self.read(frame)
        source = os.fspath(frame) if isinstance(frame, (str, os.PathLike)) else None
        rgb = self.renderer_for(gbuffer, world_to_camera=world_to_camera, source=source).render(gbuffer)
        if out is not None:
            write_output(rgb, out, self.output)
        return rgb

    __call__ = relight


def _same_file(a, b) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)

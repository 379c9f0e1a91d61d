"""The pipeline-stage API: build a :class:`Relighter` once, relight many frames.

>>> import clphong
>>> relighter = clphong.Relighter("gbuffers/spheres.toml")      # compiles once
>>> rgb = relighter.relight("gbuffers/spheres.exr")              # (H, W, 3) float32
>>> relighter.relight("gbuffers/spheres.exr", out="lit.exr")     # doctest: +SKIP
>>> relighter.relight("gbuffers/spheres.exr", sdr="lit.png", hdr="lit_pq.png")  # doctest: +SKIP

A frame is a path to a multichannel EXR G-buffer, a
:class:`~clphong.io.gbuffer.GBuffer`, a mapping ``{"position": P, "normal": N,
"albedo": C}`` (optionally ``"coverage"`` and material maps) or a tuple
``(P, N, C)`` of (H, W, 3) float32 or float16 numpy arrays. The result is an
(H, W, 3) float32 scene-linear array, and, with ``out=`` (scene-linear EXR
tagged with the working space), ``sdr=`` (PNG/TIFF), ``hdr=`` (PQ PNG or JPEG
XL) or ``contact_sheet=``, files written by :func:`clphong.deliver.outputs.render_outputs`,
the same output step as ``clphong render`` (atomically: temporary name, then
rename). Tone mapping, exposure, display, view and look come from the scene's
``[render]`` table unless ``output=OutputOptions(...)`` overrides them.

A scene without a ``[camera]`` (or with ``type = "metadata"``) takes each
frame's camera from its ``worldToCamera`` header attribute
(:mod:`clphong.io.camera`); numpy input passes the matrix as
``world_to_camera=``.

A :class:`Relighter` may be shared by several threads: frame preparation runs
in parallel and kernel launches are serialised by the renderer's lock. The
``clphong render`` and ``clphong relight`` commands go through this class.
"""

from __future__ import annotations

import copy
import dataclasses
import os
import threading
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, dataclass, field

import numpy as np

from ..color.ocio import REC709_CHROMATICITIES, WORKING_SPACES
from ..core.errors import GBufferError, OutputError
from ..deliver.outputs import (
    OUTPUT_KINDS,
    OutputOptions,
    OutputPaths,
    render_outputs,
    shading_albedo,
    write_output,
)
from ..device.envprobe import DeviceProbeShader
from ..device.renderer import Renderer
from ..device.renderer import render as render_resolved
from ..io.atomic import same_file
from ..io.camera import resolve_camera
from ..io.envmap import FrameSource, check_environment_maps, resolve_environment
from ..io.gbuffer import MAP_KEYS, GBuffer, read_gbuffer
from ..model.options import (
    DEFAULT_ENV_ERROR,
    ENV_PATHS,
    ENV_PROBES,
    RendererOptions,
    check_env_error,
    finished,
    validate_method,
)
from ..model.scene import MATERIAL_MAPS, Light, Scene, load_scene

__all__ = ["Relighter", "OutputOptions", "OutputPaths", "write_output", "as_gbuffer",
           "OUTPUT_KINDS", "REC709_CHROMATICITIES", "SCENE_LINEAR_COLORSPACE"]

#: Interop ID of the default working space (linear Rec.709), stored as ``oiio:ColorSpace``;
#: an EXR in another working space is tagged with that space (:func:`clphong.deliver.outputs.exr_attributes`).
SCENE_LINEAR_COLORSPACE = WORKING_SPACES["lin_rec709"].interop_id
#: Frames whose environment lights a Relighter keeps (env_probes="frame"): a batch of
#: one camera's frames repeats a few; the conversions are on disk besides.
FRAMES_KEPT = 4
#: Pixel types accepted for numpy G-buffer input (anything else is an error).
_INPUT_DTYPES = (np.float16, np.float32, np.float64)


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
    """Turn any accepted frame form into a :class:`~clphong.io.gbuffer.GBuffer`.

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
        maps = {k: _array(frame[k], k, c if c > 1 else None)
                for k, c in MATERIAL_MAPS.items() if k in frame}
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


@dataclass(frozen=True, kw_only=True)
class RelighterSpec(RendererOptions):
    """Everything needed to rebuild an identical :class:`Relighter` elsewhere: its
    renderer options (a :class:`~clphong.model.options.RendererOptions`, checked and
    normalised when the spec is made) and the rest.

    Picklable and hashable, so worker processes (local pools, Dask workers)
    can build their relighter once and reuse it (:func:`cached_relighter`); the
    renderer options are part of the cache key, so workers build a relighter with
    exactly these.
    """

    scene: object
    device: str | None = None
    kernel: str = "lanes"
    lanes: int | None = None
    channels: tuple = ()
    output: OutputOptions = field(default_factory=OutputOptions)

    @property
    def options(self) -> RendererOptions:
        """The renderer options alone, as checked when this spec was made."""
        return finished(RendererOptions, **self.kwargs())

    @classmethod
    def of(cls, options: RendererOptions, **rest) -> "RelighterSpec":
        """The spec of ``options`` (checked already) and the rest of the fields."""
        given = options.kwargs()
        twice = set(rest) & set(given)
        if twice:
            raise TypeError(f"RelighterSpec.of: {', '.join(sorted(twice))} given with options")
        defaults = {k: f.default if f.default is not MISSING else f.default_factory()
                    for k, f in cls.__dataclass_fields__.items()
                    if f.default is not MISSING or f.default_factory is not MISSING}
        return finished(cls, **{**defaults, **rest, **given})

    def build(self) -> Relighter:
        return Relighter(self.scene, device=self.device, kernel=self.kernel, lanes=self.lanes,
                         channels=dict(self.channels) or None, output=self.output,
                         options=self.options)


def check_renderer_options(*, fp64_directions=None, max_error=None, reference_white=1.0,
                           nonfinite="background", path=None, aovs=(),
                           env_error=DEFAULT_ENV_ERROR, light_tree=True,
                           relative=False, env_probes="frame",
                           env_path="auto") -> RendererOptions:
    """The renderer options of a :class:`Relighter`, checked without compiling anything
    (:class:`~clphong.model.options.RendererOptions`, which raises as it says)."""
    return RendererOptions(fp64_directions=fp64_directions, max_error=max_error,
                           reference_white=reference_white, nonfinite=nonfinite, path=path,
                           aovs=aovs, env_error=env_error, light_tree=light_tree,
                           relative=relative, env_probes=env_probes, env_path=env_path)


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
    scene : clphong.model.scene.Scene or str or os.PathLike
        The scene (camera, material, lights), or its TOML file.
    device, kernel, lanes
        As for :class:`clphong.Renderer`.
    fp64_directions : bool, optional
        None (default): directions in double where the device has fp64 (the
        accurate path); False: float32 directions (``--path float``); True:
        require fp64.
    path : {"accurate", "float", "fast"}, optional
        A shading path (``--path``; :data:`clphong.model.options.PATHS`), instead of
        ``fp64_directions``.
    max_error : float, optional
        Tiled light culling budget relative to ``reference_white``
        (``--max-error``); None (default): no culling.
    reference_white : float
        Output radiance of reference white for ``max_error`` (default 1.0).
    relative : bool
        ``max_error`` is a fraction of each pixel's own value, per channel
        (``--relative``; :class:`~clphong.device.renderer.Renderer`).
    nonfinite : {"background", "error", "pass"}
        NaN/Inf input policy (:mod:`clphong.io.nonfinite`); under ``"error"`` a
        frame with a non-finite value raises
        :class:`~clphong.core.errors.GBufferError` (in a batch: that frame fails).
    channels : mapping, optional
        Channel overrides used when reading frames from files.
    output : OutputOptions, optional
        How :meth:`relight` writes files: formats, and colour settings that
        override the scene's ``[render]`` keys (``None`` fields take the
        scene's). Resolved and checked here: a bad operator or working space
        fails at construction.
    env_error : float
        Relative error target of the scene's environment lights (``--env-error``,
        default 1e-3): each is resolved into directional lights here
        (:func:`clphong.io.envmap.resolve_environment`); ``environments`` holds
        what each became.
    env_probes : {"frame", "all"}
        Where that error is estimated (``--env-probes``). ``"frame"`` (default): on
        each frame's own normals and views and over its range of albedos, in
        :meth:`renderer_for`, so a frame gets the lights it needs (26,989 against
        48,393 for the 1024 × 512 sample sky on ``gbuffers/spheres.exr``); each
        frame's conversion is cached by its probes, and ``environments`` is then the
        last frame's. ``"all"``: at construction, on every normal and view at white
        albedo, one conversion for every frame.
    env_path : {"auto", "lights"}
        ``"auto"`` (default): with ``env_probes="frame"`` and the lane kernel, a frame
        whose every pixel the tables' bound holds shades its environment from them
        (:mod:`clphong.model.env_table`; ``env_tables`` and ``env_paths`` say which);
        ``"lights"``: always directional lights.

    Notes
    -----
    The kernel variant is compiled at construction (a bad device or kernel
    fails here, not on the first frame). Thread-safe: several threads may
    call :meth:`relight` on one instance.

    With environment lights and ``env_probes="frame"``, :attr:`scene` and
    :attr:`renderer` hold each environment as one dark directional light of its
    group (its place in the plan, for the compile at construction); a frame is
    shaded with its own lights only through :meth:`relight`, :meth:`deliver` and
    :meth:`renderer_for`.
    """

    def __init__(self, scene, *, device: str | None = None, kernel: str = "lanes",
                 lanes: int | None = None, channels: Mapping | None = None,
                 output: OutputOptions | None = None, fp64_directions: bool | None = None,
                 max_error: float | None = None, reference_white: float = 1.0,
                 nonfinite: str = "background", path: str | None = None, aovs=(),
                 env_error: float = DEFAULT_ENV_ERROR, light_tree: bool = True,
                 relative: bool = False, env_probes: str = "frame", env_path: str = "auto",
                 options: RendererOptions | None = None):
        # Renderer options first: a bad value fails before the scene is read or compiled.
        # Given as ``options`` they were checked where they came in, and are not again.
        given = dict(fp64_directions=fp64_directions, max_error=max_error,
                     reference_white=reference_white, nonfinite=nonfinite, path=path,
                     aovs=aovs, env_error=env_error, light_tree=light_tree,
                     relative=relative, env_probes=env_probes, env_path=env_path)
        if options is None:
            options = check_renderer_options(**given)
        else:
            twice = [k for k, v in given.items()
                     if v != RendererOptions.__dataclass_fields__[k].default]
            if twice:
                raise ValueError(f"give the renderer options as options= or as keyword "
                                 f"arguments, not both ({', '.join(twice)} given with options=)")
        self.options = options
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        # The kernels shade directional lights, not maps: environment lights resolved here,
        # or with env_probes="frame" for each frame (renderer_for), from its own pixels.
        self._probe_shader = DeviceProbeShader(device)
        self._frame_env = options.env_probes == "frame" and bool(scene.lights_of("environment"))
        self._tables = options.env_path == "auto" and kernel == "lanes"
        #: the last frame's environments shaded from tables, (index, EnvTables), and every
        #: environment's path, (index, "tables" or "lights", why)
        self.env_tables: tuple = ()
        self.env_paths: tuple = ()
        self._unresolved = scene
        self._frames: dict = {}            # the frames' probe digests -> their lights
        self._frames_lock = threading.Lock()
        if self._frame_env:
            # a map that cannot be used fails here, as it would resolved at construction
            check_environment_maps(scene, nonfinite=options.nonfinite,
                                   max_error=options.env_error if self._tables else None)
            scene = dataclasses.replace(scene, lights=tuple(
                Light(type="directional", color=(0.0, 0.0, 0.0), direction=(0.0, -1.0, 0.0),
                      group=lt.group) if lt.type == "environment" else lt
                for lt in scene.lights))
            self.environments = ()
        else:
            resolved = resolve_environment(scene, max_error=options.env_error,
                                           nonfinite=options.nonfinite, shade=self._probe_shader)
            scene = resolved.scene
            self.environments = resolved.environments
            self.env_paths = resolved.paths
        self.scene = scene
        self.channels = dict(channels) if channels else None
        self.output = (output or OutputOptions()).for_scene(scene)
        self.renderer = Renderer(scene, device=device, kernel=kernel, lanes=lanes,
                                 straight_alpha=self.output.alpha, options=options)
        # a worker rebuilds this relighter from the spec: with frame probes it resolves
        # each of its frames itself, so it gets the environment lights, not the stand-ins
        self.spec = RelighterSpec.of(options, scene=self._unresolved if self._frame_env else scene,
                                     device=device, kernel=kernel,
                                     lanes=lanes, channels=_hashable_channels(channels),
                                     output=self.output)

    @property
    def camera_from_metadata(self) -> bool:
        """True when each frame's camera comes from its ``worldToCamera``."""
        return self.scene.camera.type == "metadata"

    def read(self, frame) -> GBuffer:
        """The frame as a :class:`~clphong.io.gbuffer.GBuffer` (reads files; validates arrays)."""
        return as_gbuffer(frame, channels=self.channels)

    def renderer_for(self, gbuffer: GBuffer, *, world_to_camera=None, source: str | None = None):
        """The renderer for one frame: ours, or a view of it with the frame's camera (a
        metadata camera) and the frame's environment lights (``env_probes="frame"``).

        The view is a shallow copy: it shares the compiled programs and the launch
        lock, and only its ``scene`` differs. The eye position is a kernel argument, so
        a camera alone recompiles nothing; a frame's environment lights may change the
        plan (its light counts), whose program is then built once and cached. State a
        view changes (culling's retry count) stays with that frame's view.
        """
        if not self.camera_from_metadata and not self._frame_env:
            return self.renderer
        scene = self.scene
        if self.camera_from_metadata:
            where = source or gbuffer.sources.get("position", "<frame>").split(":")[0]
            scene = resolve_camera(self.scene, gbuffer.attributes,
                                   world_to_camera_matrix=world_to_camera, source=where)
        fallback = None
        if self._frame_env:
            # the frame as the kernels shade it: its albedo in the working space
            lights, tables, fallback = self._frame_lights(scene.camera,
                                                          shading_albedo(gbuffer, self.output))
            scene = dataclasses.replace(scene, lights=lights, env_tables=tables)
        view = copy.copy(self.renderer)
        view.scene = scene
        if fallback is not None:       # the pixels the tables' bound does not hold: lights
            view = view.with_fallback(dataclasses.replace(scene, lights=fallback[0].lights,
                                                          env_tables=()), fallback[1])
        return view

    def _frame_lights(self, camera, gbuffer) -> tuple:
        """(the scene's lights, its environment tables, the fallback: (scene, pixels) or None)
        with each environment resolved on this frame (:class:`clphong.io.envmap.FrameSource`: named by the frame's bytes, its
        probes chosen only if a conversion runs, its tables' bound checked on its
        pixels), the last few frames' kept."""
        N = np.asarray(gbuffer.normal)
        if not ((N != 0) & np.isfinite(N)).any():    # no shaded pixel: no light reaches one
            self.environments, self.env_tables, self.env_paths = (), (), ()
            return self.scene.lights, (), None
        pairs = FrameSource(camera, gbuffer, self.scene.material)
        # with tables, resolving costs the horizon check (0.1 s at 1080p), not the frame's
        # hash; a frame that takes lights finds its conversion in envmap's caches
        key = None if self._tables else pairs.digest()
        with self._frames_lock:
            hit = self._frames.get(key) if key is not None else None
        if hit is None:
            opts = self.options
            resolved = resolve_environment(self._unresolved, max_error=opts.env_error,
                                           nonfinite=opts.nonfinite, shade=self._probe_shader,
                                           pairs=pairs, tables=self._tables)
            hit = (resolved.scene.lights, resolved.scene.env_tables, resolved.fallback,
                   resolved.environments, resolved.tables, resolved.paths)
            with self._frames_lock:
                while key is not None and len(self._frames) >= FRAMES_KEPT:
                    self._frames.pop(next(iter(self._frames)))
                if key is not None:
                    self._frames[key] = hit
        self.environments, self.env_tables, self.env_paths = hit[3:]
        return hit[0], hit[1], hit[2]

    def relight(self, frame, out: str | os.PathLike | None = None, *, sdr=None, hdr=None,
                contact_sheet=None, world_to_camera=None) -> np.ndarray:
        """Relight one frame, and write any outputs asked for.

        Parameters
        ----------
        frame : str, os.PathLike, GBuffer, mapping or tuple
            The G-buffer (see the module docstring).
        out : str or os.PathLike or list of them, optional
            Scene-linear EXR file(s), tagged with the working space.
        sdr : str or os.PathLike or list of them, optional
            Display-referred SDR PNG/TIFF file(s): the scene's (or
            :attr:`output`'s) exposure and tone-mapping operator, fused in the
            shading kernel, or its OCIO display/view/look.
        hdr : str or os.PathLike or list of them, optional
            Rec.2100 PQ 16-bit PNG or JPEG XL file(s).
        contact_sheet : str or os.PathLike, optional
            PNG of the frame through every operator and view.
        world_to_camera : array_like, optional
            (4, 4) world-to-camera matrix for a metadata-camera scene when the
            frame has no header (numpy input); overrides the header otherwise.

        Returns
        -------
        numpy.ndarray
            (H, W, 3) float32 scene-linear RGB.

        Raises
        ------
        OutputError, ToneMapError, ColorError
            A bad output name or colour setting (before shading), or a write
            that fails (nothing partial is left).
        """
        paths = OutputPaths(exr=out, sdr=sdr, hdr=hdr, contact_sheet=contact_sheet)
        if isinstance(frame, (str, os.PathLike)):
            for p in paths.files:
                if same_file(frame, p):
                    raise OutputError(f"{p}: output would overwrite the input {os.fspath(frame)}")
        gbuffer = self.read(frame)
        source = os.fspath(frame) if isinstance(frame, (str, os.PathLike)) else None
        return self.deliver(gbuffer, paths, world_to_camera=world_to_camera, source=source)

    def deliver(self, gbuffer: GBuffer, paths: OutputPaths, *, world_to_camera=None,
                source: str | None = None) -> np.ndarray:
        """Shade a G-buffer and write ``paths`` with :attr:`output`: the per-frame step of the API and batches."""
        renderer = self.renderer_for(gbuffer, world_to_camera=world_to_camera, source=source)
        result, _ = render_outputs(renderer, gbuffer, self.output, paths)
        return result.image

    __call__ = relight



# --------------------------------------------------------------------------- staged delivery (batches)


class _StagedRenderer(Renderer):
    """A view of a :class:`~clphong.device.renderer.Renderer` (a shallow copy, as
    :meth:`Relighter.renderer_for` makes) with seams for :func:`deliver_staged`:
    :meth:`render` calls ``_stage_after(result)`` once the frame is shaded, before it
    returns (in :func:`render_outputs`: after the shading, before the first file is
    written); with ``_stage_replay`` set it shades nothing and returns that result.
    Not constructed: made by :func:`_staged_view`. A copy of it (``render_outputs``
    copies the renderer for straight alpha) keeps both."""

    def render(self, gbuffer, **kwargs):
        if self._stage_replay is not None:
            return self._stage_replay
        result = super().render(gbuffer, **kwargs)
        if self._stage_after is not None:
            self._stage_after(result)
        return result


def _staged_view(renderer, *, after=None, replay=None):
    view = object.__new__(_StagedRenderer)
    view.__dict__.update(renderer.__dict__)
    view._stage_after, view._stage_replay = after, replay
    return view


def deliver_staged(relighter, gbuffer: GBuffer, paths: OutputPaths, *, source: str | None = None,
                   world_to_camera=None, before_write=None,
                   parallel: bool = False) -> tuple[np.ndarray, dict[str, float]]:
    """:meth:`Relighter.deliver` with a seam between shading and writing, and the time of each.

    The same files, byte for byte: it is :func:`render_outputs` on the same
    renderer, with ``before_write()`` called in this thread once the frame is
    shaded and before its first file is written (a batch waits there for the
    previous frame's writes, so that frames are written one at a time and in
    order). An exception from ``before_write`` abandons the frame: nothing of it
    is written.

    With ``parallel`` and an EXR besides display outputs (SDR, HDR, contact
    sheet), the EXR is written in a thread of its own while this one writes the
    others, from the one shading (``render_outputs`` of the EXR alone, on the same
    result): each file as :func:`render_outputs` of all of them would write it. A
    failure of one does not stop the other; the EXR's error is raised first.

    Returns
    -------
    (numpy.ndarray, dict)
        The scene-linear image, and seconds: ``"shade"`` (from the call to the end of
        the shading: option checks, albedo conversion, non-finite policy, kernel),
        ``"wait"`` (in ``before_write``) and ``"write"`` (every file, from the end of
        ``before_write`` to the end).

    Notes
    -----
    A relighter that is not a :class:`Relighter` on a plain
    :class:`~clphong.device.renderer.Renderer` (a test double, a subclass) has no
    seam: ``before_write()`` is then called first and ``relighter.deliver`` does
    the rest, one after the other (all of it timed as ``"shade"``).
    """
    import threading
    import time

    marks: dict[str, float] = {}
    t0 = time.perf_counter()
    renderer = None
    if isinstance(relighter, Relighter):
        renderer = relighter.renderer_for(gbuffer, world_to_camera=world_to_camera, source=source)
    if renderer is None or type(renderer) is not Renderer:
        if before_write is not None:
            before_write()
        t1 = time.perf_counter()
        image = relighter.deliver(gbuffer, paths, source=source)
        return image, {"shade": time.perf_counter() - t1, "wait": t1 - t0, "write": 0.0}

    exr_alone = None
    if parallel and paths.exr and len(paths.exr) < len(paths):
        exr_alone = paths.only(paths.exr)
        paths = paths.only(p for p in paths.files if p not in set(paths.exr))
    side: dict = {}

    def write_exr(result):
        try:
            render_outputs(_staged_view(renderer, replay=result), gbuffer, relighter.output, exr_alone)
        except BaseException as exc:  # noqa: BLE001 - raised in the calling thread
            side["error"] = exc

    def after(result):
        marks["shaded"] = time.perf_counter()
        if before_write is not None:
            before_write()
        marks["writing"] = time.perf_counter()
        if exr_alone is not None:
            side["thread"] = threading.Thread(target=write_exr, args=(result,), daemon=True,
                                              name=f"{threading.current_thread().name}-exr")
            side["thread"].start()

    try:
        result, _ = render_outputs(_staged_view(renderer, after=after), gbuffer, relighter.output, paths)
    except BaseException as exc:
        if "thread" not in side:
            raise
        side["thread"].join()
        raise side.get("error", exc) from None
    if "thread" in side:
        side["thread"].join()
        if "error" in side:
            raise side["error"]
    t1 = time.perf_counter()
    return result.image, {"shade": marks["shaded"] - t0, "wait": marks["writing"] - marks["shaded"],
                          "write": t1 - marks["writing"]}


def render(scene, gbuffer, *, env_error: float = DEFAULT_ENV_ERROR, env_probes: str = "frame",
           env_path: str = "auto", **kwargs) -> np.ndarray:
    """Shade ``gbuffer`` with ``scene``: (H, W, 3) float32, scene-linear (``clphong.render``).

    :func:`clphong.device.renderer.render` after the scene's environment lights are
    resolved into directional lights within ``env_error``
    (:func:`clphong.io.envmap.resolve_environment`), estimated on this G-buffer's
    pixels (``env_probes="frame"``, the default, where the scene has its own camera)
    or on every normal and view (``"all"``), from tables where their bound holds on the
    frame (``env_path="auto"``, :class:`Relighter`); other keyword arguments go to
    :class:`~clphong.device.renderer.Renderer`.
    """
    check_env_error(env_error)
    validate_method(env_probes, ENV_PROBES, "env_probes")
    validate_method(env_path, ENV_PATHS, "env_path")
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    pairs = None
    if (env_probes == "frame" and scene.lights_of("environment")
            and scene.camera.type != "metadata" and isinstance(gbuffer, GBuffer)):
        pairs = FrameSource(scene.camera, gbuffer, scene.material)
    resolved = resolve_environment(scene, max_error=env_error,
                                   nonfinite=kwargs.get("nonfinite", "background"),
                                   shade=DeviceProbeShader(kwargs.get("device")), pairs=pairs,
                                   tables=env_path == "auto"
                                   and kwargs.get("kernel", "lanes") == "lanes")
    if resolved.fallback is None:
        return render_resolved(resolved.scene, gbuffer, **kwargs)
    renderer = Renderer(resolved.scene, **kwargs).with_fallback(*resolved.fallback)
    return renderer.render(gbuffer).image

"""Shading a G-buffer with a scene: the public rendering API.

>>> import clphong
>>> scene = clphong.load_scene("gbuffers/spheres.toml")
>>> gbuf = clphong.read_gbuffer("gbuffers/spheres.exr")
>>> rgb = clphong.render(scene, gbuf)            # (H, W, 3) float32, scene-linear

A :class:`Renderer` compiles its kernel once and then shades many frames; the
CLI and :func:`render` both go through it. :meth:`Renderer.render` returns a
:class:`RenderResult`: the image, the fused display output, the plan that ran,
timings, culling lists, non-finite counts and the number of row bands.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import DeviceError, DeviceWarning, GBufferError, SceneError
from ..core.geometry import split_hi_lo
from ..core.memory import ENV_VAR, F32, format_size, memory_budget
from ..io.nonfinite import apply_nonfinite_policy, apply_range_policy
from ..model.light_tree import SpecularModel, build_light_tree
from ..model.options import (
    check_budget,
    check_float_power,
    check_int_pow,
    check_kernel,
    check_lanes,
    check_nonfinite,
    check_relative,
    check_unroll,
    path_options,
    RendererOptions,
)
from ..model.scene import AOV_NAMES
from .bands import (
    band_align,
    band_of,
    band_rows,
    frame_origin_banded,
    light_bytes,
    map_planes,
    plan_bands,
    render_bytes_per_pixel,
    shaded_lights,
)
from .culling import (
    DirLists,
    RelativeInput,
    TileLists,
    TreeInput,
    build_dir_lists,
    build_tile_lists,
)
from .display import DisplayTransform, apply_display_transform, enqueue_display
from .frame import (
    COVERAGE_PLANE,
    LOCAL_SIZE,
    Frame,
    check_near_field,
    has_far_lights,
    material_uniforms,
    pack_lights,
    prepare_frame,
    shading_records,
)
from .isolate import VariantCrash
from .plan import ShadingPlan, make_plan
from .runtime import float4
from .selection import check_width, get_runtime, next_default, verify


@dataclass(frozen=True)
class RenderStats:
    """Seconds spent on one frame: in the shading kernel (all bands), on buffers and
    copies around it, and in all of :meth:`Renderer.render`."""

    kernel_seconds: float
    upload_seconds: float
    total_seconds: float


@dataclass(frozen=True)
class RenderResult:
    """What shading one frame gave.

    Attributes
    ----------
    image : numpy.ndarray
        (H, W, 3) float32 scene-linear RGB.
    display : numpy.ndarray or None
        (H, W, 3) float32 display output of the ``display`` transform asked for
        (kernels/tonemap_apply.cl on the shaded planes, on the device); None if none.
    plan : ShadingPlan
        The variant that ran (the brute-force fallback of culling, as it actually
        ran). The display output is not part of it: ``display_transform``.
    stats : RenderStats
    cull : TileLists or None
        The culling lists of the (last) launch; None without culling.
    nonfinite : dict
        NaN/Inf counts per buffer, before the non-finite policy.
    bands : int
        Row bands the frame was shaded in (1: one launch).
    layers : dict of str to numpy.ndarray
        (H, W, 3) float32 layers from the same pass, α-premultiplied: one per
        light group (:attr:`~clphong.model.scene.Scene.light_groups`), then
        ``"diffuse"`` and ``"specular"`` where asked for; empty otherwise.
    """

    image: np.ndarray
    display: np.ndarray | None
    plan: ShadingPlan
    stats: RenderStats
    cull: TileLists | None = None
    nonfinite: dict = field(default_factory=dict)
    bands: int = 1
    layers: dict = field(default_factory=dict)
    display_transform: DisplayTransform | None = None
    #: The directional lights' per-tile lists of the (last) launch (DIR_CULLING), or None.
    dir_lists: DirLists | None = None

    def __array__(self, dtype=None, copy=None):
        return self.image if dtype is None else self.image.astype(dtype)


class Renderer:
    """Shades G-buffers with one scene; compiles each kernel variant once.

    Parameters
    ----------
    scene : clphong.model.scene.Scene
    device : str, optional
        OpenCL device (see :mod:`clphong.device.runtime`); PoCL's CPU device by default.
    kernel : {"lanes", "obvious"}
        The fast lane kernel (default) or the one-pixel-per-work-item baseline.
    lanes : int, optional
        Pixels per work-item of the lane kernel (1, 4, 8 or 16); by default
        chosen for the device (:attr:`clphong.device.runtime.Runtime.lanes`).
    compensated : bool, optional
        Force the compensated light sum on or off (default: by light count).
    fp64_directions : bool, optional
        Compute positions, directions, n·l and δ in double (the accurate
        default where the device has fp64) or all in float (for devices
        without fast double; on a CPU with fp64 not faster from 16 lights
        on; larger
        error near grazing light and for large shininess, see
        ``docs/error-model.md``).
    nonfinite : {"background", "error", "pass"}
        What to do with NaN/Inf G-buffer values (:mod:`clphong.io.nonfinite`); the
        counts per buffer of a frame are in its :attr:`RenderResult.nonfinite`.
    max_error : float, optional
        Error budget of tiled light culling (:mod:`clphong.device.culling`), relative to
        ``reference_white``: point lights are dropped per 16×16 tile only while
        their summed upper bounds stay within ``max_error·reference_white`` of
        output radiance, per pixel and channel. 0 drops only lights whose bound
        is exactly 0 (bit-identical to brute force). None (default): no culling.
        A frame's lists are described by its :attr:`RenderResult.cull`.
    reference_white : float
        Output radiance of reference white (default 1.0, scene-linear).
    relative : bool
        With ``max_error``: the budget is a fraction of each pixel's own value, per
        channel (Lightcuts' criterion): each tile drops lights only while their summed
        bounds stay within ``max_error`` times a proven lower bound of every one of its
        pixels' totals (ambient, directional and point lights; kernels/cull.cl
        ``tile_floor``); the tree's clusters within ε/2 of each super-tile's floor.
        With light groups each group's lights are held to its own floor, so every
        group layer keeps the guarantee, and so does the beauty.
    path : {"accurate", "float", "fast"}, optional
        A shading path (:data:`clphong.model.options.PATHS`): shorthand for ``fp64_directions``,
        ``compensated`` and ``int_pow``, which must then be left unset (the
        obvious kernel, float32 with pow(), ignores them). The attribute
        ``path`` names the path the current options make (None for another
        mix, and for the obvious kernel).
    int_pow : bool or "float", optional
        True (default): a whole specular exponent (h, or 4h for Blinn-Phong,
        ≤ 65536, no shininess map) is raised by binary powering in double on
        CPU devices with fp64, on either path (faster, and within the exp/log1p
        form's error bound); False: always exp(k·log1p(−δ)); "float": binary
        powering in float on any device, with float directions (implied; the
        "fast" path, relative error ~2k·u). See :func:`clphong.device.plan.make_plan`.
    light_tree : bool or "always"
        With ``max_error``: cull clusters of the light tree too (True, default) where the
        host's cut can pay (``tree_can_pay``: not on a device that shades the frame brute
        force in under TREE_MIN_SECONDS), or on every device ("always"); False: never.
    light_tile : bool or int, optional
        Stage the light records through local memory, a work-group's worth at a time
        (the plan's LIGHT_TILE): by default where the device is a GPU
        (:attr:`clphong.device.runtime.Runtime.light_tile`); True or False to force it,
        or a number of lights a step (the pixels are bit-identical either way).
    light_unroll : {0, 2, 4, 8}, optional
        Lights an iteration of the light loops a work-item walks itself (the plan's
        LIGHT_UNROLL): by default the device's
        (:attr:`clphong.device.runtime.Runtime.light_unroll`: 4 on Intel's CPU runtime);
        0 for one (the pixels are bit-identical either way).
    dir_lists : bool
        Per-tile lists of the directional lights some normal of a tile faces (the plan's
        DIR_CULLING, where there are many; exact). False: every tile walks them all, where
        a tile's normals face every way and the lists would cost more than they drop
        (the environment conversion's probes: clphong.device.envprobe).
    options : clphong.model.options.RendererOptions, optional
        The renderer options checked where they came in (a command, a Relighter): taken
        as they are, in place of ``fp64_directions``, ``max_error``, ``reference_white``,
        ``nonfinite``, ``path``, ``aovs`` and ``light_tree``.

    The attributes ``max_error`` (the *absolute* budget
    ``max_error·reference_white``, or None), ``fp64_directions`` and
    ``nonfinite`` may still be changed after construction; the next frame
    compiles the variant they select (``fp64_directions = True`` is refused
    at once on a renderer with ``int_pow="float"``, whose power is float).

    Safe to call from several threads: launches are serialised on the queue.
    """

    def __init__(self, scene, *, device: str | None = None, kernel: str = "lanes",
                 lanes: int | None = None, compensated: bool | None = None,
                 fp64_directions: bool | None = None, nonfinite: str = "background",
                 max_error: float | None = None, reference_white: float = 1.0,
                 int_pow: bool | str | None = None, path: str | None = None,
                 aovs: Sequence[str] = (), straight_alpha: bool = False,
                 light_tree: bool = True, light_tile: bool | None = None,
                 light_unroll: int | None = None, relative: bool = False,
                 dir_lists: bool = True, options: RendererOptions | None = None):
        if options is not None:
            given = dict(fp64_directions=fp64_directions, max_error=max_error,
                         reference_white=reference_white, nonfinite=nonfinite, path=path,
                         aovs=tuple(aovs), light_tree=light_tree, relative=relative)
            twice = [k for k, v in given.items() if v != (
                () if k == "aovs" else RendererOptions.__dataclass_fields__[k].default)]
            if twice:
                raise ValueError(f"give the renderer options as options= or as keyword "
                                 f"arguments, not both ({', '.join(twice)} given with options=)")
            # finished where they came in (RendererOptions): taken as they are
            fp64_directions, max_error, path = options.fp64_directions, options.max_error, options.path
            reference_white, nonfinite = options.reference_white, options.nonfinite
            aovs, light_tree, relative = options.aovs, options.light_tree, options.relative
        self._light_unroll = None if light_unroll is None else check_unroll(light_unroll)
        self.scene = scene
        self.dir_lists = bool(dir_lists)
        self.use_tree = bool(light_tree)
        self.always_tree = light_tree == "always"
        self._cull_rest = 0          # frames left that skip culling after it lost (CULL_RETRY)
        self.groups, self.aovs = check_layers(scene, aovs or scene.aovs)
        self.straight_alpha = bool(straight_alpha)
        self._fallback = None         # (renderer view, pixels): with_fallback
        if path is not None:
            if compensated is not None or fp64_directions is not None or int_pow is not None:
                raise ValueError("give either path or fp64_directions/compensated/int_pow")
            opts = options.path_options if options is not None else path_options(path)
            fp64_directions = opts.get("fp64_directions")
            compensated = opts.get("compensated")
            int_pow = opts.get("int_pow")
        int_pow = check_int_pow(True if int_pow is None else int_pow)
        check_float_power(int_pow, fp64_directions)
        if int_pow == "float":
            fp64_directions = False
        self.int_pow = int_pow
        self.kernel_kind = check_kernel(kernel)
        self.runtime = get_runtime(device)
        lanes_given = lanes is not None or kernel != "lanes"
        if kernel != "lanes":
            lanes = 1
        elif lanes is None:
            lanes = self.runtime.lanes
        else:
            check_width(self.runtime, check_lanes(lanes))
        self.lanes = check_lanes(lanes)
        self._light_tile = light_tile
        self.compensated = compensated
        if options is None:
            relative = check_relative(relative, max_error)
            budget = check_budget(max_error, 1.0 if relative else reference_white)
        else:
            budget = options.budget
        if budget is None and scene.max_error is not None:      # the scene's render.max_error
            relative = scene.relative
            budget = scene.max_error * (1.0 if relative else float(reference_white))
        #: ε as a fraction of each pixel's own value (True), or absolute (False)
        self.relative = bool(relative) and budget is not None
        self.max_error = budget                  # absolute, a fraction with relative, or None
        self.reference_white = float(reference_white)
        if fp64_directions is None:
            fp64_directions = self.runtime.has_fp64
        elif fp64_directions and not self.runtime.has_fp64:
            raise DeviceError(f"{self.runtime.name} has no double precision (cl_khr_fp64); "
                              "use the float32 directions path")
        self._fp64_directions = bool(fp64_directions) and kernel == "lanes"
        self.nonfinite = nonfinite if options is not None else check_nonfinite(nonfinite)
        # Launches on one device are serialised: its cached kernel objects hold their
        # arguments between set_args and the enqueue.
        self._lock = self.runtime.lock
        # Compile the variant without maps now, so errors surface at construction; a
        # compiler that dies on it moves to the next narrower width the device passed
        # (unless the caller chose the width), with a warning.
        while True:
            try:
                self.plan_for(())
                break
            except VariantCrash as exc:
                narrower = self._narrower_width(pinned=lanes_given)
                if narrower is not None:
                    warnings.warn(DeviceWarning(f"{str(exc).splitlines()[0]}; using {narrower} "
                                                "lane(s) instead"))
                    self.lanes = narrower
                    continue
                # no narrower width: the next default device, unless the caller chose one
                other = None if lanes_given or device is not None else next_default(self.runtime)
                if other is None:
                    raise
                warnings.warn(DeviceWarning(f"{str(exc).splitlines()[0]}; using {other.name} "
                                            f"at {other.lanes} lane(s) instead"))
                self.runtime, self.lanes, self._lock = other, other.lanes, other.lock
                self._fp64_directions = self._fp64_directions and other.has_fp64

    @property
    def light_unroll(self) -> int:
        """Lights an iteration of the light loops: the one given, else the device's
        (:attr:`clphong.device.runtime.Runtime.light_unroll`)."""
        return self.runtime.light_unroll if self._light_unroll is None else self._light_unroll

    def _narrower_width(self, *, pinned: bool) -> int | None:
        """The next width below :attr:`lanes` that the host rule allows on this device and
        whose self-test passes; None if there is none or the caller chose the width."""
        if pinned:
            return None
        for width in self.runtime.decision.widths:
            if width < self.lanes and verify(self.runtime, width)["ok"]:
                return width
        return None

    @property
    def fp64_directions(self) -> bool:
        """Whether positions, directions, n·l and δ are computed in double."""
        return self._fp64_directions

    @fp64_directions.setter
    def fp64_directions(self, value: bool) -> None:
        if value and self.int_pow == "float":
            raise ValueError("this renderer raises the power in float (int_pow='float', the fast "
                             "path), which takes float directions only; build a Renderer with "
                             "another path instead")
        if value and not self.runtime.has_fp64:
            raise DeviceError(f"{self.runtime.name} has no double precision (cl_khr_fp64)")
        self._fp64_directions = bool(value) and self.kernel_kind == "lanes"

    @property
    def path(self) -> str | None:
        """The shading path (``PATHS``) the current options make, or None for another mix
        (on a device without fp64, "accurate" and "float" are the same variant)."""
        if self.kernel_kind != "lanes":
            return None
        if (self.int_pow, self.compensated, self.fp64_directions) == ("float", False, False):
            return "fast"
        if self.int_pow is True and self.compensated is None:
            if self.fp64_directions == self.runtime.has_fp64:
                return "accurate"
            return "float" if not self.fp64_directions else None
        return None

    @property
    def light_tile(self) -> int:
        """Light records staged through local memory per step (0: none): the work-group
        size where the device stages them (or ``light_tile=True`` asked for it)."""
        staged = self.runtime.light_tile if self._light_tile is None else self._light_tile
        if staged is True or (staged and not isinstance(staged, int)):
            return LOCAL_SIZE
        return int(staged) if staged else 0

    def plan_for(self, map_names, *, culling: bool = True) -> ShadingPlan:
        """The plan for frames with these material maps (its program built and cached);
        ``culling=False``: the same variant without culling (the brute-force fallback)."""
        plan, _ = self._plan_and_program(map_names, culling=culling)
        return plan

    def _plan_and_program(self, map_names, *, culling: bool = True, coverage: bool = False,
                          dir_lists: bool = True, far: bool = False):
        plan = make_plan(self.scene, map_names, kernel=self.kernel_kind, lanes=self.lanes,
                         compensated=self.compensated, fp64_directions=self.fp64_directions,
                         max_error=self.max_error if culling else None,
                         relative=self.relative, has_fp64=self.runtime.fast_fp64, int_pow=self.int_pow,
                         coverage=coverage, groups=self.scene.light_groups, aovs=self.aovs,
                         light_tile=self.light_tile if self.kernel_kind == "lanes" else 0,
                         rsqrt_builtin=self.runtime.rsqrt_builtin(self.lanes),
                         light_unroll=self.light_unroll if self.kernel_kind == "lanes" else 0,
                         rsqrt_native=self.runtime.rsqrt_native(self.lanes),
                         dir_lists=dir_lists and self.dir_lists, far_lights=far)
        return plan, self.runtime.program(plan.entry_file, plan.defines)

    # ------------------------------------------------------------------ a whole frame

    def with_fallback(self, scene, pixels) -> "Renderer":
        """A view of this renderer (a shallow copy: the same programs and launch lock) that
        shades ``pixels`` (flat indices of the frames it renders) with ``scene`` instead, in a
        second launch on those pixels alone (:meth:`render`): an environment's tables for
        the frame, its directional lights where the tables' bound does not hold
        (clphong.io.envmap)."""
        view = copy.copy(self)
        other = copy.copy(self)
        other.scene, other._fallback = scene, None
        view._fallback = (other, np.asarray(pixels, np.intp))
        return view

    def render(self, gbuffer, *, display: DisplayTransform | None = None,
               rows: int | None = None) -> RenderResult:
        """Shade ``gbuffer`` (:meth:`_render`); with a fallback (:meth:`with_fallback`) its
        pixels are shaded again with the fallback's scene and put in place, in every layer,
        before the display transform."""
        fallback = getattr(self, "_fallback", None)
        if fallback is None or not len(fallback[1]):
            return self._render(gbuffer, display=display, rows=rows)
        other, idx = fallback
        t0 = time.perf_counter()
        result = self._render(gbuffer, display=None, rows=rows)
        part = other._render(gbuffer.pixels(idx))
        h, w = gbuffer.shape
        image = np.array(result.image)
        image.reshape(h * w, 3)[idx] = part.image.reshape(-1, 3)
        layers = {}
        for name, layer in result.layers.items():
            layers[name] = np.array(layer)
            if name in part.layers:
                layers[name].reshape(h * w, 3)[idx] = part.layers[name].reshape(-1, 3)
        shown = None if display is None else self._display_of(image, gbuffer, display)
        stats = RenderStats(kernel_seconds=result.stats.kernel_seconds + part.stats.kernel_seconds,
                            upload_seconds=result.stats.upload_seconds + part.stats.upload_seconds,
                            total_seconds=time.perf_counter() - t0)
        return dataclasses.replace(result, image=image, layers=layers, display=shown,
                                   display_transform=display, stats=stats)

    def _display_of(self, image, gbuffer, display: DisplayTransform) -> np.ndarray:
        """The display output of a whole shaded ``image`` (after bands or a fallback's pixels),
        by the same device code the fused launch runs."""
        straight = self.straight_alpha and gbuffer.coverage is not None
        return apply_display_transform(image, display, runtime=self.runtime,
                                       lanes=self.lanes if self.kernel_kind == "lanes" else None,
                                       coverage=gbuffer.coverage if straight else None,
                                       background=self.scene.background)

    def _render(self, gbuffer, *, display: DisplayTransform | None = None,
                rows: int | None = None) -> RenderResult:
        """Shade ``gbuffer``: the non-finite policy, then one launch or row bands.

        Parameters
        ----------
        gbuffer : clphong.io.gbuffer.GBuffer
        display : DisplayTransform, optional
            A display transform whose output :attr:`RenderResult.display` holds:
            fused into the shading kernel's store in one launch, or run on the
            whole frame after the bands (the same device code, the same values).
        rows : int, optional
            Rows per band; by default :func:`~clphong.device.bands.band_rows` of
            the memory budget and the device's limits (the whole frame when it fits).

        Returns
        -------
        RenderResult
            Bit-identical whether shaded in one launch or in bands.

        Raises
        ------
        GBufferError
            When not even one row fits beside the output, with the sizes; or the
            non-finite policy "error" and a NaN/Inf input.
        DeviceError
            When an OpenCL allocation or launch fails anyway.
        """
        t0 = time.perf_counter()
        # NaN/Inf inputs: counted per buffer, then the policy (clphong.io.nonfinite).
        gbuffer, nonfinite = apply_nonfinite_policy(gbuffer, self.nonfinite)
        # negative albedo or maps: refused under "error", else clamped to 0 with a warning
        gbuffer, _ = apply_range_policy(gbuffer, "error" if self.nonfinite == "error" else "clamp")
        h, w = gbuffer.shape
        if rows is None:
            rows = self._band_rows(gbuffer, display is not None)
        if rows >= h:
            one = self._launch(prepare_frame(gbuffer, lanes=self.lanes), display)
            return dataclasses.replace(one, nonfinite=nonfinite, display_transform=display,
                                       stats=dataclasses.replace(
                one.stats, total_seconds=time.perf_counter() - t0))
        # Band edges on the culling super-tile grid keep each tile's light list,
        # and so the result, the same as in one launch (clphong.device.bands).
        align = band_align(self.lanes)
        if rows >= align:
            rows -= rows % align
        bands = plan_bands(h, rows)
        origin = frame_origin_banded(gbuffer, bands)
        try:
            image = np.empty((h, w, 3), np.float32)
        except MemoryError:
            raise GBufferError(f"a {w}x{h} frame: no memory for its "
                               f"{format_size(F32 * 3 * h * w)} output") from None
        kernel_s = upload_s = 0.0
        last = None
        layers = {name: np.empty((h, w, 3), np.float32) for name in (*self.groups, *self.aovs)}
        for y0, y1 in bands:
            frame = prepare_frame(band_of(gbuffer, y0, y1), lanes=self.lanes)
            frame.origin = origin
            last = self._launch(frame, None)
            image[y0:y1] = last.image
            for name, layer in last.layers.items():
                layers[name][y0:y1] = layer
            kernel_s += last.stats.kernel_seconds
            upload_s += last.stats.upload_seconds
            del frame
        shown = None if display is None else self._display_of(image, gbuffer, display)
        stats = RenderStats(kernel_seconds=kernel_s, upload_seconds=upload_s,
                            total_seconds=time.perf_counter() - t0)
        return RenderResult(image=image, display=shown, plan=last.plan, stats=stats, cull=last.cull,
                            nonfinite=nonfinite, bands=len(bands), layers=layers,
                            display_transform=display, dir_lists=last.dir_lists)

    def _band_rows(self, gbuffer, display: bool) -> int:
        """The rows one launch may shade (the memory model and the device's limits)."""
        h, w = gbuffer.shape
        # the coverage plane, and per layer its device and host planes and (H, W, 3) array
        m = map_planes(gbuffer) + 1 + 5 * (len(self.scene.light_groups) + len(self.aovs))
        records = light_bytes(self.scene)
        max_alloc, global_mem = self.runtime.limits()
        if max_alloc is not None and records > max_alloc:
            n = shaded_lights(self.scene)
            raise DeviceError(
                f"{self.scene.source}: {n} point and directional lights need about "
                f"{format_size(records)} of light records, more than the largest buffer "
                f"{self.runtime.name} allows ({format_size(max_alloc)}); use fewer lights")
        budget = memory_budget()
        rows = band_rows((h, w), n_map_planes=m, lanes=self.lanes, light_bytes=records,
                         budget=budget.bytes, max_alloc=max_alloc, global_mem=global_mem,
                         display=display)
        if rows <= 0:
            row_bytes = render_bytes_per_pixel(m, display=display) * w
            one_row = row_bytes + F32 * 3 * h * w + records
            raise GBufferError(
                f"a {w}x{h} frame cannot be shaded here: its output alone needs "
                f"{format_size(F32 * 3 * h * w)} and one row of shading "
                f"{format_size(row_bytes)} more ({format_size(one_row)} in "
                f"all), but only {budget.describe()} is usable; crop the G-buffer or use a "
                "machine with more memory")
        return rows

    def _launch(self, frame: Frame, display: DisplayTransform | None) -> RenderResult:
        """:meth:`shade`, with OpenCL failures as DeviceError."""
        import pyopencl as cl

        try:
            return self.shade(frame, display=display)
        except cl.Error as exc:
            h, w = frame.shape
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise DeviceError(
                f"shading a {w}x{h} band on {self.runtime.name} failed ({first}); lower "
                f"{ENV_VAR} (e.g. {ENV_VAR}=1G) to shade in smaller bands, or choose another "
                "device with --device or PYOPENCL_CTX") from exc

    # ------------------------------------------------------------------ light tree

    def light_tree(self):
        """The scene's light tree (clphong/model/light_tree.py), built once; None
        where too few lights may be clustered."""
        if not hasattr(self, "_light_tree"):
            self._light_tree = build_light_tree(self.scene.light_arrays)
        return self._light_tree

    def _tree_input(self, plan, frame, lights):
        """What culling's light-tree cut needs, or None (no tree)."""
        if not self.use_tree:
            return None
        if not self.always_tree and not tree_can_pay(self.runtime.pair_rate,
                                                     frame.shape[0] * frame.shape[1] * plan.n_point):
            return None
        spec = SpecularModel.of_scene(self.scene, lights.eye,
                                      shininess_map="h" in frame.map_names)
        ends = (np.asarray(self.scene.light_arrays["point_group_end"], np.uint32)
                if self.scene.light_groups else None)
        return TreeInput(tree=self.light_tree, spec=spec, point64=lights.point64, point_end=ends)

    # ------------------------------------------------------------------ one launch

    def _cull_or_brute(self, plan, prog, frame, lights, *, far=False, **buffers):
        """With a culling plan: the frame's tile lists, or brute force where they lose
        (too long, or keeping nearly every light: their cost stays in ``cull.seconds``,
        their kept share in the result) or lost on one of the last CULL_RETRY frames.
        (plan, program, TileLists or None, the kernel's list arguments, the tree's
        (records, records64) or None)."""
        if not plan.defines.get("CULLING"):
            return plan, prog, None, [], None
        cull = None
        if self._cull_rest > 0:
            self._cull_rest -= 1
        else:
            relative = RelativeInput.of(self.scene, lights) if self.relative else None
            cull = build_tile_lists(self.runtime, plan, frame, lights.point, plan.n_point,
                                    budget=self.max_error, relative=relative,
                                    tree=self._tree_input(plan, frame, lights),
                                    **buffers)
            if cull is not None and cull.pays:
                records = None if cull.records is None else (cull.records, cull.records64)
                return plan, prog, cull, cull.kernel_args(), records
            if cull is not None:
                cull = dataclasses.replace(cull, brute=True)
            self._cull_rest = CULL_RETRY
        plan, prog = self._plan_and_program(frame.map_names, culling=False, coverage=frame.coverage,
                                            far=far)
        return plan, prog, cull, [], None

    def shade(self, frame: Frame, *, display: DisplayTransform | None = None) -> RenderResult:
        """One launch of the shading kernel on a prepared :class:`~clphong.device.frame.Frame`
        (no non-finite policy, no memory check: see :meth:`render`)."""
        import pyopencl as cl

        t0 = time.perf_counter()
        lights = pack_lights(self.scene, frame.origin)
        far = has_far_lights(frame, lights)    # POINT_GUARD on the float lanes path
        plan, prog = self._plan_and_program(frame.map_names, coverage=frame.coverage, far=far)
        check_near_field(self.scene, frame, lights, bool(plan.defines.get("DIRECTIONS_FP64")))
        k_d, S, k = material_uniforms(self.scene, frame.map_names)
        ctx, queue = self.runtime.context, self.runtime.queue
        mf = cl.mem_flags
        ro = mf.READ_ONLY | mf.COPY_HOST_PTR
        with self._lock:
            t1 = time.perf_counter()
            # The frame's planes are used in place (USE_HOST_PTR): on a CPU device
            # no copy at all (73 ms -> 4 ms at 1080p); the kernels only read them
            # and `frame` outlives the launch.
            g = cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=frame.gbuf)
            mp = cl.Buffer(ctx, mf.READ_ONLY | mf.USE_HOST_PTR, hostbuf=frame.maps)
            # DIRECTIONS_FP64 does not rebase: P as stored, lights and eye as they are.
            fp64 = bool(plan.defines.get("DIRECTIONS_FP64"))
            origin = np.zeros(3) if fp64 else frame.origin
            eye, eye_lo = lights.kernel_eye(fp64)
            # WEIGHTS_FP64 forms D, S, the ambient term and a non-whole power in double: hi + lo
            _, (kd_lo, *S_lo, k_lo) = split_hi_lo([k_d, *S, k])
            amb_lo = split_hi_lo(lights.ambient)[1]
            spots = plan.n_spot > 0
            quarter = not fp64 and plan.kernel == "lanes"    # the float lanes loop's units
            pl = cl.Buffer(ctx, ro, hostbuf=shading_records(
                lights.point64 if fp64 else lights.point, spots, quarter=quarter))
            dl = cl.Buffer(ctx, ro, hostbuf=lights.directional)
            out = np.empty((3 * (1 + len(plan.layers)), frame.stride), np.float32)
            gt = cl.Buffer(ctx, ro, hostbuf=lights.group_table)
            ga = cl.Buffer(ctx, ro, hostbuf=lights.group_ambient)
            env, env_rotation = env_table_records(self.scene)
            eb = cl.Buffer(ctx, ro, hostbuf=env)
            ob = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
            bg = self.scene.background
            plan, prog, cull, cull_args, records = self._cull_or_brute(
                plan, prog, frame, lights, far=far, k_d=k_d, S=S, gbuf_buffer=g, maps_buffer=mp)
            if records is not None:                  # the lists name the tree's clusters too
                pl = cl.Buffer(ctx, ro, hostbuf=shading_records(records[1] if fp64 else records[0],
                                                                spots, quarter=quarter))
                if cull.point_end is not None:       # each group's representatives follow it
                    table = lights.group_table.copy()
                    table[len(cull.point_end):] = cull.point_end
                    gt = cl.Buffer(ctx, ro, hostbuf=table)
            dirs, dir_args = None, []
            if plan.defines.get("DIR_CULLING"):       # the lights some normal of a tile faces
                dirs = build_dir_lists(self.runtime, plan, frame, lights.directional,
                                       plan.n_directional, k_d=k_d, S=S, gbuf_buffer=g,
                                       maps_buffer=mp)
                if dirs is None:                      # too long: the plain loop this frame
                    plan, prog = self._plan_and_program(
                        frame.map_names, culling=bool(plan.defines.get("CULLING")),
                        coverage=frame.coverage, dir_lists=False, far=far)
                else:
                    dir_args = dirs.kernel_args()
            kern = self.runtime.kernel(prog, "shade")
            kern.set_args(
                g, mp, ob, np.uint32(frame.stride), np.uint32(0),
                pl, np.uint32(plan.n_point), dl, np.uint32(plan.n_directional),
                float4(*origin), float4(*eye), float4(*lights.ambient),
                np.float32(k_d), float4(*S), np.float32(k), float4(*bg),
                float4(*eye_lo), float4(*amb_lo, kd_lo), float4(*S_lo, k_lo), gt, ga,
                eb, np.float32(env_rotation), *cull_args, *dir_args)
            items = frame.stride // self.lanes
            lights_per_item = max(plan.n_point + plan.n_directional, 1) * self.lanes
            events = []
            for start, count in launch_pieces(items, lights_per_item, self.kernel_kind,
                                              rate=self.runtime.pair_rate,
                                              least=self.runtime.fill_groups * LOCAL_SIZE):
                # one piece at a time: a signal (SIGTERM, Ctrl-C) is handled between
                # pieces, at most PIECE_SECONDS late, and nothing is left queued
                kern.set_arg(ITEM0_ARG, np.uint32(start))
                events.append(cl.enqueue_nd_range_kernel(queue, kern, (count,), (LOCAL_SIZE,)))
                events[-1].wait()
            evt = events[-1]
            cl.enqueue_copy(queue, out, ob, wait_for=[evt])
            disp = None
            if display is not None:
                # the display program on the beauty planes, on the device; with straight
                # alpha it reads the coverage plane (gbuf plane COVERAGE_PLANE)
                alpha = None
                if self.straight_alpha and frame.coverage:
                    alpha = g.get_sub_region(COVERAGE_PLANE * frame.stride * 4, frame.stride * 4)
                dbuf, devt = enqueue_display(self.runtime, display, ob, frame.stride, self.lanes,
                                             wait_for=[evt], alpha=alpha, background=bg)
                disp = np.empty((3, frame.stride), np.float32)
                cl.enqueue_copy(queue, disp, dbuf, wait_for=[devt])
            queue.finish()
            t2 = time.perf_counter()
        kernel_s = sum((e.profile.end - e.profile.start) * 1e-9 for e in events)
        h, w = frame.shape
        image = np.ascontiguousarray(out[:3, : h * w].T).reshape(h, w, 3)
        # every group is shaded (the beauty is summed group by group); the chosen are kept
        layers = {name: np.ascontiguousarray(out[3 + 3 * k:6 + 3 * k, : h * w].T).reshape(h, w, 3)
                  for k, name in enumerate(plan.layers) if name in self.groups or name in self.aovs}
        shown = None if disp is None else np.ascontiguousarray(disp[:, : h * w].T).reshape(h, w, 3)
        stats = RenderStats(kernel_seconds=kernel_s, upload_seconds=t2 - t1 - kernel_s,
                            total_seconds=time.perf_counter() - t0)
        return RenderResult(image=image, display=shown, plan=plan, stats=stats, cull=cull,
                            layers=layers, display_transform=display, dir_lists=dirs)


def env_table_records(scene) -> tuple[np.ndarray, float]:
    """The ``env_table`` buffer (float4s: the diffuse table, then the lobe table; one
    zero float4 without tables) and the ``env_rotation`` argument (radians) of shade.cl."""
    if not scene.env_tables:
        return np.zeros((1, 4), np.float32), 0.0
    tables = scene.env_tables[0][0]
    parts = [tables.diffuse.values] + ([tables.specular.values]
                                       if tables.specular is not None else [])
    out = np.zeros((sum(p.shape[0] * p.shape[1] for p in parts), 4), np.float32)
    at = 0
    for p in parts:
        n = p.shape[0] * p.shape[1]
        out[at:at + n, :3] = p.reshape(-1, 3)
        at += n
    return out, math.radians(tables.rotation % 360.0)


#: A launch is split into pieces of about this long (at a pessimistic rate), so
#: that a signal takes effect soon even in a long frame (SIGTERM within 1 s).
PIECE_SECONDS = 0.25
#: Pixel-light pairs a second the pieces are sized for where the device's rate was not
#: measured: below the lane kernel's rate on 2 loaded cores (0.15-0.8 GPLE/s measured),
#: the obvious kernel's own; a 1080p frame at 256 lights is 6 pieces of about 0.1 s
#: (the pieces cost nothing measurable: work-item ids continue through ``item0``, not a
#: global offset, which PoCL 3.0 runs through a slower, unspecialised function).
PIECE_RATE = {"lanes": 2e8, "obvious": 3e6}
#: A measured rate (the calibration frame's, ``Runtime.pair_rate``) is divided by this
#: before sizing the pieces: a scene with spots, maps, groups or layers runs slower than
#: the calibration frame (at most ~2x on the bench's scenes).
RATE_MARGIN = 4.0


#: After a frame whose culling lost (its lists kept more than culling.BRUTE_ABOVE of the
#: lights, or were too long), this many frames of the renderer are shaded brute force
#: without building lists, then culling is tried again: a sequence whose lights reach every
#: pixel pays for the lists once in CULL_RETRY + 1 frames (on an H200 at 65,536 wide lights
#: the lists cost 1.7x the brute-force frame).
CULL_RETRY = 7


#: The light tree's cut runs on the host's cores (clphong/model/light_tree.py): 0.5 s for
#: the wide scene's 1080p frame at 4,096 lights on 16 cores, 12 s for 65,536 clustered
#: lights, measured beside an H200 that shades either frame brute force in 0.05-0.8 s. On a
#: device this much faster than a CPU (measured pixel-light pairs a second) the cut is
#: tried only where brute force would take TREE_MIN_SECONDS or more.
TREE_DEVICE_RATE = 1e10
TREE_MIN_SECONDS = 2.0


def tree_can_pay(rate: float | None, pairs: float) -> bool:
    """Whether the host's light-tree cut may be tried for a frame of ``pairs`` pixel-light
    pairs on a device shading ``rate`` pairs a second (None: not measured, a CPU's rate)."""
    return rate is None or rate < TREE_DEVICE_RATE or pairs / rate >= TREE_MIN_SECONDS


#: Index of shade.cl's ``item0`` argument (include/shade_args.h).
ITEM0_ARG = 4


def launch_pieces(items: int, pairs_per_item: int, kernel: str = "lanes", *,
                  rate: float | None = None, least: int = 0) -> list[tuple[int, int]]:
    """(first work-item, count) of each piece of a launch of ``items`` work-items
    (a multiple of LOCAL_SIZE), each of about PIECE_SECONDS, in whole work-groups; one
    piece when the launch is short.

    ``rate``: the device's measured pairs a second (lane kernel only; divided by
    RATE_MARGIN), else PIECE_RATE's; ``least``: work-items a piece holds at least, enough
    to fill the device (a GPU at 65,536 lights would otherwise get pieces of a few
    work-groups, and run at a few per cent of its speed).
    """
    if rate is not None and rate > 0 and kernel == "lanes":
        per_second = rate / RATE_MARGIN
    else:
        per_second = PIECE_RATE.get(kernel, PIECE_RATE["lanes"])
    per = max(per_second * PIECE_SECONDS / max(pairs_per_item, 1), least)
    size = max(LOCAL_SIZE, int(per) // LOCAL_SIZE * LOCAL_SIZE)
    return [(s, min(size, items - s)) for s in range(0, items, size)]


def check_layers(scene, aovs) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(light-group layers, component layers) for ``aovs``: names from
    :data:`~clphong.model.scene.AOV_NAMES` and the scene's light groups. Every
    group of the scene is a layer unless ``aovs`` names some, then only those are
    returned (all are still shaded: the kernel sums the beauty group by group)."""
    if isinstance(aovs, str):
        aovs = [a.strip() for a in aovs.split(",") if a.strip()]
    valid = (*AOV_NAMES, *scene.light_groups)
    for a in aovs:
        if a not in valid:
            groups = (f"light groups {', '.join(scene.light_groups)}" if scene.light_groups
                      else "no light groups in the scene")
            raise SceneError(f"{scene.source}: --aov {a!r} is neither a component "
                             f"({', '.join(AOV_NAMES)}) nor a light group ({groups})")
    named = tuple(g for g in scene.light_groups if g in aovs)
    return (named or scene.light_groups), tuple(a for a in AOV_NAMES if a in aovs)


def straight_of(image, coverage, background) -> np.ndarray:
    """The straight shade S from the beauty α·S + (1 − α)·background (where α > 0;
    the background elsewhere): the banded path's display input with straight alpha."""
    a = np.asarray(coverage, np.float32)[..., None]
    bg = np.asarray(background, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (image - (1 - a) * bg) / a
    return np.where(a > 0, s, bg).astype(np.float32)


def render(scene, gbuffer, **kwargs) -> np.ndarray:
    """Shade ``gbuffer`` with ``scene`` once: (H, W, 3) float32 scene-linear RGB.

    See :class:`Renderer` for the options; :meth:`Renderer.render` gives the
    whole :class:`RenderResult`."""
    return Renderer(scene, **kwargs).render(gbuffer).image

"""Shading a G-buffer with a scene: the public rendering API.

>>> import clphong
>>> scene = clphong.load_scene("gbuffers/spheres.toml")
>>> gbuf = clphong.read_gbuffer("gbuffers/spheres.exr")
>>> rgb = clphong.render(scene, gbuf)            # (H, W, 3) float32, scene-linear

A :class:`Renderer` compiles its kernel once and then shades many frames; the
CLI and :func:`render` both go through it.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from .plan import ShadingPlan, make_plan
from .runtime import float4, get_runtime

#: Work-items per work-group. PoCL runs anything from 8 to ~1000 equally well
#: and 1 badly (POCL-NOTES "Local size").
LOCAL_SIZE = 64
#: Planes of Frame.gbuf: P xyz, unit N xyz (float), C_d rgb, N's float64 remainder xyz.
GBUF_PLANES = 12


@dataclass
class Frame:
    """A G-buffer laid out for the kernels: float32 planes, padded.

    ``gbuf`` holds the planes Px Py Pz Nx Ny Nz Cr Cg Cb, ``stride`` floats
    each. N is unit (normalised in float64 here) and exactly 0 on background
    pixels; P is as stored. ``origin`` is the float32 point the kernel subtracts
    from P (and the host from every light) so that distances keep their digits.
    """

    gbuf: np.ndarray
    maps: np.ndarray
    map_names: tuple[str, ...]
    shape: tuple[int, int]
    stride: int
    origin: np.ndarray        # (3,) float32
    background: np.ndarray    # (H*W,) bool

    @property
    def pixels(self) -> int:
        return self.shape[0] * self.shape[1]


def unit_normal_planes(normal: np.ndarray) -> list[np.ndarray]:
    """N/|N| in float64, as three (M,) planes x, y, z (|N|² = (x² + y²) + z²).

    The one normalisation of the kernels' host side and of the float64
    reference (:mod:`clphong.reference`), so both see the same unit normals;
    per plane, it runs 1.8× faster than on (M, 3) rows.
    """
    n = normal.reshape(-1, 3)
    c = [n[:, a].astype(np.float64) for a in range(3)]
    length = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
    with np.errstate(invalid="ignore", divide="ignore"):
        for x in c:
            np.divide(x, length, out=x)
    return c


def position_bounds(position: np.ndarray, background: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), float64 per axis, of the finite, shaded positions; ±inf if there are none.

    Masked reductions per axis (no boolean-indexed copy of the frame).
    """
    p = position.reshape(-1, 3)
    axes = [p[:, a] for a in range(3)]
    ok = ~background.reshape(-1)
    for c in axes:
        ok &= np.isfinite(c)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    if ok.any():
        for a, c in enumerate(axes):
            lo[a] = c.min(where=ok, initial=np.inf)
            hi[a] = c.max(where=ok, initial=-np.inf)
    return lo, hi


def origin_of_bounds(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The float32 centre of a bounding box; 0 for an empty one."""
    if not np.all(np.isfinite(lo)):
        return np.zeros(3, np.float32)
    return ((lo + hi) / 2).astype(np.float32)


def frame_origin(position: np.ndarray, background: np.ndarray) -> np.ndarray:
    """A float32 point at the centre of the finite, shaded positions (0 if none).

    The kernel subtracts it from P in float32; for positions within a factor 2 of
    it the difference is exact (Sterbenz), so a scene far from the world origin
    keeps the digits of its distances.
    """
    return origin_of_bounds(*position_bounds(position, background))


def prepare_frame(gbuffer, *, lanes: int = 16) -> Frame:
    """Lay out a :class:`~clphong.gbuffer.GBuffer` as kernel planes."""
    h, w = gbuffer.shape
    n = h * w
    block = lanes * LOCAL_SIZE
    stride = max(block, math.ceil(n / block) * block)
    background = gbuffer.background_mask().reshape(-1)
    gbuf = np.empty((GBUF_PLANES, stride), np.float32)
    gbuf[:, n:] = 0.0                                       # padding: background
    P, C = gbuffer.position.reshape(-1, 3), gbuffer.albedo.reshape(-1, 3)
    for a, n64 in enumerate(unit_normal_planes(gbuffer.normal)):
        n64[background] = 0.0
        gbuf[a, :n] = P[:, a]
        gbuf[6 + a, :n] = C[:, a]
        gbuf[3 + a, :n] = n64
        # The float64 remainder of the unit normal, for DIRECTIONS_FP64 (shade.cl).
        gbuf[9 + a, :n] = n64 - gbuf[3 + a, :n]
    names = []
    planes = []
    for name in ("k_d", "k_s", "h"):
        if name in gbuffer.maps:
            names.append(name)
            planes.append(gbuffer.maps[name].reshape(1, -1))
    if "specular_color" in gbuffer.maps:
        names.append("specular_color")
        planes.append(gbuffer.maps["specular_color"].reshape(-1, 3).T)
    if planes:
        stacked = np.concatenate(planes, axis=0)
        maps = np.zeros((stacked.shape[0], stride), np.float32)
        maps[:, :n] = stacked
    else:
        maps = np.zeros((1, lanes), np.float32)
    return Frame(gbuf=gbuf, maps=maps, map_names=tuple(names), shape=(h, w), stride=stride,
                 origin=frame_origin(gbuffer.position, background), background=background)


@dataclass(frozen=True)
class LightArrays:
    """The scene's lights packed as the kernels read them (see kernels/clphong.h)."""

    point: np.ndarray        # (n_point*3, 4) float32: the float path's (and cull.py's source)
    point64: np.ndarray      # the same records in float64, not rebased, for DIRECTIONS_FP64
    directional: np.ndarray  # (n_dir*6, 4) float32
    ambient: np.ndarray      # (3,) float64: k_a·Σ ambient radiance
    eye: np.ndarray          # (3,) float64: perspective eye − origin, or orthographic unit v
    eye64: np.ndarray        # (3,) float64: perspective eye (not rebased), or unit v

    def kernel_eye(self, fp64: bool) -> tuple[np.ndarray, np.ndarray]:
        """The shading kernel's (eye, eye_lo): with DIRECTIONS_FP64 the eye as it
        is, float32 hi + lo (lo = eye − hi, rounded); else rebased, and lo = 0."""
        return split_hi_lo(self.eye64) if fp64 else (self.eye, np.zeros(3))


def split_hi_lo(x) -> tuple[np.ndarray, np.ndarray]:
    """float64 ``x`` as float32 ``hi`` and ``lo = float32(x − hi)``: hi + lo carries ~48 bits."""
    x = np.asarray(x, np.float64)
    hi = x.astype(np.float32)
    return hi, (x - hi.astype(np.float64)).astype(np.float32)


def view_vector(camera) -> np.ndarray | None:
    """Unit v (towards the viewer) of an orthographic camera, else None."""
    if camera.type != "orthographic":
        return None
    return -np.asarray(camera.direction, np.float64)


def half_vector(l: np.ndarray, v: np.ndarray):
    """Blinn's h = (l + v)/|l + v| in float64, and whether it is undefined (l = −v).

    ``l`` may hold many directions (..., 3); then ``undefined`` is a bool array.
    """
    s = np.asarray(l, np.float64) + np.asarray(v, np.float64)
    norm = np.sqrt(np.einsum("...i,...i->...", s, s))
    undefined = norm == 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(undefined[..., None], 0.0, s / norm[..., None])
    if h.ndim == 1:
        return h, bool(undefined)
    return h, undefined


#: The shading paths a user picks (``--path``, ``Renderer(path=...)``) and the
#: Renderer options each stands for (docs/error-model.md, docs/bench.md):
#: ``accurate`` (default: double directions, weights and sums where the device
#: has fp64), ``float`` (float32 directions), ``fast`` (float32 throughout:
#: directions, the integer power and a naive light sum).
PATHS = {
    "accurate": {},
    "float": {"fp64_directions": False},
    "fast": {"fp64_directions": False, "compensated": False, "int_pow": "float"},
}


def path_options(path: str) -> dict:
    """The Renderer options of a shading path (``PATHS``); a bad name lists the valid ones."""
    if path not in PATHS:
        raise ValueError(f"path must be one of {', '.join(PATHS)}, not {path!r}")
    return dict(PATHS[path])


#: The smallest float64 that rounds to +inf as float32 (FLT_MAX + half an ulp).
F32_ROUNDS_TO_INF = 3.4028235677973366e38


def _check_reach(scene, o: np.ndarray, rebased: np.ndarray) -> None:
    """Refuse a point light (``rebased``: the positions minus the frame origin ``o``)
    or eye that lies beyond float32 from the frame (one end of the range against
    positions at the other): it would round to ±inf, and the pixels to NaN."""
    reach = np.abs(rebased).max(axis=1, initial=0.0)
    far = None
    if reach.size and reach.max() >= F32_ROUNDS_TO_INF:
        points = [i for i, lt in enumerate(scene.lights) if lt.type == "point"]
        far = (f"light[{points[int(np.argmax(reach))]}].position", reach.max())
    elif scene.camera.type == "perspective":
        x = np.abs(np.asarray(scene.camera.position) - o).max()
        if x >= F32_ROUNDS_TO_INF:
            far = ("camera.position", x)
    if far is not None:
        from .errors import SceneError
        centre = ", ".join(f"{c:.3g}" for c in o)
        raise SceneError(f"{scene.source}: {far[0]} lies {float(far[1]):.3g} units along an axis "
                         f"from this frame's positions (centred near ({centre})), beyond the "
                         "float32 range the kernels compute in (3.4e38)")


def pack_lights(scene, origin: np.ndarray) -> LightArrays:
    """Point lights as float64 records as they are (the fp64 path's: it does not
    rebase, L − P in double is correctly rounded from them and the float32 P) and
    as float32 records rebased on ``origin`` in float64 (the float path's, and
    culling's); other lights as float32 records with hi+lo remainders."""
    o = np.asarray(origin, np.float64)
    arrays = scene.light_arrays
    n_pts = len(arrays["point_position"])
    rec = np.zeros((max(n_pts, 1), 3, 4))           # (x, y, z, c0) (r, g, b, c1) (c2, 0, 0, 0)
    rec[:n_pts, 0, :3] = arrays["point_position"]
    if n_pts:
        att = arrays["point_attenuation"]
        rec[:, 0, 3] = att[:, 0]
        rec[:, 1, :3] = arrays["point_radiance"]
        rec[:, 1, 3] = att[:, 1]
        rec[:, 2, 0] = att[:, 2]
    point64 = rec.reshape(-1, 4).copy()
    rec[:n_pts, 0, :3] -= o
    _check_reach(scene, o, rec[:n_pts, 0, :3])
    point = rec.reshape(-1, 4).astype(np.float32)
    n_dirs = len(arrays["directional_direction"])
    directional = np.zeros((max(n_dirs, 1) * 6, 4), np.float32)
    v = view_vector(scene.camera)
    if n_dirs:
        rec = np.zeros((n_dirs, 6, 4))
        l = -arrays["directional_direction"]
        rec[:, 0, :3] = l
        rec[:, 3, :3] = split_hi_lo(l)[1]
        rec[:, 1, :3] = arrays["directional_radiance"]
        rec[:, 5, :3] = split_hi_lo(arrays["directional_radiance"])[1]
        if v is not None:
            hv, undefined = half_vector(l, v)
            rec[:, 2, :3] = hv
            rec[:, 4, :3] = split_hi_lo(hv)[1]
            rec[:, 2, 3] = np.where(undefined, 1.0, 0.0)
        directional = rec.reshape(-1, 4).astype(np.float32)
    amb = arrays["ambient_radiance"] * scene.material.k_a
    eye64 = v if v is not None else np.asarray(scene.camera.position, np.float64)
    eye = eye64 if v is not None else eye64 - o
    return LightArrays(point=point, point64=point64, directional=directional, ambient=amb,
                       eye=eye, eye64=eye64)


def material_uniforms(scene, map_names) -> tuple[float, np.ndarray, float]:
    """(k_d, S_uniform, exponent) kernel arguments; maps replace uniform values."""
    m = scene.material
    cs = np.asarray(m.specular_color, np.float64)
    ks = 1.0 if "k_s" in map_names else m.k_s
    S = (np.ones(3) if "specular_color" in map_names else cs) * ks
    return m.k_d, S, m.exponent


@dataclass
class RenderStats:
    kernel_seconds: float
    upload_seconds: float
    total_seconds: float


class Renderer:
    """Shades G-buffers with one scene; compiles each kernel variant once.

    Parameters
    ----------
    scene : clphong.scene.Scene
    device : str, optional
        OpenCL device (see :mod:`clphong.runtime`); PoCL's CPU device by default.
    kernel : {"lanes", "obvious"}
        The fast lane kernel (default) or the one-pixel-per-work-item baseline.
    lanes : int, optional
        Pixels per work-item of the lane kernel (1, 4, 8 or 16); by default
        chosen for the device (:attr:`clphong.runtime.Runtime.lanes`).
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
        What to do with NaN/Inf G-buffer values (:mod:`clphong.inputs`); the
        counts per buffer of the last frame are in ``last_nonfinite``.
    max_error : float, optional
        Error budget of tiled light culling (:mod:`clphong.cull`), relative to
        ``reference_white``: point lights are dropped per 16×16 tile only while
        their summed upper bounds stay within ``max_error·reference_white`` of
        output radiance, per pixel and channel. 0 drops only lights whose bound
        is exactly 0 (bit-identical to brute force). None (default): no culling.
        The last frame's lists are described by ``last_cull``.
    reference_white : float
        Output radiance of reference white (default 1.0, scene-linear).
    path : {"accurate", "float", "fast"}, optional
        A shading path (``PATHS``): shorthand for ``fp64_directions``,
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
        "fast" path, relative error ~2k·u). See :func:`clphong.plan.make_plan`.

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
                 int_pow: bool | str | None = None, path: str | None = None):
        self.scene = scene
        if path is not None:
            if compensated is not None or fp64_directions is not None or int_pow is not None:
                raise ValueError("give either path or fp64_directions/compensated/int_pow")
            opts = path_options(path)
            fp64_directions = opts.get("fp64_directions")
            compensated = opts.get("compensated")
            int_pow = opts.get("int_pow")
        if int_pow is None:
            int_pow = True
        if not (isinstance(int_pow, bool) or int_pow == "float"):
            raise ValueError(f"int_pow must be True, False or 'float', not {int_pow!r}")
        if int_pow == "float":
            if fp64_directions:
                raise ValueError("int_pow='float' is for float directions (fp64_directions=False)")
            fp64_directions = False
        self.int_pow = int_pow
        self.kernel_kind = kernel
        self.runtime = get_runtime(device)
        if kernel != "lanes":
            lanes = 1
        elif lanes is None:
            lanes = self.runtime.lanes
        self.lanes = lanes
        self.compensated = compensated
        from .cull import check_budget
        self.max_error = check_budget(max_error, reference_white)   # absolute, or None
        self.reference_white = float(reference_white)
        self.last_cull = None
        if fp64_directions is None:
            fp64_directions = self.runtime.has_fp64
        elif fp64_directions and not self.runtime.has_fp64:
            from .errors import DeviceError
            raise DeviceError(f"{self.runtime.name} has no double precision (cl_khr_fp64); "
                              "use the float32 directions path")
        self._fp64_directions = bool(fp64_directions) and kernel == "lanes"
        from .inputs import POLICIES
        if nonfinite not in POLICIES:
            raise ValueError(f"nonfinite must be one of {', '.join(POLICIES)}, not {nonfinite!r}")
        self.nonfinite = nonfinite
        self.last_nonfinite: dict[str, int] = {}
        self._lock = threading.Lock()
        self.last_stats: RenderStats | None = None
        # Compile the variant without maps now, so errors surface at construction.
        self.plan_for(())

    #: A clphong.display.DisplayTransform to fuse into the kernel's store (None:
    #: scene-linear only); its (H, W, 3) result lands in ``last_display``
    #: (see clphong.display.render_display).
    display = None
    last_display = None
    #: The ShadingPlan of the last launch (with the fused display output, or the
    #: brute-force fallback of culling, as it actually ran); None before any.
    last_plan = None

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
            from .errors import DeviceError
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

    def plan_for(self, map_names, *, culling: bool = True) -> ShadingPlan:
        """The plan for frames with these material maps (its program built and cached);
        ``culling=False``: the same variant without culling (the brute-force fallback)."""
        plan, _ = self._plan_and_program(map_names, culling=culling)
        return plan

    def _plan_and_program(self, map_names, *, culling: bool = True):
        plan = make_plan(self.scene, map_names, kernel=self.kernel_kind, lanes=self.lanes,
                         compensated=self.compensated, fp64_directions=self.fp64_directions,
                         display=self.display, max_error=self.max_error if culling else None,
                         has_fp64=self.runtime.fast_fp64, int_pow=self.int_pow)
        return plan, self.runtime.program(plan.entry_file, plan.defines)

    def render(self, gbuffer, *, frame: Frame | None = None) -> np.ndarray:
        """Shade ``gbuffer``; return (H, W, 3) float32 scene-linear RGB.

        Without ``frame``, :func:`clphong.tiling.render_frame` checks the memory
        and the device's limits and shades in row bands when the frame is too
        big for one launch (bit-identical), or refuses with a clear error.
        """
        import pyopencl as cl

        if frame is None:
            from .inputs import apply_nonfinite_policy
            from .tiling import render_frame

            # NaN/Inf inputs: counted per buffer, then the policy (clphong.inputs).
            gbuffer, self.last_nonfinite = apply_nonfinite_policy(gbuffer, self.nonfinite)
            return render_frame(self, gbuffer)
        t0 = time.perf_counter()
        plan, prog = self._plan_and_program(frame.map_names)
        lights = pack_lights(self.scene, frame.origin)
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
            pl = cl.Buffer(ctx, ro, hostbuf=lights.point64 if fp64 else lights.point)
            dl = cl.Buffer(ctx, ro, hostbuf=lights.directional)
            out = np.empty((3, frame.stride), np.float32)
            ob = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
            bg = self.scene.background
            cull_args, self.last_cull = [], None
            if plan.defines.get("CULLING"):
                from .cull import build_tile_lists
                self.last_cull = build_tile_lists(self.runtime, plan, frame, lights.point,
                                                  plan.n_point, budget=self.max_error, k_d=k_d, S=S,
                                                  gbuf_buffer=g, maps_buffer=mp)
                if self.last_cull is None:   # lists too long to pay off: brute force
                    plan, prog = self._plan_and_program(frame.map_names, culling=False)
                else:
                    cull_args = self.last_cull.kernel_args()
            self.last_plan = plan           # the variant that actually runs (--stats)
            kern = cl.Kernel(prog, "shade")
            from .display import display_kernel_args
            disp, display_args = display_kernel_args(self.display, ctx, frame.stride)
            kern.set_args(
                g, mp, ob, np.uint32(frame.stride),
                pl, np.uint32(plan.n_point), dl, np.uint32(plan.n_directional),
                float4(*origin), float4(*eye), float4(*lights.ambient),
                np.float32(k_d), float4(*S), np.float32(k), float4(*bg),
                float4(*eye_lo), float4(*amb_lo, kd_lo), float4(*S_lo, k_lo),
                *display_args, *cull_args)
            items = frame.stride // self.lanes
            evt = cl.enqueue_nd_range_kernel(queue, kern, (items,), (LOCAL_SIZE,))
            cl.enqueue_copy(queue, out, ob, wait_for=[evt])
            if disp is not None:
                cl.enqueue_copy(queue, disp, display_args[0], wait_for=[evt])
            queue.finish()
            t2 = time.perf_counter()
        kernel_s = (evt.profile.end - evt.profile.start) * 1e-9
        h, w = frame.shape
        rgb = np.ascontiguousarray(out[:, : h * w].T).reshape(h, w, 3)
        self.last_display = (None if disp is None
                             else np.ascontiguousarray(disp[:, : h * w].T).reshape(h, w, 3))
        self.last_stats = RenderStats(kernel_seconds=kernel_s, upload_seconds=t2 - t1 - kernel_s,
                                      total_seconds=time.perf_counter() - t0)
        return rgb


def render(scene, gbuffer, **kwargs) -> np.ndarray:
    """Shade ``gbuffer`` with ``scene`` once; see :class:`Renderer` for options."""
    return Renderer(scene, **kwargs).render(gbuffer)

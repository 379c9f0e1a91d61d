"""The display transform on the device: exposure, tone mapping, sRGB encoding.

:class:`DisplayTransform` describes what ``kernels/tonemap.cl`` does to a
scene-linear pixel: multiply by 2^EV, convert the working space to Rec.709,
apply a tone-mapping operator (:mod:`clphong.tonemap`), and encode for an sRGB
display (or leave display-linear). The shading kernel fuses it into its final
store when a :class:`~clphong.render.Renderer` is given one (no round trip
through the host); :func:`apply_display_transform` runs the same code on
planes already shaded (the contact sheet, the operator tests).

>>> dt = DisplayTransform("agx", exposure=1.0)          # doctest: +SKIP
>>> srgb = apply_display_transform(rgb, dt)              # (H, W, 3) float32 in [0, 1]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import tonemap

__all__ = ["DisplayTransform", "apply_display_transform", "render_display",
           "display_kernel_args", "check_exposure", "ENCODINGS", "MAX_EXPOSURE"]

#: DISPLAY_ENCODING values: display-linear Rec.709, or sRGB (IEC 61966-2-1) encoded.
ENCODINGS = {"linear": 0, "srgb": 1}

#: Largest |exposure| in stops, for every display output and the scene key
#: ``render.exposure`` alike: 2^±100 (1.3e30, 7.9e-31) and a pixel times it stay
#: normal float32 numbers.
MAX_EXPOSURE = 100.0


def check_exposure(ev, what: str = "exposure") -> float:
    """``ev`` as a float if it is a finite number of stops within ±:data:`MAX_EXPOSURE`.

    Raises
    ------
    ToneMapError
        One line naming ``what`` (e.g. ``--exposure``).
    """
    ev = float(ev)
    if not math.isfinite(ev):
        raise tonemap.ToneMapError(f"{what} must be a finite number of stops, got {ev!r}")
    if abs(ev) > MAX_EXPOSURE:
        raise tonemap.ToneMapError(f"{what} {ev:g} stops is out of range (2^EV must stay a "
                                   f"float32); use -{MAX_EXPOSURE:g}..{MAX_EXPOSURE:g}")
    return ev


@dataclass(frozen=True)
class DisplayTransform:
    """Exposure, operator and encoding of the fused display output.

    Parameters
    ----------
    operator : str
        Tone-mapping operator name (:data:`clphong.tonemap.OPERATORS`).
    exposure : float
        Stops; the scene-linear value is multiplied by 2^exposure first.
    white : float, optional
        White point of ``reinhard-extended`` / ``hable`` (operator default if None).
    matrix : (3, 3) array_like, optional
        Working space → Rec.709 primaries (None: the working space is Rec.709).
    encoding : {"srgb", "linear"}
    """

    operator: str = "none"
    exposure: float = 0.0
    white: float | None = None
    matrix: tuple | None = field(default=None)
    encoding: str = "srgb"

    def __post_init__(self):
        op = tonemap.operator(self.operator)          # raises on a bad name
        object.__setattr__(self, "operator", op.name)
        check_exposure(self.exposure)
        tonemap.operator_params(op.name, self.white)  # validates the white point
        if self.encoding not in ENCODINGS:
            raise tonemap.ToneMapError(f"display encoding must be one of {', '.join(ENCODINGS)}, "
                                       f"not {self.encoding!r}")
        if self.matrix is not None:
            m = np.asarray(self.matrix, np.float64)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise tonemap.ToneMapError("display matrix must be a finite 3x3 matrix")
            object.__setattr__(self, "matrix", tuple(map(tuple, m)))

    @property
    def id(self) -> int:
        return tonemap.operator(self.operator).id

    def defines(self) -> dict[str, int]:
        """The ``-D`` defines of kernels/tonemap.cl for this transform."""
        return {"DISPLAY_OUT": 1, "TONEMAP": self.id,
                "DISPLAY_MATRIX": int(self.matrix is not None),
                "DISPLAY_ENCODING": ENCODINGS[self.encoding]}

    def reasons(self) -> dict[str, str]:
        op = tonemap.operator(self.operator)
        return {
            "DISPLAY_OUT": "a display output is written without an OCIO view: tone mapping is "
                           "fused into the shading kernel's store",
            "TONEMAP": f"operator {op.name!r} ({op.source}), exposure {self.exposure:+g} EV",
            "DISPLAY_MATRIX": ("working space -> Rec.709 matrix before the operator"
                               if self.matrix is not None else "working space is Rec.709"),
            "DISPLAY_ENCODING": {"srgb": "sRGB (IEC 61966-2-1) encoded",
                                 "linear": "display-linear Rec.709"}[self.encoding],
        }

    def kernel_args(self) -> list:
        """exposure, tonemap_params, m0, m1, m2: the arguments appended to the kernels."""
        from .runtime import float4

        p = tonemap.operator_params(self.operator, self.white)
        m = np.eye(3) if self.matrix is None else np.asarray(self.matrix, np.float64)
        return [np.float32(2.0 ** self.exposure), float4(*p),
                float4(*m[0]), float4(*m[1]), float4(*m[2])]

    def reference(self, rgb) -> np.ndarray:
        """float64 twin (:func:`clphong.tonemap.reference`)."""
        return tonemap.reference(rgb, self.operator, exposure=self.exposure, white=self.white,
                                 matrix=self.matrix, encoding=ENCODINGS[self.encoding])

    def error_bound(self, rgb) -> np.ndarray:
        """The kernel's error bound (:func:`clphong.tonemap.error_bound`)."""
        return tonemap.error_bound(rgb, self.operator, exposure=self.exposure, white=self.white,
                                   matrix=self.matrix, encoding=ENCODINGS[self.encoding])


def display_kernel_args(transform: DisplayTransform | None, context, stride: int):
    """The arguments shade.cl and shade_obvious.cl take after ``eye_lo``.

    Returns
    -------
    (numpy.ndarray or None, list)
        The host array the display planes are copied into (None without a
        transform), and [display buffer, exposure, tonemap_params, m0, m1, m2].
        Without a transform the kernel never touches the display buffer
        (DISPLAY_OUT=0), so a 4-byte one stands in.
    """
    import pyopencl as cl

    from .runtime import float4

    if transform is None:
        buf = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, 4)
        z = float4()
        return None, [buf, np.float32(1.0), z, z, z, z]
    host = np.empty((3, stride), np.float32)
    buf = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, host.nbytes)
    return host, [buf, *transform.kernel_args()]


def render_display(renderer, gbuffer, transform: DisplayTransform) -> tuple[np.ndarray, np.ndarray]:
    """Shade ``gbuffer`` and tone-map it in the same kernel launch.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        Scene-linear (H, W, 3) float32 and display (H, W, 3) float32.

    Notes
    -----
    When the frame is too large for one launch and is shaded in row bands
    (:mod:`clphong.tiling`), the display transform runs afterwards on the whole
    scene-linear frame with :func:`apply_display_transform` (the same device
    code, so the same values).
    """
    import copy

    # A shallow copy carries the transform: it shares the compiled programs and
    # the launch lock, and the settings of ``renderer`` are not modified, so
    # several threads may call this with one renderer.
    view = copy.copy(renderer)
    view.display = transform
    view.last_display = None
    rgb = view.render(gbuffer)
    shown = view.last_display
    if getattr(view, "last_bands", 1) != 1 or shown is None or shown.shape != rgb.shape:
        shown = apply_display_transform(rgb, transform, runtime=renderer.runtime,
                                        lanes=renderer.lanes if renderer.kernel_kind == "lanes" else None)
    # The last frame's records, as a plain render leaves them (--stats, tests).
    for name in ("last_stats", "last_cull", "last_nonfinite", "last_bands", "last_display",
                 "last_plan"):
        if name in vars(view):
            setattr(renderer, name, getattr(view, name))
    return rgb, shown


def apply_display_transform(rgb, transform: DisplayTransform, *, device: str | None = None,
                            lanes: int | None = None, runtime=None) -> np.ndarray:
    """Run ``kernels/tonemap_apply.cl`` on an (H, W, 3) scene-linear image.

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float32 display RGB.
    """
    import pyopencl as cl

    from .render import LOCAL_SIZE
    from .runtime import get_runtime

    rt = runtime if runtime is not None else get_runtime(device)   # a renderer's own device
    lanes = lanes or rt.lanes
    rgb = np.asarray(rgb, np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise tonemap.ToneMapError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    h, w, _ = rgb.shape
    n = h * w
    block = lanes * LOCAL_SIZE
    stride = max(block, math.ceil(n / block) * block)
    planes = np.zeros((3, stride), np.float32)
    planes[:, :n] = rgb.reshape(-1, 3).T
    defines = dict(transform.defines())
    defines["LANES"] = lanes
    prog = rt.program("tonemap_apply.cl", defines)
    mf = cl.mem_flags
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=planes)
    out = np.empty_like(planes)
    dst = cl.Buffer(rt.context, mf.WRITE_ONLY, out.nbytes)
    kern = cl.Kernel(prog, "tonemap_planes")
    kern.set_args(src, dst, np.uint32(stride), *transform.kernel_args())
    evt = cl.enqueue_nd_range_kernel(rt.queue, kern, (stride // lanes,), (LOCAL_SIZE,))
    cl.enqueue_copy(rt.queue, out, dst, wait_for=[evt])
    rt.queue.finish()
    return np.ascontiguousarray(out[:, :n].T).reshape(h, w, 3)

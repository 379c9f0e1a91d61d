"""The display transform on the device: exposure, tone mapping, sRGB encoding.

:class:`DisplayTransform` describes what ``kernels/tonemap.cl`` does to a
scene-linear pixel: multiply by 2^EV, convert the working space to Rec.709,
apply a tone-mapping operator (:mod:`clphong.reference.tonemap`), and encode for an sRGB
display (or leave display-linear). The shading kernel fuses it into its final
store when a :class:`~clphong.device.renderer.Renderer` is given one (no round trip
through the host); :func:`apply_display_transform` runs the same code on
planes already shaded (the contact sheet, the operator tests).

>>> dt = DisplayTransform("agx", exposure=1.0)          # doctest: +SKIP
>>> srgb = apply_display_transform(rgb, dt)              # (H, W, 3) float32 in [0, 1]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..core.errors import ToneMapError
from ..model import tonemap
from ..model.options import ENCODINGS, check_exposure
from ..reference import tonemap as tonemap_reference
from .frame import LOCAL_SIZE
from .runtime import float4, get_runtime

__all__ = ["DisplayTransform", "apply_display_transform", "display_kernel_args"]


@dataclass(frozen=True)
class DisplayTransform:
    """Exposure, operator and encoding of the fused display output.

    Parameters
    ----------
    operator : str
        Tone-mapping operator name (:data:`clphong.model.tonemap.OPERATORS`).
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
            raise ToneMapError(f"display encoding must be one of {', '.join(ENCODINGS)}, "
                                       f"not {self.encoding!r}")
        if self.matrix is not None:
            m = np.asarray(self.matrix, np.float64)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise ToneMapError("display matrix must be a finite 3x3 matrix")
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

        p = tonemap.operator_params(self.operator, self.white)
        m = np.eye(3) if self.matrix is None else np.asarray(self.matrix, np.float64)
        return [np.float32(2.0 ** self.exposure), float4(*p),
                float4(*m[0]), float4(*m[1]), float4(*m[2])]

    def reference(self, rgb) -> np.ndarray:
        """float64 twin (:func:`clphong.reference.tonemap.reference`)."""
        return tonemap_reference.reference(rgb, self.operator, exposure=self.exposure, white=self.white,
                                 matrix=self.matrix, encoding=ENCODINGS[self.encoding])

    def error_bound(self, rgb) -> np.ndarray:
        """The kernel's error bound (:func:`clphong.reference.tonemap.error_bound`)."""
        return tonemap_reference.error_bound(rgb, self.operator, exposure=self.exposure, white=self.white,
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

    if transform is None:
        buf = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, 4)
        z = float4()
        return None, [buf, np.float32(1.0), z, z, z, z]
    host = np.empty((3, stride), np.float32)
    buf = cl.Buffer(context, cl.mem_flags.WRITE_ONLY, host.nbytes)
    return host, [buf, *transform.kernel_args()]


def apply_display_transform(rgb, transform: DisplayTransform, *, device: str | None = None,
                            lanes: int | None = None, runtime=None) -> np.ndarray:
    """Run ``kernels/tonemap_apply.cl`` on an (H, W, 3) scene-linear image.

    Returns
    -------
    numpy.ndarray
        (H, W, 3) float32 display RGB.
    """
    import pyopencl as cl

    rt = runtime if runtime is not None else get_runtime(device)   # a renderer's own device
    lanes = lanes or rt.lanes
    rgb = np.asarray(rgb, np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ToneMapError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
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
    with rt.lock:
        kern = rt.kernel(prog, "tonemap_planes")
        kern.set_args(src, dst, np.uint32(stride), *transform.kernel_args())
        evt = cl.enqueue_nd_range_kernel(rt.queue, kern, (stride // lanes,), (LOCAL_SIZE,))
    cl.enqueue_copy(rt.queue, out, dst, wait_for=[evt])
    rt.queue.finish()
    return np.ascontiguousarray(out[:, :n].T).reshape(h, w, 3)

"""The display transform on the device: exposure, tone mapping, sRGB encoding.

:class:`DisplayTransform` describes what ``kernels/tonemap.cl`` does to a
scene-linear pixel: multiply by 2^EV, convert the working space to Rec.709,
apply a tone-mapping operator (:mod:`clphong.reference.tonemap`), and encode for an sRGB
display (or leave display-linear). A :class:`~clphong.device.renderer.Renderer`
given one runs it on the shading kernel's output buffer, on the device, right
after the shading (:func:`enqueue_display`: no round trip through the host); it
is a program of its own, so a change of operator, exposure or output never
rebuilds the shading kernel. :func:`apply_display_transform` runs the same code
on planes already shaded (the banded path, the contact sheet, the operator
tests).

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
from .runtime import float4
from .selection import get_runtime

__all__ = ["DisplayTransform", "apply_display_transform", "display_program", "enqueue_display",
           "display_matrix"]


def display_matrix(matrix) -> tuple | None:
    """A working space → Rec.709 matrix as the display transform holds it (a 3x3 tuple of
    floats), or None for None; a ToneMapError unless it is a finite 3x3 matrix."""
    if matrix is None:
        return None
    m = np.asarray(matrix, np.float64)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ToneMapError("display matrix must be a finite 3x3 matrix")
    return tuple(map(tuple, m))


@dataclass(frozen=True)
class DisplayTransform:
    """Exposure, operator and encoding of the display output (kernels/tonemap_apply.cl).

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
        object.__setattr__(self, "matrix", display_matrix(self.matrix))

    @property
    def id(self) -> int:
        return tonemap.operator(self.operator).id

    def defines(self) -> dict[str, int]:
        """The ``-D`` defines of kernels/tonemap_apply.cl (include/tonemap.h) for this transform."""
        return {"DISPLAY_OUT": 1, "TONEMAP": self.id,
                "DISPLAY_MATRIX": int(self.matrix is not None),
                "DISPLAY_ENCODING": ENCODINGS[self.encoding]}

    def reasons(self) -> dict[str, str]:
        op = tonemap.operator(self.operator)
        return {
            "DISPLAY_OUT": "a display output is written without an OCIO view: tone mapping by "
                           "kernels/tonemap_apply.cl on the shaded planes",
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


def display_program(runtime, transform: DisplayTransform, lanes: int, straight: bool = False):
    """kernels/tonemap_apply.cl built for ``transform`` (small: a change of operator,
    exposure or encoding rebuilds only this, never a shading kernel)."""
    defines = dict(transform.defines())
    defines["LANES"] = lanes
    defines["DISPLAY_STRAIGHT"] = int(straight)
    return runtime.program("tonemap_apply.cl", defines)


def enqueue_display(runtime, transform: DisplayTransform, src, stride: int, lanes: int, *,
                    wait_for=None, alpha=None, background=(0.0, 0.0, 0.0)):
    """Enqueue kernels/tonemap_apply.cl on the device planes ``src`` (R G B,
    ``stride`` floats a plane, a multiple of ``lanes`` × LOCAL_SIZE).

    ``alpha``: a buffer whose first ``stride`` floats are the coverage, for an
    output with straight alpha (DISPLAY_STRAIGHT): the display then takes the
    un-premultiplied shade. Returns (the display buffer, the event). Call with
    ``runtime.lock`` held.
    """
    import pyopencl as cl

    prog = display_program(runtime, transform, lanes, straight=alpha is not None)
    dst = cl.Buffer(runtime.context, cl.mem_flags.WRITE_ONLY, 3 * stride * 4)
    if alpha is None:
        alpha = cl.Buffer(runtime.context, cl.mem_flags.READ_ONLY, 4)   # unused stand-in
    kern = runtime.kernel(prog, "tonemap_planes")
    kern.set_args(src, dst, np.uint32(stride), *transform.kernel_args(), alpha,
                  float4(*background))
    evt = cl.enqueue_nd_range_kernel(runtime.queue, kern, (stride // lanes,), (LOCAL_SIZE,),
                                     wait_for=wait_for)
    return dst, evt


def apply_display_transform(rgb, transform: DisplayTransform, *, device: str | None = None,
                            lanes: int | None = None, runtime=None, coverage=None,
                            background=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Run ``kernels/tonemap_apply.cl`` on an (H, W, 3) scene-linear image.

    ``coverage`` (H, W): the image is the beauty α·S + (1 − α)·``background``
    and the display takes the straight shade S (an output with straight alpha).

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
    mf = cl.mem_flags
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=planes)
    alpha = None
    if coverage is not None:
        a = np.ones(stride, np.float32)
        a[:n] = np.asarray(coverage, np.float32).reshape(-1)
        alpha = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=a)
    out = np.empty_like(planes)
    with rt.lock:
        dst, evt = enqueue_display(rt, transform, src, stride, lanes, alpha=alpha,
                                   background=background)
        cl.enqueue_copy(rt.queue, out, dst, wait_for=[evt])
        rt.queue.finish()
    return np.ascontiguousarray(out[:, :n].T).reshape(h, w, 3)

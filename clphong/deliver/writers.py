"""Writing each kind of output: scene-linear EXR, SDR PNG/TIFF, HDR PQ PNG/JPEG XL.

Every writer goes through :func:`clphong.io.atomic.atomic_path` (no partial file on
failure) and tags the file with what its pixels are:

* **scene-linear EXR** (:func:`write_scene_linear`): half or float, zip or piz,
  ``chromaticities`` of the working space and ``oiio:ColorSpace`` set to its
  interop ID (``lin_rec709_scene`` or ``lin_ap1_scene``); no stale
  ``colorInteropID``.
* **SDR** (:func:`write_sdr`): display-encoded values in [0, 1] as 8- or 16-bit
  PNG or TIFF, dithered before 8-bit quantisation (OpenImageIO's
  ``oiio:dither``: ±½ LSB of noise, so smooth gradients do not band), tagged
  with the display colour space and, where it has one, its cICP.
* **HDR** (:func:`write_hdr`): Rec.2100 PQ code values as a 16-bit PNG with the
  cICP chunk (9, 16, 0, 1), or JPEG XL where OpenImageIO has the plugin.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from ..color.ocio import PQ_CICP, SRGB_DISPLAY_INTEROP, WorkingSpace
from ..core.errors import OutputError
from ..io.atomic import write_exr, write_image_atomically

__all__ = ["write_scene_linear", "write_sdr", "write_hdr", "SDR_EXTENSIONS", "HDR_EXTENSIONS",
           "EXR_COMPRESSIONS", "check_compression", "SDR_BITS", "check_bits", "jpegxl_available"]

SDR_EXTENSIONS = (".png", ".tif", ".tiff")
HDR_EXTENSIONS = (".png", ".jxl")
EXR_COMPRESSIONS = ("zip", "piz")
#: Bit depths of the SDR outputs (``--bits``).
SDR_BITS = (8, 16)
#: Seed of the 8-bit dither (fixed: the same frame gives the same file).
DITHER_SEED = 1


def check_compression(compression, where: str | None = None) -> str:
    """``compression`` if it is one of :data:`EXR_COMPRESSIONS`; else an OutputError naming ``where``."""
    if compression in EXR_COMPRESSIONS:
        return compression
    subject = f"{where}: EXR compression" if where else "EXR compression"
    raise OutputError(f"{subject} must be one of {', '.join(EXR_COMPRESSIONS)}, not {compression!r}")


def check_bits(bits, where: str | None = None) -> int:
    """``bits`` if it is one of :data:`SDR_BITS`; else an OutputError naming ``where``."""
    if bits in SDR_BITS and not isinstance(bits, bool):
        return bits
    subject = f"{where}: SDR bit depth" if where else "SDR bit depth"
    raise OutputError(f"{subject} must be {' or '.join(map(str, SDR_BITS))}, not {bits!r}")



def _oiio():
    import OpenImageIO as oiio

    return oiio


def jpegxl_available() -> bool:
    """Whether this OpenImageIO can write JPEG XL."""
    fmts = _oiio().get_string_attribute("format_list").split(",")
    return "jpegxl" in fmts


def _ext(path: str, allowed: Sequence[str], kind: str) -> str:
    ext = os.path.splitext(path)[1].lower()
    if ext not in allowed:
        raise OutputError(f"{path}: a {kind} output must end in {' or '.join(allowed)}")
    return ext


def write_scene_linear(path, rgb, ws: WorkingSpace, *, pixel_type: str = "float",
                       compression: str = "zip", software: str = "clphong",
                       attributes: dict | None = None) -> None:
    """Write scene-linear ``rgb`` (working space ``ws``) as an OpenEXR file.

    ``attributes`` are extra header attributes, set after the colour-space tags.

    Raises
    ------
    OutputError
        A bad extension, pixel type or compression, or any write failure.
    """
    path = os.fspath(path)
    _ext(path, (".exr",), "scene-linear")
    check_compression(compression, path)
    tags = {"chromaticities": ws.chromaticities, "oiio:ColorSpace": ws.interop_id,
            "Software": software}
    tags.update(attributes or {})
    write_exr(path, rgb, pixel_type=pixel_type, compression=compression, attributes=tags)


def _write_display(path: str, data: np.ndarray, fmt, attributes: dict, dither: bool) -> None:
    oiio = _oiio()
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for k, v in attributes.items():
        if isinstance(v, tuple):
            spec.attribute(k, oiio.TypeDesc(f"int[{len(v)}]"), v)
        else:
            spec.attribute(k, v)
    if dither:
        spec.attribute("oiio:dither", DITHER_SEED)
    write_image_atomically(path, spec, np.ascontiguousarray(data, np.float32),
                           what="a writer for this format")


def _check(path: str, rgb) -> np.ndarray:
    a = np.asarray(rgb, np.float32)
    if a.ndim != 3 or a.shape[2] != 3 or 0 in a.shape:
        raise OutputError(f"{path}: expected a non-empty (H, W, 3) image, got shape {a.shape}")
    # Display code values: clip to the encodable range (a view can overshoot by an ulp).
    return np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0)


def write_sdr(path, display_rgb, *, bits: int = 8, dither: bool = True,
              colorspace: str = SRGB_DISPLAY_INTEROP, cicp: tuple | None = None) -> None:
    """Write display-encoded SDR code values (0..1) as an 8/16-bit PNG or TIFF.

    Parameters
    ----------
    path : str or os.PathLike
        ``.png``, ``.tif`` or ``.tiff``.
    display_rgb : (H, W, 3) array
        Display-encoded values; clipped to [0, 1].
    bits : {8, 16}
    dither : bool
        Dither before 8-bit quantisation (ignored at 16 bits).
    colorspace : str
        The display colour space (``oiio:ColorSpace``).
    cicp : tuple of 4 int, optional
        Written as the PNG cICP chunk (TIFF has none).
    """
    path = os.fspath(path)
    ext = _ext(path, SDR_EXTENSIONS, "SDR")
    check_bits(bits, path)
    oiio = _oiio()
    data = _check(path, display_rgb)
    attrs = {"oiio:ColorSpace": colorspace, "Software": "clphong"}
    if cicp is not None and ext == ".png":
        attrs["CICP"] = tuple(int(v) for v in cicp)
    if ext != ".png":
        attrs["compression"] = "zip"
    _write_display(path, data, oiio.UINT8 if bits == 8 else oiio.UINT16, attrs,
                   dither and bits == 8)


def write_hdr(path, pq_rgb, *, colorspace: str = "pq_rec2020_display",
              cicp: tuple = PQ_CICP) -> None:
    """Write Rec.2100 PQ code values (0..1) as a 16-bit PNG with cICP, or JPEG XL.

    Raises
    ------
    OutputError
        A bad extension, or ``.jxl`` where OpenImageIO has no JPEG XL writer.
    """
    path = os.fspath(path)
    ext = _ext(path, HDR_EXTENSIONS, "HDR")
    if ext == ".jxl" and not jpegxl_available():
        raise OutputError(f"{path}: this OpenImageIO cannot write JPEG XL; write a .png instead")
    oiio = _oiio()
    data = _check(path, pq_rgb)
    attrs = {"oiio:ColorSpace": colorspace, "CICP": tuple(int(v) for v in cicp),
             "Software": "clphong"}
    _write_display(path, data, oiio.UINT16, attrs, dither=False)

"""Writing each kind of output: scene-linear EXR, SDR PNG/TIFF, HDR PQ PNG/JPEG XL.

Every writer goes through :func:`clphong.io.atomic.atomic_path` (no partial file on
failure) and tags the file with what its pixels are:

* **scene-linear EXR** (:func:`write_scene_linear`): half or float, any
  compression of :func:`exr_compressions` (``NAME`` or ``NAME:LEVEL``, see
  :func:`check_compression`), ``chromaticities`` of the working space and
  ``oiio:ColorSpace`` set to its interop ID (``lin_rec709_scene`` or
  ``lin_ap1_scene``); no stale ``colorInteropID``.
* **SDR** (:func:`write_sdr`): display-encoded values in [0, 1] as 8- or 16-bit
  PNG or TIFF, or 8-bit JPEG (quality :data:`JPEG_QUALITY`), dithered before
  8-bit quantisation (OpenImageIO's ``oiio:dither``: ±½ LSB of noise, so smooth
  gradients do not band), tagged with the display colour space and, where it
  has one, its cICP.
* **HDR** (:func:`write_hdr`): Rec.2100 PQ code values as a 16-bit PNG with the
  cICP chunk (9, 16, 0, 1), or JPEG XL where OpenImageIO has the plugin.

SDR and HDR outputs take an optional straight (unassociated) alpha channel,
written as a fourth channel A with ``oiio:UnassociatedAlpha = 1`` (JPEG has none).
"""

from __future__ import annotations

import functools
import os
import re
import tempfile
from collections.abc import Sequence

import numpy as np

from ..color.ocio import PQ_CICP, SRGB_DISPLAY_INTEROP, WorkingSpace
from ..core.errors import OutputError
from ..io.atomic import write_exr, write_image_atomically

__all__ = ["write_scene_linear", "write_sdr", "write_hdr", "SDR_EXTENSIONS", "HDR_EXTENSIONS",
           "EXR_BASE_COMPRESSIONS", "HTJ2K_COMPRESSIONS",
           "EXR_COMPRESSION_LEVELS", "exr_compressions",
           "check_compression", "check_sdr", "SDR_BITS", "check_bits", "jpegxl_available", "JPEG_EXTENSIONS",
           "JPEG_QUALITY"]

#: Extensions of the JPEG SDR outputs (8-bit, no alpha).
JPEG_EXTENSIONS = (".jpg", ".jpeg")
SDR_EXTENSIONS = (".png", ".tif", ".tiff") + JPEG_EXTENSIONS
HDR_EXTENSIONS = (".png", ".jxl")
#: Quality of a JPEG output: OpenImageIO's ``Compression = "jpeg:95"`` (IJG scaling:
#: the standard quantisation tables times 0.1, so the lowest frequencies get steps of 1-2).
JPEG_QUALITY = 95
#: The EXR compressions every OpenImageIO 3 / OpenEXR 3 writer has, as its
#: ``compression`` attribute names them. Lossless: none, rle, zips, zip, piz;
#: lossy: pxr24 (float rounded to 24 bits; half exact), b44 and b44a (half only;
#: float channels are stored as they are), dwaa and dwab (DCT).
EXR_BASE_COMPRESSIONS = ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a",
                         "dwaa", "dwab")
#: OpenEXR 3.4's lossless High-Throughput JPEG 2000 compressions (chunks of 256 and
#: 32 scanlines); offered only where this OpenImageIO writes them (:func:`exr_compressions`).
HTJ2K_COMPRESSIONS = ("htj2k256", "htj2k32")
#: The largest level OpenImageIO can take: it parses the text after the colon into a C int.
_LEVEL_MAX = 2**31 - 1
#: The compressions that take ``NAME:LEVEL``, with the smallest and largest level.
#: zip/zips: zlib's levels (OpenImageIO's default 4). dwaa/dwab: OpenEXR's
#: dwaCompressionLevel (default 45; larger is smaller and lossier), which OpenImageIO
#: takes as a whole number only ("dwaa:45.5" is 45); 0 would mean "the default".
EXR_COMPRESSION_LEVELS = {"zip": (1, 9), "zips": (1, 9), "dwaa": (1, _LEVEL_MAX),
                          "dwab": (1, _LEVEL_MAX)}
#: Bit depths of the SDR outputs (``--bits``).
SDR_BITS = (8, 16)
#: Seed of the 8-bit dither (fixed: the same frame gives the same file).
DITHER_SEED = 1


def _exr_writes(compression: str) -> bool:
    """Whether OpenImageIO's EXR writer records ``compression`` in a file: it writes
    zip, silently, for a name it (or its OpenEXR) lacks, so only a file read back tells."""
    oiio = _oiio()
    try:
        with tempfile.TemporaryDirectory(prefix="clphong-exr-probe-") as folder:
            name = os.path.join(folder, "probe.exr")
            spec = oiio.ImageSpec(4, 4, 1, oiio.HALF)
            spec.attribute("compression", compression)
            out = oiio.ImageOutput.create(name)
            if out is None:
                oiio.geterror()                 # retrieved, so OpenImageIO does not print it at exit
                return False
            ok = out.open(name, spec) and out.write_image(np.zeros((4, 4, 1), np.float32))
            ok = out.close() and ok
            if not ok:
                out.geterror()
                return False
            inp = oiio.ImageInput.open(name)
            if inp is None:
                oiio.geterror()
                return False
            try:
                return inp.spec().get_string_attribute("compression") == compression
            finally:
                inp.close()
    except OSError:
        # No writable temporary folder: offer only the compressions every writer has.
        return False


@functools.cache
def exr_compressions() -> tuple[str, ...]:
    """The EXR compression names this OpenImageIO writes (probed once, then cached).

    Returns
    -------
    tuple of str
        :data:`EXR_BASE_COMPRESSIONS`, then each of :data:`HTJ2K_COMPRESSIONS`
        that a tiny EXR written to a temporary folder reads back with.
    """
    return EXR_BASE_COMPRESSIONS + tuple(c for c in HTJ2K_COMPRESSIONS if _exr_writes(c))


def _level_range(name: str) -> str:
    """The levels ``name`` takes, in words: ``1 to 9``, or ``a whole number ≥ 1``
    where the top is only :data:`_LEVEL_MAX`."""
    lo, hi = EXR_COMPRESSION_LEVELS[name]
    return f"{lo} to {hi}" if hi < _LEVEL_MAX else f"a whole number ≥ {lo}"


def _compression_syntax() -> str:
    """The valid values of an EXR compression, for messages."""
    groups: dict[str, list[str]] = {}
    for n in EXR_COMPRESSION_LEVELS:
        groups.setdefault(_level_range(n), []).append(n)
    levels = ", ".join(f"{'/'.join(names)}:LEVEL with LEVEL {words}" for words, names in groups.items())
    return f"one of {', '.join(exr_compressions())} ({levels})"


def check_compression(compression, where: str | None = None) -> str:
    """The EXR compression ``compression`` as OpenImageIO's ``compression`` attribute takes it.

    Parameters
    ----------
    compression : str
        ``NAME`` (one of :func:`exr_compressions`, lower case) or ``NAME:LEVEL``
        for a name of :data:`EXR_COMPRESSION_LEVELS`: ``zip:9``, ``dwaa:45``.
    where : str, optional
        The file or option named in the message.

    Returns
    -------
    str
        ``NAME`` or ``NAME:LEVEL`` with the level in plain digits (``zip:09`` ->
        ``zip:9``); OpenImageIO reads either the same way.

    Raises
    ------
    OutputError
        One line naming ``where`` and listing the valid names and levels: an unknown
        name (OpenImageIO would write zip without a word), a level for a compression
        that takes none, or a level out of range or not a whole number (OpenImageIO
        would ignore it, or truncate ``dwaa:45.5`` to 45).
    """
    subject = f"{where}: EXR compression" if where else "EXR compression"
    name, colon, level = compression.partition(":") if isinstance(compression, str) else ("", "", "")
    # the base names need no probe (a probe writes a small EXR: not at argparse time)
    if name not in EXR_BASE_COMPRESSIONS and name not in exr_compressions():
        raise OutputError(f"{subject} must be {_compression_syntax()}, not {compression!r}")
    if not colon:
        return name
    if name not in EXR_COMPRESSION_LEVELS:
        raise OutputError(f"{subject} {compression!r}: {name} takes no level; "
                          f"valid: {_compression_syntax()}")
    lo, hi = EXR_COMPRESSION_LEVELS[name]
    if not re.fullmatch(r"[0-9]+", level) or not lo <= int(level) <= hi:
        raise OutputError(f"{subject} {compression!r}: the level of {name} must be "
                          f"{_level_range(name)}, not {level!r}; valid: {_compression_syntax()}")
    return f"{name}:{int(level)}"


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
                       attributes: dict | None = None, alpha: np.ndarray | None = None,
                       layers: dict | None = None) -> None:
    """Write scene-linear ``rgb`` (working space ``ws``) as an OpenEXR file.

    ``attributes`` are extra header attributes, set after the colour-space tags.
    ``alpha``: (H, W) coverage written as ``A`` beside ``R, G, B``, which are then
    premultiplied by it, as OpenEXR expects (clphong's beauty already is).
    ``layers``: name -> (H, W, 3) written as ``NAME.R, NAME.G, NAME.B`` (light
    groups, ``diffuse``, ``specular``), in that order, after the beauty.

    Raises
    ------
    OutputError
        A bad extension, pixel type or compression, or any write failure.
    """
    path = os.fspath(path)
    _ext(path, (".exr",), "scene-linear")
    compression = check_compression(compression, path)
    tags = {"chromaticities": ws.chromaticities, "oiio:ColorSpace": ws.interop_id,
            "Software": software}
    tags.update(attributes or {})
    names = ["R", "G", "B"]
    planes = [np.asarray(rgb, np.float32)]
    if alpha is not None:
        names.append("A")
        planes.append(np.asarray(alpha, np.float32)[..., None])
    for name, layer in (layers or {}).items():
        names += [f"{name}.R", f"{name}.G", f"{name}.B"]
        planes.append(np.asarray(layer, np.float32))
    data = planes[0] if len(planes) == 1 else np.concatenate(planes, axis=-1)
    write_exr(path, data, pixel_type=pixel_type, compression=compression, attributes=tags,
              channel_names=names)


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
    # Display code values: clip to the encodable range (a view can overshoot by an ulp);
    # NaN is 0, -Inf 0, +Inf 1. fmax/fmin (NaN-ignoring) in one new array: no temporary.
    out = np.fmax(a, np.float32(0.0))
    return np.fmin(out, np.float32(1.0), out=out)


def _with_alpha(path: str, rgb: np.ndarray, alpha, attrs: dict) -> np.ndarray:
    """``rgb`` with ``alpha`` appended as a fourth channel A, straight (not premultiplied).

    ``oiio:UnassociatedAlpha = 1`` goes into ``attrs``: without it OpenImageIO takes
    the pixels for premultiplied and divides RGB by A before writing a PNG (whose
    alpha is straight by definition), and tags a TIFF's alpha as associated.
    """
    a = np.asarray(alpha, np.float32)
    if a.shape != rgb.shape[:2]:
        raise OutputError(f"{path}: expected an alpha channel of shape {rgb.shape[:2]} (H, W) "
                          f"for the {rgb.shape[1]}x{rgb.shape[0]} image, got shape {a.shape}")
    attrs["oiio:UnassociatedAlpha"] = 1
    # Coverage in [0, 1], clipped as the colour is; NaN is no coverage.
    a = np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0)
    return np.concatenate([rgb, a[:, :, None]], axis=2)


def check_sdr(path: str, *, bits: int, alpha: bool, colorspace: str | None) -> str:
    """What an SDR output at ``path`` can hold, checked before any work; its extension.

    A bad extension or bit depth; a JPEG at 16 bits, with alpha, or tagged with a
    colour space other than sRGB (``colorspace``; None: not known yet), and a TIFF
    other than sRGB (the only display colour space its file can name).

    Raises
    ------
    OutputError
        One line naming ``path``.
    """
    ext = _ext(path, SDR_EXTENSIONS, "SDR")
    check_bits(bits, path)
    if ext in JPEG_EXTENSIONS:
        if bits != 8:
            raise OutputError(f"{path}: JPEG holds 8 bits per channel; use --bits 8 or a PNG/TIFF")
        if alpha:
            raise OutputError(f"{path}: JPEG cannot hold an alpha channel (--alpha); use PNG or TIFF")
    if ext != ".png" and colorspace not in (None, SRGB_DISPLAY_INTEROP):
        # A JPEG without the sRGB tag reads back as sRGB anyway: it would be mislabelled.
        kind = "JPEG" if ext in JPEG_EXTENSIONS else "TIFF"
        raise OutputError(f"{path}: a {kind} cannot be tagged with the colour space {colorspace!r} "
                          "(only sRGB); write a .png, which carries cICP")
    return ext


def write_sdr(path, display_rgb, *, bits: int = 8, dither: bool = True,
              colorspace: str = SRGB_DISPLAY_INTEROP, cicp: tuple | None = None,
              alpha=None) -> None:
    """Write display-encoded SDR code values (0..1) as an 8/16-bit PNG or TIFF, or 8-bit JPEG.

    Parameters
    ----------
    path : str or os.PathLike
        ``.png``, ``.tif``, ``.tiff``, ``.jpg`` or ``.jpeg``.
    display_rgb : (H, W, 3) array
        Display-encoded values; clipped to [0, 1]. With ``alpha``, the colour of
        each pixel as shown (un-premultiplied), not colour times alpha.
    bits : {8, 16}
        16 is refused for a JPEG (8 bits per channel).
    dither : bool
        Dither the colour channels before 8-bit quantisation (ignored at 16 bits).
    colorspace : str
        The display colour space (``oiio:ColorSpace``). A JPEG can only say sRGB
        (OpenImageIO's JPEG writer records an sRGB tag, EXIF ColorSpace = 1, and
        nothing else), so any other is refused for one.
    cicp : tuple of 4 int, optional
        Written as the PNG cICP chunk (TIFF and JPEG have none).
    alpha : (H, W) array, optional
        Straight (unassociated) alpha in [0, 1] (clipped; NaN is 0), written as a
        fourth channel A with ``oiio:UnassociatedAlpha = 1`` and quantised like the
        colour. A is never dithered (OpenImageIO's ``oiio:dither`` skips the alpha
        channel): it is rounded to the nearest code, so opaque stays exactly opaque.
        Refused for a JPEG, which has no alpha channel.

    Raises
    ------
    OutputError
        One line naming ``path``: a bad extension, bit depth, shape, a JPEG at 16
        bits, with alpha or in a colour space other than sRGB, or a failed write.

    Notes
    -----
    A JPEG is written at quality :data:`JPEG_QUALITY` with libjpeg's default 4:2:0
    chroma subsampling, dithered like an 8-bit PNG.
    """
    path = os.fspath(path)
    ext = check_sdr(path, bits=bits, alpha=alpha is not None, colorspace=colorspace)
    jpeg = ext in JPEG_EXTENSIONS
    oiio = _oiio()
    data = _check(path, display_rgb)
    attrs = {"oiio:ColorSpace": colorspace, "Software": "clphong"}
    if cicp is not None and ext == ".png":
        attrs["CICP"] = tuple(int(v) for v in cicp)
    if jpeg:
        attrs["Compression"] = f"jpeg:{JPEG_QUALITY}"
    elif ext != ".png":
        attrs["compression"] = "zip"
    if alpha is not None:
        data = _with_alpha(path, data, alpha, attrs)
    _write_display(path, data, oiio.UINT8 if bits == 8 else oiio.UINT16, attrs,
                   dither and bits == 8)


def write_hdr(path, pq_rgb, *, colorspace: str = "pq_rec2020_display",
              cicp: tuple = PQ_CICP, alpha=None) -> None:
    """Write Rec.2100 PQ code values (0..1) as a 16-bit PNG with cICP, or JPEG XL.

    Parameters
    ----------
    path : str or os.PathLike
        ``.png`` or ``.jxl``.
    pq_rgb : (H, W, 3) array
        PQ code values; clipped to [0, 1]. With ``alpha``, un-premultiplied.
    colorspace : str
        The display colour space (``oiio:ColorSpace``).
    cicp : tuple of 4 int
        The cICP of the file (PNG chunk, JPEG XL colour encoding).
    alpha : (H, W) array, optional
        Straight alpha in [0, 1], a fourth channel A at 16 bits with
        ``oiio:UnassociatedAlpha = 1`` (as :func:`write_sdr`; nothing is dithered here).

    Raises
    ------
    OutputError
        A bad extension or shape, or ``.jxl`` where OpenImageIO has no JPEG XL writer.
    """
    path = os.fspath(path)
    ext = _ext(path, HDR_EXTENSIONS, "HDR")
    if ext == ".jxl" and not jpegxl_available():
        raise OutputError(f"{path}: this OpenImageIO cannot write JPEG XL; write a .png instead")
    oiio = _oiio()
    data = _check(path, pq_rgb)
    attrs = {"oiio:ColorSpace": colorspace, "CICP": tuple(int(v) for v in cicp),
             "Software": "clphong"}
    if alpha is not None:
        data = _with_alpha(path, data, alpha, attrs)
    _write_display(path, data, oiio.UINT16, attrs, dither=False)

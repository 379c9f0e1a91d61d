"""``clphong inspect`` and ``clphong diff``: look inside EXRs, and compare two images.

:func:`inspect_file` reports what a file holds: parts, sizes (data and
display windows), channels with their pixel types, the detected G-buffer
convention (:func:`clphong.read_gbuffer`), the camera metadata
(``worldToCamera``, and the eye it gives), and per channel the range and the
NaN, Inf and negative counts.

:func:`diff_images` compares a test image B with a reference A by one metric
and a tolerance (the exit status of ``clphong diff``: 0 match, 1 differ,
2 trouble, like ``cmp``/``diff``):

``max-rel``
    ``max |B − A| / max(|A|, floor)`` over pixels and channels; ``floor``
    defaults to ``1e-6 · max|A|``, the convention of the project's error
    reports (relative error on values ≥ 1e-6 of the peak). Match: ≤ tol.
``mean-abs``
    ``mean |B − A|``. Match: ≤ tol.
``psnr``
    ``10 log10(peak² / MSE)`` in dB with ``peak = max|A|`` unless given
    (scene-linear images have no fixed peak). Match: ≥ tol; identical
    images give +inf.
``flip``
    The mean of NVIDIA's FLIP perceptual error map (Andersson et al. 2020,
    HDR-FLIP for float images, 2021), as computed by OpenImageIO's
    ``ImageBufAlgo.FLIP_diff(ref=A, test=B)`` on R, G, B. Match: ≤ tol.

Non-finite values: a pixel value is equal to its counterpart when both are
the same Inf or both NaN; any other NaN/Inf mismatch makes the images differ
(the metric is reported as inf or nan, and the mismatches are counted).
The heat map is the per-pixel error (the metric's per-pixel quantity, over
channels): an EXR gets the raw values as one channel ``Y``; any other format
gets a false-colour (``inferno``) image of the error scaled to its maximum
(FLIP: not scaled, it is already in [0, 1]).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np
import OpenImageIO as oiio

from ..core.errors import ClphongError, GBufferError, OutputError
from ..model.options import check_number
from .atomic import _one_line, atomic_path, check_image_written, same_file, write_exr
from .camera import WORLD_TO_CAMERA, eye_from_matrix, world_to_camera
from .exrfile import open_image
from .gbuffer import read_gbuffer

__all__ = ["inspect_file", "format_report", "diff_images", "DiffResult", "DiffError", "METRICS"]

#: Metrics of :func:`diff_images`.
METRICS = ("max-rel", "mean-abs", "psnr", "flip")


class DiffError(ClphongError):
    """``clphong diff`` could not compare (unreadable file, bad option): exit status 2."""

    exit_code = 2


# --------------------------------------------------------------------------- reading


def _open(path: str):
    return open_image(path, what="an image", verb="read")


def _read_pixels(inp, path: str, subimage: int, spec) -> np.ndarray:
    pix = inp.read_image(subimage, 0, 0, spec.nchannels, oiio.TypeDesc("float"))
    if pix is None:
        raise GBufferError(f"{path}: reading the pixels failed: {_one_line(inp.geterror() or oiio.geterror())}")
    return np.asarray(pix, np.float32).reshape(spec.height, spec.width, spec.nchannels)


def _channel_types(spec) -> list[str]:
    formats = list(spec.channelformats) if len(spec.channelformats) else [spec.format] * spec.nchannels
    return [str(f) for f in formats]


# --------------------------------------------------------------------------- inspect


def inspect_file(path: str | os.PathLike, *, stats: bool = True) -> dict:
    """Everything ``clphong inspect`` prints, as plain data (JSON-ready).

    Parameters
    ----------
    path : str or os.PathLike
        An image file (EXR or anything OpenImageIO reads).
    stats : bool
        Read the pixels and count NaN, Inf and negative values per channel.

    Raises
    ------
    GBufferError
        The file is missing or unreadable.
    """
    path = os.fspath(path)
    inp = _open(path)
    parts = []
    try:
        fmt = inp.format_name()
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            part = {
                "index": sub,
                "name": spec.get_string_attribute("name", ""),
                "data_window": [spec.x, spec.y, spec.width, spec.height],
                "display_window": [spec.full_x, spec.full_y, spec.full_width, spec.full_height],
                "tiled": [spec.tile_width, spec.tile_height] if spec.tile_width else None,
                "deep": bool(spec.deep),
                "compression": spec.get_string_attribute("compression", ""),
                "channels": [{"name": n, "type": t} for n, t in zip(spec.channelnames, _channel_types(spec))],
            }
            attrs = {a.name: a.value for a in spec.extra_attribs}
            part["colorspace"] = spec.get_string_attribute("oiio:ColorSpace", "")
            part["camera"] = _camera_info(attrs, path)
            if stats and not spec.deep:
                pix = _read_pixels(inp, path, sub, spec)
                part["stats"] = _channel_stats(pix, spec.channelnames)
            parts.append(part)
            sub += 1
    finally:
        inp.close()
    report = {"file": path, "format": fmt, "parts": parts, "gbuffer": _gbuffer_info(path)}
    return report


def _camera_info(attrs: dict, path: str) -> dict | None:
    info = {}
    try:
        M = world_to_camera(attrs)
    except GBufferError as exc:
        return {"error": str(exc)}
    if M is not None:
        info[WORLD_TO_CAMERA] = M.tolist()
        for up in ("y", "z"):
            try:
                info[f"eye_{up}_up"] = eye_from_matrix(M, up=up, source=path).tolist()
            except GBufferError as exc:
                info["error"] = str(exc)
                break
    if "worldToNDC" in attrs:
        info["worldToNDC"] = np.asarray(attrs["worldToNDC"], np.float64).reshape(4, 4).tolist()
    return info or None


def _channel_stats(pix: np.ndarray, names) -> list[dict]:
    out = []
    for i, name in enumerate(names):
        c = pix[..., i]
        finite = np.isfinite(c)
        vals = c[finite]
        out.append({
            "name": name,
            "min": float(vals.min()) if vals.size else None,
            "max": float(vals.max()) if vals.size else None,
            "nan": int(np.isnan(c).sum()),
            "inf": int(np.isinf(c).sum()),
            "negative": int((c < 0).sum()),          # -inf counts as negative too
        })
    return out


def _gbuffer_info(path: str) -> dict:
    try:
        gb = read_gbuffer(path)
    except ClphongError as exc:
        return {"convention": None, "reason": str(exc)}
    h, w = gb.shape
    return {"convention": gb.convention, "size": [w, h], "sources": dict(gb.sources),
            "coverage": gb.coverage is not None, "maps": sorted(gb.maps),
            "background_pixels": int(gb.background_mask().sum())}


def format_report(report: dict) -> str:
    """The human-readable form of :func:`inspect_file`'s report."""
    lines = [f"{report['file']}: {report['format']}, {len(report['parts'])} part(s)"]
    for part in report["parts"]:
        x, y, w, h = part["data_window"]
        fx, fy, fw, fh = part["display_window"]
        head = f"part {part['index']}" + (f" ({part['name']})" if part["name"] else "")
        layout = f"tiled {part['tiled'][0]}x{part['tiled'][1]}" if part["tiled"] else "scanline"
        lines.append(f"{head}: {w}x{h}, {layout}, compression {part['compression'] or 'n/a'}"
                     + (", deep" if part["deep"] else ""))
        if (x, y, w, h) != (fx, fy, fw, fh):
            lines.append(f"  data window {w}x{h} at ({x}, {y}); display window {fw}x{fh} at ({fx}, {fy})")
        if part["colorspace"]:
            lines.append(f"  colour space: {part['colorspace']}")
        stats = {s["name"]: s for s in part.get("stats", [])}
        lines.append(f"  {len(part['channels'])} channel(s):"
                     + ("       min          max          NaN      Inf      negative" if stats else ""))
        for ch in part["channels"]:
            s = stats.get(ch["name"])
            text = f"    {ch['name']:<24} {ch['type']:<6}"
            if s:
                lo = "-" if s["min"] is None else f"{s['min']:<12.6g}"
                hi = "-" if s["max"] is None else f"{s['max']:<12.6g}"
                text += f" {lo:<12} {hi:<12} {s['nan']:<8} {s['inf']:<8} {s['negative']}"
            lines.append(text.rstrip())
        if stats:
            tot = {k: sum(s[k] for s in stats.values()) for k in ("nan", "inf", "negative")}
            lines.append(f"  totals: {tot['nan']} NaN, {tot['inf']} Inf, {tot['negative']} negative values")
        cam = part["camera"]
        if not cam:
            lines.append("  camera: no worldToCamera attribute")
        else:
            if WORLD_TO_CAMERA in cam:
                rows = "; ".join(" ".join(f"{v:.6g}" for v in r) for r in cam[WORLD_TO_CAMERA])
                lines.append(f"  camera: worldToCamera [{rows}]")
            if "eye_y_up" in cam:
                ey, ez = cam["eye_y_up"], cam["eye_z_up"]
                lines.append(f"    eye {_vec(ey)} (up = \"y\"), {_vec(ez)} (up = \"z\", rotated to Y-up)")
            if "worldToNDC" in cam:
                lines.append("    worldToNDC present")
            if "error" in cam:
                lines.append(f"    unusable: {cam['error']}")
    gb = report["gbuffer"]
    if gb["convention"]:
        w, h = gb["size"]
        lines.append(f"G-buffer: {gb['convention']} convention, {w}x{h}, "
                     f"{gb['background_pixels']} background pixel(s)")
        for key, src in gb["sources"].items():
            lines.append(f"  {key:<15} {src}")
        if not gb["coverage"]:
            lines.append("  coverage        none (background = zero or non-finite normals)")
    else:
        lines.append(f"G-buffer: not usable: {gb['reason']}")
    return "\n".join(lines)


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


# --------------------------------------------------------------------------- diff


@dataclass
class DiffResult:
    """The outcome of :func:`diff_images`."""

    metric: str
    value: float
    tol: float
    match: bool
    reason: str = ""
    worst: tuple | None = None                 # (x, y, channel) of the largest error
    nonfinite_mismatches: int = 0
    details: dict = field(default_factory=dict)

    def line(self) -> str:
        """One line for stdout."""
        if self.reason:
            return f"differ: {self.reason}"
        cmp = ">=" if self.metric == "psnr" else "<="
        verdict = "match" if self.match else "differ"
        text = f"{self.metric} = {self.value:.6g} (need {cmp} {self.tol:g}): {verdict}"
        if self.worst is not None and self.metric in ("max-rel", "flip") and self.value > 0:
            x, y, c = self.worst
            text += f"; worst at pixel ({x}, {y})" + (f" channel {c}" if c else "")
        if self.nonfinite_mismatches:
            text += f"; {self.nonfinite_mismatches} NaN/Inf mismatch(es)"
        return text


def _load(path: str):
    inp = _open(path)
    try:
        spec = inp.spec()
        if spec.deep:
            raise GBufferError(f"{path}: deep images cannot be compared; flatten first")
        pix = _read_pixels(inp, path, 0, spec)
        return pix, list(spec.channelnames), spec
    finally:
        inp.close()


def _select(pix, names, wanted, path):
    idx = []
    for c in wanted:
        if c not in names:
            raise GBufferError(f"{path}: no channel {c!r}; the file has {', '.join(names)}")
        idx.append(names.index(c))
    return pix[..., idx]


def diff_images(a: str | os.PathLike, b: str | os.PathLike, *, metric: str = "max-rel", tol: float,
                channels: list[str] | None = None, heatmap: str | os.PathLike | None = None,
                floor: float | None = None, peak: float | None = None) -> DiffResult:
    """Compare test image ``b`` with reference ``a`` (see the module docstring).

    Parameters
    ----------
    a, b : str or os.PathLike
        Reference and test images.
    metric : {"max-rel", "mean-abs", "psnr", "flip"}
    tol : float
        Tolerance: the largest allowed error, or for ``psnr`` the smallest
        allowed PSNR in dB.
    channels : list of str, optional
        Channels to compare (default: all; the files must have the same
        channel names).
    heatmap : str or os.PathLike, optional
        Also write the per-pixel error image there (atomically); never one of
        the inputs.
    floor, peak : float, optional
        ``max-rel`` denominator floor; ``psnr`` peak.

    Raises
    ------
    GBufferError, OutputError, ValueError
        Unreadable file, missing channel, bad metric, unwritable heat map or
        one that would overwrite an input.
    """
    if heatmap is not None:
        for src in (a, b):
            if same_file(src, heatmap):
                raise OutputError(f"{os.fspath(heatmap)}: the heat map would overwrite the input "
                                  f"{os.fspath(src)}; choose another name")
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; choose one of {', '.join(METRICS)}")
    if not math.isfinite(tol):
        raise ValueError(f"tolerance must be a finite number, got {tol}")
    # at the door: --floor inf (or --peak inf) made an all-black image "match" a lit one
    floor = None if floor is None else check_number(floor, "--floor")
    peak = None if peak is None else check_number(peak, "--peak")
    a, b = os.fspath(a), os.fspath(b)
    pa, na, sa = _load(a)
    pb, nb, sb = _load(b)
    if (sa.width, sa.height) != (sb.width, sb.height):
        return DiffResult(metric, math.inf, tol, False,
                          reason=f"{a} is {sa.width}x{sa.height} but {b} is {sb.width}x{sb.height}")
    if channels is None:
        if metric == "flip":
            rgb = ["R", "G", "B"]
            if all(c in na for c in rgb) and all(c in nb for c in rgb):
                channels = rgb
        if channels is None:
            if sorted(na) != sorted(nb):
                return DiffResult(metric, math.inf, tol, False,
                                  reason=f"{a} has channels {','.join(na)} but {b} has {','.join(nb)}")
            channels = na
    A = _select(pa, na, channels, a).astype(np.float64)
    B = _select(pb, nb, channels, b).astype(np.float64)

    same = (A == B) | (np.isnan(A) & np.isnan(B))
    finite = np.isfinite(A) & np.isfinite(B)
    bad = ~same & ~finite                        # NaN/Inf where the other image differs
    n_bad = int(bad.sum())
    diff = np.where(same | ~finite, 0.0, np.abs(B - A))

    details: dict = {"channels": list(channels)}
    value, heat, per, match = _measure(metric, A, B, diff, bad, tol, details, channels=channels,
                                       floor=floor, peak=peak,
                                       hdr=sa.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE))
    worst = _worst_pixel(heat, per if metric == "max-rel" else None, channels, n_bad)
    if heatmap is not None:
        _write_heatmap(os.fspath(heatmap), heat, metric)
    return DiffResult(metric, value, tol, bool(match), worst=worst, nonfinite_mismatches=n_bad,
                      details=details)


def _measure(metric, A, B, diff, bad, tol, details, *, channels, floor, peak, hdr):
    """(value, per-pixel heat, per-channel error or None, match) of ``metric`` on the finite
    differences ``diff`` (``bad``: a NaN or Inf where the other image differs)."""
    n_bad = int(bad.sum())
    finite_a = np.abs(A[np.isfinite(A)])
    a_peak = float(finite_a.max()) if finite_a.size else 0.0
    per = None
    if metric == "max-rel":
        fl = floor if floor is not None else 1e-6 * a_peak
        fl = fl if fl > 0 else np.finfo(np.float64).tiny
        per = diff / np.maximum(np.where(np.isfinite(A), np.abs(A), 0.0), fl)
        per = np.where(bad, np.inf, per)
        value = float(per.max()) if per.size else 0.0
        details["floor"] = fl
        return value, per.max(axis=2), per, value <= tol
    if metric == "mean-abs":
        per = np.where(bad, np.inf, diff)
        value = float(per.mean()) if per.size else 0.0
        return value, per.mean(axis=2), None, value <= tol
    if metric == "psnr":
        pk = peak if peak is not None else a_peak
        sq = np.where(bad, np.inf, diff * diff)
        mse = float(sq.mean()) if sq.size else 0.0
        if mse == 0.0:
            value = math.inf
        elif pk <= 0 or not math.isfinite(mse):
            value = -math.inf
        else:
            value = 10.0 * math.log10(pk * pk / mse)
        details["peak"] = pk
        return value, sq.mean(axis=2), None, value >= tol
    if len(channels) != 3:
        raise ValueError(f"flip compares 3 colour channels; give --channels R,G,B "
                         f"(got {','.join(channels)})")
    heat, value = _flip(A, B, hdr=hdr)
    if n_bad:
        value = math.inf
        heat = np.where(bad.any(axis=2), np.inf, heat)
    return value, heat, None, value <= tol


def _worst_pixel(heat, per, channels, n_bad):
    """(x, y, channel) of the largest heat (the channel with ``per``, max-rel's), or None."""
    if not (heat.size and np.isfinite(heat).any() or n_bad):
        return None
    flat = np.nanargmax(np.where(np.isnan(heat), -np.inf, heat))
    y, x = np.unravel_index(flat, heat.shape)
    return int(x), int(y), (channels[int(np.argmax(per[y, x]))] if per is not None else "")


def _buf(arr: np.ndarray) -> oiio.ImageBuf:
    h, w, c = arr.shape
    buf = oiio.ImageBuf(oiio.ImageSpec(w, h, c, oiio.TypeDesc("float")))
    buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, c), np.ascontiguousarray(arr, np.float32))
    return buf


def _flip(A: np.ndarray, B: np.ndarray, *, hdr: bool) -> tuple[np.ndarray, float]:
    """OpenImageIO's FLIP map (ref A, test B) and its mean; non-finite values zeroed first."""
    A = np.where(np.isfinite(A), A, 0.0)
    B = np.where(np.isfinite(B), B, 0.0)
    out = oiio.ImageBufAlgo.FLIP_diff(_buf(A), _buf(B), hdr=int(hdr))
    if out is None or out.has_error:
        raise GBufferError(f"FLIP failed: {_one_line(out.geterror() if out is not None else oiio.geterror())}")
    heat = np.asarray(out.get_pixels(oiio.TypeDesc("float")), np.float64)[..., 0]
    mean = out.spec().get_float_attribute("FLIP:meanerror", float(heat.mean()))
    return heat, float(mean)


def _write_heatmap(path: str, heat: np.ndarray, metric: str) -> None:
    if path.lower().endswith(".exr"):
        write_exr(path, heat.astype(np.float32), channel_names=("Y",))
        return
    finite = heat[np.isfinite(heat)]
    scale = 1.0 if metric == "flip" else (float(finite.max()) if finite.size and finite.max() > 0 else 1.0)
    norm = np.clip(np.where(np.isfinite(heat), heat / scale, 1.0), 0.0, 1.0)
    mapped = oiio.ImageBufAlgo.color_map(_buf(norm[..., None]), 0, "inferno")
    with atomic_path(path) as tmp:
        if not mapped.write(tmp):
            raise OutputError(f"{path}: cannot write the heat map: {_one_line(mapped.geterror())}")
        check_image_written(tmp, path)

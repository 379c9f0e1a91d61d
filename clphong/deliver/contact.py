"""A contact sheet: one frame through every tone-mapping operator and OCIO view.

For people who would rather look than read: a PNG grid of labelled tiles, the
same scene-linear frame through each operator of :mod:`clphong.reference.tonemap` (the
device's display transform, sRGB-encoded) and through each view of the SDR
display (OCIO), at the same exposure. For a display other than sRGB the
operator tiles are converted to that display's colour space (OCIO), and the
sheet is tagged with it.
"""

from __future__ import annotations

import math

import numpy as np

from ..color.ocio import SRGB_CICP, ColorConfig, ColorError, WorkingSpace
from ..device.display import DisplayTransform, apply_display_transform
from ..model import tonemap
from .writers import write_sdr

__all__ = ["contact_sheet", "write_contact_sheet", "TILE_WIDTH", "LABEL_HEIGHT"]

#: Largest tile width in pixels; bigger frames are downsized (in scene-linear).
TILE_WIDTH = 480
LABEL_HEIGHT = 26
GAP = 4
COLUMNS = 4
_LABEL_BG = 0.12


def _resize(rgb: np.ndarray, width: int) -> np.ndarray:
    import OpenImageIO as oiio

    h, w, _ = rgb.shape
    if w <= width:
        return rgb
    nh = max(1, round(h * width / w))
    src = oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32))
    dst = oiio.ImageBufAlgo.resize(src, roi=oiio.ROI(0, width, 0, nh, 0, 1, 0, 3))
    return dst.get_pixels(oiio.FLOAT)


def _label(tile: np.ndarray, text: str) -> np.ndarray:
    import OpenImageIO as oiio

    h, w, _ = tile.shape
    out = np.full((h + LABEL_HEIGHT, w, 3), _LABEL_BG, np.float32)
    out[:h] = tile
    buf = oiio.ImageBuf(out)
    # The label is an annotation: no text on a failing font is better than no sheet.
    oiio.ImageBufAlgo.render_text(buf, 6, h + LABEL_HEIGHT - 8, text, 15, "", (0.95, 0.95, 0.95))
    return buf.get_pixels(oiio.FLOAT)


def sheet_colorspace(config: ColorConfig, display: str) -> str:
    """The display colour space of a sheet for ``display`` (that of its default view)."""
    return config.display_colorspace(display, config.oiio.getDefaultViewName(display))


def _srgb_colorspace(config: ColorConfig) -> str:
    """The config's sRGB display colour space (cICP 1, 13), which the operator tiles are in."""
    for d in config.displays():
        cs = sheet_colorspace(config, d)
        if config.cicp(cs) == SRGB_CICP:
            return cs
    raise ColorError(f"the OCIO config {config.path} has no sRGB display to convert the "
                     "operator tiles of the contact sheet from; choose an sRGB --display")


def contact_sheet(rgb, ws: WorkingSpace, config: ColorConfig, *, exposure: float = 0.0,
                  white: float | None = None, display: str | None = None,
                  look: str | None = None, operators=None,
                  views=None) -> tuple[np.ndarray, list[str]]:
    """Build the sheet: (H, W, 3) float32 encoded for ``display``'s colour space
    (:func:`sheet_colorspace`; sRGB by default) and the tile labels in order.

    Parameters
    ----------
    rgb : (H, W, 3) array
        Scene-linear frame in working space ``ws``.
    display : str, optional
        The SDR display whose views are shown (the config's default).
    look : str, optional
        OCIO look(s) applied in the views.
    operators, views : sequence of str, optional
        Subsets to show (all operators; every view of ``display`` but ``Raw``).
    """
    display, _, looks = config.check_display_view(display, None, look)
    target = sheet_colorspace(config, display)
    source = target if config.cicp(target) == SRGB_CICP else _srgb_colorspace(config)
    small = _resize(np.asarray(rgb, np.float32), TILE_WIDTH)
    matrix = config.working_to_rec709(ws)
    tiles, labels = [], []
    for name in operators or tonemap.operator_names():
        dt = DisplayTransform(name, exposure=exposure, white=white, matrix=matrix)
        tile = apply_display_transform(small, dt)
        tiles.append(tile if source == target else config.convert(tile, source, target))
        labels.append(f"{dt.operator}")
    if views is None:
        views = [v for v in config.views(display) if v.lower() != "raw"]
    for view in views:
        tiles.append(config.display_view(small, ws, display, view, looks, exposure=exposure))
        labels.append(f"{view}")
    th, tw, _ = small.shape
    cols = min(COLUMNS, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    cell_h, cell_w = th + LABEL_HEIGHT + GAP, tw + GAP
    sheet = np.zeros((rows * cell_h + GAP, cols * cell_w + GAP, 3), np.float32)
    for k, (tile, text) in enumerate(zip(tiles, labels)):
        r, c = divmod(k, cols)
        y, x = GAP + r * cell_h, GAP + c * cell_w
        sheet[y:y + th + LABEL_HEIGHT, x:x + tw] = _label(np.clip(tile, 0, 1), text)
    return sheet, labels


def write_contact_sheet(path, rgb, ws: WorkingSpace, config: ColorConfig, **kwargs) -> list[str]:
    """Write :func:`contact_sheet` as an 8-bit PNG; return the labels.

    The sheet is encoded for ``display`` (default: the config's default display,
    sRGB in the built-in config) and tagged with its colour space and cICP.
    """
    sheet, labels = contact_sheet(rgb, ws, config, **kwargs)
    display, _, _ = config.check_display_view(kwargs.get("display"), None)
    cs = sheet_colorspace(config, display)
    write_sdr(path, sheet, bits=8, dither=True, colorspace=config.interop_id(cs), cicp=config.cicp(cs))
    return labels

"""A contact sheet: one frame through every tone-mapping operator and OCIO view.

For people who would rather look than read: a PNG grid of labelled tiles, the
same scene-linear frame through each operator of :mod:`clphong.tonemap` (the
device's display transform, sRGB-encoded) and through each view of the SDR
display (OCIO), at the same exposure.
"""

from __future__ import annotations

import math

import numpy as np

from . import tonemap
from .color import SRGB_CICP, ColorConfig, WorkingSpace
from .display import DisplayTransform, apply_display_transform
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


def contact_sheet(rgb, ws: WorkingSpace, config: ColorConfig, *, exposure: float = 0.0,
                  white: float | None = None, display: str | None = None,
                  operators=None, views=None) -> tuple[np.ndarray, list[str]]:
    """Build the sheet: sRGB-encoded (H, W, 3) float32 and the tile labels in order.

    Parameters
    ----------
    rgb : (H, W, 3) array
        Scene-linear frame in working space ``ws``.
    display : str, optional
        The SDR display whose views are shown (the config's default).
    operators, views : sequence of str, optional
        Subsets to show (all operators; every view of ``display`` but ``Raw``).
    """
    display, _, _ = config.check_display_view(display, None)
    small = _resize(np.asarray(rgb, np.float32), TILE_WIDTH)
    matrix = config.working_to_rec709(ws)
    tiles, labels = [], []
    for name in operators or tonemap.operator_names():
        dt = DisplayTransform(name, exposure=exposure, white=white, matrix=matrix)
        tiles.append(apply_display_transform(small, dt))
        labels.append(f"{dt.operator}")
    if views is None:
        views = [v for v in config.views(display) if v.lower() != "raw"]
    for view in views:
        tiles.append(config.display_view(small, ws, display, view, exposure=exposure))
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
    """Write :func:`contact_sheet` as an 8-bit sRGB PNG; return the labels.

    The views are encoded for ``display`` (default: the config's default display,
    sRGB in the built-in config); the sheet is tagged as sRGB.
    """
    sheet, labels = contact_sheet(rgb, ws, config, **kwargs)
    write_sdr(path, sheet, bits=8, dither=True, colorspace="srgb_rec709_display",
              cicp=SRGB_CICP)
    return labels

"""Colour management: OCIO configs, working spaces, display/view/look transforms.

Everything goes through OpenColorIO as OpenImageIO embeds it
(``import OpenImageIO as oiio``):

* :func:`load_config` opens the built-in ``ocio://default`` config (which
  carries the ACES 2.0 SDR and HDR views), the user's ``$OCIO``, or an explicit
  path (``--ocio-config``). OpenImageIO silently falls back to a minimal
  built-in config when a config does not load; that is detected and is an error.
* The working colour space is ``lin_rec709`` (linear Rec.709/sRGB primaries,
  D65; the default) or ``acescg`` (ACES AP1, ACES white). Albedo, light colours
  and the scene-linear EXR are in it. Every buffer handed to OCIO is tagged
  with it explicitly: OpenImageIO treats an untagged buffer as the config's
  ``scene_linear`` role, which is ACEScg in the built-in config.
* :func:`display_view` applies ``ImageBufAlgo.ociodisplay`` (display, view and
  looks, as ``oiiotool --ociodisplay``) after exposure.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass

import numpy as np

from ..core.errors import ClphongError
from ..model.options import check_exposure

__all__ = [
    "ColorError", "WorkingSpace", "WORKING_SPACES", "working_space", "ColorConfig",
    "load_config", "DEFAULT_CONFIG", "HDR_DISPLAY", "HDR_VIEW", "PQ_CICP", "SRGB_CICP",
    "SRGB_DISPLAY_INTEROP",
]

#: The config used when neither --ocio-config nor $OCIO is given.
DEFAULT_CONFIG = "ocio://default"
#: The HDR output: Rec.2100 PQ through the ACES 2.0 1000-nit view of the built-in config.
HDR_DISPLAY = "Rec.2100-PQ - Display"
HDR_VIEW = "ACES 2.0 - HDR 1000 nits (Rec.2020)"
#: cICP of a Rec.2100 PQ RGB PNG: BT.2020 primaries (9), PQ (16), identity matrix (0,
#: the PNG spec requires it for RGB), full range (1). ITU-T H.273.
PQ_CICP = (9, 16, 0, 1)
#: cICP of sRGB: BT.709 primaries (1), IEC 61966-2-1 transfer (13), RGB, full range.
SRGB_CICP = (1, 13, 0, 1)
#: The colour interop ID of sRGB display-referred images (``oiio:ColorSpace`` of
#: the SDR output without an OCIO view; the only space a TIFF output may carry).
SRGB_DISPLAY_INTEROP = "srgb_rec709_display"


class ColorError(ClphongError):
    """An OCIO config that does not load, or an unknown display, view, look or space."""


@dataclass(frozen=True)
class WorkingSpace:
    """A scene-linear working colour space.

    Attributes
    ----------
    name : str
        clphong's name (scene key ``render.working_space``).
    interop_id : str
        The OCIO/OpenImageIO colour interop ID written as ``oiio:ColorSpace``.
    ocio_names : tuple of str
        Names and aliases under which configs carry it (the first found is used).
    chromaticities : tuple of 8 float
        xy of R, G, B and white (the EXR ``chromaticities`` attribute).
    """

    name: str
    interop_id: str
    ocio_names: tuple[str, ...]
    chromaticities: tuple[float, ...]
    description: str


#: Rec. ITU-R BT.709-6 primaries, D65 white.
REC709_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: ACES AP1 primaries and the ACES white point (SMPTE ST 2065-1, S-2014-004).
AP1_CHROMATICITIES = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)

WORKING_SPACES: dict[str, WorkingSpace] = {
    "lin_rec709": WorkingSpace("lin_rec709", "lin_rec709_scene",
                               ("lin_rec709_scene", "lin_rec709", "Linear Rec.709 (sRGB)"),
                               REC709_CHROMATICITIES, "linear Rec.709/sRGB primaries, D65"),
    "acescg": WorkingSpace("acescg", "lin_ap1_scene", ("lin_ap1_scene", "ACEScg", "lin_ap1"),
                           AP1_CHROMATICITIES, "ACEScg: linear AP1 primaries, ACES white"),
}


def working_space(name: str) -> WorkingSpace:
    """The working space called ``name``; a bad name lists the valid ones."""
    key = str(name).strip().lower()
    if key in WORKING_SPACES:
        return WORKING_SPACES[key]
    raise ColorError(f"unknown working colour space {name!r}; valid: "
                     + ", ".join(repr(k) for k in WORKING_SPACES))


def _oiio():
    import OpenImageIO as oiio

    return oiio


def _one_line(text: str) -> str:
    return "; ".join(p.strip() for p in str(text).splitlines() if p.strip())


def _suggest(name: str, valid) -> str:
    close = difflib.get_close_matches(name, list(valid), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


class ColorConfig:
    """An OCIO config loaded through OpenImageIO, checked to be the one asked for.

    Use :func:`load_config` to make one.
    """

    def __init__(self, path: str, source: str):
        oiio = _oiio()
        self.path = path
        self.source = source
        self.oiio = oiio.ColorConfig(path)
        error = self.oiio.geterror()
        # OpenImageIO keeps going with a minimal built-in config named "built-in"
        # when the requested one does not load: treat that as the error it is.
        if error or (self.oiio.configname() == "built-in" and path != "built-in"):
            raise ColorError(f"{path}: OCIO config ({source}) does not load: "
                             f"{_one_line(error) or 'OpenImageIO fell back to its built-in config'}")

    # -- listing ----------------------------------------------------------

    def displays(self) -> list[str]:
        return list(self.oiio.getDisplayNames())

    def views(self, display: str) -> list[str]:
        return list(self.oiio.getViewNames(display))

    def looks(self) -> list[str]:
        return list(self.oiio.getLookNames())

    def default_display(self) -> str:
        return self.oiio.getDefaultDisplayName()

    def describe(self) -> str:
        """Displays with their views (default first, marked), and looks: for ``clphong displays``."""
        lines = [f"OCIO config: {self.path} ({self.source})"]
        default = self.default_display()
        for d in self.displays():
            mark = "  (default)" if d == default else ""
            lines.append(f"display {d!r}{mark}")
            dv = self.oiio.getDefaultViewName(d)
            for v in self.views(d):
                lines.append(f"    view {v!r}" + ("  (default)" if v == dv else ""))
        looks = self.looks()
        lines.append("looks: " + (", ".join(repr(x) for x in looks) if looks else "none"))
        return "\n".join(lines)

    # -- names ------------------------------------------------------------

    def space_name(self, ws: WorkingSpace) -> str:
        """The config's name of working space ``ws``; an error if it has none."""
        names = set(self.oiio.getColorSpaceNames())
        for n in ws.ocio_names:
            resolved = self.oiio.resolve(n)
            if n in names or resolved in names:
                return resolved if resolved in names else n
        raise ColorError(f"{self.path}: the OCIO config has no colour space for the working "
                         f"space {ws.name!r} (looked for {', '.join(ws.ocio_names)})")

    def check_display_view(self, display: str | None, view: str | None,
                           looks: str | None = None) -> tuple[str, str, str]:
        """Resolve defaults and check names: (display, view, looks)."""
        displays = self.displays()
        display = display or self.default_display()
        if display not in displays:
            raise ColorError(f"display {display!r} is not in the OCIO config {self.path}; "
                             f"displays: {', '.join(repr(d) for d in displays)}"
                             f"{_suggest(display, displays)}")
        views = self.views(display)
        view = view or self.oiio.getDefaultViewName(display)
        if view not in views:
            raise ColorError(f"view {view!r} is not a view of display {display!r} in {self.path}; "
                             f"views: {', '.join(repr(v) for v in views)}{_suggest(view, views)}")
        looks = looks or ""
        valid = self.looks()
        for look in (x.strip().lstrip("+-") for x in looks.split(",") if x.strip()):
            if look not in valid:
                raise ColorError(f"look {look!r} is not in the OCIO config {self.path}; looks: "
                                 + (", ".join(repr(x) for x in valid) or "none")
                                 + _suggest(look, valid))
        return display, view, looks

    def check_colorspace(self, name: str, origin: str = "colour space") -> str:
        """``name`` resolved to a colour space of the config (roles and aliases
        included); a one-line ColorError naming ``origin`` if it has none."""
        names = list(self.oiio.getColorSpaceNames())
        resolved = self.oiio.resolve(name)
        if name in names or resolved in names:
            return resolved if resolved in names else name
        raise ColorError(f"{origin}: {name!r} is not a colour space of the OCIO config "
                         f"{self.path}{_suggest(name, names)} (see 'clphong displays')")

    def display_colorspace(self, display: str, view: str) -> str:
        """The display colour space a (display, view) encodes to (for the file's tag)."""
        return self.oiio.getDisplayViewColorSpaceName(display, view) or display

    def cicp(self, colorspace: str) -> tuple[int, int, int, int] | None:
        """cICP of a display colour space for an RGB file (matrix coefficients 0)."""
        c = self.oiio.get_cicp(colorspace)
        if not c:
            return None
        return (int(c[0]), int(c[1]), 0, int(c[3]))

    def interop_id(self, colorspace: str) -> str:
        return self.oiio.get_color_interop_id(colorspace) or colorspace

    # -- transforms -------------------------------------------------------

    def _buf(self, rgb: np.ndarray, space: str):
        oiio = _oiio()
        buf = oiio.ImageBuf(np.ascontiguousarray(rgb, np.float32))
        buf.specmod().attribute("oiio:ColorSpace", space)   # explicit tag, never the role
        return buf

    def convert(self, rgb, from_space: str, to_space: str) -> np.ndarray:
        """``ImageBufAlgo.colorconvert`` of (H, W, 3) float32, tagged explicitly."""
        oiio = _oiio()
        out = oiio.ImageBufAlgo.colorconvert(self._buf(rgb, from_space), from_space, to_space,
                                             unpremult=False, colorconfig=self.path)
        if out.has_error:
            raise ColorError(f"colour conversion {from_space!r} -> {to_space!r} failed: "
                             f"{_one_line(out.geterror())}")
        return out.get_pixels(oiio.FLOAT)

    def matrix(self, from_space: str, to_space: str) -> np.ndarray:
        """The 3×3 matrix of a linear conversion, read off OCIO by converting the unit vectors.

        Raises
        ------
        ColorError
            If the conversion is not linear (checked on a fourth colour).
        """
        probe = np.array([[[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.25, 2.0, 0.5]]], np.float32)
        out = self.convert(probe, from_space, to_space)[0].astype(np.float64)
        m = out[:3].T
        if not np.allclose(m @ probe[0, 3], out[3], rtol=1e-5, atol=1e-6):
            raise ColorError(f"{from_space!r} -> {to_space!r} is not a linear transform")
        return m

    def working_to_rec709(self, ws: WorkingSpace) -> np.ndarray | None:
        """Working space → linear Rec.709 matrix (None for lin_rec709)."""
        if ws.name == "lin_rec709":
            return None
        return self.matrix(self.space_name(ws), self.space_name(WORKING_SPACES["lin_rec709"]))

    def display_view(self, rgb, ws: WorkingSpace, display: str | None, view: str | None,
                     looks: str | None = None, exposure: float = 0.0) -> np.ndarray:
        """Scene-linear ``rgb`` (working space ``ws``) through exposure and an OCIO view.

        Returns
        -------
        numpy.ndarray
            (H, W, 3) float32 display-encoded values (not clipped).
        """
        oiio = _oiio()
        display, view, looks = self.check_display_view(display, view, looks)
        exposure = check_exposure(exposure)      # the one rule of every display output
        rgb = np.asarray(rgb, np.float32)
        if exposure:
            rgb = rgb * np.float32(2.0 ** exposure)
        src_space = self.space_name(ws)
        out = oiio.ImageBufAlgo.ociodisplay(self._buf(rgb, src_space), display, view,
                                            fromspace=src_space, looks=looks, unpremult=False,
                                            colorconfig=self.path)
        if out.has_error:
            raise ColorError(f"OCIO display {display!r} view {view!r} failed: "
                             f"{_one_line(out.geterror())}")
        return out.get_pixels(oiio.FLOAT)


def load_config(path: str | os.PathLike | None = None) -> ColorConfig:
    """Open an OCIO config: ``path``, else ``$OCIO``, else ``ocio://default``.

    Raises
    ------
    ColorError
        One line naming the config and why it does not load (a missing file, a
        YAML error, an unknown ``ocio://`` name), instead of OpenImageIO's
        silent fallback to a minimal built-in config.
    """
    if path is not None:
        path, source = os.fspath(path), "--ocio-config"
    elif os.environ.get("OCIO"):
        path, source = os.environ["OCIO"], "$OCIO"
    else:
        path, source = DEFAULT_CONFIG, "built-in default"
    if not path.startswith("ocio://") and not os.path.isfile(path):
        raise ColorError(f"{path}: OCIO config ({source}) does not exist or is not a file")
    return ColorConfig(path, source)

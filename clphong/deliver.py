"""Display outputs of one frame: SDR, HDR and the contact sheet, in one run.

:func:`render_outputs` shades a G-buffer once and writes every display output
asked for, choosing the path for each:

* SDR without an OCIO display, view or look: exposure, the tone-mapping
  operator and sRGB encoding run fused in the shading kernel's store
  (:func:`clphong.display.render_display`), no round trip through the host;
* SDR with a display/view/look: scene-linear → ``ImageBufAlgo.ociodisplay``
  (the view does the tone mapping, as in oiiotool, Blender and Nuke);
* HDR: Rec.2100 PQ through the 1000-nit view (``HDR_DISPLAY``/``HDR_VIEW``);
* contact sheet: every operator and every view of the SDR display.

The scene-linear EXR is written by the caller (``clphong.api.write_output``)
with :func:`exr_attributes` of the working space.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import color, tonemap
from .display import DisplayTransform, render_display
from .writers import write_hdr, write_sdr

__all__ = ["OutputRequest", "render_outputs", "exr_attributes"]


def exr_attributes(working_space: str) -> dict:
    """Header tags of a scene-linear EXR in ``working_space``: chromaticities and colour space."""
    ws = color.working_space(working_space)
    return {"chromaticities": ws.chromaticities, "oiio:ColorSpace": ws.interop_id}


@dataclass
class OutputRequest:
    """What to write and how (CLI options override the scene's ``[render]`` keys)."""

    sdr: list[str] = field(default_factory=list)
    hdr: list[str] = field(default_factory=list)
    contact_sheet: str | None = None
    bits: int = 8
    dither: bool = True
    working_space: str = "lin_rec709"
    exposure: float = 0.0
    tonemap: str = "none"
    white: float | None = None
    display: str | None = None
    view: str | None = None
    look: str | None = None
    hdr_view: str = color.HDR_VIEW
    ocio_config: str | None = None

    @classmethod
    def from_scene(cls, scene, **overrides) -> "OutputRequest":
        c = scene.color
        req = cls(working_space=c.working_space, exposure=c.exposure, tonemap=c.tonemap,
                  white=c.white_point, display=c.display, view=c.view, look=c.look)
        for k, v in overrides.items():
            if v is not None:
                setattr(req, k, v)
        return req

    @property
    def ocio_view(self) -> bool:
        """Whether SDR goes through an OCIO view (any of display, view, look given)."""
        return bool(self.display or self.view or self.look)

    def check(self) -> None:
        """Validate names before any work; raises ToneMapError / ColorError."""
        op = tonemap.operator(self.tonemap)
        self.tonemap = op.name
        color.working_space(self.working_space)
        if self.ocio_view and op.name != "none" and self.sdr:
            raise color.ColorError(
                f"tone-mapping operator {op.name!r} and an OCIO view both tone-map; give "
                "--tonemap without --display/--view/--look (fused in the kernel), or a view alone")


def render_outputs(renderer, gbuffer, req: OutputRequest) -> tuple[np.ndarray, dict[str, float]]:
    """Shade ``gbuffer`` once and write every SDR/HDR/contact-sheet output of ``req``.

    Returns
    -------
    (numpy.ndarray, dict)
        The scene-linear (H, W, 3) float32 frame, and seconds spent per output
        kind (tone mapping + encoding + writing; the fused SDR path's tone
        mapping is inside the shading launch and is not separable).
    """
    req.check()
    ws = color.working_space(req.working_space)
    needs_config = (req.hdr or req.contact_sheet or req.ocio_view or ws.name != "lin_rec709")
    cfg = color.load_config(req.ocio_config) if needs_config else None
    if cfg is not None:
        if req.ocio_view:
            cfg.check_display_view(req.display, req.view, req.look)
        if req.hdr:
            cfg.check_display_view(color.HDR_DISPLAY, req.hdr_view, req.look)
    times: dict[str, float] = {}
    matrix = cfg.working_to_rec709(ws) if cfg is not None else None
    if req.sdr and not req.ocio_view:
        dt = DisplayTransform(req.tonemap, exposure=req.exposure, white=req.white, matrix=matrix)
        rgb, shown = render_display(renderer, gbuffer, dt)
        t0 = time.perf_counter()
        for path in req.sdr:
            write_sdr(path, shown, bits=req.bits, dither=req.dither,
                      colorspace="srgb_rec709_display", cicp=color.SRGB_CICP)
        times["sdr"] = time.perf_counter() - t0
    else:
        rgb = renderer.render(gbuffer)
    if req.sdr and req.ocio_view:
        t0 = time.perf_counter()
        display, view, looks = cfg.check_display_view(req.display, req.view, req.look)
        shown = cfg.display_view(rgb, ws, display, view, looks, exposure=req.exposure)
        space = cfg.display_colorspace(display, view)
        for path in req.sdr:
            write_sdr(path, shown, bits=req.bits, dither=req.dither,
                      colorspace=cfg.interop_id(space), cicp=cfg.cicp(space))
        times["sdr"] = time.perf_counter() - t0
    if req.hdr:
        t0 = time.perf_counter()
        pq = cfg.display_view(rgb, ws, color.HDR_DISPLAY, req.hdr_view, req.look,
                              exposure=req.exposure)
        space = cfg.display_colorspace(color.HDR_DISPLAY, req.hdr_view)
        for path in req.hdr:
            write_hdr(path, pq, colorspace=cfg.interop_id(space), cicp=color.PQ_CICP)
        times["hdr"] = time.perf_counter() - t0
    if req.contact_sheet:
        from .contact import write_contact_sheet

        t0 = time.perf_counter()
        write_contact_sheet(req.contact_sheet, rgb, ws, cfg, exposure=req.exposure,
                            white=req.white)
        times["contact_sheet"] = time.perf_counter() - t0
    return rgb, times

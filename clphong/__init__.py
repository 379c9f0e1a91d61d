"""clphong: OpenCL image-space deferred Phong shading of EXR G-buffers.

The Python API and the ``clphong`` command go through the same functions::

    import clphong
    scene = clphong.load_scene("gbuffers/spheres.toml")
    gbuffer = clphong.read_gbuffer("gbuffers/spheres.exr")
    rgb = clphong.render(scene, gbuffer)          # (H, W, 3) float32, scene-linear
    clphong.write_output(rgb, "spheres.exr")      # tagged: chromaticities, colour space

:func:`render` and :class:`Relighter` resolve environment lights into directional
lights first (``env_error``, default 1e-3 relative); :class:`Renderer` takes a
scene without them. :class:`Renderer` compiles once and shades many frames; :class:`Relighter`
(the pipeline-stage API) adds file and numpy input, output writing and the
camera from EXR metadata, and is what the CLI uses.
"""

from .core.errors import (
    ClphongError,
    DeviceError,
    GBufferError,
    OutputError,
    SceneError,
)
from .device.plan import ShadingPlan, make_plan
from .device.renderer import Renderer, RenderResult
from .io.atomic import write_exr
from .io.gbuffer import GBuffer, read_gbuffer
from .model.scene import Scene, load_scene, parse_scene
from .pipeline.relighter import OutputOptions, Relighter, render, write_output

__version__ = "0.1.0"

__all__ = [
    "ClphongError", "DeviceError", "GBufferError", "OutputError", "SceneError",
    "GBuffer", "read_gbuffer", "write_exr", "ShadingPlan", "make_plan",
    "Renderer", "RenderResult", "render", "Scene", "load_scene", "parse_scene", "__version__",
    "Relighter", "OutputOptions", "write_output",
]

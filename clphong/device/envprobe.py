"""An environment conversion's probe pixels on an OpenCL device (issue 25: the conversion).

:func:`clphong.model.environment.environment_lights` estimates its error from the pixel
values of a few thousand probes (a normal and a view each) lit by a tree's lights, again
and again as its search moves; :func:`~clphong.model.environment.probe_pixels` forms
them in float64 numpy, about 12 ns a probe-light pair on one core. Here the same pixels
come from the shading kernel itself: the probes are a one-row G-buffer (normal n, white
albedo, position −v before an eye at the origin, so the kernel's v is the probe's), the
lights are directional lights (and no ambient light, so no ambient term), the material
is the scene's, on the accurate path. Its relative error is within the accurate path's
5e-6 target (tests/device/test_envprobe.py), far below the estimates' 1e-3. The probes'
directions are the float32 roundings of the numpy ones: that moves the estimates by
about 1e-4 of themselves (the sample sky, 1024 × 512, at 1e-3: 7.0562e-4 against
7.0569e-4), and the search ended on the same 10,808 lights.

Measured on 2 Ice Lake cores (Intel's runtime, 16 lanes): 2,048 probes × 43,232 lights
in 0.12 s against 0.99 s in numpy (two threads).
"""

from __future__ import annotations

import threading

import numpy as np

from ..io.gbuffer import GBuffer
from ..model.scene import Camera, directional_scene
from .frame import prepare_frame
from .renderer import Renderer

__all__ = ["DeviceProbeShader"]


class DeviceProbeShader:
    """``shade(n, v, l, radiance, material, albedo=None)`` → (P, 3) float64 on an OpenCL
    device, with the meaning of :func:`clphong.model.environment.probe_pixels` (``device`` as
    :class:`~clphong.device.renderer.Renderer` takes it; None: the default device).

    ``key`` names it in the conversion caches. It does not name the device: every
    conformant device shades the same float32 probes within the accurate path's 5e-6,
    so a conversion made on one serves another; and reading the key starts nothing (a
    map that cannot be read is refused before a device is opened)."""

    key = "opencl probes, float32 directions"

    def __init__(self, device: str | None = None):
        self.device = device
        self._frame = None            # ((probes, lanes), Frame): the search reuses it
        self._lock = threading.Lock() # a Relighter's frames may convert in two threads at once

    def __call__(self, n, v, l, radiance, material, albedo=None) -> np.ndarray:
        with self._lock:
            return np.asarray(self._shade(n, v, l, radiance, material, albedo).image,
                              np.float64).reshape(-1, 3)

    def terms(self, n, v, l, radiance, material) -> np.ndarray:
        """(P, 6): the probes' diffuse and specular terms apart at white albedo, as
        :func:`clphong.model.environment.probe_terms`: the kernel's diffuse and specular
        layers of one launch."""
        with self._lock:
            r = self._shade(n, v, l, radiance, material, None, aovs=("diffuse", "specular"))
        return np.concatenate([np.asarray(r.layers[k], np.float64).reshape(-1, 3)
                               for k in ("diffuse", "specular")], axis=1)

    def _shade(self, n, v, l, radiance, material, albedo, aovs=()):
        n = np.asarray(n, np.float64)
        v = np.asarray(v, np.float64)
        a = (np.ones((len(n), 3), np.float32) if albedo is None
             else np.asarray(albedo, np.float32).reshape(-1, 3))
        # columns, not a Light object a light (scene.directional_scene: the same scene)
        scene = directional_scene(Camera(type="perspective", position=(0.0, 0.0, 0.0)),
                                  material, l, radiance, source="environment probes")
        # no directional lists: a tile's 16 probes face every way, so the lists keep
        # nearly every light and cost their build (the conversion of the 1024 × 512 sky
        # with spheres_sky's material: 3.56-3.86 s without them, 4.18-4.24 s with them;
        # the same lights and estimates)
        r = Renderer(scene, device=self.device, path="accurate", light_tree=False,
                     dir_lists=False, aovs=aovs)
        key = (n.tobytes(), v.tobytes(), a.tobytes(), r.lanes)
        if self._frame is None or self._frame[0] != key:
            P = len(n)
            gb = GBuffer(position=(-v).astype(np.float32).reshape(1, P, 3),
                         normal=n.astype(np.float32).reshape(1, P, 3),
                         albedo=a.reshape(1, P, 3))
            self._frame = (key, prepare_frame(gb, lanes=r.lanes))
        return r.shade(self._frame[1])

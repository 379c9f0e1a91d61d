"""The exact texel sum of environment lights: the oracle of their error.

An environment light means the limit of directional lights: each texel is a
directional light from its direction with radiance = texel radiance x solid
angle x intensity (:func:`clphong.model.environment.texel_lights`). This module
shades exactly that, every texel, in float64, on the pixels of a G-buffer (a
sample of them, :func:`clphong.tools.bench.sub_gbuffer`, for speed: about 16 ns
a pixel-texel pair, 8.6 s for 1000 pixels of a 1024 x 512 map, on one core).

Two ways, the same sum:

``method="reference"``
    Through :func:`clphong.reference.shading.shade` itself, on scenes whose
    lights are chunks of texels as directional lights: the same code as every
    other error figure, every material option included (about 180 ns a pair).
``method="fast"``
    Matrix products of the dot products and the model's terms on them
    (:func:`clphong.model.environment.probe_sums`) with the pixels' inputs from
    :mod:`clphong.reference.shading` (unit normals, views, C·k_d, k_s·C_s);
    where it applies: no shininess map and no Fresnel. ``"auto"`` (default)
    takes it there. tests/reference/test_environment.py holds the two together.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..io.envmap import environment_key, read_envmap
from ..model.env_table import env_table_coords, env_table_lookup
from ..model.environment import probe_sums, texel_lights
from ..model.scene import Light
from . import shading

__all__ = ["texel_sum", "environment_texel_sum", "texel_terms", "without_environment", "METHODS",
           "table_terms"]

#: The ways of :func:`texel_sum`.
METHODS = ("auto", "fast", "reference")
#: Texels a chunk of the reference method.
REFERENCE_CHUNK = 4096


def without_environment(scene):
    """``scene`` with its environment lights removed (everything else as it is)."""
    return dataclasses.replace(scene, lights=tuple(lt for lt in scene.lights if lt.type != "environment"))


def _fast_applies(scene, gbuffer) -> bool:
    return "h" not in gbuffer.maps and scene.material.fresnel == "none"


def _texels_fast(scene, gbuffer, l, E):
    px, C, D, S, fg = shading._inputs(scene, gbuffer)
    diffuse, specular = probe_sums(px.n, px.v, l, E, scene.material, specular=px.specular)
    return D * diffuse + S * specular, fg


def _texels_reference(scene, gbuffer, l, E, chunk: int = REFERENCE_CHUNK):
    bare = dataclasses.replace(scene, background=(0.0, 0.0, 0.0))
    fg = ~gbuffer.background_mask().reshape(-1)
    straight = dataclasses.replace(gbuffer, coverage=None if gbuffer.coverage is None
                                   else np.where(np.asarray(gbuffer.coverage) > 0, np.float32(1),
                                                 np.float32(0)))
    total = np.zeros((int(fg.sum()), 3))
    for a in range(0, len(l), chunk):
        lights = tuple(Light(type="directional", color=(float(e[0]), float(e[1]), float(e[2])),
                             intensity=1.0, direction=(float(-x[0]), float(-x[1]), float(-x[2])))
                       for x, e in zip(l[a:a + chunk], E[a:a + chunk]))
        img = shading.shade(dataclasses.replace(bare, lights=lights), straight)
        total += img.reshape(-1, 3)[fg]
    return total, fg


def environment_texel_sum(scene, gbuffer, radiance, *, rotation: float = 0.0,
                          intensity: float = 1.0, method: str = "auto") -> np.ndarray:
    """One environment map's light alone, every texel a directional light: (H·W, 3)
    float64 rows, 0 on background pixels, straight (before coverage).

    ``scene`` gives the camera and the material (its lights are ignored);
    ``radiance`` is the (H, W, 3) map.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, not {method!r}")
    fast = method == "fast" or (method == "auto" and _fast_applies(scene, gbuffer))
    if fast and not _fast_applies(scene, gbuffer):
        raise ValueError("the fast texel sum has no shininess map and no Fresnel; use "
                         "method='reference'")
    l, E = texel_lights(radiance, rotation=rotation, intensity=intensity)
    keep = E.max(axis=1) > 0                        # black texels add exactly 0
    add, fg = (_texels_fast if fast else _texels_reference)(scene, gbuffer, l[keep], E[keep])
    H, W = gbuffer.shape
    out = np.zeros((H * W, 3))
    out[fg] = add
    return out


def texel_terms(scene, gbuffer, l, radiance):
    """(C·k_d·diffuse, k_s·C_s·specular), (M, 3) each on the shaded pixels, of the
    directional lights ``l`` (towards them), ``radiance`` ((K, 3)): the two terms
    apart (no shininess map, no Fresnel), to say which one an error comes from."""
    if not _fast_applies(scene, gbuffer):
        raise ValueError("the terms apart need no shininess map and no Fresnel")
    px, C, D, S, fg = shading._inputs(scene, gbuffer)
    diffuse, specular = probe_sums(px.n, px.v, l, radiance, scene.material, specular=px.specular)
    return D * diffuse, S * specular


def texel_sum(scene, gbuffer, *, method: str = "auto") -> np.ndarray:
    """The scene shaded with every texel of its environment lights as a directional light.

    Parameters
    ----------
    scene : Scene
        With environment lights (unresolved); its other lights are shaded by
        :func:`clphong.reference.shading.shade` as usual.
    gbuffer : GBuffer
        Usually a pixel sample (``tools.bench.sub_gbuffer``).
    method : {"auto", "fast", "reference"}
        See the module docstring.

    Returns
    -------
    (H, W, 3) float64
        What :func:`clphong.reference.shading.shade` would give for the scene
        with every texel as a light (coverage applied as it applies it).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, not {method!r}")
    out = shading.shade(without_environment(scene), gbuffer).reshape(-1, 3).copy()
    a = shading.partial_coverage(gbuffer)
    for i, lt in enumerate(scene.lights):
        if lt.type != "environment":
            continue
        L = read_envmap(lt.file, environment_key(scene, i))
        add = environment_texel_sum(scene, gbuffer, L, rotation=lt.rotation,
                                    intensity=lt.intensity, method=method)
        out += add if a is None else add * a[:, None]
    H, W = gbuffer.shape
    return out.reshape(H, W, 3)


def table_terms(scene, gbuffer, tables):
    """(C·k_d·diffuse, k_s·C_s·specular), (M, 3) each on the shaded pixels: shade.cl's
    ENV_TABLE block in float64 (kernels/include/envtable.h), ``tables`` an
    :class:`clphong.model.env_table.EnvTables`: E(n) and T(R), R = 2(n·v)n − v, by the
    kernel's own coordinates and cubic look-ups (:func:`env_table_coords`,
    :func:`env_table_lookup`) on the same tables, plus its sun as directional lights
    (:func:`texel_terms`). No shininess map (the table holds one h); Phong's Fresnel W
    in k_s·C_s as the kernel has it."""
    if "h" in gbuffer.maps:
        raise ValueError("the tables hold one exponent: no shininess map")
    px, C, D, S, fg = shading._inputs(scene, gbuffer)
    rot = np.radians(tables.rotation % 360.0)
    d_t = tables.diffuse
    E = env_table_lookup(d_t.values, *env_table_coords(px.n, rot, d_t.rows, d_t.cols))
    diffuse = D * E
    specular = np.zeros_like(diffuse)
    if px.specular and tables.specular is not None:
        s_t = tables.specular
        R = 2.0 * np.einsum("ij,ij->i", px.n, px.v)[:, None] * px.n - px.v
        specular = S * env_table_lookup(s_t.values, *env_table_coords(R, rot, s_t.rows, s_t.cols))
    if len(tables.sun_l):
        # S holds Phong's Fresnel W (one a pixel): the sums without it
        plain = dataclasses.replace(scene.material, fresnel="none", f0=None)
        sd, ss = probe_sums(px.n, px.v, tables.sun_l, tables.sun_radiance, plain,
                            specular=px.specular)
        diffuse = diffuse + D * sd
        specular = specular + S * ss
    return diffuse, specular

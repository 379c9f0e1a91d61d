"""Generator of the sample G-buffers in ``gbuffers/``.

Both samples are ray-cast analytically in float64, so P, N and the albedo are
exact (up to the float32 rounding of the stored file):

``spheres``
    Three spheres on a checkered ground plane through a perspective camera
    (``gbuffers/spheres.exr`` + ``spheres.toml``: point lights, Phong).
``ortho``
    A 3 × 3 grid of spheres seen through an orthographic camera, with
    per-pixel k_s and shininess maps (``gbuffers/ortho.exr`` + ``ortho.toml``:
    directional lights, Blinn-Phong).
``sky``
    A procedural HDR sky, a latitude-longitude environment map in OpenEXR's
    orientation (:func:`sky_envmap`; ``gbuffers/sky.exr``, 256 × 128 half
    floats, lights ``gbuffers/spheres_sky.toml``; ``clphong bench`` shades its
    1024 × 512 version).

Regenerate with ``python -m clphong.tools.samples gbuffers/`` (the sky too). The scene TOMLs are
written by hand; their cameras must equal :data:`SPHERES_CAMERA` and
:data:`ORTHO_CAMERA` (tests/test_gbuffer.py checks both, and that each shipped
EXR holds exactly this module's output).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ..core.errors import OutputError
from ..io.atomic import check_output_path, write_exr
from ..io.gbuffer import GBuffer, write_gbuffer
from ..model.environment import texel_directions
from ..model.scene import parse_scene

SPHERES_CAMERA = dict(type="perspective", position=(0.0, 2.0, 6.0), target=(0.0, 0.5, 0.0),
                      fov_y_degrees=40.0)
ORTHO_CAMERA = dict(type="orthographic", direction=(-1.0, -2.0, -2.0), target=(0.0, 0.0, 0.0),
                    height=5.0)


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _basis(forward):
    f = _normalize(np.asarray(forward, np.float64))
    right = _normalize(np.cross(f, [0.0, 1.0, 0.0]))
    up = np.cross(right, f)
    return f, right, up


def _trace(origins, dirs, spheres, plane_extent, checker):
    """Nearest hit of rays with the spheres and the plane y = 0 (|x|,|z| ≤ extent)."""
    n = len(dirs)
    t_best = np.full(n, np.inf)
    P = np.zeros((n, 3))
    N = np.zeros((n, 3))
    A = np.zeros((n, 3))
    obj = np.full(n, -1)
    for idx, (centre, radius, albedo) in enumerate(spheres):
        oc = origins - np.asarray(centre)
        b = np.einsum("ij,ij->i", oc, dirs)
        c = np.einsum("ij,ij->i", oc, oc) - radius * radius
        disc = b * b - c
        hit = disc > 0
        t = np.where(hit, -b - np.sqrt(np.where(hit, disc, 0.0)), np.inf)
        hit &= (t > 1e-9) & (t < t_best)
        t_best[hit] = t[hit]
        P[hit] = origins[hit] + t[hit, None] * dirs[hit]
        N[hit] = (P[hit] - np.asarray(centre)) / radius
        A[hit] = albedo
        obj[hit] = idx
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origins[:, 1] / dirs[:, 1]
    hit = (dirs[:, 1] < 0) & (t > 1e-9) & (t < t_best)
    q = origins + np.where(hit, t, 0.0)[:, None] * dirs
    hit &= (np.abs(q[:, 0]) <= plane_extent) & (np.abs(q[:, 2]) <= plane_extent)
    P[hit] = q[hit]
    P[hit, 1] = 0.0
    N[hit] = (0.0, 1.0, 0.0)
    cell = (np.floor(q[:, 0]) + np.floor(q[:, 2])).astype(int) & 1
    A[hit] = np.where(cell[hit, None] == 1, checker[0], checker[1])
    obj[hit] = len(spheres)
    return P, N, A, obj


def spheres(width: int = 384, height: int = 256):
    """The perspective sample: (position, normal, albedo, coverage) as float32 arrays."""
    cam = SPHERES_CAMERA
    eye = np.asarray(cam["position"])
    f, right, up = _basis(np.asarray(cam["target"]) - eye)
    tan = np.tan(np.radians(cam["fov_y_degrees"]) / 2)
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    x = (2 * j / width - 1) * tan * width / height
    y = (1 - 2 * i / height) * tan
    dirs = _normalize(f + x[..., None] * right + y[..., None] * up).reshape(-1, 3)
    origins = np.broadcast_to(eye, dirs.shape)
    balls = [((-1.3, 0.6, 0.0), 0.6, (0.80, 0.20, 0.15)),
             ((0.2, 0.8, -0.7), 0.8, (0.20, 0.35, 0.80)),
             ((1.5, 0.4, 0.7), 0.4, (0.25, 0.70, 0.25))]
    P, N, A, obj = _trace(origins, dirs, balls, 6.0, ((0.75, 0.75, 0.72), (0.35, 0.35, 0.33)))
    cov = (obj >= 0).astype(np.float32)
    shp = (height, width, 3)
    return (P.reshape(shp).astype(np.float32), N.reshape(shp).astype(np.float32),
            A.reshape(shp).astype(np.float32), cov.reshape(height, width))


def ortho(width: int = 256, height: int = 256):
    """The orthographic sample: (position, normal, albedo, coverage, maps)."""
    cam = ORTHO_CAMERA
    f, right, up = _basis(cam["direction"])
    half_h = cam["height"] / 2
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    x = (2 * j / width - 1) * half_h * width / height
    y = (1 - 2 * i / height) * half_h
    origins = (np.asarray(cam["target"]) - 20.0 * f + x[..., None] * right
               + y[..., None] * up).reshape(-1, 3)
    dirs = np.broadcast_to(f, origins.shape)
    balls = []
    hues = [(0.85, 0.25, 0.2), (0.9, 0.7, 0.2), (0.3, 0.75, 0.3),
            (0.2, 0.6, 0.85), (0.55, 0.3, 0.8), (0.85, 0.45, 0.65),
            (0.6, 0.6, 0.6), (0.9, 0.9, 0.85), (0.3, 0.3, 0.32)]
    for a in range(3):
        for b in range(3):
            balls.append(((1.2 * (b - 1), 0.45, 1.2 * (a - 1)), 0.45, hues[3 * a + b]))
    P, N, A, obj = _trace(origins, dirs, balls, 2.2, ((0.7, 0.7, 0.7), (0.5, 0.5, 0.5)))
    # Material maps: shininess rises and k_s falls along the grid; the plane is matte.
    k_s = np.where(obj < 0, 0.0, np.where(obj < 9, 0.15 + 0.05 * (obj % 3), 0.0))
    h = np.where((obj >= 0) & (obj < 9), 8.0 * 4.0 ** (obj // 3), 1.0)
    cov = (obj >= 0).astype(np.float32)
    shp = (height, width)
    maps = {"k_s": k_s.reshape(shp).astype(np.float32), "h": h.reshape(shp).astype(np.float32)}
    return (P.reshape(*shp, 3).astype(np.float32), N.reshape(*shp, 3).astype(np.float32),
            A.reshape(*shp, 3).astype(np.float32), cov.reshape(shp), maps)


#: The scene of ``gbuffers/spheres.toml``, as data (a test checks that they agree), so
#: that the spheres sample can be shaded without a source checkout.
SPHERES_SCENE = {
    "camera": {"type": "perspective", "position": [0.0, 2.0, 6.0]},
    "material": {"model": "phong", "k_a": 0.1, "k_d": 0.7, "k_s": 0.2, "h": 32.0},
    "light": [
        {"type": "point", "position": [3.0, 5.0, 4.0], "color": [1.0, 0.9, 0.8],
         "intensity": 5.0, "attenuation": [1.0, 0.0, 0.02]},
        {"type": "point", "position": [-4.0, 3.0, 2.0], "color": [0.6, 0.7, 1.0],
         "intensity": 2.0, "attenuation": [1.0, 0.1, 0.0]},
        {"type": "ambient", "color": [1.0, 1.0, 1.0], "intensity": 1.0},
    ],
}


def spheres_scene():
    """The :class:`~clphong.model.scene.Scene` of ``gbuffers/spheres.toml``, built in memory."""
    return parse_scene(SPHERES_SCENE, source="clphong.tools.samples:spheres")


def spheres_gbuffer(width: int = 384, height: int = 256):
    """The spheres sample as a :class:`~clphong.io.gbuffer.GBuffer`, in memory (no file)."""
    P, N, A, cov = spheres(width, height)
    return GBuffer(position=P, normal=N, albedo=A, coverage=cov, maps={})


# ------------------------------------------------------------------ the sky (environment map)

#: The sample sky's sun: latitude and longitude (degrees, OpenEXR's orientation:
#: longitude 0 along +z, 90 along +x), angular radius (degrees) and radiance.
SKY_SUN = (25.0, 20.0, 1.0, 2000.0)
#: Its seed (the clouds).
SKY_SEED = 3


def sky_envmap(width: int = 256, height: int = 128, seed: int = SKY_SEED) -> np.ndarray:
    """A procedural outdoor sky: (height, width, 3) float32 radiance, lat-long (width = 2 height).

    A blue gradient from the horizon (0.9, 0.95, 1) to the zenith (0.25, 0.45, 1),
    40 soft clouds (Gaussian blobs in direction, seeded), a brown ground
    (0.25, 0.2, 0.15 darkening to 60 % below) with a ±30 % texture of about 9°
    period, and a sun (:data:`SKY_SUN`: radiance 2000 within 1° of its
    direction; at 1024 × 512 it carries about as much energy as the sky). The
    sun's edge and the ground's texture are what an environment light's
    conversion finds hard (:mod:`clphong.model.environment`).
    """
    d = texel_directions(width, height)
    y = d[..., 1]
    rng = np.random.default_rng(seed)
    zenith = np.array([0.25, 0.45, 1.0])
    horizon = np.array([0.9, 0.95, 1.0])
    ground = np.array([0.25, 0.2, 0.15])
    t = np.sqrt(np.clip(y, 0.0, 1.0))[..., None]
    L = np.where(y[..., None] > 0, horizon * (1 - t) + zenith * t,
                 ground * (0.6 + 0.4 * np.clip(-y, 0.0, 1.0))[..., None])
    for _ in range(40):
        c = rng.normal(size=3)
        c[1] = abs(c[1]) + 0.2
        c /= np.linalg.norm(c)
        w = rng.uniform(0.05, 0.3)
        a = rng.uniform(0.3, 1.5)
        L = L + (a * np.exp(-2.0 * (1.0 - d @ c) / w ** 2) * (y > 0))[..., None]
    L = L * (1.0 + 0.3 * (y < 0) * np.sin(40.0 * d[..., 0]) * np.cos(37.0 * d[..., 2]))[..., None]
    lat, lon, radius, radiance = SKY_SUN
    la, lo = np.radians(lat), np.radians(lon)
    sun = np.array([np.sin(lo) * np.cos(la), np.sin(la), np.cos(lo) * np.cos(la)])
    inside = d @ sun > np.cos(np.radians(radius))
    L = L + radiance * np.array([1.0, 0.95, 0.85]) * inside[..., None]
    return L.astype(np.float32)


def write_envmap(path, width: int = 256, height: int = 128) -> Path:
    """Write :func:`sky_envmap` as a half-float EXR (``gbuffers/sky.exr``)."""
    write_exr(path, sky_envmap(width, height), pixel_type="half")
    return Path(path)


def write_samples(folder, *, parents: bool = False) -> list[Path]:
    """Write ``spheres.exr`` and ``ortho.exr`` into ``folder``.

    ``folder`` must exist (as for every clphong output), unless ``parents``:
    then it is created, with any missing parents.

    Raises
    ------
    OutputError
        One line naming ``folder``: missing (without ``parents``), not a
        folder, or not creatable.
    """
    folder = Path(folder)
    if parents and not folder.is_dir():
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"{folder}: cannot create the folder: {exc.strerror or exc}") from None
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: is a file, not a folder; choose another output folder")
    check_output_path(folder / "spheres.exr", exr=True)   # a missing folder: one line, nothing written
    P, N, A, cov = spheres()
    write_gbuffer(folder / "spheres.exr", P, N, A, coverage=cov)
    P, N, A, cov, maps = ortho()
    write_gbuffer(folder / "ortho.exr", P, N, A, coverage=cov, maps=maps)
    return [folder / "spheres.exr", folder / "ortho.exr"]


if __name__ == "__main__":  # pragma: no cover
    folder = sys.argv[1] if len(sys.argv) > 1 else "gbuffers"
    for path in write_samples(folder, parents=True) + [write_envmap(Path(folder) / "sky.exr")]:
        print(path)

"""The bench's scenes and G-buffer, the numpy float32 baseline, the float64 oracle on
sampled pixels, and the frame timer (clphong.tools.bench runs them)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..io.gbuffer import GBuffer
from ..model.scene import Camera, Light, Material, Scene
from ..reference import shading as reference

#: Seed of every random choice in the bench (scenes, sampled pixels).
SEED = 2026


def _crop_rows(width: int, height: int, n: int, pairs: float, least: int = 4) -> int:
    rows = int(pairs // max(width * n, 1))
    return max(min(least, height), min(height, rows))


# ------------------------------------------------------------------------------ scenes

def bench_gbuffer(width: int, height: int, rows: int | None = None):
    """The benchmark G-buffer (see the module docstring); ``rows``: only the top rows."""
    h = height if rows is None else min(rows, height)
    x = np.linspace(-8.0, 8.0, width)
    y = np.linspace(4.5, -4.5, height)[:h]
    X, Y = np.meshgrid(x, y)
    Z = 0.05 * np.sin(1.3 * X) * np.cos(1.7 * Y) + 0.03 * np.sin(3.1 * X + 1.0)
    dzdx = 0.05 * 1.3 * np.cos(1.3 * X) * np.cos(1.7 * Y) + 0.03 * 3.1 * np.cos(3.1 * X + 1.0)
    dzdy = -0.05 * 1.7 * np.sin(1.3 * X) * np.sin(1.7 * Y)
    P = np.stack([X, Y, Z], -1)
    N = np.stack([-dzdx, -dzdy, np.ones_like(Z)], -1)
    C = np.stack([0.45 + 0.35 * np.sin(0.7 * X), 0.5 + 0.3 * np.cos(0.9 * Y),
                  0.4 + 0.3 * np.sin(0.5 * (X + Y))], -1)
    cov = np.ones(Z.shape, np.float32)
    cov[(X < -8 + 16 * 0.2) & (Y > 4.5 - 9 * 0.2)] = 0.0      # a 4 % background corner
    return GBuffer(position=P.astype(np.float32), normal=N.astype(np.float32),
                   albedo=C.astype(np.float32), coverage=cov, maps={})


#: Light groups of the ``clusters`` bench scene.
CLUSTERS = 64


def bench_scene(kind: str, n_lights: int):
    """The ``wide`` or ``small`` scene with ``n_lights`` point lights (seeded)."""
    rng = np.random.default_rng(SEED + n_lights)
    lights = [Light(type="ambient", color=(1.0, 1.0, 1.0), intensity=0.3)]
    x = rng.uniform(-8, 8, n_lights)
    y = rng.uniform(-4.5, 4.5, n_lights)
    colors = rng.uniform(0.3, 1.0, (n_lights, 3))
    if kind == "wide":
        z = rng.uniform(0.5, 3.0, n_lights)
        att, intensity, k_s = (1.0, 0.1, 0.05), 3.0 * min(1.0, 16.0 / n_lights), 0.2
    elif kind == "small":
        z = rng.uniform(0.01, 0.05, n_lights)
        att, intensity, k_s = (1.0, 0.0, 1.0e6), 2.0, 0.02
    elif kind == "clusters":
        # CLUSTERS compact groups (Gaussian, σ = 0.1) 8–12 units above the surface:
        # chandeliers or LED panels, far from the pixels for their size
        centres = np.column_stack([rng.uniform(-8, 8, CLUSTERS), rng.uniform(-4.5, 4.5, CLUSTERS),
                                   rng.uniform(8.0, 12.0, CLUSTERS)])
        which = np.arange(n_lights) % CLUSTERS
        x, y, z = (centres[which] + rng.normal(0.0, 0.1, (n_lights, 3))).T
        colors = rng.uniform(0.3, 1.0, (CLUSTERS, 3))[which]     # one colour a cluster
        att, intensity, k_s = (1.0, 0.0, 0.01), 40.0 / n_lights, 0.2
    else:
        raise ValueError(f"scene kind must be 'wide', 'small' or 'clusters', not {kind!r}")
    for j in range(n_lights):
        lights.append(Light(type="point", color=tuple(colors[j]), intensity=intensity,
                            position=(float(x[j]), float(y[j]), float(z[j])), attenuation=att))
    return Scene(camera=Camera(type="perspective", position=(0.0, -4.0, 10.0)),
                 material=Material(model="blinn-phong", k_a=0.1, k_d=0.7, k_s=k_s, h=32.0),
                 lights=tuple(lights), source=f"bench:{kind}:{n_lights}")


# ------------------------------------------------------------------------------- numpy

def _dot3(ax, ay, az, bx, by, bz, out, tmp):
    """out = a·b over SoA planes, in place (``tmp``: a scratch plane)."""
    np.multiply(ax, bx, out=out)
    np.multiply(ay, by, out=tmp)
    out += tmp
    np.multiply(az, bz, out=tmp)
    out += tmp
    return out


def numpy_shade(scene, gbuffer) -> np.ndarray:
    """The same shading in plain numpy float32, as its best numpy user writes it:
    SoA planes (one contiguous float32 array per coordinate), every operation in
    place into preallocated buffers (``out=``), a loop over the lights, and
    binary powering for the whole exponent (``np.power`` with a float exponent
    ran 5× slower, and the (3, P) arrays with ``.sum(axis=0)`` of the first
    version another 2×: 4.2 against 23.7 MPLE/s on 1/8 of the frame).

    Blinn-Phong ``max(n·h, 0)^k``, point lights with attenuation, ambient, on the
    shaded pixels only (unit normals and view directions from float64, as the
    kernel's inputs); background pixels take the background value.
    """
    f = np.float32
    H, W = gbuffer.shape
    bg = gbuffer.background_mask().reshape(-1)
    fg = ~bg                                   # shade only the shaded pixels, as the kernel does
    P = gbuffer.position.reshape(-1, 3)[fg].astype(np.float64)
    N = gbuffer.normal.reshape(-1, 3)[fg].astype(np.float64)
    N /= np.sqrt((N * N).sum(axis=1))[:, None]
    Cd = gbuffer.albedo.reshape(-1, 3)[fg].astype(np.float64)
    m = scene.material
    V = np.asarray(scene.camera.position, np.float64) - P
    V /= np.sqrt((V * V).sum(axis=1))[:, None]
    px, py, pz = (np.ascontiguousarray(P[:, i], f) for i in range(3))
    nx, ny, nz = (np.ascontiguousarray(N[:, i], f) for i in range(3))
    vx, vy, vz = (np.ascontiguousarray(V[:, i], f) for i in range(3))
    D = [np.ascontiguousarray(Cd[:, i] * m.k_d, f) for i in range(3)]
    S = [f(x * m.k_s) for x in m.specular_color]
    amb = sum((np.asarray(lt.radiance, np.float64) for lt in scene.lights_of("ambient")),
              np.zeros(3))
    E = [np.ascontiguousarray(Cd[:, i] * amb[i] * m.k_a, f) for i in range(3)]
    K = m.exponent
    whole = float(K).is_integer()
    n = len(px)
    dx, dy, dz, d2, t, inv, NoL, hx, hy, hz, c, s, att, wd, ws = (np.empty(n, f) for _ in range(15))
    for lt in scene.lights_of("point"):
        Lx, Ly, Lz = (f(v) for v in lt.position)
        np.subtract(Lx, px, out=dx)
        np.subtract(Ly, py, out=dy)
        np.subtract(Lz, pz, out=dz)
        _dot3(dx, dy, dz, dx, dy, dz, d2, t)
        np.sqrt(d2, out=t)                                   # d
        np.divide(f(1), t, out=inv)
        dx *= inv                                            # l
        dy *= inv
        dz *= inv
        _dot3(nx, ny, nz, dx, dy, dz, NoL, wd)
        np.add(dx, vx, out=hx)                               # l + v
        np.add(dy, vy, out=hy)
        np.add(dz, vz, out=hz)
        _dot3(hx, hy, hz, hx, hy, hz, c, wd)
        np.sqrt(c, out=c)
        _dot3(nx, ny, nz, hx, hy, hz, s, wd)
        np.divide(s, c, out=c)                               # n·h
        np.maximum(c, f(0), out=c)
        if whole:                                            # c^K by binary powering
            s.fill(1)
            e = int(K)
            while e:
                if e & 1:
                    s *= c
                e >>= 1
                if e:
                    np.multiply(c, c, out=c)
        else:
            np.power(c, f(K), out=s)
        c0, c1, c2 = (f(v) for v in lt.attenuation)
        np.multiply(t, c2, out=att)                          # 1/(c0 + c1·d + c2·d²)
        att += c1
        att *= t
        att += c0
        np.divide(f(1), att, out=att)
        np.maximum(NoL, f(0), out=wd)
        wd *= att
        np.multiply(s, att, out=ws)
        ws[NoL <= 0] = 0
        for ch in range(3):
            np.multiply(D[ch], wd, out=t)
            t += S[ch] * ws
            t *= f(lt.radiance[ch])
            E[ch] += t
    out = np.empty((H * W, 3), f)
    out[bg] = np.asarray(scene.background, f)
    out[fg] = np.stack(E, axis=1)
    return out.reshape(H, W, 3)


# ------------------------------------------------------------------------------- errors

def shaded_pixels(gbuffer) -> int:
    """How many pixels of ``gbuffer`` are shaded (not background)."""
    return int(np.count_nonzero(~gbuffer.background_mask()))


def sample_pixels(gbuffer, n: int, seed: int = SEED) -> np.ndarray:
    """Flat indices of ``n`` shaded pixels, seeded (all of them if fewer)."""
    fg = np.flatnonzero(~gbuffer.background_mask().reshape(-1))
    if n >= len(fg):
        return fg
    return np.sort(np.random.default_rng(seed).choice(fg, n, replace=False))


def sub_gbuffer(gbuffer, idx):
    """The pixels ``idx`` (flat indices) as a 1 × len(idx) G-buffer (:meth:`GBuffer.pixels`)."""
    return gbuffer.pixels(idx)


@dataclass
class Oracle:
    """The float64 reference on a pixel sample, and the terminator band there."""

    idx: np.ndarray
    ref: np.ndarray           # (M, 3)
    band: np.ndarray          # (M,) bool

    def errors(self, rgb: np.ndarray) -> dict:
        got = rgb.reshape(-1, 3)[self.idx].astype(np.float64)
        err = np.abs(got - self.ref)
        big = self.ref >= 1e-6 * max(float(self.ref.max(initial=0.0)), 1e-300)
        rel = np.where(big, err / np.where(big, self.ref, 1.0), 0.0)
        inside = rel[~self.band][big[~self.band]]
        band = rel[self.band][big[self.band]]
        return {
            "max_rel": float(inside.max(initial=0.0)),
            "mean_rel": float(inside.mean()) if inside.size else 0.0,
            "max_abs": float(err.max(initial=0.0)),
            "band_pixels": int(self.band.sum()),
            "band_max_rel": float(band.max(initial=0.0)),
            "sampled_pixels": int(len(self.idx)),
        }


def make_oracle(scene, gbuffer, frame, n_pixels: int) -> Oracle:
    idx = sample_pixels(gbuffer, n_pixels)
    sub = sub_gbuffer(gbuffer, idx)
    ref = reference.shade(scene, sub).reshape(-1, 3)
    _, band = reference.error_bound(scene, sub, origin=frame.origin)
    return Oracle(idx=idx, ref=ref, band=band.reshape(-1))


# --------------------------------------------------------------------------------- timing

def time_frame(renderer, gbuffer, frame):
    """One frame: (seconds of shading + culling, of culling alone, the RenderResult):
    device time of the kernels, plus the host's light-tree cut where one ran."""
    result = renderer.shade(frame)
    c = result.cull.seconds + result.cull.tree_seconds if result.cull is not None else 0.0
    return result.stats.kernel_seconds + c, c, result


def _time_slots(slots, *, keep: bool) -> None:
    """One frame of each slot in turn (its ``result``); ``keep``: record its times."""
    for slot in slots:
        t, c, slot["result"] = time_frame(slot["r"], slot["gb"], slot["frame"])
        if slot["result"].cull is not None:      # the lists of the last frame that built them
            slot["last_cull"] = slot["result"].cull
        elif keep and slot.get("budget") is not None:
            slot["lists_skipped"] = slot.get("lists_skipped", 0) + 1    # renderer.CULL_RETRY
        if keep:
            slot["times"].append(t)
            slot["cull"].append(c)

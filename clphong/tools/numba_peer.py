"""The numba peer of ``clphong bench``: the bench scene's shading as its best
numba user would write it.

``@njit(parallel=True, fastmath=True)``, float32 throughout, SoA planes, a
``prange`` over 256-pixel tiles with the lights loop outside the pixel loop (so
LLVM vectorises across pixels, as clphong's kernel does by hand), and binary
powering for a whole exponent with the exponent a compile-time constant (the
loop over its bits unrolls). Blinn-Phong ``max(n·h, 0)^k``, point lights with
``1/(c0 + c1·d + c2·d²)``, one ambient term, the same inputs as the kernel
(unit normals from the host). It is a yardstick, not a renderer: no maps,
groups, coverage or guards beyond the kernel's own (d = 0, l = −v).

numba is optional (the ``bench`` extra): :func:`available` says whether it
imports.
"""

from __future__ import annotations

import functools

import numpy as np

TILE = 256


def import_numba():
    """``import numba``, where colour-science may have put a stand-in for a missing
    SciPy into ``sys.modules`` (a MagicMock, which numba takes for SciPy and
    fails on): the stand-in is set aside while numba imports. None without numba."""
    import sys
    import types

    stand_in = sys.modules.get("scipy")
    fake = stand_in is not None and not isinstance(stand_in, types.ModuleType)
    if fake:
        del sys.modules["scipy"]
    try:
        import numba
    except ImportError:
        return None
    finally:
        if fake:
            sys.modules["scipy"] = stand_in
    return numba


def available() -> bool:
    return import_numba() is not None


@functools.lru_cache(maxsize=None)
def _kernel(k: int, blinn: bool):
    """The compiled tile loop for the whole exponent ``k`` (a constant of the closure)."""
    numba = import_numba()

    K = int(k)
    c_min = np.float32(np.finfo(np.float32).tiny ** (1.0 / K)) if K else np.float32(0.0)

    @numba.njit(parallel=True, fastmath=True, cache=False, boundscheck=False)
    def shade(px, py, pz, nx, ny, nz, dr, dg, db, sr, sg, sb, ar, ag, ab,
              vx, vy, vz, lights, out):
        n = px.shape[0]
        n_tiles = (n + TILE - 1) // TILE
        n_lights = lights.shape[0]
        for t in numba.prange(n_tiles):
            a = t * TILE
            b = min(a + TILE, n)
            # the tile's planes as views: unsigned-looking indices, no wraparound checks
            tpx, tpy, tpz = px[a:b], py[a:b], pz[a:b]
            tnx, tny, tnz = nx[a:b], ny[a:b], nz[a:b]
            tvx, tvy, tvz = vx[a:b], vy[a:b], vz[a:b]
            tdr, tdg, tdb = dr[a:b], dg[a:b], db[a:b]
            tsr, tsg, tsb = sr[a:b], sg[a:b], sb[a:b]
            er = ar[a:b].copy()
            eg = ag[a:b].copy()
            eb = ab[a:b].copy()
            m = b - a
            for j in range(n_lights):
                Lx = lights[j, 0]
                Ly = lights[j, 1]
                Lz = lights[j, 2]
                Rr = lights[j, 3]
                Rg = lights[j, 4]
                Rb = lights[j, 5]
                c0 = lights[j, 6]
                c1 = lights[j, 7]
                c2 = lights[j, 8]
                for q in range(m):
                    dx = Lx - tpx[q]
                    dy = Ly - tpy[q]
                    dz = Lz - tpz[q]
                    d2 = dx * dx + dy * dy + dz * dz
                    inv = np.float32(1.0) / np.sqrt(d2)
                    d = d2 * inv
                    lx = dx * inv
                    ly = dy * inv
                    lz = dz * inv
                    NoL = tnx[q] * lx + tny[q] * ly + tnz[q] * lz
                    if blinn:
                        hx = lx + tvx[q]
                        hy = ly + tvy[q]
                        hz = lz + tvz[q]
                        hinv = np.float32(1.0) / np.sqrt(hx * hx + hy * hy + hz * hz)
                        c = (tnx[q] * hx + tny[q] * hy + tnz[q] * hz) * hinv
                    else:
                        two = NoL + NoL
                        c = ((two * tnx[q] - lx) * tvx[q] + (two * tny[q] - ly) * tvy[q]
                             + (two * tnz[q] - lz) * tvz[q])
                    # below c_min, c^K < FLT_MIN: 0, not a denormal (which costs 3-4x on
                    # x86 and that numba cannot flush; the kernel flushes them too)
                    c = c if c > c_min else np.float32(0.0)
                    s = np.float32(1.0)
                    e = K
                    while e:            # binary powering; K is a constant, so this unrolls
                        if e & 1:
                            s *= c
                        c *= c
                        e >>= 1
                    att = np.float32(1.0) / (c0 + d * (c1 + d * c2))
                    wd = max(NoL, np.float32(0.0)) * att
                    ws = s * att if NoL > np.float32(0.0) else np.float32(0.0)
                    er[q] += Rr * (tdr[q] * wd + tsr[q] * ws)
                    eg[q] += Rg * (tdg[q] * wd + tsg[q] * ws)
                    eb[q] += Rb * (tdb[q] * wd + tsb[q] * ws)
            out[0, a:b] = er
            out[1, a:b] = eg
            out[2, a:b] = eb

    return shade


class NumbaPeer:
    """The bench scene's shading on the shaded pixels of ``gbuffer``, set up once
    (planes, lights, the compiled loop), then :meth:`shade` per frame."""

    def __init__(self, scene, gbuffer):
        f = np.float32
        m = scene.material
        k = m.exponent
        if k != int(k) or not 0 <= k <= 65536:
            raise ValueError(f"the numba peer needs a whole exponent, not {k}")
        self.shape = gbuffer.shape
        bg = gbuffer.background_mask().reshape(-1)
        self.fg = ~bg
        self.background = np.asarray(scene.background, f)
        P = gbuffer.position.reshape(-1, 3)[self.fg].astype(np.float64)
        N = gbuffer.normal.reshape(-1, 3)[self.fg].astype(np.float64)
        N /= np.linalg.norm(N, axis=1, keepdims=True)
        Cd = gbuffer.albedo.reshape(-1, 3)[self.fg].astype(np.float64)
        V = np.asarray(scene.camera.position, np.float64) - P
        V /= np.linalg.norm(V, axis=1, keepdims=True)
        D = Cd * m.k_d
        S = np.broadcast_to(np.asarray(m.specular_color, np.float64) * m.k_s, D.shape)
        amb = sum((np.asarray(lt.radiance, np.float64) for lt in scene.lights_of("ambient")),
                  np.zeros(3))
        A = Cd * (amb * m.k_a)
        planes = [P, N, D, S, A, V]
        self.args = [np.ascontiguousarray(a[:, c], f) for a in planes for c in range(3)]
        pts = scene.lights_of("point")
        self.lights = np.array([tuple(lt.position) + tuple(lt.radiance) + tuple(lt.attenuation)
                                for lt in pts], f).reshape(-1, 9)
        self.fn = _kernel(int(k), m.model == "blinn-phong")
        self.out = np.empty((3, len(P)), f)
        self.shade_flat()                      # compile now, not in the first timed frame

    def shade_flat(self) -> np.ndarray:
        """The shaded pixels' RGB, (3, S)."""
        self.fn(*self.args, self.lights, self.out)
        return self.out

    def shade(self) -> np.ndarray:
        """The whole frame, (H, W, 3), background pixels the scene's background."""
        H, W = self.shape
        img = np.empty((H * W, 3), np.float32)
        img[:] = self.background
        img[self.fg] = self.shade_flat().T
        return img.reshape(H, W, 3)


# ------------------------------------------------------------------------- FMA loop

#: Floats a thread keeps in flight: 12 chains of 16 lanes (24 of 8).
FMA_WIDTH = 192
FMA_METHOD = (f"numba @njit(parallel=True, fastmath=True): per thread {FMA_WIDTH} float32 "
              "a = a*b + c chains (LLVM vectorises them into independent FMA registers), "
              "2e6 steps, one thread per core, best of 5")


@functools.lru_cache(maxsize=None)
def _fma_loop():
    numba = import_numba()

    W = FMA_WIDTH

    @numba.njit(parallel=True, fastmath=True)
    def loop(iters, threads, b, c):
        out = np.zeros(threads, np.float32)
        for t in numba.prange(threads):
            a = np.empty(W, np.float32)
            for k in range(W):
                a[k] = np.float32(k) * np.float32(0.001)
            for _ in range(iters):
                for k in range(W):
                    a[k] = a[k] * b + c
            out[t] = a.sum()
        return out

    return loop


def fma_peak_gflops(iterations: int = 2_000_000, repeats: int = 5) -> float:
    """FP32 GFLOP/s of a numba FMA loop on every core (the check on kernels/peak.cl)."""
    import os
    import time

    numba = import_numba()
    loop = _fma_loop()
    threads = numba.get_num_threads() or os.cpu_count() or 1
    loop(10, threads, np.float32(0.999), np.float32(1e-3))
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        loop(iterations, threads, np.float32(0.999), np.float32(1e-3))
        best = max(best, 2.0 * FMA_WIDTH * iterations * threads / (time.perf_counter() - t0) / 1e9)
    return best


def fma_vector_bits() -> int:
    """The vector width numba's LLVM chose for the FMA loop (256 on AVX-512 too:
    LLVM prefers 256-bit vectors on most AVX-512 cores), from its assembly."""
    import re

    asm = "\n".join(_fma_loop().inspect_asm().values())
    for reg, bits in (("zmm", 512), ("ymm", 256), ("xmm", 128)):
        if re.search(rf"vfmadd\w*ps\s+[^\n]*%{reg}", asm):
            return bits
    return 32

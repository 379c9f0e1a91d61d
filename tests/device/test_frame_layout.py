"""clphong.device.frame.prepare_frame lays out the same planes, bit for bit, as its
plain formulation (a copy per component, masks by indexing, a float64 remainder
temporary, the origin from the (H, W, 3) positions)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clphong.core.geometry import frame_origin, unit_normal_planes
from clphong.device.frame import COVERAGE_PLANE, GBUF_PLANES, LOCAL_SIZE, prepare_frame
from clphong.io.gbuffer import GBuffer
from clphong.model.scene import MATERIAL_MAPS


def _plain(gbuffer, lanes):
    """prepare_frame as it was written before (issue 14)."""
    h, w = gbuffer.shape
    n = h * w
    block = lanes * LOCAL_SIZE
    stride = max(block, math.ceil(n / block) * block)
    background = gbuffer.background_mask().reshape(-1)
    partial = gbuffer.partly_covered()
    gbuf = np.empty((GBUF_PLANES + partial, stride), np.float32)
    gbuf[:, n:] = 0.0
    P, C = gbuffer.position.reshape(-1, 3), gbuffer.albedo.reshape(-1, 3)
    for a, n64 in enumerate(unit_normal_planes(gbuffer.normal)):
        n64[background] = 0.0
        gbuf[a, :n] = P[:, a]
        gbuf[6 + a, :n] = C[:, a]
        gbuf[3 + a, :n] = n64
        gbuf[9 + a, :n] = n64 - gbuf[3 + a, :n]
    if partial:
        gbuf[COVERAGE_PLANE, :n] = np.clip(gbuffer.coverage.reshape(-1), 0.0, 1.0)
    planes = [gbuffer.maps[k].reshape(-1, c).T for k, c in MATERIAL_MAPS.items() if k in gbuffer.maps]
    maps = np.zeros((sum(p.shape[0] for p in planes), stride), np.float32) if planes else None
    if planes:
        maps[:, :n] = np.concatenate(planes, axis=0)
    return gbuf, maps, frame_origin(gbuffer.position, background), background


def _gbuffer(h, w, dtype=np.float32, seed=0, partial=True):
    rng = np.random.default_rng(seed)
    P = (rng.standard_normal((h, w, 3)) * 1e3 + 5e4).astype(dtype)
    N = rng.standard_normal((h, w, 3)).astype(dtype)
    N[rng.uniform(size=(h, w)) < 0.1] = 0.0
    N[0, 0] = [np.nan, 1, 0]
    N[0, 1] = [1e-45, 0, -0.0] if dtype == np.float32 else [0, 0, -0.0]
    P[1, 2] = [np.inf, 0, 0]
    A = rng.uniform(0, 1, (h, w, 3)).astype(dtype)
    cov = rng.choice(np.float32([0, 0.5, 1, 1]), (h, w)) if partial else None
    maps = {"k_s": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "specular_color": rng.uniform(0, 1, (h, w, 3)).astype(np.float32)}
    return GBuffer(position=P, normal=N, albedo=A, coverage=cov, maps=maps)


@pytest.mark.parametrize("lanes", [1, 16])
@pytest.mark.parametrize("dtype,partial", [(np.float32, True), (np.float32, False),
                                           (np.float64, True), (np.float16, False)])
def test_prepare_frame_is_the_plain_layout_bit_for_bit(lanes, dtype, partial):
    gb = _gbuffer(37, 61, dtype, partial=partial)
    frame = prepare_frame(gb, lanes=lanes)
    gbuf, maps, origin, background = _plain(gb, lanes)
    assert frame.gbuf.tobytes() == gbuf.tobytes() and frame.gbuf.shape == gbuf.shape
    assert frame.maps.tobytes() == maps.tobytes()
    assert frame.origin.tobytes() == origin.tobytes() and frame.origin.dtype == np.float32
    assert np.array_equal(frame.background, background)
    assert frame.coverage == partial and frame.map_names == ("k_s", "specular_color")


def test_prepare_frame_of_views_and_an_empty_frame():
    """Arrays that are views (not C-contiguous) and a frame with nothing shaded."""
    big = _gbuffer(40, 70, seed=2)
    gb = GBuffer(position=big.position[::2, 1::2], normal=big.normal[::2, 1::2],
                 albedo=big.albedo[::2, 1::2])
    frame = prepare_frame(gb, lanes=16)
    gbuf, _, origin, _ = _plain(gb, 16)
    assert frame.gbuf.tobytes() == gbuf.tobytes() and frame.origin.tobytes() == origin.tobytes()
    empty = GBuffer(position=np.ones((3, 4, 3), np.float32), normal=np.zeros((3, 4, 3), np.float32),
                    albedo=np.ones((3, 4, 3), np.float32))
    frame = prepare_frame(empty, lanes=1)
    assert frame.background.all() and not frame.origin.any()

"""Row bands with culling: band edges on the culling grid keep the result bit-identical.

A culled frame's light lists are built per 16×16 tile inside super-tiles of
``super_tiles(lanes)`` tiles (8, or 16 with 16 lanes) counted from the frame's
corner. A band that starts off that grid sees other super-tiles, so other lists:
with bands of 128 or 384 rows at 16 lanes (super-tiles of 256 rows) about
49 000 pixels of a 768×96 frame under 400 lights differed from one launch, by up
to 2e-4. Band heights are now multiples of :func:`clphong.device.bands.band_align`.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_gbuffer, make_scene, skip_unless_lanes

from clphong.device.bands import band_align
from clphong.device.culling import TILE, super_tiles
from clphong.device.renderer import Renderer


def _tall_frame(rng, h=768, w=96):
    """A wavy surface 9.6 × 76.8 units seen from above: coherent tiles, so culling drops."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) * 0.1
    z = 0.3 * np.sin(xs * 1.7) * np.cos(ys * 1.3)
    P = np.stack([xs, ys, z], -1)
    N = np.stack([-0.51 * np.cos(xs * 1.7) * np.cos(ys * 1.3),
                  0.39 * np.sin(xs * 1.7) * np.sin(ys * 1.3), np.ones_like(z)], -1)
    C = rng.uniform(0.1, 1.0, (h, w, 3))
    return make_gbuffer(P, N, C, np.ones((h, w), np.float32))


def _lights(rng, n=400, h=768, w=96):
    return [dict(type="point", position=(rng.uniform(0, w / 10), rng.uniform(0, h / 10),
                                         rng.uniform(0.05, 0.6)),
                 color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(0.5, 3.0)),
                 attenuation=(1.0, 0.0, 300.0)) for _ in range(n)]


def test_band_align_is_the_culling_super_tile_edge():
    """Derived, not retyped: TILE pixels × the super-tile's tiles for the lane width."""
    assert [band_align(lanes) for lanes in (1, 4, 8, 16)] == [TILE * super_tiles(k)
                                                               for k in (1, 4, 8, 16)]
    assert band_align(8) == 128 and band_align(16) == 256


@pytest.mark.parametrize("lanes", [8, 16])
@pytest.mark.parametrize("rows", [128, 384, 640])
def test_culled_frame_in_bands_equals_one_launch(lanes, rows, device):
    """Bit-identical (np.array_equal) to the whole-frame launch, bands asked for at odd
    multiples of 128 rows; tolerance: none. Culling alone: whether the light tree's
    lists are used is each launch's own choice (the next test)."""
    skip_unless_lanes(lanes, device)
    rng = np.random.default_rng(3)
    gb = _tall_frame(rng)
    r = Renderer(make_scene(_lights(rng), model="blinn-phong", h=30.0), lanes=lanes,
                 max_error=1e-3, device=device, light_tree=False)
    whole = r.render(gb)
    assert whole.bands == 1 and whole.plan.defines["CULLING"] == 1
    assert whole.cull.kept_fraction < 0.5            # culling really drops lights here
    banded = r.render(gb, rows=rows)
    align = band_align(lanes)
    expect = -(-768 // (rows - rows % align)) if rows >= align else -(-768 // rows)
    assert banded.bands == expect and banded.bands > 1
    if rows >= align:
        assert np.array_equal(banded.image, whole.image)
    else:
        # A band shorter than one super-tile row cannot keep the whole frame's lists
        # (its super-tiles hold other pixels): each band's culling still drops at most
        # ε per pixel and channel, so the two differ by at most 2ε (plus the sums'
        # rounding, below 1e-6 here), never more.
        assert np.abs(banded.image - whole.image).max() <= 2 * 1e-3 + 1e-6


@pytest.mark.parametrize("rows", [128, 384])
def test_with_the_light_tree_each_band_keeps_the_budget(rows, device):
    """With the light tree, each launch chooses its own lists (with clusters or without:
    culling._build_tile_lists), so a band may choose otherwise than the whole frame: on
    this frame at 8 lanes, 128-row bands took clusters where the whole frame did not.
    Each is within ε of the exact sum, so the two differ by at most 2ε (plus the sums'
    rounding, below 1e-6 here)."""
    rng = np.random.default_rng(3)
    gb = _tall_frame(rng)
    r = Renderer(make_scene(_lights(rng), model="blinn-phong", h=30.0), max_error=1e-3,
                 device=device, light_tree="always")
    whole = r.render(gb)
    banded = r.render(gb, rows=rows)
    assert banded.bands > 1
    assert np.abs(banded.image - whole.image).max() <= 2 * 1e-3 + 1e-6

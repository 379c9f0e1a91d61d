"""Lat-long tables of an environment's zonal sums (clphong.model.env_table): at their nodes
they are the texel sum itself, and between nodes the bilinear look-up converges."""

import numpy as np
import pytest

from clphong.model.env_table import lookup, weighted_map, zonal_table
from clphong.model.environment import texel_directions, texel_lights

#: float64 FFT round-off: each output is a sum of H·N products computed through two
#: transforms of length N; its error is a few ulp times log2(N) times the sum of the
#: magnitudes (all terms here are >= 0, so that sum is the value's scale, the table's max).
ROUNDOFF = 64 * np.finfo(np.float64).eps * 8


def _direct(dirs, radiance, power):
    l, E = texel_lights(radiance)
    return np.maximum(dirs.reshape(-1, 3) @ l.T, 0.0) ** power @ E


@pytest.mark.parametrize("power", [1.0, 8.0, 2.5])
@pytest.mark.parametrize("rows, step", [(9, 1), (7, 4), (2, 16)])
def test_the_table_at_its_nodes_is_the_texel_sum(power, rows, step):
    rng = np.random.default_rng(int(power * 10) + rows)
    radiance = rng.uniform(0.0, 1.0, (17, 33, 3)) ** 4       # W - 1 = 32 columns a turn
    radiance[3, 5] = 40.0                                     # one bright texel
    t = zonal_table(weighted_map(radiance), power, rows, step)
    assert t.values.shape == (rows, 32 // step + 1, 3)
    nodes = texel_directions(32 // step + 1, rows)
    want = _direct(nodes, radiance, power).reshape(t.values.shape)
    assert np.max(np.abs(t.values - want)) <= ROUNDOFF * want.max()
    # a pole's nodes are one direction: one value
    assert np.ptp(t.values[0], axis=0).max() <= ROUNDOFF * want.max()


def test_lookup_at_the_nodes_and_across_the_seam():
    rng = np.random.default_rng(3)
    radiance = rng.uniform(0.0, 1.0, (9, 17, 3))
    t = zonal_table(weighted_map(radiance, intensity=2.0), 1.0, 5, 2)
    nodes = texel_directions(9, 5)
    assert np.allclose(lookup(t, nodes), t.values, rtol=0, atol=1e-12 * t.values.max())
    # longitude +pi and -pi (the first and last columns) are one meridian
    a = np.array([[np.sin(np.pi - 1e-12) * 0.6, 0.8, np.cos(np.pi - 1e-12) * 0.6]])
    b = np.array([[np.sin(-np.pi + 1e-12) * 0.6, 0.8, np.cos(-np.pi + 1e-12) * 0.6]])
    assert np.allclose(lookup(t, a), lookup(t, b), rtol=1e-9, atol=0)


def test_between_nodes_the_error_falls_as_the_square_of_the_spacing():
    """Bilinear interpolation of a smooth function: halving the spacing divides the
    error by about 4 (second order); the map is smooth, so the diffuse sum is."""
    H, W = 65, 129
    lat = np.linspace(np.pi / 2, -np.pi / 2, H)[:, None]
    lon = np.linspace(np.pi, -np.pi, W)[None, :]
    radiance = np.stack([1.5 + np.sin(lat) + 0.3 * np.cos(lon) * np.cos(lat)] * 3, -1)
    dirs = np.random.default_rng(0).normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    truth = _direct(dirs, radiance, 1.0)
    errs = [np.max(np.abs(lookup(zonal_table(weighted_map(radiance), 1.0, rows, step), dirs) - truth))
            for rows, step in ((9, 8), (17, 4), (33, 2))]
    assert errs[1] < errs[0] / 2.5 and errs[2] < errs[1] / 2.5, errs


def test_a_step_that_does_not_divide_the_turn_is_refused():
    with pytest.raises(ValueError, match="step dividing 32"):
        zonal_table(np.ones((9, 33, 3)), 1.0, 5, 3)

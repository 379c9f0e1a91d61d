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


# ------------------------------------------------------------------ the kernels' tables

from clphong.model.env_table import (  # noqa: E402
    CHECK_MARGIN,
    LUNE_MARGIN,
    MAX_SUN_TEXELS,
    TablesUnfit,
    cubic_table,
    diffuse_lower_bound,
    env_table_coords,
    env_table_lookup,
    environment_tables,
    horizon_budget,
    horizon_misses,
    lune_bound,
    lune_weights,
    table_refusal,
)
from clphong.model.environment import _fibonacci  # noqa: E402
from clphong.model.scene import Material  # noqa: E402


def _sky(H=64, W=129, seed=0):
    """A smooth sky over a darker ground with a few soft clouds (no sun), (H, W, 3)."""
    rng = np.random.default_rng(seed)
    lat = np.linspace(np.pi / 2, -np.pi / 2, H)[:, None]
    lon = np.linspace(np.pi, -np.pi, W)[None, :]
    sky = np.where(lat > 0, 1.0 + 0.8 * np.sin(lat), 0.25 + 0.1 * np.cos(3 * lon))
    for _ in range(4):
        a, b = rng.uniform(0.1, 1.2), rng.uniform(-np.pi, np.pi)
        sky = sky + 0.6 * np.exp(-((lat - a) ** 2 + (lon - b) ** 2) / 0.05)
    return np.stack([sky, 0.9 * sky, 0.7 * sky + 0.1], -1)


def _direction(lat, lon):
    c = np.cos(lat)
    return np.stack(np.broadcast_arrays(np.sin(lon) * c, np.sin(lat), np.cos(lon) * c), -1)


def _phong(h=16.0, k_s=0.2, model="phong", **kw):
    return Material(model=model, k_a=0.0, k_d=0.7, k_s=k_s, h=h, **kw)


@pytest.mark.parametrize("power", [1.0, 16.0])
def test_cubic_table_nodes_are_the_texel_sum_over_the_poles_too(power):
    """Every node, the rows over the poles included ((π − lat, lon + π) is the direction a
    latitude beyond ±π/2 names), is the texel sum to float64 round-off."""
    radiance = _sky(17, 33)
    t = cubic_table(weighted_map(radiance), power, 9)
    rows, cols = t.rows, t.cols
    lat = np.pi / 2 - np.pi / (rows - 1) * (np.arange(rows + 2) - 1.0)
    lon = np.pi - 2 * np.pi * np.arange(cols) / cols
    want = _direct(_direction(lat[:, None], lon[None, :]), radiance, power).reshape(t.values.shape)
    assert np.max(np.abs(t.values - want)) <= ROUNDOFF * want.max()


@pytest.mark.parametrize("power", [1.0, 16.0])
def test_the_estimate_holds_at_held_out_directions(power):
    """The estimate (the check grid's worst, times CHECK_MARGIN) is at least the error at
    2000 directions that are neither nodes nor check points, and within 20x of it: a
    0 or a made-up estimate fails."""
    radiance = _sky()
    t = cubic_table(weighted_map(radiance), power, 17)
    dirs = _fibonacci(2000, offset=0.3)
    got = env_table_lookup(t.values, *env_table_coords(dirs, 0.0, t.rows, t.cols))
    truth = _direct(dirs, radiance, power)
    err = np.max(np.abs(got - truth) / truth)
    assert 0 < err <= t.estimate <= 20 * err, (err, t.estimate)
    assert CHECK_MARGIN >= 1


def test_cubic_look_ups_converge_as_the_fourth_power():
    """Lagrange cubics: halving the spacing divides the error by about 16 (fourth order),
    for a smooth map, until the texel sum's own kinks (a small one wherever a normal's
    horizon crosses a texel, about 3e-5 relative on this 257-row map; less on finer maps)
    floor it. A map with a step, as _sky's horizon, floors it higher: the estimates above
    hold that."""
    H, W = 257, 513
    lat = np.linspace(np.pi / 2, -np.pi / 2, H)[:, None]
    lon = np.linspace(np.pi, -np.pi, W)[None, :]
    radiance = np.stack([1.5 + np.sin(lat) + 0.3 * np.cos(lon) * np.cos(lat)] * 3, -1)
    dirs = _fibonacci(1000, offset=0.3)
    truth = _direct(dirs, radiance, 1.0)
    errs = []
    for rows in (5, 9, 17):
        t = cubic_table(weighted_map(radiance), 1.0, rows)
        got = env_table_lookup(t.values, *env_table_coords(dirs, 0.0, t.rows, t.cols))
        errs.append(np.max(np.abs(got - truth) / truth))
    assert errs[1] < errs[0] / 10 and errs[2] < errs[1] / 10, errs


def test_a_rotated_map_is_looked_up_where_its_texels_went():
    radiance = _sky(33, 65)
    t = environment_tables(radiance, _phong(), rotation=40.0, intensity=0.5, max_error=1e-2)
    dirs = _fibonacci(500, offset=0.3)
    l, E = texel_lights(radiance, rotation=40.0, intensity=0.5)
    truth = np.maximum(dirs @ l.T, 0.0) @ E
    d = t.diffuse
    got = env_table_lookup(d.values, *env_table_coords(dirs, np.radians(40.0), d.rows, d.cols))
    assert np.max(np.abs(got - truth) / truth) <= t.estimate


def test_the_sun_is_split_out_as_exact_lights():
    radiance = _sky(33, 65)
    radiance[10, 20] = radiance[10, 21] = 500.0
    t = environment_tables(radiance, _phong(), max_error=1e-2)
    assert t.sun_count == 2
    l, E = texel_lights(radiance)
    assert np.allclose(np.sort(t.sun_radiance[:, 0]), np.sort(E[[10 * 65 + 20, 10 * 65 + 21], 0]))
    assert t.radiance_max.max() < 10.0          # the sun is not in the tables


def test_what_cannot_be_tabled_says_why():
    with pytest.raises(TablesUnfit, match="Blinn-Phong"):
        environment_tables(_sky(17, 33), _phong(model="blinn-phong"))
    stars = np.zeros((64, 129, 3))
    stars.reshape(-1, 3)[::3] = 1.0                 # a third of the texels over 50x the median 0
    assert (stars.sum(-1) > 0).sum() > MAX_SUN_TEXELS
    with pytest.raises(TablesUnfit, match="texels are over"):
        environment_tables(stars, _phong())
    # Blinn-Phong without a specular term is a diffuse table
    t = environment_tables(_sky(), _phong(model="blinn-phong", k_s=0.0), max_error=1e-2)
    assert t.specular is None
    # a k_s map over k_s = 0, a shininess map, an exponent below 1: refused, with the reason
    assert "k_s map" in table_refusal(_phong(k_s=0.0), ("k_s",))
    assert "shininess map" in table_refusal(_phong(), ("h",))
    assert "below 1" in table_refusal(_phong(h=0.5))
    assert table_refusal(_phong(), ("k_d", "specular_color")) is None


def test_a_map_whose_columns_are_all_nodes_is_checked_between_them():
    """A 33-column map: its tables' columns can only be its own (every one a node), so the
    estimate checks the longitudes midway between them (a shifted kernel): it holds at
    held-out directions, and where no size meets the budget the map is refused."""
    radiance = _sky(17, 33)
    t = cubic_table(weighted_map(radiance), 8.0, 17)
    assert t.cols == 32
    dirs = _fibonacci(3000, offset=0.3)
    got = env_table_lookup(t.values, *env_table_coords(dirs, 0.0, t.rows, t.cols))
    truth = _direct(dirs, radiance, 8.0)
    err = np.max(np.abs(got - truth) / truth)
    assert err <= t.estimate <= 20 * err
    with pytest.raises(TablesUnfit, match="largest table"):
        environment_tables(radiance, _phong(), max_error=1e-3)


def test_an_all_black_map_is_exact_zero_tables():
    t = environment_tables(np.zeros((17, 33, 3)), _phong(), max_error=1e-3)
    assert t.estimate == 0 and not t.diffuse.values.any() and t.sun_count == 0


@pytest.mark.parametrize("h", [8.0, 32.0, 200.0])
@pytest.mark.parametrize("H", [64, 256])
def test_the_lune_bound_holds_the_texels_below_the_plane(h, H):
    """lune_bound (G at e less a texel) is at least the texels' sum below the plane (a
    uniform map: the worst case of the bound's L_max), at any e, on a coarse and a finer
    map; and at the finer map's nodes, for the sums that matter, within 3x of it."""
    G = lune_weights(h)
    steps = (len(G) - 1) // 2
    texel = max(np.pi / (H - 1), 2 * np.pi / (2 * H))
    l, E = texel_lights(np.ones((H, 2 * H + 1, 3)))
    n = np.array([0.3, 0.1, 1.0])
    n /= np.linalg.norm(n)
    u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    below = l @ n <= 0
    for k in (0, 1, 8, 40, 100, 180):           # e below a texel too: G at e - texel < 0
        for extra in (0.0, 0.4):
            e = (k + extra) * (np.pi / 2) / steps
            R = np.cos(e) * u + np.sin(e) * n              # rises e above the plane
            s = float(np.where(below, np.maximum(l @ R, 0.0) ** h, 0.0) @ E[:, 0])
            bound = float(lune_bound(G, np.array([np.sin(e)]), texel)[0])
            assert s <= LUNE_MARGIN * bound, (k, extra, s, bound)
            if H == 256 and extra == 0 and s > 1e-6 and k >= 8:
                assert bound <= 3 * s, (k, s, bound)


def test_the_diffuse_lower_bound_is_below_the_texel_sum_and_near_it():
    radiance = _sky()
    t = environment_tables(radiance, _phong(), max_error=1e-3)
    dirs = _fibonacci(3000, offset=0.1)
    truth = _direct(dirs, radiance, 1.0)
    lb = diffuse_lower_bound(t, dirs)
    assert np.all(lb <= truth * (1 + 1e-12))
    assert np.median(lb / truth) > 0.5
    assert np.all(t.diffuse_floor <= truth.min(axis=0))


def test_pixels_the_tables_keep_are_within_their_horizon_budget():
    """For random pixels (normals, views on both sides of grazing, albedos), every pixel
    the check keeps has its exact lobe below the tangent plane, S·C, within ε_h of D·E;
    and grazing pixels are missed (the check can fail)."""
    radiance = _sky()
    m = _phong(h=16.0)
    t = environment_tables(radiance, m, max_error=1e-3)
    rng = np.random.default_rng(5)
    n = rng.normal(size=(1500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = rng.uniform(0.02, 1.0, 1500) ** 0.5                 # n·v
    t_ = rng.normal(size=(1500, 3))
    t_ -= np.einsum("ij,ij->i", t_, n)[:, None] * n
    t_ /= np.linalg.norm(t_, axis=1, keepdims=True)
    v = c[:, None] * n + np.sqrt(1 - c * c)[:, None] * t_
    d = rng.uniform(0.05, 1.0, (1500, 3))
    sp = np.ones((1500, 3))
    miss = horizon_misses(t, m, np.einsum("ij,ij->i", n, v), d, sp, n)
    assert miss.any() and not miss.all()
    l, E = texel_lights(radiance)
    R = 2 * np.einsum("ij,ij->i", n, v)[:, None] * n - v
    below = (n @ l.T) <= 0
    C = np.where(below, np.maximum(R @ l.T, 0.0) ** m.h, 0.0) @ E
    De = np.maximum(n @ l.T, 0.0) @ E
    kept = ~miss
    assert np.all(m.k_s * C[kept] <= horizon_budget(t) * m.k_d * d[kept] * De[kept])
    # and the pixels missed lie at the grazing end
    assert np.median(c[miss]) < np.median(c[kept])


def test_a_specular_colour_channel_of_0_still_bounds_a_map_there():
    """A material C_s with a 0 channel and a specular-colour map: the map's weights there are
    the map itself (clphong.io.envmap._probe_weights), so the bound takes k_s·1 there,
    not 0: the same pixels miss as with a white C_s and the same weights."""
    radiance = _sky()
    t = environment_tables(radiance, _phong(), max_error=1e-3)
    rng = np.random.default_rng(9)
    n = np.tile([0.0, 0.0, 1.0], (400, 1))
    c = rng.uniform(0.05, 1.0, 400)
    d = rng.uniform(0.05, 1.0, (400, 3))
    sp = rng.uniform(0.0, 1.0, (400, 3))
    red = _phong(specular_color=(1.0, 0.0, 0.0))
    white = _phong()
    a = horizon_misses(t, red, c, d, sp, n)
    b = horizon_misses(t, white, c, d, sp, n)
    assert np.array_equal(a, b) and a.any()


def test_a_bright_region_the_tables_cannot_hold_is_split_out_at_a_lower_ratio():
    """Two texels at 45x the median of a smooth sky (under SUN_RATIO): their kinks keep the
    diffuse table over its share at every size, so the next ratio splits them out as
    lights, and the tables of the rest meet the budget."""
    H, W = 65, 129
    lat = np.linspace(np.pi / 2, -np.pi / 2, H)[:, None]
    lon = np.linspace(np.pi, -np.pi, W)[None, :]
    radiance = np.stack([1.5 + np.sin(lat) + 0.3 * np.cos(lon) * np.cos(lat)] * 3, -1)
    radiance[20, 40:42] = 45 * np.median(radiance.sum(-1)) / 3
    tried = []
    t = environment_tables(radiance, _phong(), max_error=1e-3,
                           on_size=lambda tb: tried.append((tb.power, tb.rows, tb.estimate)))
    assert (1.0, 257, tried[3][2]) == tried[3] and tried[3][2] > 5e-4   # at 50x: no size fits
    assert t.sun_count == 2 and t.estimate <= 5e-4

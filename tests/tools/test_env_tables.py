"""python -m clphong.tools.env_tables on a small sky: its rows are what they say."""

from clphong.tools import env_tables


def test_rows_on_a_small_sky():
    lines = []
    rows = env_tables.measure((65, 33), diffuse=((17, 1),), specular=((8.0, 33, 1),), probes=200,
                              log=lines.append)
    assert [r["kind"] for r in rows] == ["diffuse", "specular"]
    assert rows[0]["cols"] == 65 and rows[0]["rows"] == 17
    assert all(0 < r["max_rel"] < 0.5 for r in rows)
    assert lines[0].startswith("map 65x33: ")


def test_pixel_rows_split_the_horizon_from_the_tables():
    p = env_tables.pixels((65, 33), h=8.0, diffuse_rows=33, lobe_rows=33, probes=200, lower=(1e-2,),
                          log=lambda s: None)
    # the tables hold the zonal sums closely; the horizon (n·l > 0 for specular) is what
    # a lobe table cannot hold, and at h = 8 it costs far more than the tables do
    assert p["diffuse"] < 0.05 and p["lobe"] < 0.05
    assert p["horizon"] > 10 * max(p["diffuse"], p["lobe"])
    assert p["over_0.0001"] >= p["over_0.001"] > 0
    # subtracting the lights below the tangent plane takes most of the horizon's error away
    assert p["lower_0.01"]["max_rel"] < p["horizon"] / 3


def test_on_a_floor_the_upper_half_table_holds_the_horizon():
    f = env_tables.floor((129, 65), h=8.0, lobe_rows=65, probes=300)
    # the clipped table is the model's sum at its nodes; the whole map's over-counts
    # the lower half near grazing views
    assert f["clipped"] < 0.05 < f["whole"]
    assert f["whole"] > 10 * f["clipped"]


def test_split_rows_are_exact_with_every_texel_a_light():
    """With as many lights as texels the tree is the texel sum: every column ~0; with few,
    each column is an error of the lights it still uses."""
    rows = env_tables.split((16, 8), counts=(4, 128), probes=200, log=lambda s: None)
    few, every = rows
    assert every["lights"] == 128 and max(every["all"], every["diffuse_exact"],
                                          every["specular_exact"]) < 1e-12
    assert few["all"] > 1e-3 and few["diffuse_exact"] > 0 and few["specular_exact"] > 0


def test_tile_floor_keeps_more_lights_for_a_smaller_budget():
    rows = env_tables.tile_floor((64, 32), eps=(1e-2, 1e-5, 0.0), tiles=12, frame=(96, 54),
                                 log=lambda s: None)
    loose, tight, none = rows
    assert loose["tiles"] == tight["tiles"] > 0
    assert loose["median"] <= tight["median"] <= none["median"] <= loose["lights"]
    assert loose["median"] < none["median"]


def test_cone_weights_bound_every_pixels_weight_and_are_exact_for_one_pixel():
    """The cone bound is at least each pixel's Blinn-Phong weight (the spherical triangle
    inequality), and for a one-pixel tile (both cones a point) it is that weight."""
    import dataclasses

    import numpy as np

    from clphong.model.environment import lobe_weights
    from clphong.tools.bench_scenes import bench_scene

    material = dataclasses.replace(bench_scene("wide", 1).material, h=8.0)
    rng = np.random.default_rng(3)
    l = rng.normal(size=(300, 3))
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    for spread in (0.02, 0.3):
        N = np.array([0.2, 0.1, 1.0]) + spread * rng.normal(size=(16, 3))
        N /= np.linalg.norm(N, axis=1, keepdims=True)
        V = np.array([0.0, -0.4, 1.0]) + spread * rng.normal(size=(16, 3))
        V /= np.linalg.norm(V, axis=1, keepdims=True)
        exact = lobe_weights(N, V, l, material).max(axis=0)
        bound = env_tables.cone_weights(N, V, l, material.exponent)
        assert (bound >= exact * (1 - 1e-9)).all()
        assert (bound > 2 * exact).any()              # a bound, not the weights themselves
    one = env_tables.cone_weights(N[:1], V[:1], l, material.exponent)
    assert np.allclose(one, lobe_weights(N[:1], V[:1], l, material)[0], rtol=1e-9, atol=1e-300)

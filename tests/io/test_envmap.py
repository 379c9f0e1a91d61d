"""clphong.io.envmap: reading lat-long maps (one-line errors naming the scene key) and
resolving environment lights into directional ones."""

from __future__ import annotations

import os
import tracemalloc

import numpy as np
import OpenImageIO as oiio
import pytest

from clphong.core.errors import SceneError
from clphong.io import envmap
from clphong.io.atomic import write_exr
from clphong.model import environment as env
from clphong.model.scene import load_scene
from clphong.tools import samples

KEY = "scene.toml: light[3].file"


def _write(path, rgb, channels=("R", "G", "B")):
    write_exr(path, np.asarray(rgb, np.float32), channel_names=channels)
    return str(path)


def _one_line(exc):
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_reads_exr_and_hdr_by_channel_name(tmp_path):
    L = samples.sky_envmap(32, 16)
    p = _write(tmp_path / "sky.exr", L)
    assert np.array_equal(envmap.read_envmap(p, KEY), L)
    # channels found by name, whatever their order in the file
    q = _write(tmp_path / "bgr.exr", L[..., ::-1], channels=("B", "G", "R"))
    assert np.array_equal(envmap.read_envmap(q, KEY), L)
    grey = _write(tmp_path / "y.exr", L[..., 1], channels=("Y",))
    assert np.array_equal(envmap.read_envmap(grey, KEY), np.repeat(L[..., 1:2], 3, axis=-1))
    # Radiance HDR (RGBE: 8-bit mantissas under the texel's largest channel's exponent,
    # so within 2^-7 of that channel, truncation and rounding both)
    h = str(tmp_path / "sky.hdr")
    out = oiio.ImageOutput.create(h)
    assert out.open(h, oiio.ImageSpec(32, 16, 3, "float"))
    assert out.write_image(L)
    out.close()
    got = envmap.read_envmap(h, KEY)
    assert got.shape == L.shape
    assert (np.abs(got - L) <= 2 ** -7 * L.max(axis=-1, keepdims=True)).all()


def test_missing_folder_fifo_and_garbage_are_one_line_naming_the_key(tmp_path):
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(str(tmp_path / "nope.exr"), KEY)
    assert _one_line(e) == f"{KEY}: {tmp_path / 'nope.exr'}: no such file"
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(str(tmp_path), KEY)
    assert _one_line(e).startswith(f"{KEY}: {tmp_path}: cannot read: it is a directory")
    fifo = tmp_path / "pipe.exr"
    os.mkfifo(fifo)
    with pytest.raises(SceneError) as e:                 # and does not block
        envmap.read_envmap(str(fifo), KEY)
    assert "it is a FIFO (named pipe); give a regular file" in _one_line(e)
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"\x76\x2f\x31\x01" + b"\x00" * 64)
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(str(junk), KEY)
    assert _one_line(e).startswith(f"{KEY}: {junk}: cannot read: ")


@pytest.mark.parametrize("w,h", [(30, 16), (16, 16), (2, 1)])
def test_not_two_to_one_says_the_size(tmp_path, w, h):
    p = _write(tmp_path / "m.exr", np.ones((h, w, 3)))
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(p, KEY)
    assert f"{KEY}: {p}: {w} x {h} texels: a latitude-longitude map is 2:1" in _one_line(e)


def test_nan_inf_and_negative_texels_are_counted(tmp_path):
    L = np.ones((8, 16, 3), np.float32)
    L[0, :12, 0] = np.nan                   # 12 texels with a NaN
    L[1, 0, :] = np.nan                     # one more (three NaN channels, one texel)
    L[2, :2, 1] = np.inf
    L[3, :3, 2] = -1.0
    L[4, 0] = [-1.0, -2.0, -3.0]
    p = _write(tmp_path / "bad.exr", L)
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(p, KEY)
    assert _one_line(e).startswith(f"{KEY}: {p}: 13 NaN texel(s), 2 with Inf, 4 negative; ")
    L = np.ones((8, 16, 3), np.float32)
    L[5, 5, 1] = -1e-30
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(_write(tmp_path / "neg.exr", L), KEY)
    assert ": 1 negative texel(s); " in _one_line(e)


def test_a_map_larger_than_memory_allows_is_refused_before_reading(tmp_path, monkeypatch):
    p = _write(tmp_path / "m.exr", np.ones((64, 128, 3)))
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "1M")
    with pytest.raises(SceneError) as e:
        envmap.read_envmap(p, KEY)
    msg = _one_line(e)
    assert msg.startswith(f"{KEY}: {p}: reading and resolving a 128x64 environment map needs about")
    assert "CLPHONG_MAX_MEMORY" in msg


@pytest.mark.parametrize("w,h,eps", [(128, 64, 3e-2), (1024, 512, 1e-2)])
def test_memory_model_bounds_the_peak(tmp_path, w, h, eps):
    """ENV_BYTES_PER_TEXEL·texels + ENV_FIXED_BYTES (+ the float32 read) is above
    tracemalloc's peak of reading and resolving a map (the fixed part dominates the
    small map, the per-texel part the large one)."""
    p = _write(tmp_path / "m.exr", samples.sky_envmap(w, h))
    m = load_scene_material()
    tracemalloc.start()
    try:
        L = envmap.read_envmap(p, KEY)
        env.environment_lights(L, m, max_error=eps)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 12 * w * h + envmap.ENV_BYTES_PER_TEXEL * w * h + envmap.ENV_FIXED_BYTES


def load_scene_material():
    from clphong.tools.bench import bench_scene

    return bench_scene("wide", 1).material


SCENE = """
[camera]
type = "perspective"
position = [0.0, 2.0, 6.0]
[material]
model = "phong"
k_a = 0.1
k_d = 0.7
k_s = 0.2
h = 32.0
[[light]]
type = "ambient"
intensity = 0.5
[[light]]
type = "environment"
file = "maps/sky.exr"
intensity = 0.5
rotation = 30
group = "sky"
[[light]]
type = "directional"
direction = [0, -1, 0]
"""


def test_resolve_replaces_the_environment_in_place_within_its_group(tmp_path):
    (tmp_path / "maps").mkdir()
    L = samples.sky_envmap(64, 32)
    _write(tmp_path / "maps" / "sky.exr", L)
    (tmp_path / "s.toml").write_text(SCENE)
    scene = load_scene(tmp_path / "s.toml")
    r = envmap.resolve_environment(scene, max_error=1e-2)
    (i, conv), = r.environments
    assert i == 1 and conv.met and conv.count > 0
    lights = r.scene.lights
    assert lights[0] == scene.lights[0] and lights[-1] == scene.lights[2]
    middle = lights[1:-1]
    assert len(middle) == conv.count
    assert all(lt.type == "directional" and lt.group == "sky" for lt in middle)
    assert r.scene.light_groups == ("default", "sky")
    # the lights are the conversion's: direction −l, radiance as colour
    assert np.allclose([lt.direction for lt in middle], -conv.l)
    assert np.allclose([lt.radiance for lt in middle], conv.radiance)
    # the same as converting the map by hand with the light's rotation and intensity
    again = env.environment_lights(L, scene.material, rotation=30, intensity=0.5, max_error=1e-2)
    assert np.array_equal(again.l, conv.l) and np.array_equal(again.radiance, conv.radiance)
    # cached: the same object for the same file, unchanged
    assert envmap.resolve_environment(scene, max_error=1e-2).environments[0][1] is conv
    # no environment light: the scene itself
    plain = r.scene
    assert envmap.resolve_environment(plain).scene is plain


def test_resolve_names_the_scene_and_the_light(tmp_path):
    (tmp_path / "s.toml").write_text(SCENE)
    scene = load_scene(tmp_path / "s.toml")
    with pytest.raises(SceneError) as e:
        envmap.resolve_environment(scene)
    assert _one_line(e) == (f"{tmp_path / 's.toml'}: light[1].file: "
                            f"{tmp_path / 'maps' / 'sky.exr'}: no such file")


def test_the_shipped_sky_is_the_generator_output():
    here = os.path.join(os.path.dirname(__file__), "..", "..", "gbuffers")
    L = envmap.read_envmap(os.path.join(here, "sky.exr"))
    made = samples.sky_envmap()
    assert L.shape == made.shape == (128, 256, 3)
    assert np.array_equal(L, made.astype(np.float16).astype(np.float32))
    scene = load_scene(os.path.join(here, "spheres_sky.toml"))
    (lt,) = scene.lights_of("environment")
    assert os.path.samefile(lt.file, os.path.join(here, "sky.exr"))
    assert scene.camera.position == samples.SPHERES_CAMERA["position"]


# ------------------------------------------------------------------ the command and the API

def _sky_scene(tmp_path, extra=""):
    _write(tmp_path / "sky.exr", samples.sky_envmap(32, 16))
    (tmp_path / "s.toml").write_text(
        '[camera]\ntype = "perspective"\nposition = [0.0, 2.0, 6.0]\n'
        '[material]\nmodel = "phong"\nk_a = 0.0\nk_d = 0.7\nk_s = 0.2\nh = 32.0\n'
        '[[light]]\ntype = "environment"\nfile = "sky.exr"\nintensity = 0.3\n' + extra)
    return tmp_path / "s.toml"


def test_render_relight_and_the_api_resolve_the_environment(tmp_path, capsys):
    """`clphong render --env-error`, a Relighter and clphong.render shade the same
    resolved lights: the same pixels; --stats names the conversion."""
    import clphong
    from clphong.console.cli import main

    scene_path = _sky_scene(tmp_path)
    gb = samples.spheres_gbuffer(64, 32)          # 2:1, so read_envmap reads the output back
    from clphong.io.gbuffer import write_gbuffer

    write_gbuffer(tmp_path / "g.exr", gb.position, gb.normal, gb.albedo, coverage=gb.coverage)
    assert main(["render", str(scene_path), str(tmp_path / "g.exr"), "-o", str(tmp_path / "o.exr"),
                 "--env-error", "0.02", "--stats"]) == 0
    err = capsys.readouterr().err
    assert "environment: light[0]: 512 texels as " in err and "(--env-error 0.02)" in err
    got = envmap.read_envmap(str(tmp_path / "o.exr"))       # any RGB EXR reads back this way
    api = clphong.render(load_scene(scene_path), gb, env_error=0.02)
    assert np.array_equal(got, api)
    # a Relighter on this frame's probes (the default): resolved per frame, the same lights
    f = clphong.Relighter(scene_path, env_error=0.02)
    assert f.environments == () and not f.scene.lights_of("environment")
    assert np.array_equal(f.relight(gb), api) and f.environments[0][1].max_error == 0.02
    # a worker's relighter from the spec resolves its frames too: the same pixels
    assert np.array_equal(f.spec.build().relight(gb), api)
    # on every normal and view: resolved at construction, for any frame
    r = clphong.Relighter(scene_path, env_error=0.02, env_probes="all")
    assert not r.scene.lights_of("environment") and r.environments[0][1].max_error == 0.02
    assert r.spec.env_error == 0.02 and r.spec.build().scene.lights == r.scene.lights
    every = clphong.render(load_scene(scene_path), gb, env_error=0.02, env_probes="all")
    assert np.array_equal(r.relight(gb), every)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "x"])
def test_bad_env_error_is_a_usage_line(tmp_path, capsys, value):
    from clphong.console.cli import main

    with pytest.raises(SystemExit) as e:
        main(["render", "s.toml", "g.exr", "-o", str(tmp_path / "o.exr"), "--env-error", value])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--env-error" in err and "environment error" in err


def test_a_bad_map_stops_render_with_one_line(tmp_path, capsys):
    from clphong.console.cli import main

    scene_path = _sky_scene(tmp_path)
    L = samples.sky_envmap(32, 16)
    L[0, :5] = -1.0
    _write(tmp_path / "sky.exr", L)
    write = samples.spheres_gbuffer(16, 8)
    from clphong.io.gbuffer import write_gbuffer

    write_gbuffer(tmp_path / "g.exr", write.position, write.normal, write.albedo, coverage=write.coverage)
    assert main(["render", str(scene_path), str(tmp_path / "g.exr"), "-o", str(tmp_path / "o.exr")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{scene_path}: light[0].file: {tmp_path / 'sky.exr'}: 5 negative texel(s); " in err
    assert not (tmp_path / "o.exr").exists()


# ------------------------------------------------------------------- the disk cache (issue 25)

@pytest.fixture
def disk(tmp_path, monkeypatch):
    """An empty disk cache and no in-process one; the map and scene of SCENE."""
    from clphong.core.cache import Store

    store = Store(str(tmp_path / "cache"), ".npz", 3)
    monkeypatch.setattr(envmap, "_DISK", store)
    monkeypatch.setattr(envmap, "_CACHE", {})
    (tmp_path / "maps").mkdir()
    _write(tmp_path / "maps" / "sky.exr", samples.sky_envmap(64, 32))
    (tmp_path / "s.toml").write_text(SCENE)
    return store, load_scene(tmp_path / "s.toml")


def _no_conversion(*a, **k):
    raise AssertionError("converted again")


def test_a_second_process_converts_nothing(disk, monkeypatch):
    """The conversion is kept on disk, keyed by the map's content and the settings: with the
    process's own cache emptied (a new process), nothing is converted and the lights are
    the same to the bit; seconds is 0 (no conversion ran)."""
    store, scene = disk
    first = envmap.resolve_environment(scene, max_error=1e-2).environments[0][1]
    assert first.seconds > 0 and len(list(store.folder.glob("*.npz"))) == 1
    monkeypatch.setattr(envmap, "_CACHE", {})
    monkeypatch.setattr(envmap, "environment_lights", _no_conversion)
    again = envmap.resolve_environment(scene, max_error=1e-2).environments[0][1]
    assert np.array_equal(again.l, first.l) and np.array_equal(again.radiance, first.radiance)
    assert (again.count, again.estimated_error, again.met, again.texels, again.seconds) == (
        first.count, first.estimated_error, first.met, first.texels, 0.0)


class _KeyedShader:
    """A probe shader with a cache key: the float64 numpy pixels under another name."""

    key = "another probe shader"

    def __call__(self, *args):
        from clphong.model.environment import probe_pixels

        return probe_pixels(*args)


@pytest.mark.parametrize("change", ["target", "map", "material", "shader"])
def test_what_the_conversion_depends_on_converts_again(disk, monkeypatch, tmp_path, change):
    store, scene = disk
    envmap.resolve_environment(scene, max_error=1e-2)
    monkeypatch.setattr(envmap, "_CACHE", {})
    eps = 1e-2
    if change == "shader":
        envmap.resolve_environment(scene, max_error=eps, shade=_KeyedShader())
    elif change == "target":
        eps = 2e-2
    elif change == "map":                     # other content (same name, size and shape)
        _write(tmp_path / "maps" / "sky.exr", samples.sky_envmap(64, 32) * 2.0)
    else:
        import dataclasses

        scene = dataclasses.replace(scene, material=dataclasses.replace(scene.material, h=8.0))
    if change != "shader":
        envmap.resolve_environment(scene, max_error=eps)
    assert len(list(store.folder.glob("*.npz"))) == 2


def test_a_damaged_or_unwritable_cache_only_converts_again(disk, monkeypatch):
    store, scene = disk
    first = envmap.resolve_environment(scene, max_error=1e-2).environments[0][1]
    entry, = store.folder.glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:100])              # a truncated entry
    monkeypatch.setattr(envmap, "_CACHE", {})
    again = envmap.resolve_environment(scene, max_error=1e-2).environments[0][1]
    assert again.seconds > 0 and np.array_equal(again.l, first.l)
    assert envmap._load(entry) is not None                   # rewritten whole
    # a cache folder that cannot be made: the conversion still runs, nothing is kept
    blocker = store.folder.parent / "file"
    blocker.write_text("x")
    from clphong.core.cache import Store

    monkeypatch.setattr(envmap, "_DISK", Store(str(blocker / "cache"), ".npz", 3))
    monkeypatch.setattr(envmap, "_CACHE", {})
    assert envmap.resolve_environment(scene, max_error=1e-2).environments[0][1].seconds > 0


def test_the_cache_keeps_its_newest_entries(disk, monkeypatch):
    store, scene = disk                                      # keep = 3
    for eps in (1e-2, 2e-2, 3e-2, 4e-2):
        monkeypatch.setattr(envmap, "_CACHE", {})
        envmap.resolve_environment(scene, max_error=eps)
        os.utime(next(iter(sorted(store.folder.glob("*.npz"), key=os.path.getmtime))),
                 (1, 1))                                     # the oldest, clearly
    assert len(list(store.folder.glob("*.npz"))) == 3
    assert not list(store.folder.glob(".*.tmp"))


def test_a_conversion_says_it_runs_and_a_hit_says_nothing(disk, monkeypatch):
    store, scene = disk
    lines = []
    monkeypatch.setattr(envmap, "conversion_notice", lines.append)
    monkeypatch.setattr(envmap, "NOTICE_AFTER_S", 0.0)
    envmap.resolve_environment(scene, max_error=1e-2)
    assert lines[0].startswith("clphong: converting ") and "sky.exr" in lines[0]
    assert "cached afterwards" in lines[0] and " lights, estimated error " in lines[1]
    lines.clear()
    monkeypatch.setattr(envmap, "_CACHE", {})
    envmap.resolve_environment(scene, max_error=1e-2)
    assert lines == []


def test_building_tables_says_it_runs_and_a_hit_says_nothing(disk, monkeypatch):
    store, scene = disk
    lines = []
    monkeypatch.setattr(envmap, "conversion_notice", lines.append)
    monkeypatch.setattr(envmap, "NOTICE_AFTER_S", 0.0)
    monkeypatch.setattr(envmap, "_TABLES", {})
    from clphong.core.cache import Store
    monkeypatch.setattr(envmap, "_TABLE_DISK", Store(str(store.folder) + "-tables", ".npz", 3))
    sky = next(lt for lt in scene.lights if lt.type == "environment")
    envmap._tables(sky, "light[0]", scene.material, 1e-2)
    assert lines[0].startswith("clphong: converting light[0]: ") and "into tables" in lines[0]
    assert "the diffuse table, " in lines[1] and "estimated error" in lines[1]
    lines.clear()
    monkeypatch.setattr(envmap, "_TABLES", {})
    envmap._tables(sky, "light[0]", scene.material, 1e-2)
    assert lines == []


# ------------------------------------------------- bad maps follow --nonfinite (issue 25)

def _nan_map(tmp_path):
    L = samples.sky_envmap(64, 32)
    L[3, :7, 0] = np.nan
    L[5, 2] = np.inf
    return _write(tmp_path / "maps" / "sky.exr", L), L


def test_nan_texels_follow_the_nonfinite_policy(tmp_path):
    (tmp_path / "maps").mkdir()
    p, L = _nan_map(tmp_path)
    with pytest.warns(Warning, match=r"7 NaN texel\(s\), 1 with Inf taken as 0, no light from there"):
        got = envmap.read_envmap(p, KEY, "background")
    bad = ~np.isfinite(L).all(axis=-1)
    assert (got[bad] == 0).all() and np.array_equal(got[~bad], L[~bad])
    for policy in ("error", "pass"):
        with pytest.raises(SceneError) as e:
            envmap.read_envmap(p, KEY, policy)
        assert "7 NaN texel(s), 1 with Inf;" in _one_line(e)
        assert "--nonfinite background takes NaN/Inf texels as 0" in _one_line(e)
    L2 = L.copy()
    L2[7, 0] = -1.0                      # negative radiance: refused whatever the policy
    with pytest.raises(SceneError, match="1 negative"):
        envmap.read_envmap(_write(tmp_path / "neg.exr", L2), KEY, "background")


def test_an_all_zero_map_warns_and_adds_no_light(tmp_path):
    p = _write(tmp_path / "zero.exr", np.zeros((8, 16, 3), np.float32))
    with pytest.warns(Warning, match="every texel is 0: the environment adds no light"):
        assert not envmap.read_envmap(p, KEY).any()


def test_a_one_channel_map_is_grey_and_alpha_is_ignored(tmp_path):
    L = samples.sky_envmap(32, 16)
    grey = _write(tmp_path / "y.exr", L[..., :1], channels=("Y",))
    assert np.array_equal(envmap.read_envmap(grey, KEY), np.repeat(L[..., :1], 3, axis=-1))
    rgba = np.concatenate([L, np.full(L.shape[:2] + (1,), 0.25, np.float32)], axis=-1)
    p = _write(tmp_path / "rgba.exr", rgba, channels=("R", "G", "B", "A"))
    assert np.array_equal(envmap.read_envmap(p, KEY), L)


def test_the_policy_is_part_of_the_cache_key_and_warnings_come_back(disk, tmp_path, monkeypatch):
    """A map converted with NaN texels taken as 0 is not served to a run that refuses them,
    and a run served from the cache says the same warning."""
    store, scene = disk
    _nan_map(tmp_path)
    with pytest.warns(Warning, match="taken as 0"):
        envmap.resolve_environment(scene, max_error=1e-2, nonfinite="background")
    monkeypatch.setattr(envmap, "_CACHE", {})
    with pytest.raises(SceneError, match="NaN"):
        envmap.resolve_environment(scene, max_error=1e-2, nonfinite="error")
    monkeypatch.setattr(envmap, "environment_lights", _no_conversion)
    for cache in ({}, None):             # from the disk, then from the process's own cache
        if cache is not None:
            monkeypatch.setattr(envmap, "_CACHE", cache)
        with pytest.warns(Warning, match="taken as 0"):
            envmap.resolve_environment(scene, max_error=1e-2, nonfinite="background")


def test_render_takes_nan_texels_as_0_by_default_and_stops_with_nonfinite_error(tmp_path, capsys):
    from clphong.console.cli import main
    from clphong.io.gbuffer import write_gbuffer

    scene_path = _sky_scene(tmp_path)
    L = samples.sky_envmap(32, 16)
    L[2, :4, 1] = np.nan
    _write(tmp_path / "sky.exr", L)
    g = samples.spheres_gbuffer(16, 8)
    write_gbuffer(tmp_path / "g.exr", g.position, g.normal, g.albedo, coverage=g.coverage)
    argv = ["render", str(scene_path), str(tmp_path / "g.exr"), "-o", str(tmp_path / "o.exr")]
    assert main(argv) == 0
    assert "4 NaN texel(s) taken as 0" in capsys.readouterr().err
    (tmp_path / "o.exr").unlink()
    assert main(argv + ["--nonfinite", "error"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "4 NaN texel(s);" in err and not (tmp_path / "o.exr").exists()


def test_plan_names_each_environments_path(tmp_path, capsys):
    from clphong.console.cli import main

    scene_path = _sky_scene(tmp_path)
    _write(tmp_path / "sky.exr", samples.sky_envmap(32, 16))
    assert main(["plan", str(scene_path), "--env-error", "1e-2"]) == 0
    out = capsys.readouterr().out.splitlines()
    env = [ln for ln in out if ln.startswith("environment: light[0] ")]
    assert len(env) == 2
    # no frame: no horizon check, so the lights' path, and why
    assert ": lights: its estimate covers every normal and view" in env[0]
    assert "directional lights of its 512 texels" in env[1]
    assert "within --env-error 0.01" in env[1]


def test_plan_with_a_frame_names_the_tables(tmp_path, capsys):
    """Given a frame whose every pixel the tables' bound holds (a heightfield seen from
    above, Phong), plan names the tables, their sizes and the sun's lights, and compiles
    ENV_TABLE."""
    from clphong.console.cli import main
    from clphong.io.gbuffer import write_gbuffer
    from conftest import heightfield

    scene_path = _sky_scene(tmp_path)
    _write(tmp_path / "sky.exr", samples.sky_envmap(64, 32))
    g = heightfield(np.random.default_rng(0), 16, 20)
    write_gbuffer(tmp_path / "g.exr", g.position, g.normal, g.albedo, coverage=g.coverage)
    assert main(["plan", str(scene_path), str(tmp_path / "g.exr"), "--env-error", "1e-2"]) == 0
    out = capsys.readouterr().out
    assert "-DENV_TABLE=1" in out and "-DENV_D_ROWS=" in out
    line = next(ln for ln in out.splitlines() if ln.startswith("environment: light[0] "))
    assert ": tables: diffuse " in line and "sun texel(s) as lights" in line


# ------------------------------------------------------------------- a frame's own probes

def test_frame_pairs_are_the_pixels_as_the_kernel_sees_them():
    """frame_pairs: the shaded pixels only (no zero normal, no NaN, no 0 coverage), unit
    normals, v towards the eye (n at the eye) or the orthographic view, and per-pixel
    k_d, k_s and specular-colour maps folded into the albedo (a relative error does not
    change when a pixel is scaled); None without a shaded pixel."""
    from clphong.io.gbuffer import GBuffer
    from clphong.model.scene import Camera, Material

    P = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [0, 0, 5]]], np.float32)
    N = np.array([[[0, 0, 2], [0, 0, 0], [0, 1, 1], [np.nan, 0, 1], [0, 0, 1]]], np.float32)
    A = np.full((1, 5, 3), 0.5, np.float32)
    cov = np.array([[1.0, 1.0, 0.0, 1.0, 1.0]], np.float32)
    mat = Material(model="phong", k_a=0.0, k_d=0.5, k_s=0.25, h=8.0)
    maps = {"k_d": np.full((1, 5), 1.0, np.float32), "k_s": np.array([[0.5, 0, 0, 0, 0]], np.float32)}
    gb = GBuffer(position=P, normal=N, albedo=A, coverage=cov, maps=maps)
    cam = Camera(type="perspective", position=(0.0, 0.0, 5.0))
    fp = envmap.frame_pairs(cam, gb, material=mat)
    assert np.array_equal(fp.n, [[0, 0, 1], [0, 0, 1]])  # pixels 0 and 4
    assert np.allclose(fp.v, [[0, 0, 1], [0, 0, 1]])     # pixel 4 is at the eye: v = n
    # pixel 0: diffuse 0.5 · (1/0.5) = 1, specular 0.5/0.25 = 2: folded 0.5; pixel 4 has no
    # specular (k_s map 0): pure diffuse, the cap
    assert np.allclose(fp.diffuse, 1.0) and np.allclose(fp.specular, [[2.0] * 3, [0.0] * 3])
    assert np.allclose(fp.albedo[0], 0.5) and np.all(fp.albedo[1] == env.ALBEDO_CAP)
    assert np.allclose(fp.low, 0.5) and np.all(fp.high == env.ALBEDO_CAP)
    assert np.allclose(fp.diffuse_max, 1.0) and np.allclose(fp.specular_max, 2.0)
    ortho = Camera(type="orthographic", direction=(0.0, -0.6, -0.8))
    fp = envmap.frame_pairs(ortho, gb)
    assert np.allclose(fp.v, [[0, 0.6, 0.8]] * 2) and np.all(fp.albedo == 0.5)
    dark = GBuffer(position=P, normal=np.zeros_like(N), albedo=A)
    assert envmap.frame_pairs(cam, dark) is None
    # a NaN albedo (the non-finite policy's pixel) is neither a probe nor in the range
    A2 = A.copy()
    A2[0, 0] = np.nan
    A2[0, 4] = 0.25
    fp = envmap.frame_pairs(cam, GBuffer(position=P, normal=N, albedo=A2, coverage=cov))
    assert len(fp.n) == 1 and np.allclose(fp.low, 0.25) and np.allclose(fp.high, 0.25)


def test_a_frames_probes_are_part_of_the_cache_key(disk, monkeypatch):
    """A conversion on a frame's probes is its own cache entry: other probes convert
    again, the same probes (another process) convert nothing."""
    store, scene = disk

    def probes(low):
        return env.FrameProbes(n=[[0.0, 1.0, 0.0], [0.6, 0.8, 0.0]], v=[[0.0, 0.6, 0.8], [0.0, 0.0, 1.0]],
                               diffuse=np.full((2, 3), 0.5), specular=np.ones((2, 3)), low=[low] * 3,
                               high=[0.5] * 3, diffuse_max=[0.5] * 3, specular_max=[1.0] * 3)

    a = envmap.resolve_environment(scene, max_error=1e-2, pairs=probes(0.5))
    envmap.resolve_environment(scene, max_error=1e-2)
    envmap.resolve_environment(scene, max_error=1e-2, pairs=probes(0.25))
    assert len(list(store.folder.glob("*.npz"))) == 3
    monkeypatch.setattr(envmap, "_CACHE", {})
    monkeypatch.setattr(envmap, "environment_lights", _no_conversion)
    b = envmap.resolve_environment(scene, max_error=1e-2, pairs=probes(0.5))
    assert np.array_equal(a.environments[0][1].l, b.environments[0][1].l)


def test_a_batch_with_a_bad_map_stops_once_before_any_frame(tmp_path):
    """check_environment_maps: the map's one-line error, without a conversion."""
    scene_path = _sky_scene(tmp_path)
    L = samples.sky_envmap(32, 16)
    L[1, :3] = -2.0
    _write(tmp_path / "sky.exr", L)
    with pytest.raises(SceneError, match="3 negative texel"):
        envmap.check_environment_maps(load_scene(scene_path))
    # a Relighter on frame probes reads its maps at construction too: the same line, early
    import clphong

    with pytest.raises(SceneError, match="3 negative texel"):
        clphong.Relighter(scene_path)


def test_a_frame_source_is_named_by_its_bytes_and_chooses_probes_only_to_convert(disk, monkeypatch):
    """FrameSource: the same frame, camera and material give the same name, another albedo
    or camera another; a conversion found on disk (another process) chooses no probes."""
    from clphong.model.scene import Camera

    store, scene = disk
    gb = samples.spheres_gbuffer(32, 16)
    src = envmap.FrameSource(scene.camera, gb, scene.material)
    assert src.digest() == envmap.FrameSource(scene.camera, gb, scene.material).digest()
    other = samples.spheres_gbuffer(32, 16)
    other.albedo[np.unravel_index(np.argmax(other.albedo[..., 0]), other.shape)] *= 0.5
    assert envmap.FrameSource(scene.camera, other, scene.material).digest() != src.digest()
    moved = Camera(type="perspective", position=(0.0, 2.0, 6.5))
    assert envmap.FrameSource(moved, gb, scene.material).digest() != src.digest()
    first = envmap.resolve_environment(scene, max_error=1e-2, pairs=src).environments[0][1]
    monkeypatch.setattr(envmap, "_CACHE", {})

    def no_probes(*a, **k):
        raise AssertionError("chose probes for a conversion found on disk")

    monkeypatch.setattr(envmap, "frame_pairs", no_probes)
    again = envmap.resolve_environment(scene, max_error=1e-2,
                                       pairs=envmap.FrameSource(scene.camera, gb, scene.material))
    assert np.array_equal(again.environments[0][1].l, first.l)

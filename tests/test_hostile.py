"""Hostile input and faults: the catalogue of bad inputs, run through the CLI.

Every case runs ``clphong render`` in-process (``clphong.console.cli.main``) and checks
what a user sees and what is left on disk:

- exactly one ``clphong: error: ...`` line on stderr (warnings aside), naming
  the file, channel or key at fault;
- a non-zero exit status (1 for processing errors, 128 + signal when stopped);
- no output file, partial or otherwise, and no temporary file left behind,
  and an output that existed before is left byte-for-byte as it was.

A few cases also run as subprocesses (the real entry point, real environment).
Cases already covered elsewhere are not repeated: a missing G-buffer or scene
file, an unknown scene key via the API, the output overwriting the G-buffer
and a missing output folder are in tests/console/test_cli.py; OpenImageIO failures at
each stage of a write are in tests/io/test_atomic.py.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from conftest import CATALOGUE, random_gbuffer

from clphong.console.cli import main
from clphong.device import runtime, selection
from clphong.io.atomic import write_exr
from clphong.io.gbuffer import write_gbuffer

H, W = 6, 8

SCENE = """\
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
type = "point"
position = [3.0, 5.0, 4.0]
color = [1.0, 0.9, 0.8]
intensity = 5.0
attenuation = [1.0, 0.0, 0.02]

[[light]]
type = "directional"
direction = [-1.0, -1.5, -1.0]
intensity = 2.0

[[light]]
type = "ambient"
intensity = 1.0
"""


# --------------------------------------------------------------------------- helpers


@pytest.fixture
def work(tmp_path):
    """inputs in tmp/in, outputs in tmp/out; a valid scene and G-buffer."""
    src = tmp_path / "in"
    out = tmp_path / "out"
    src.mkdir()
    out.mkdir()
    (src / "scene.toml").write_text(SCENE)
    gb = random_gbuffer(np.random.default_rng(7), H, W)
    write_gbuffer(src / "gbuf.exr", gb.position, gb.normal, gb.albedo, coverage=gb.coverage)
    return src, out


def _files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def cli(argv) -> int:
    """``clphong`` in-process, with paths as strings."""
    return main([str(a) for a in argv])


def fails(argv, capsys, root: Path, *needles: str, code: int = 1) -> str:
    """Run the CLI; check one error line with ``needles``, exit ``code``, nothing written."""
    before = _files(root)
    rc = cli(argv)
    err = capsys.readouterr().err
    assert rc == code, err
    lines = err.splitlines()
    errors = [ln for ln in lines if not ln.startswith("clphong: warning: ")]
    assert len(errors) == 1, err
    line = errors[0]
    if code == 1:
        assert line.startswith("clphong: error: "), line
    for needle in needles:
        assert needle in line, f"{needle!r} not in {line!r}"
    after = _files(root)
    assert after == before, f"left behind: {sorted(set(after) - set(before))}"
    assert not [p for p in after if ".tmp-" in p]
    case = os.environ.get("PYTEST_CURRENT_TEST", "?").split("::")[-1].split(" ")[0]
    CATALOGUE.append((case, rc, line.replace(str(root), "DIR")))
    return line


def render_argv(src: Path, out: Path, gbuffer=None, scene=None, output=None, extra=()):
    return ["render", scene or src / "scene.toml", gbuffer or src / "gbuf.exr",
            "-o", output or out / "beauty.exr", *extra]


def _raw_exr(path, planes: dict, *, window=None, display=None, pixel_type="float"):
    """Write channels {name: (h, w)} with OpenImageIO; optional data/display windows.

    ``window`` = (x, y) origin of the data window; ``display`` = (W, H) of the
    display window (at 0, 0).
    """
    names = list(planes)
    data = np.ascontiguousarray(np.stack([np.asarray(planes[n], np.float32) for n in names], -1))
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], len(names), oiio.TypeDesc(pixel_type))
    spec.channelnames = tuple(names)
    if window is not None:
        spec.x, spec.y = window
    if display is not None:
        spec.full_x = spec.full_y = 0
        spec.full_width, spec.full_height = display
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(data), out.geterror()
    assert out.close()
    return path


def _vec(name, arr, comps="XYZ"):
    return {f"{name}.{c}" if name else c: arr[..., i] for i, c in enumerate(comps)}


# =========================================================================== bad EXR files


def test_truncated_exr(work, capsys):
    src, out = work
    data = (src / "gbuf.exr").read_bytes()
    (src / "cut.exr").write_bytes(data[: len(data) // 2])
    fails(render_argv(src, out, gbuffer=src / "cut.exr"), capsys, src.parent, "cut.exr",
          "missing or corrupted")


def test_truncated_inside_the_header(work, capsys):
    src, out = work
    (src / "cut.exr").write_bytes((src / "gbuf.exr").read_bytes()[:60])
    fails(render_argv(src, out, gbuffer=src / "cut.exr"), capsys, src.parent, "cut.exr",
          "cannot read as EXR")


def test_random_bytes_named_exr(work, capsys):
    src, out = work
    (src / "noise.exr").write_bytes(np.random.default_rng(1).bytes(4096))
    fails(render_argv(src, out, gbuffer=src / "noise.exr"), capsys, src.parent, "noise.exr",
          "cannot read as EXR", "not an OpenEXR file")


def test_empty_file_named_exr(work, capsys):
    src, out = work
    (src / "empty.exr").write_bytes(b"")
    fails(render_argv(src, out, gbuffer=src / "empty.exr"), capsys, src.parent, "empty.exr",
          "cannot read as EXR")


@pytest.mark.parametrize("name", ["frame.png", "frame.exr"], ids=["png", "png-renamed-exr"])
def test_png_given_as_gbuffer(work, capsys, name):
    src, out = work
    png = src / "real.png"
    o = oiio.ImageOutput.create(str(png))
    assert o.open(str(png), oiio.ImageSpec(W, H, 3, "uint8"))
    assert o.write_image(np.full((H, W, 3), 128, np.uint8)) and o.close()
    shutil.copy(png, src / name)
    fails(render_argv(src, out, gbuffer=src / name), capsys, src.parent, name,
          "not an OpenEXR file (it is a PNG file)")


@pytest.mark.parametrize("command", ["render", "inspect"])
def test_broken_png_gives_one_line_not_libpngs_as_well(tmp_path, command):
    """A file with PNG's signature and junk after it: OpenImageIO's PNG reader let
    libpng print its own complaint on stderr (file descriptor 2) before clphong's
    line. A subprocess, so that the C library's stderr is what is checked."""
    fake = tmp_path / ("fake.exr" if command == "render" else "fake.png")
    fake.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    scene = Path(__file__).resolve().parent.parent / "gbuffers" / "spheres.toml"
    argv = (["render", str(scene), str(fake), "-o", str(tmp_path / "o.exr")] if command == "render"
            else ["inspect", str(fake)])
    p = subprocess.run([sys.executable, "-m", "clphong", *argv], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode != 0
    assert p.stderr.count("\n") == 1 and p.stderr.startswith("clphong: error: "), p.stderr
    assert str(fake) in p.stderr and "libpng" not in p.stderr.split(": ", 2)[1]
    assert not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("missing", ["normal", "position"])
def test_exr_missing_a_buffer(work, capsys, missing):
    src, out = work
    gb = random_gbuffer(np.random.default_rng(2), H, W)
    planes = {**_vec("P", gb.position), **_vec("N", gb.normal), **_vec("albedo", gb.albedo, "RGB")}
    drop = "P" if missing == "position" else "N"
    planes = {k: v for k, v in planes.items() if not k.startswith(drop + ".")}
    _raw_exr(src / "partial.exr", planes)
    line = fails(render_argv(src, out, gbuffer=src / "partial.exr"), capsys, src.parent,
                 "partial.exr", f"no {missing} channels found", "the file has: ")
    assert f"--channels {missing}=" in line


def test_separate_buffers_of_different_sizes(work, capsys):
    src, out = work
    write_exr(src / "P.exr", np.zeros((H, W, 3)))
    write_exr(src / "N.exr", np.ones((H + 1, W, 3)))
    write_exr(src / "A.exr", np.ones((H, W, 3)))
    argv = ["render", src / "scene.toml", "--position", src / "P.exr", "--normal", src / "N.exr",
            "--albedo", src / "A.exr", "-o", out / "beauty.exr"]
    fails(argv, capsys, src.parent, f"position {src / 'P.exr'} is {W}x{H}",
          f"normal {src / 'N.exr'} is {W}x{H + 1}", "same size")


def _separate_files_with_windows(src, windows, display=(W, H)):
    """P, N, A files whose data windows are ``windows[k]`` = (x, y, w, h) in a WxH display."""
    rng = np.random.default_rng(3)
    for key, (x, y, w, h) in windows.items():
        arr = rng.uniform(0.2, 1.0, (h, w, 3))
        if key == "N":
            arr[..., 2] += 1.0
        _raw_exr(src / f"{key}.exr", _vec("", arr, "RGB"), window=(x, y), display=display)
    return ["--position", src / "P.exr", "--normal", src / "N.exr", "--albedo", src / "A.exr"]


def test_data_windows_that_do_not_overlap(work, capsys):
    src, out = work
    files = _separate_files_with_windows(src, {"P": (0, 0, 3, H), "N": (4, 0, 4, H), "A": (0, 0, W, H)})
    line = fails(["render", src / "scene.toml", *files, "-o", out / "beauty.exr"], capsys, src.parent,
                 "data windows", "do not overlap", "P.exr", "N.exr")
    assert "position" in line and "normal" in line


def test_data_windows_that_overlap_in_part_shade_only_the_overlap(work, capsys):
    """Accepted: where a buffer has no data the pixel is background (README policy)."""
    import clphong

    src, out = work
    files = _separate_files_with_windows(src, {"P": (0, 0, 6, H), "N": (2, 1, 6, 5), "A": (0, 0, W, H)})
    assert cli(["render", src / "scene.toml", *files, "-o", out / "b.exr"]) == 0
    gb = clphong.read_gbuffer(position=src / "P.exr", normal=src / "N.exr", albedo=src / "A.exr")
    bg = gb.background_mask()
    inside = np.zeros((H, W), bool)
    inside[1:6, 2:6] = True                   # the intersection of the three data windows
    assert np.array_equal(~bg, inside)
    rgb = clphong.render(clphong.load_scene(src / "scene.toml"), gb)
    assert np.all(rgb[~inside] == 0) and np.all(rgb[inside].sum(-1) > 0)


def test_deep_exr(work, capsys):
    src, out = work
    spec = oiio.ImageSpec(W, H, 2, "float")
    spec.channelnames = ("A", "Z")
    spec.deep = True
    deep = oiio.DeepData()
    deep.init(spec)
    path = str(src / "deep.exr")
    o = oiio.ImageOutput.create(path)
    assert o.open(path, spec) and o.write_deep_image(deep) and o.close()
    fails(render_argv(src, out, gbuffer=path), capsys, src.parent, "deep.exr",
          "deep EXR files are not supported", "oiiotool --flatten")


def test_multipart_exr_duplicate_channel(work, capsys):
    src, out = work
    gb = random_gbuffer(np.random.default_rng(4), H, W)
    path = str(src / "parts.exr")
    specs = []
    for name, chans in (("geo", ("P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z")),
                        ("col", ("albedo.R", "albedo.G", "N.Y"))):          # N.Y in two parts
        s = oiio.ImageSpec(W, H, len(chans), "float")
        s.channelnames = chans
        s.attribute("name", name)
        specs.append(s)
    o = oiio.ImageOutput.create(path)
    assert o.open(path, specs)
    assert o.write_image(np.ascontiguousarray(np.concatenate([gb.position, gb.normal], -1)))
    assert o.open(path, specs[1], "AppendSubimage") and o.write_image(gb.albedo) and o.close()
    fails(render_argv(src, out, gbuffer=path), capsys, src.parent, "parts.exr",
          "channel 'N.Y' is in part 0 (geo) and in part 1 (col)", "unique across parts")


def _huge_display_window(src, size):
    """A tiny file: a 2x2 data window in a size x size display window."""
    gb = random_gbuffer(np.random.default_rng(5), 2, 2)
    planes = {**_vec("P", gb.position), **_vec("N", gb.normal), **_vec("albedo", gb.albedo, "RGB")}
    return _raw_exr(src / "huge.exr", planes, window=(0, 0), display=(size, size))


def test_huge_display_window_is_refused_not_killed(work, capsys):
    """1e5 x 1e5 pixels would need ~720 GB: refused from the header, whatever the machine."""
    src, out = work
    path = _huge_display_window(src, 100_000)
    assert path.stat().st_size < 10_000
    line = fails(render_argv(src, out, gbuffer=path), capsys, src.parent, "huge.exr",
                 "100000x100000", "data window 2x2", "needs about", "of memory")
    assert "crop" in line


def test_16k_frame_over_the_memory_limit_is_refused(work, capsys, monkeypatch):
    """16K x 16K with 9 channels needs ~18 GiB to read: refused under a 2 GiB limit."""
    src, out = work
    path = _huge_display_window(src, 16384)
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "2G")
    fails(render_argv(src, out, gbuffer=path), capsys, src.parent, "huge.exr", "16384x16384",
          "CLPHONG_MAX_MEMORY=2G")


# =========================================================================== bad scene files


def _scene(src: Path, text: str, name="bad.toml") -> Path:
    (src / name).write_text(text)
    return src / name


@pytest.mark.parametrize("case,text,needles", [
    ("invalid-toml", SCENE.replace("k_d = 0.7", "k_d = = 0.7"), ["bad.toml:8:", "invalid TOML"]),
    ("unknown-key", SCENE.replace("k_s = 0.2", "k_ss = 0.2"),
     ["bad.toml: material.k_ss: unknown key", "did you mean 'k_s'?"]),
    ("unknown-table", SCENE.replace("[material]", "[materials]"), ["bad.toml: materials: unknown key"]),
    ("wrong-type", SCENE.replace("intensity = 5.0", 'intensity = "5"'),
     ["bad.toml: light[0].intensity: expected a number", "without quotes"]),
    ("wrong-type-vector", SCENE.replace("position = [3.0, 5.0, 4.0]", "position = 3.0"),
     ["bad.toml: light[0].position: expected an array of 3 numbers"]),
    ("nan", SCENE.replace("h = 32.0", "h = nan"), ["bad.toml: material.h: must be finite, got nan"]),
    ("inf", SCENE.replace("intensity = 2.0", "intensity = -inf"),
     ["bad.toml: light[1].intensity: must be finite, got -inf"]),
    ("zero-direction", SCENE.replace("direction = [-1.0, -1.5, -1.0]", "direction = [0, 0.0, -0.0]"),
     ["bad.toml: light[1].direction: zero-length vector"]),
    ("zero-camera-direction", SCENE.replace('type = "perspective"\nposition = [0.0, 2.0, 6.0]',
                                            'type = "orthographic"\ndirection = [0, 0, 0]'),
     ["bad.toml: camera.direction: zero-length vector"]),
    ("attenuation-zero", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "attenuation = [1.0, -2.0, 1.0]"),
     ["bad.toml: light[0].attenuation: p(d) = c0 + c1*d + c2*d^2 reaches 0 at d = 1"]),
    ("attenuation-c0-zero-c1-negative", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "attenuation = [0, -1, 1]"),
     ["bad.toml: light[0].attenuation:", "with c0 = 0 both must be >= 0"]),
    ("power-and-intensity", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "power = 100.0"),
     ["bad.toml: light[0].power: give power (watts, with Cycles' 1/d^2 falloff) or intensity, not both"]),
    ("not-utf8", None, ["bad.toml:6: invalid TOML: not UTF-8 (byte 80)"]),
    # finite in float64, infinite as the kernels' float32 (NaN pixels before)
    ("beyond-float32", SCENE.replace("position = [3.0, 5.0, 4.0]", "position = [3.0, 5.0, 4e38]"),
     ["bad.toml: light[0].position[2]: 4e+38 is beyond the float32 range"]),
    # NaN pixels with exit 0 before: a float32 subnormal c0 is 0 to the kernels (1/0·0) ...
    ("attenuation-f32-subnormal", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "attenuation = [1e-40, 0, 0]"),
     ["bad.toml: light[0].attenuation[0]: 1e-40 is nonzero but below the smallest normal float32"]),
    # ... so is a float64 one (a warning before)
    ("attenuation-f64-subnormal", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "attenuation = [1e-320, 0, 0]"),
     ["bad.toml: light[0].attenuation[0]: 1e-320 is nonzero but below the smallest normal float32"]),
    # ... and radiance x 1/p(d) = 1e40 is inf as a float32 (the float and fast paths)
    ("radiance-times-falloff", SCENE.replace("attenuation = [1.0, 0.0, 0.02]", "attenuation = [1e-10, 0, 0]")
     .replace("intensity = 5.0", "intensity = 1e30"),
     ["bad.toml: light[0].attenuation: color x intensity x the largest falloff 1/min p(d) = 1e+40 is "
      "beyond the float32 range"]),
    # found by tests/test_fuzz.py: tomllib recurses per nesting level (RecursionError)
    ("deeply-nested", "x = " + "[" * 2000 + "]" * 2000 + "\n" + SCENE, ["bad.toml", "nested too deeply"]),
], ids=lambda v: v if isinstance(v, str) and len(v) < 30 else "")
def test_bad_scene(work, capsys, case, text, needles):
    src, out = work
    if text is None:
        (src / "bad.toml").write_bytes(SCENE.encode().replace(b'"phong"', b'"ph\xf6ng"'))
    else:
        _scene(src, text)
    fails(render_argv(src, out, scene=src / "bad.toml"), capsys, src.parent, *needles)


def test_light_beyond_float32_range_of_the_frame(work, capsys):
    """Each finite as float32, but 4.5e38 apart: rebased on the frame, the light would
    round to inf (NaN pixels): a one-line error naming the scene, no output. (The
    positions stay below 2^127 = 1.7e38: beyond it they are implausible and left
    as background, clphong.io.nonfinite.LIMITS.)"""
    src, out = work
    gb = random_gbuffer(np.random.default_rng(7), H, W)
    write_gbuffer(src / "far.exr", gb.position - np.float32(1.5e38), gb.normal, gb.albedo,
                  coverage=gb.coverage)
    _scene(src, SCENE.replace("position = [3.0, 5.0, 4.0]", "position = [3e38, 5.0, 4.0]"))
    fails(render_argv(src, out, gbuffer=src / "far.exr", scene=src / "bad.toml"), capsys,
          src.parent, "bad.toml: light[0].position lies 4.5e+38 units along an axis from this "
          "frame's positions (centred near (-1.5e+38, -1.5e+38, -1.5e+38))", "float32 range")


def test_scene_file_too_large_for_memory(work, capsys, monkeypatch):
    """A million lights under a 256 MiB limit: refused from the file size, before parsing."""
    src, out = work
    head = SCENE.split("[[light]]")[0]
    path = src / "million.toml"
    path.write_text(head + '[[light]]\ntype = "point"\nposition = [1.0, 2.0, 3.0]\n' * 1_000_000)
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "256M")
    fails(render_argv(src, out, scene=path), capsys, src.parent, "million.toml",
          "scene file needs about", "CLPHONG_MAX_MEMORY=256M", "fewer lights")


def test_bad_memory_limit_setting(work, capsys, monkeypatch):
    src, out = work
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "lots")
    fails(render_argv(src, out), capsys, src.parent, "CLPHONG_MAX_MEMORY='lots'", "not a size")


@pytest.mark.parametrize("c0", [1e-10, 4.8497015458773895e-12, 0.3, 1.2e-38])
def test_brightest_accepted_light_renders_no_nan_on_any_path(work, c0):
    """attenuation [c0, 0, 0] puts the largest falloff 1/c0 on every pixel: at the
    brightest intensity the scene accepts, no path makes Inf·0 = NaN (before, the
    limit itself was accepted and the float and fast paths gave NaN for c0 = 4.85e-12)."""
    import tomllib

    import clphong
    from clphong.core.errors import SceneError

    src, _ = work
    gb = clphong.read_gbuffer(src / "gbuf.exr")
    top = 3.4028234663852886e38 * c0
    text = SCENE.replace("attenuation = [1.0, 0.0, 0.02]", f"attenuation = [{c0!r}, 0, 0]") \
                .replace("color = [1.0, 0.9, 0.8]", "color = [1.0, 1.0, 1.0]")
    scenes = []
    for scale in (1.0, 1 - 2.0 ** -22, 1 - 2.0 ** -20):
        doc = tomllib.loads(text.replace("intensity = 5.0", f"intensity = {top * scale!r}"))
        try:
            scenes.append(clphong.parse_scene(doc, "s.toml"))
        except SceneError as exc:
            assert "beyond the float32 range" in str(exc)
    assert scenes, "the margin refuses even 2^-20 below the limit"
    for scene in scenes:
        for path in (None, "float", "fast"):
            rgb = clphong.Renderer(scene, path=path).render(gb).image
            assert not np.isnan(rgb).any(), (scene.lights[0].intensity, path)


def _read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    px = np.asarray(inp.read_image(0, 0, 0, 3, "float"))
    inp.close()
    return px


def test_empty_light_list_renders_black_and_says_why(work, capsys):
    """Allowed (README): no lights, so every shaded pixel is exactly 0 and the background keeps its value."""
    src, out = work
    text = SCENE.split("[[light]]")[0] + "[render]\nbackground = [0.25, 0.5, 0.75]\n"
    scene = _scene(src, text, "dark.toml")
    assert cli(render_argv(src, out, scene=scene)) == 0
    err = capsys.readouterr().err
    assert "material.k_a" in err and "the ambient term is 0" in err      # k_a = 0.1 but no ambient light
    import clphong

    px = _read(out / "beauty.exr")
    bg = clphong.read_gbuffer(src / "gbuf.exr").background_mask()
    assert bg.any() and (~bg).any()
    assert np.all(px[~bg] == 0.0)
    assert np.all(px[bg] == np.float32([0.25, 0.5, 0.75]))


def test_ambient_only_scene_matches_the_reference(work, capsys):
    import clphong
    from clphong.reference import shading as reference

    src, out = work
    text = SCENE.split("[[light]]")[0] + '[[light]]\ntype = "ambient"\ncolor = [1.0, 0.5, 0.25]\nintensity = 2.0\n'
    scene_path = _scene(src, text, "amb.toml")
    assert cli(render_argv(src, out, scene=scene_path)) == 0
    px = _read(out / "beauty.exr").astype(np.float64)
    scene = clphong.load_scene(scene_path)
    gb = clphong.read_gbuffer(src / "gbuf.exr")
    ref = reference.shade(scene, gb)
    # E = C_d·k_a·A: one float32 product of float32-rounded factors, so |err|
    # ≤ 3u·|E| (two roundings of the factors and one of the product), u = 2^-24.
    assert np.all(np.abs(px - ref) <= 3 * 2.0 ** -24 * np.abs(ref))
    assert np.any(ref > 0)


def test_many_lights_accepted(work, capsys):
    """5 000 point lights through the CLI, checked against the float64 reference.

    The full million is in :func:`test_million_lights_accepted` (slow, opt-in);
    its refusal under a memory limit is :func:`test_scene_file_too_large_for_memory`.
    """
    import clphong
    from clphong.reference import shading as reference

    src, out = work
    rng = np.random.default_rng(11)
    pos = rng.uniform(-20, 20, (5000, 3)) + [0, 0, 25]
    lights = "".join(f'[[light]]\ntype = "point"\nposition = [{x:.6f}, {y:.6f}, {z:.6f}]\nintensity = 0.01\n'
                     for x, y, z in pos)
    head = SCENE.split("[[light]]")[0].replace("k_a = 0.1", "k_a = 0.0")
    scene_path = _scene(src, head + lights, "many.toml")
    assert cli(render_argv(src, out, scene=scene_path)) == 0
    scene = clphong.load_scene(scene_path)
    gb = clphong.read_gbuffer(src / "gbuf.exr")
    px = _read(out / "beauty.exr").astype(np.float64)
    r = clphong.Renderer(scene)
    from clphong.device.renderer import prepare_frame
    frame = prepare_frame(gb, lanes=r.lanes)
    plan = r.plan_for(frame.map_names)
    bound, _ = reference.error_bound(scene, gb, origin=frame.origin,
                                     compensated=bool(plan.defines.get("COMPENSATED_SUM", 0)))
    assert np.all(np.abs(px - reference.shade(scene, gb)) <= bound)


@pytest.mark.skipif(not os.environ.get("CLPHONG_SLOW_TESTS"), reason="slow (about a minute): set CLPHONG_SLOW_TESTS=1")
def test_million_lights_accepted(work, capsys):
    src, out = work
    head = SCENE.split("[[light]]")[0]
    path = src / "million.toml"
    path.write_text(head + '[[light]]\ntype = "point"\nposition = [1.0, 2.0, 3.0]\nintensity = 1e-6\n'
                    * 1_000_000)
    assert cli(render_argv(src, out, scene=path)) == 0
    px = _read(out / "beauty.exr")
    assert np.all(np.isfinite(px))


# =========================================================================== output problems


def test_output_folder_is_a_file(work, capsys):
    src, out = work
    (out / "plain").write_text("not a folder")
    fails(render_argv(src, out, output=out / "plain" / "sub" / "beauty.exr"), capsys, src.parent,
          f"{out / 'plain'} is a file, not a folder")


def test_output_in_a_read_only_file_system(work, capsys):
    """/proc takes no new files, even for root (folder permissions would not stop root)."""
    src, out = work
    fails(render_argv(src, out, output="/proc/beauty.exr"), capsys, src.parent,
          "/proc/beauty.exr", "cannot write in folder /proc")


def test_output_that_is_a_folder(work, capsys):
    src, out = work
    fails(render_argv(src, out, output=out), capsys, src.parent, f"{out}: is a directory")


def test_output_not_exr_is_refused_before_work(work, capsys, monkeypatch):
    import importlib

    src, out = work
    render = importlib.import_module("clphong.device.renderer")

    def no_render(*a, **k):                     # the check comes first: nothing is shaded
        raise AssertionError("rendered before checking the output name")

    monkeypatch.setattr(render.Renderer, "render", no_render)
    fails(render_argv(src, out, output=out / "beauty.png"), capsys, src.parent, "beauty.png",
          "give a name ending in .exr")


@pytest.mark.parametrize("which", ["scene", "gbuffer-symlink"])
def test_output_identical_to_an_input(work, capsys, which):
    src, out = work
    before = {p: p.read_bytes() for p in src.iterdir()}
    if which == "scene":
        target = src / "scene.toml"
        # .toml is refused as an overwrite before its extension is looked at
        needles = ["output would overwrite the input", "scene.toml"]
    else:
        target = out / "link.exr"
        target.symlink_to(src / "gbuf.exr")
        needles = ["link.exr", "output would overwrite the input", "gbuf.exr"]
    fails(render_argv(src, out, output=target), capsys, src.parent, *needles)
    assert {p: p.read_bytes() for p in src.iterdir()} == before


class _FileSizeLimitedOutput:
    """oiio.ImageOutput whose writes run under RLIMIT_FSIZE: the kernel refuses the
    bytes past the limit (EFBIG), a real write error like a full disk's ENOSPC."""

    real = oiio.ImageOutput
    limit = 4096

    @classmethod
    def create(cls, name):
        out = cls.real.create(name)
        return None if out is None else cls(out)

    def __init__(self, out):
        self._out = out

    def __getattr__(self, name):
        return getattr(self._out, name)

    def _limited(self, fn, *args):
        import resource

        old = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (self.limit, old[1]))
        try:                        # Python ignores SIGXFSZ, so write() returns EFBIG
            return fn(*args)
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, old)

    def write_image(self, data):
        return self._limited(self._out.write_image, data)

    def close(self):
        return self._limited(self._out.close)


def test_disk_full_while_writing_keeps_the_previous_output(work, capsys, monkeypatch):
    from clphong.io import atomic as output

    src, out = work
    big = random_gbuffer(np.random.default_rng(9), 64, 64)          # ~48 KB of noise: > limit
    write_gbuffer(src / "big.exr", big.position, big.normal, big.albedo, coverage=big.coverage)
    assert cli(render_argv(src, out, gbuffer=src / "big.exr")) == 0
    good = (out / "beauty.exr").read_bytes()
    capsys.readouterr()
    monkeypatch.setattr(output.oiio, "ImageOutput", _FileSizeLimitedOutput)
    fails(render_argv(src, out, gbuffer=src / "big.exr"), capsys, src.parent, "beauty.exr",
          "failed")
    assert (out / "beauty.exr").read_bytes() == good


class _FullAtClose(_FileSizeLimitedOutput):
    """The disk fills up just as the file is closed: close() may write nothing more.
    OpenImageIO's PNG and EXR writers then return True with no error recorded."""

    @classmethod
    def create(cls, name):
        out = super().create(name)
        if out is not None:
            out.name = name
        return out

    def write_image(self, data):
        return self._out.write_image(data)

    def close(self):
        self.limit = os.path.getsize(self.name)     # what is on the disk so far
        return super().close()


@pytest.mark.parametrize("option,name,when", [
    # (-o while writing: test_disk_full_while_writing_keeps_the_previous_output)
    ("-o", "beauty.exr", "closing"),
    ("--sdr", "beauty.png", "writing"), ("--sdr", "beauty.png", "closing"),
    ("--hdr", "beauty_pq.png", "writing"), ("--hdr", "beauty_pq.png", "closing"),
    ("--contact-sheet", "sheet.png", "writing"), ("--contact-sheet", "sheet.png", "closing"),
])
def test_disk_full_while_writing_any_output_keeps_the_previous_one(work, capsys, monkeypatch,
                                                                   option, name, when):
    """Before, these exited 0 leaving a PNG cut short (or empty), or an empty EXR."""
    from clphong.io import atomic as output

    src, out = work
    big = random_gbuffer(np.random.default_rng(9), 64, 64)
    write_gbuffer(src / "big.exr", big.position, big.normal, big.albedo, coverage=big.coverage)
    argv = ["render", src / "scene.toml", src / "big.exr", option, out / name]
    assert cli(argv) == 0
    good = (out / name).read_bytes()
    capsys.readouterr()
    monkeypatch.setattr(output.oiio, "ImageOutput",
                        _FileSizeLimitedOutput if when == "writing" else _FullAtClose)
    fails(argv, capsys, src.parent, name, "failed")
    assert (out / name).read_bytes() == good


@pytest.mark.parametrize("how,code,text", [
    ("SIGTERM", 143, "clphong: terminated (SIGTERM)"),
    ("SIGHUP", 129, "clphong: terminated (SIGHUP)"),
    ("SIGQUIT", 131, "clphong: terminated (SIGQUIT)"),
    # round 3: these left .NAME.tmp-XXXX.exr behind (their default action ends the process)
    ("SIGUSR1", 138, "clphong: terminated (SIGUSR1)"),
    ("SIGUSR2", 140, "clphong: terminated (SIGUSR2)"),
    ("SIGALRM", 142, "clphong: terminated (SIGALRM)"),
    ("SIGVTALRM", 154, "clphong: terminated (SIGVTALRM)"),
    ("SIGPROF", 155, "clphong: terminated (SIGPROF)"),
    ("SIGXCPU", 152, "clphong: terminated (SIGXCPU)"),
    ("SIGRTMIN", 128 + signal.SIGRTMIN, "clphong: terminated (SIGRTMIN"),
    ("ctrl-c", 130, "clphong: interrupted"),
])
def test_stopped_while_writing_leaves_nothing(work, capsys, monkeypatch, how, code, text,
                                            signals_not_ignored):
    """Every catchable terminating signal removes the temporary output and exits
    128 + N with one line (SIGHUP and SIGQUIT left .NAME.tmp-XXXX.exr behind)."""
    from clphong.io import atomic as output

    class Stopped(_FileSizeLimitedOutput):
        limit = 2 ** 40

        def write_image(self, data):
            if how.startswith("SIG"):
                # raise_signal: to this (the main) thread, so the handler runs before the
                # write returns; os.kill may land on another thread (pytest-xdist's I/O
                # thread, the runtime's) and be handled a few steps later
                signal.raise_signal(getattr(signal, how))    # handled by the CLI as an interrupt
            else:
                raise KeyboardInterrupt
            return True

    from clphong.core.signals import TERMINATING

    names = [n for n in TERMINATING + ("SIGRTMIN", "SIGRTMAX") if hasattr(signal, n)]
    # as they were before the command (SIG_DFL, or a test runner's own: pytest-timeout's SIGALRM)
    before = {n: signal.getsignal(getattr(signal, n)) for n in names}
    src, out = work
    monkeypatch.setattr(output.oiio, "ImageOutput", Stopped)
    line = fails(render_argv(src, out), capsys, src.parent, code=code)
    assert line.startswith(text)
    for name in names:                                              # restored after the command
        assert signal.getsignal(getattr(signal, name)) is before[name], name


def _slow_enough_device(pairs: float, seconds: float) -> str:
    """The default device if it shades ``pairs`` pixel-light pairs in at least ``seconds``
    at its measured rate (the self-test's calibration frame), else the first device that
    does (a CPU beside a GPU); the test skips where none does (an H200 alone shades the
    frame below in about a tenth of a second)."""
    from clphong.core.errors import DeviceError
    from clphong.device.runtime import _full_names

    default = selection.get_runtime()
    others = []
    for name, _ in _full_names():
        try:
            others.append(selection.get_runtime(name))
        except DeviceError:
            continue
    for rt in [default] + others:
        if rt.pair_rate is None or pairs / rt.pair_rate >= seconds:
            return rt.selector
    pytest.skip(f"every device here shades the frame in under {seconds:g} s "
                f"({default.name}: {pairs / default.pair_rate:.2g} s): it ends before a signal "
                "can reach it mid-frame; the pieces' size is tested in tests/device/test_renderer.py")


def test_sigterm_stops_a_long_frame_within_a_second(tmp_path):
    """A frame whose shading takes many seconds (1024x768, 4096 lights) is shaded in
    pieces (clphong.device.renderer.launch_pieces): SIGTERM, sent while the kernel
    runs, ends the command within 1 s (it waited for the whole launch: 8.5 s), exit
    143, one line, no output and no temporary left."""
    import subprocess
    import sys
    import time

    from clphong.tools.bench import bench_gbuffer, bench_scene
    from clphong.tools.commands import scene_toml

    device = _slow_enough_device(1024 * 768 * 16384, seconds=8.0)
    gb = bench_gbuffer(1024, 768)
    write_gbuffer(tmp_path / "g.exr", gb.position, gb.normal, gb.albedo, coverage=gb.coverage)
    # 16,384 lights: Intel's CPU runtime at 16 lanes shaded 4,096 in under 4 s (Zen 5)
    (tmp_path / "s.toml").write_text(scene_toml(bench_scene("wide", 16384)))
    out = tmp_path / "o.exr"
    cmd = [sys.executable, "-m", "clphong.console.cli", "render", str(tmp_path / "s.toml"),
           str(tmp_path / "g.exr"), "-o", str(out), "--stats", "--device", device]
    # warm the kernel cache first (a cold build would be timed otherwise)
    subprocess.run([sys.executable, "-c", "from clphong.tools.bench import bench_scene, bench_gbuffer;"
                    "from clphong.device.renderer import Renderer;"
                    f"Renderer(bench_scene('wide', 16384), device={device!r})"
                    ".render(bench_gbuffer(64, 16))"], check=True)
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    time.sleep(4.0)          # start-up, reading, the first pieces
    assert proc.poll() is None, "the frame finished before the signal: make it longer"
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    waited = time.perf_counter() - t0
    assert proc.returncode == 143, err
    assert waited < 1.0, f"SIGTERM took {waited:.2f} s"
    lines = err.strip().splitlines()
    assert lines[-1].startswith("clphong: terminated (SIGTERM)"), err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]


# =========================================================================== no usable device


@pytest.fixture
def fresh_runtimes(monkeypatch):
    """No runtime cached in this process, so device selection runs again."""
    monkeypatch.setattr(selection, "_RUNTIMES", {})
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)


def test_no_opencl_platform(work, capsys, monkeypatch, fresh_runtimes):
    import pyopencl as cl

    def none(*a, **k):
        raise cl.LogicError("clGetPlatformIDs failed: PLATFORM_NOT_FOUND_KHR")

    monkeypatch.setattr(cl, "get_platforms", none)
    src, out = work
    fails(render_argv(src, out), capsys, src.parent, "no OpenCL platform found",
          "PLATFORM_NOT_FOUND_KHR", "PYOPENCL_CTX", 'pip install "pyopencl[pocl]"')


def test_platform_without_devices(work, capsys, monkeypatch, fresh_runtimes):
    import pyopencl as cl

    monkeypatch.setattr(cl, "get_platforms", lambda: [])
    src, out = work
    fails(render_argv(src, out), capsys, src.parent, "no OpenCL device found", "PYOPENCL_CTX",
          'pip install "pyopencl[pocl]"')


def test_kernel_build_fails(work, capsys, monkeypatch, fresh_runtimes):
    import pyopencl as cl

    def broken(self, *a, **k):
        raise cl.RuntimeError("clBuildProgram failed: BUILD_PROGRAM_FAILURE\n"
                              "shade.cl:12:3: error: use of undeclared identifier 'floatL'")

    monkeypatch.setattr(cl.Program, "build", broken)
    # compile in this process, as the compiling child does (it reports the same line)
    monkeypatch.setenv("CLPHONG_OPENCL_CHILD", "1")
    src, out = work
    fails(render_argv(src, out), capsys, src.parent, "kernels/shade.cl failed to build",
          "undeclared identifier", "--device", "PYOPENCL_CTX", "clphong devices")


def test_a_build_error_in_the_compiling_child_is_its_one_line(work, capsys, monkeypatch,
                                                              fresh_runtimes, tmp_path):
    """The compiling child answers with the compiler's first error line; the parent says
    it as it is, exit 1, no output."""
    import os
    import sys

    from clphong.device import isolate

    (tmp_path / "refusing_child.py").write_text(
        "import json, sys\n"
        "for line in sys.stdin:\n"
        "    print(json.dumps({'error': 'kernels/shade.cl failed to build on X: shade.cl:3:1: "
        "error: expected identifier'}), flush=True)\n")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), *sys.path]))
    monkeypatch.setattr(isolate.BuildChild, "module", "refusing_child")
    children = {}
    monkeypatch.setattr(isolate, "_CHILDREN", children)
    monkeypatch.setattr(runtime.Runtime, "_binary_path", lambda *a: None)
    src, out = work
    try:
        fails(render_argv(src, out), capsys, src.parent, "kernels/shade.cl failed to build on X",
              "expected identifier")
    finally:
        for child in children.values():
            child.close()


def test_pyopencl_ctx_names_no_device(work, capsys, monkeypatch, fresh_runtimes):
    monkeypatch.setenv("PYOPENCL_CTX", "9:9")
    src, out = work
    line = fails(render_argv(src, out), capsys, src.parent, "PYOPENCL_CTX='9:9' names no usable",
                 "unset it or set it to one of: 0:0", 'pip install "pyopencl[pocl]"')
    assert "\n" not in line


def test_device_option_names_no_device(work, capsys):
    src, out = work
    fails(render_argv(src, out, extra=["--device", "quantum"]), capsys, src.parent,
          "device 'quantum': no match; available: 0:0",
          # the other ways to choose a device, and how to get one (README, 'No usable device')
          "PYOPENCL_CTX", 'pip install "pyopencl[pocl]"')
    fails(render_argv(src, out, extra=["--device", "7:3"]), capsys, src.parent,
          "device '7:3': no such OpenCL device", "PYOPENCL_CTX", 'pip install "pyopencl[pocl]"')


# =========================================================================== memory: row bands


def test_frame_too_big_for_one_launch_is_shaded_in_bands(work, capsys, monkeypatch):
    """A small frame forced into bands by a memory limit is bit-identical to one launch.

    Each band is shaded with the whole frame's rebasing origin, so every pixel
    goes through the same float32 operations: equality is exact, not within a
    tolerance. The result is also held to the reference's error bound.
    """
    import clphong
    from clphong.device.bands import render_bytes_per_pixel
    from clphong.device.renderer import prepare_frame
    from clphong.reference import shading as reference

    src, out = work
    gb = random_gbuffer(np.random.default_rng(12), 96, 40, maps=("k_s", "h"))
    write_gbuffer(src / "tall.exr", gb.position, gb.normal, gb.albedo, coverage=gb.coverage, maps=gb.maps)
    scene = clphong.load_scene(src / "scene.toml")
    gb = clphong.read_gbuffer(src / "tall.exr")
    r = clphong.Renderer(scene)
    result = r.render(gb)
    whole = result.image
    assert result.bands == 1
    # Room for the (96, 40, 3) output and ~10 rows of shading, not the whole frame.
    limit = 12 * 96 * 40 + render_bytes_per_pixel(3) * (r.lanes * 64 + 10 * 40) + 512 * 3
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", str(limit))
    result = r.render(gb)
    banded = result.image
    assert result.bands > 1
    assert np.array_equal(banded, whole)
    frame = prepare_frame(gb, lanes=r.lanes)
    plan = r.plan_for(frame.map_names)
    bound, _ = reference.error_bound(scene, gb, origin=frame.origin,
                                     compensated=bool(plan.defines.get("COMPENSATED_SUM", 0)))
    assert np.all(np.abs(banded - reference.shade(scene, gb)) <= bound)
    # and through the CLI, with room to read the file (8 bytes a pixel and
    # channel, 12 channels) but not to shade it in one launch
    from clphong.device import renderer as renderer_module

    calls = []
    real_plan = renderer_module.plan_bands
    monkeypatch.setattr(renderer_module, "plan_bands",
                        lambda h, rows: calls.append(rows) or real_plan(h, rows))
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", str(8 * 12 * 96 * 40 + limit))
    assert 8 * 12 * 96 * 40 + limit < render_bytes_per_pixel(3) * 96 * 40
    assert cli(render_argv(src, out, gbuffer=src / "tall.exr")) == 0
    assert calls and calls[-1] < 96
    assert np.array_equal(_read(out / "beauty.exr"), whole)


def test_frame_over_the_devices_largest_buffer_is_shaded_in_bands(monkeypatch):
    """The device's CL_DEVICE_MAX_MEM_ALLOC_SIZE also bounds a launch (measured with
    POCL_MEMORY_LIMIT=1, 256 MiB: one launch of 3000x2000 failed with INVALID_BUFFER_SIZE).
    Here the limit is lowered to a few rows of a small frame."""
    import clphong
    from clphong.device.frame import GBUF_PLANES

    r = clphong.Renderer(_scene_of(SCENE))
    block = r.lanes * 64
    rows = 3 * 2 * block // 30                     # three bands of two blocks, whatever the lanes
    gb = random_gbuffer(np.random.default_rng(14), rows, 30)
    result = r.render(gb)
    whole = result.image
    assert result.bands == 1
    monkeypatch.setattr(r.runtime, "limits", lambda: (4 * GBUF_PLANES * 2 * block, None))
    result = r.render(gb)
    banded = result.image
    assert result.bands == -(-rows * 30 // (2 * block // 30 * 30)) and result.bands > 1
    assert np.array_equal(banded, whole)


def _scene_of(text):
    import tomllib

    from clphong.model.scene import parse_scene
    return parse_scene(tomllib.loads(text), "scene.toml")


def test_band_origin_is_the_whole_frames_origin():
    from clphong.core.geometry import frame_origin
    from clphong.device.bands import frame_origin_banded, plan_bands

    gb = random_gbuffer(np.random.default_rng(13), 37, 11)
    gb.position[5:9] += 1000.0                                   # a far-away strip in one band
    whole = frame_origin(gb.position, gb.background_mask().reshape(-1))
    for rows in (1, 4, 10, 37):
        assert np.array_equal(frame_origin_banded(gb, plan_bands(37, rows)), whole)


def test_16k_frame_plan_respects_device_and_memory_limits():
    """The plan for 16K x 16K with many lights, without allocating it."""
    from clphong.device.bands import band_rows, render_bytes_per_pixel
    from clphong.device.renderer import LOCAL_SIZE

    h = w = 16384
    rows = band_rows((h, w), n_map_planes=0, lanes=16, light_bytes=128 * 10_000,
                     budget=16 * 2 ** 30, max_alloc=2 ** 30, global_mem=4 * 2 ** 30)
    assert 1 <= rows < h
    stride = -(-rows * w // (16 * LOCAL_SIZE)) * 16 * LOCAL_SIZE
    from clphong.device.frame import GBUF_PLANES
    assert 4 * GBUF_PLANES * stride <= 2 ** 30                            # largest buffer
    assert 12 * h * w + render_bytes_per_pixel(0) * stride + 128 * 10_000 <= 16 * 2 ** 30
    # not even the output fits: 0 rows, which render_frame turns into a clear refusal
    assert band_rows((h, w), n_map_planes=0, lanes=16, budget=2 ** 30) == 0


def test_frame_whose_output_alone_exceeds_the_limit_is_refused(work, monkeypatch):
    import clphong
    from clphong.core.errors import GBufferError

    src, _ = work
    gb = clphong.read_gbuffer(src / "gbuf.exr")
    r = clphong.Renderer(clphong.load_scene(src / "scene.toml"))
    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "100")       # less than the 6x8x3 float32 output
    with pytest.raises(GBufferError) as exc:
        r.render(gb).image
    msg = str(exc.value)
    assert f"a {W}x{H} frame cannot be shaded here" in msg and "CLPHONG_MAX_MEMORY=100" in msg
    assert "\n" not in msg


# =========================================================================== as subprocesses


def _cli():
    exe = shutil.which("clphong")
    return [exe] if exe else [sys.executable, "-m", "clphong"]


def _subprocess_fails(argv, root, *needles, env=None, code=1):
    before = _files(root)
    r = subprocess.run(_cli() + [str(a) for a in argv], capture_output=True, text=True, timeout=300,
                       env=env)
    assert r.returncode == code, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if not ln.startswith("clphong: warning: ")]
    assert len(errors) == 1 and errors[0].startswith("clphong: error: "), r.stderr
    for n in needles:
        assert n in errors[0]
    assert _files(root) == before


def test_subprocess_truncated_exr_and_bad_scene(work):
    src, out = work
    data = (src / "gbuf.exr").read_bytes()
    (src / "cut.exr").write_bytes(data[: len(data) * 2 // 3])
    _subprocess_fails(render_argv(src, out, gbuffer=src / "cut.exr"), src.parent, "cut.exr")
    _scene(src, SCENE.replace("h = 32.0", "h = inf"))
    _subprocess_fails(render_argv(src, out, scene=src / "bad.toml"), src.parent,
                      "material.h: must be finite")


def test_subprocess_pyopencl_ctx_without_a_device(work):
    """The real environment variable, no monkeypatching: PyOpenCL finds no such platform."""
    src, out = work
    env = dict(os.environ, PYOPENCL_CTX="42")
    _subprocess_fails(render_argv(src, out), src.parent, "PYOPENCL_CTX='42'",
                      'pip install "pyopencl[pocl]"', env=env)


def test_subprocess_huge_frame_under_an_address_space_limit(work):
    """With RLIMIT_AS at 3 GiB and no CLPHONG_MAX_MEMORY, the 16K x 16K read is refused
    from the rlimit, instead of dying in an allocation."""
    import resource

    src, out = work
    path = _huge_display_window(src, 16384)
    env = {k: v for k, v in os.environ.items() if k != "CLPHONG_MAX_MEMORY"}
    before = _files(src.parent)

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))

    r = subprocess.run(_cli() + [str(a) for a in render_argv(src, out, gbuffer=path)],
                       capture_output=True, text=True, timeout=300, env=env, preexec_fn=limit)
    assert r.returncode == 1, r.stderr
    assert r.stderr.count("\n") == 1 and "huge.exr" in r.stderr
    assert "address-space rlimit" in r.stderr
    assert _files(src.parent) == before


# =========================================================================== round 2 (issue 15)


@pytest.mark.parametrize("which", ["scene", "gbuffer"])
@pytest.mark.parametrize("kind", ["fifo", "char-device", "directory"])
def test_inputs_that_are_not_regular_files_are_one_line(work, capsys, which, kind):
    """A FIFO blocked forever, /dev/zero as the scene read until memory ran out."""
    src, out = work
    if kind == "fifo":
        path = src / "pipe"
        os.mkfifo(path)
        needle = "a FIFO (named pipe)"
    elif kind == "char-device":
        path, needle = Path("/dev/zero"), "a character device"
    else:
        path = src / "folder"
        path.mkdir()
        needle = "a directory"
    argv = render_argv(src, out, **{which: path})
    line = fails(argv, capsys, src.parent, str(path))
    assert needle in line and ("give a regular file" in line or kind == "directory")


def test_inspect_of_a_fifo_is_one_line(work, capsys):
    src, _ = work
    os.mkfifo(src / "pipe")
    assert cli(["inspect", src / "pipe"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a FIFO (named pipe)" in err


def test_control_bytes_in_a_channel_name_do_not_reach_the_terminal(work, capsys):
    """A channel named ESC[2K ESC[1G erased the 'clphong: error: FILE' prefix on a
    real terminal: every line clphong prints is escaped."""
    src, out = work
    bad = src / "ctl.exr"
    planes = {"\x1b[2K\x1b[1G.R": np.zeros((H, W), np.float32)}
    _raw_exr(bad, planes)
    line = fails(render_argv(src, out, gbuffer=bad), capsys, src.parent)
    assert "\x1b" not in line and all(ch.isprintable() for ch in line)


def test_an_endless_unknown_key_is_cut(work, capsys):
    src, out = work
    _scene(src, SCENE + "\n" + "k" * 100_000 + " = 1\n")
    line = fails(render_argv(src, out, scene=src / "bad.toml"), capsys, src.parent, "bad.toml")
    # issue 26: the key quoted in at most QUOTE_MAX characters (was: the line cut at 2,000)
    assert len(line) < 600 and "…" in line and "characters)" in line


def test_a_bad_display_from_the_scene_names_the_file_and_key(work, capsys):
    src, out = work
    _scene(src, SCENE + '\n[render]\ndisplay = "nope"\n')
    fails(render_argv(src, out, scene=src / "bad.toml", output=out / "o.png")[:-2] + ["--sdr", out / "o.png"],
          capsys, src.parent, "the scene key render.display in", "bad.toml", "display 'nope'")


def test_render_removes_its_own_stale_temporaries(work, capsys):
    """What a killed earlier run left for this output (.NAME.tmp-XXXXXXXX.EXT), only
    that pattern and that name, is removed with one warning line."""
    src, out = work
    stale = out / ".beauty.tmp-0123abcd.exr"
    stale.write_bytes(b"half a file")
    # the name a temporary file has before it takes its own: a SIGKILL between the two
    # left one (tests/pipeline/test_batch.py::test_resume_after_killed_run[SIGKILL], 1 run in 8)
    born = out / ".beauty.tmp-4567cdef.exr.born"
    born.write_bytes(b"")
    other = out / ".other.tmp-0123abcd.exr"
    other.write_bytes(b"not ours")
    unlike = out / ".beauty.tmp-xyz.exr"
    unlike.write_bytes(b"not the pattern")
    unlike_born = out / ".beauty.tmp-0123abcd.exr.borne"
    unlike_born.write_bytes(b"not the pattern")
    assert cli(render_argv(src, out)) == 0
    err = capsys.readouterr().err
    assert not stale.exists() and not born.exists()
    assert other.exists() and unlike.exists() and unlike_born.exists()
    assert err.count("\n") == 1 and "removed 2 temporary file" in err


def test_a_signalling_nan_in_a_normal_gives_no_numpy_line(work, capsys):
    """numpy's 'invalid value encountered in cast' was a stray second line."""
    src, out = work
    gb = random_gbuffer(np.random.default_rng(3), H, W)
    n = gb.normal.copy()
    n.view(np.uint32)[0, 0, 0] = 0x7FA00000          # a signalling NaN
    bad = src / "snan.exr"
    write_gbuffer(bad, gb.position, n, gb.albedo, coverage=gb.coverage)
    rc = cli(render_argv(src, out, gbuffer=bad, extra=["--nonfinite", "background"]))
    err = capsys.readouterr().err
    assert rc == 0 and "encountered" not in err, err
    assert err.count("\n") <= 1


def _with_maps(src, maps, albedo=None, name="maps.exr"):
    gb = random_gbuffer(np.random.default_rng(5), H, W)
    write_gbuffer(src / name, gb.position, gb.normal, gb.albedo if albedo is None else albedo,
                  coverage=gb.coverage, maps=maps)
    return src / name


@pytest.mark.parametrize("case,maps,label", [
    ("shininess-1e6-one-pixel", {"h": np.where(np.arange(H * W).reshape(H, W) == 7, -1e6, 20.0)}, ": 1 pixel"),
    ("shininess-1e6-everywhere", {"h": np.full((H, W), -1e6)}, "shininess"),
    ("shininess-minus-2", {"h": np.full((H, W), -2.0)}, "shininess"),
    ("k_s-minus-1", {"k_s": np.full((H, W), -1.0)}, "k_s"),
    ("k_d-minus-1", {"k_d": np.full((H, W), -1.0)}, "k_d"),
    ("specular-colour-minus-1", {"specular_color": np.full((H, W, 3), -1.0)}, "R 41, G 41, B 41 pixel(s)"),
    ("albedo-minus-1", None, ": G 41 pixel(s)"),
])
def test_negative_maps_and_albedo_are_clamped_with_counts_or_refused(work, capsys, case, maps, label):
    """A shininess of -1e6 gave NaN pixels, exit 0, even with --nonfinite error; a k_s of
    -1 negative radiance; -2 highlights of 4e14. Now: clamped to 0 with one warning
    giving the counts per buffer and channel (the output finite, and >= 0 where the
    lights are), or refused under --nonfinite error with those counts."""
    src, out = work
    albedo = None
    if maps is None:
        albedo = random_gbuffer(np.random.default_rng(5), H, W).albedo.copy()
        albedo[..., 1] = -1.0
        maps = {}
    path = _with_maps(src, {k: np.asarray(v, np.float32) for k, v in maps.items()}, albedo)
    assert cli(render_argv(src, out, gbuffer=path)) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "negative G-buffer values clamped to 0" in err and label in err, err
    import OpenImageIO as oiio

    pix = oiio.ImageBuf(str(out / "beauty.exr")).get_pixels(oiio.FLOAT)
    assert np.all(np.isfinite(pix)) and pix[..., :3].min() >= 0.0
    (out / "beauty.exr").unlink()
    fails(render_argv(src, out, gbuffer=path, extra=["--nonfinite", "error"]), capsys, src.parent,
          "negative G-buffer values", label)


def _gbuffer_planes(h=H, w=W):
    gb = random_gbuffer(np.random.default_rng(8), h, w)
    return {**_vec("P", gb.position), **_vec("N", gb.normal), **_vec("albedo", gb.albedo, "RGB")}


@pytest.mark.parametrize("case,window,display,needles", [
    # one flipped byte in 'displayWindow': OpenEXR falls back to 64x64 at (0, 0); a
    # 64x64 black frame with exit 0 before
    ("damaged-display-window", (0, 0), (64, 64), ["(0,0)-(79,39)", "(0,0)-(63,63)",
                                                   "OpenEXR's default", "displayWindow"]),
    ("data-outside-display", (100, 100), (40, 30), ["(100,100)-(179,139)", "no pixel in the display window"]),
])
def test_display_windows_that_cannot_be_right_are_refused(work, capsys, case, window, display, needles):
    src, out = work
    bad = _raw_exr(src / "win.exr", _gbuffer_planes(40, 80), window=window, display=display)
    fails(render_argv(src, out, gbuffer=bad), capsys, src.parent, "win.exr", *needles)


def test_a_display_window_smaller_than_the_data_window_warns_with_both(work, capsys):
    """An edited display window smaller than the data window cropped silently."""
    src, out = work
    bad = _raw_exr(src / "crop.exr", _gbuffer_planes(40, 80), display=(60, 30))
    assert cli(render_argv(src, out, gbuffer=bad)) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "(0,0)-(79,39)" in err and "(0,0)-(59,29)" in err, err
    assert f"{80 * 40 - 60 * 30} pixel(s) of data outside it are not shaded" in err


def test_an_output_that_is_a_symlink_is_replaced_and_its_target_kept(work, capsys):
    """Chosen and documented (README, Errors and limits): -o naming a symbolic link
    replaces the link with the new file, atomically; the link's target is untouched."""
    src, out = work
    target = out / "target.exr"
    target.write_bytes(b"the target")
    link = out / "beauty.exr"
    link.symlink_to(target)
    assert cli(render_argv(src, out)) == 0
    assert not link.is_symlink() and link.stat().st_size > 100
    assert target.read_bytes() == b"the target"


def test_a_uint_channel_among_floats_is_refused(work, capsys):
    """A pixel-type byte flipped FLOAT -> UINT decoded to garbage (NaN, ±3.4e38,
    41,201 negative pixels) with exit 0."""
    src, out = work
    planes = _gbuffer_planes()
    names = list(planes)
    data = np.ascontiguousarray(np.stack([np.asarray(planes[n], np.float32) for n in names], -1))
    spec = oiio.ImageSpec(W, H, len(names), oiio.TypeDesc("float"))
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(oiio.TypeDesc("uint") if n == "P.Z" else oiio.TypeDesc("float")
                                for n in names)
    bad = src / "uint.exr"
    o = oiio.ImageOutput.create(str(bad))
    assert o.open(str(bad), spec)
    assert o.write_image(data)
    assert o.close()
    fails(render_argv(src, out, gbuffer=bad), capsys, src.parent, "uint.exr", "channel P.Z is stored as uint",
          "(the others as float)")


# =========================================================================== implausible decodes
# Issue 15: a flipped compression byte (ZIP read as PXR24) or pixel type decoded to
# garbage (NaN, ±3.4e38, 41,201 negative pixels) with exit 0 and NaN in the output.

SAMPLES = Path(__file__).resolve().parent.parent / "gbuffers"


def warns(argv, capsys, root: Path, *needles: str, lines: int = 1) -> str:
    """Run the CLI; check exit 0, ``lines`` warning lines (the first with ``needles``),
    no error, and an output file of finite values only (R, G, B and A); catalogued."""
    rc = cli(argv)
    err = capsys.readouterr().err
    assert rc == 0, err
    got = err.splitlines()
    assert len(got) == lines and all(ln.startswith("clphong: warning: ") for ln in got), err
    for needle in needles:
        assert needle in got[0], f"{needle!r} not in {got[0]!r}"
    out = Path(argv[argv.index("-o") + 1])
    pix = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)
    assert np.all(np.isfinite(pix)), f"{int((~np.isfinite(pix)).sum())} non-finite value(s) in {out}"
    case = os.environ.get("PYTEST_CURRENT_TEST", "?").split("::")[-1].split(" ")[0]
    CATALOGUE.append((case, rc, got[0].replace(str(root), "DIR")))
    return got[0]


def _pixels_at(shape, *flat):
    """(H, W) bool, True at the given flat pixel indices."""
    m = np.zeros(shape, bool)
    m.reshape(-1)[list(flat)] = True
    return m


_IMPLAUSIBLE = [
    ("position-3.4e38", "position", 3.4028235e38, "P.X,P.Y,P.Z: X 2 pixel(s)"),
    ("position-minus-2^127", "position", -2.0 ** 127, "P.X,P.Y,P.Z: X 2 pixel(s)"),
    ("albedo-1e30", "albedo", 1e30, "albedo.R,albedo.G,albedo.B: R 2 pixel(s)"),
    ("k_s-3e38", "k_s", 3e38, "k_s: 2 pixel(s)"),
    ("specular-colour-2^63", "specular_color", 2.0 ** 63, "specular_color.R,specular_color.G,"
                                                           "specular_color.B: R 2 pixel(s)"),
    ("shininess-2^126", "h", 2.0 ** 126, "shininess: 2 pixel(s)"),
]


@pytest.mark.parametrize("case,buffer,value,label", _IMPLAUSIBLE, ids=[c[0] for c in _IMPLAUSIBLE])
def test_implausible_magnitudes_are_background_with_counts_or_refused(work, capsys, case, buffer,
                                                                       value, label):
    """A finite value at or beyond its buffer's limit (clphong.io.nonfinite.LIMITS: the
    kernels' float32 differences, products or Blinn's 4h would overflow) shaded as it
    was, with exit 0 (and NaN pixels on the float paths). Now: those pixels are
    background, with one warning giving the counts per channel, or refused under
    --nonfinite error."""
    src, out = work
    gb = random_gbuffer(np.random.default_rng(5), H, W)
    at = _pixels_at((H, W), 3, 17)
    P, A = gb.position.copy(), gb.albedo.copy()
    maps = {"k_s": np.full((H, W), 0.3, np.float32), "h": np.full((H, W), 20.0, np.float32),
            "specular_color": np.ones((H, W, 3), np.float32)}
    target = {"position": P, "albedo": A}.get(buffer, maps.get(buffer))
    if target.ndim == 3:
        target[at, 0] = value
    else:
        target[at] = value
    path = src / "big.exr"
    write_gbuffer(path, P, gb.normal, A, coverage=np.ones((H, W), np.float32), maps=maps)
    warns(render_argv(src, out, gbuffer=path), capsys, src.parent, "big.exr",
          "implausibly large G-buffer values", "left unshaded as background", label)
    pix = oiio.ImageBuf(str(out / "beauty.exr")).get_pixels(oiio.FLOAT)
    assert np.all(pix[at][:, :3] == 0.0) and np.all(pix[~at][:, :3] > 0)   # the scene's background
    (out / "beauty.exr").unlink()
    fails(render_argv(src, out, gbuffer=path, extra=["--nonfinite", "error"]), capsys, src.parent,
          "big.exr", "implausibly large G-buffer values", label)


def test_a_nan_coverage_is_background_not_a_nan_alpha(work, capsys):
    """A NaN coverage (a garbage decode of A) made the pixel's A, and with partial
    coverage its colour, NaN in the output, with exit 0. Now: background, counted."""
    src, out = work
    gb = random_gbuffer(np.random.default_rng(5), H, W)
    cov = np.full((H, W), 0.5, np.float32)
    cov[_pixels_at((H, W), 4, 9)] = np.nan
    write_gbuffer(src / "nancov.exr", gb.position, gb.normal, gb.albedo, coverage=cov)
    warns(render_argv(src, out, gbuffer=src / "nancov.exr"), capsys, src.parent, "nancov.exr: A: 2 pixel(s)",
          "non-finite G-buffer values left unshaded as background")
    (out / "beauty.exr").unlink()
    fails(render_argv(src, out, gbuffer=src / "nancov.exr", extra=["--nonfinite", "error"]), capsys,
          src.parent, "nancov.exr: A: 2 pixel(s)")


def test_a_nan_in_a_map_does_not_let_its_negative_values_escape_the_clamp(work, capsys):
    """A NaN anywhere in a map made its minimum NaN, so the negative check saw none:
    a shininess of -1.4e6 beside it (a PXR24 garbage decode of gbuffers/ortho.exr)
    shaded to NaN with exit 0. Now: the NaN pixel is background, the negative one
    clamped, each with its line."""
    src, out = work
    fg = np.flatnonzero(~random_gbuffer(np.random.default_rng(5), H, W).background_mask())
    h = np.full((H, W), 20.0, np.float32)
    h.reshape(-1)[fg[0]] = np.nan
    h.reshape(-1)[fg[1]] = -1.4e6
    path = _with_maps(src, {"h": h})
    rc = cli(render_argv(src, out, gbuffer=path))
    err = capsys.readouterr().err
    assert rc == 0 and err.count("\n") == 2, err
    nonfinite, negative = err.splitlines()
    assert "non-finite G-buffer values left unshaded as background" in nonfinite
    assert "negative G-buffer values clamped to 0" in negative and "maps.exr: shininess: 1 pixel(s)" in negative
    assert np.all(np.isfinite(oiio.ImageBuf(str(out / "beauty.exr")).get_pixels(oiio.FLOAT)))


def _recompressed_as(sample: Path, dst: Path, code: int) -> Path:
    """``sample`` with the compression attribute's byte changed to ``code`` (5 = PXR24)
    in every part, the rest as it was (the chunks still hold the old compression)."""
    data = bytearray(sample.read_bytes())
    key = b"compression\x00compression\x00\x01\x00\x00\x00"
    at = data.find(key)
    assert at >= 0
    while at >= 0:
        data[at + len(key)] = code
        at = data.find(key, at + 1)
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize("sample,scene,needles", [
    ("spheres.exr", "spheres.toml", ["P.X,P.Y,P.Z: X ", "albedo.R,albedo.G,albedo.B: R ", "A: "]),
    ("ortho.exr", "ortho.toml", ["P.X,P.Y,P.Z: X ", "shininess: "]),
    ("blender/cycles-5.0.exr", "blender/spheres.toml", ["ViewLayer.Position.X,"]),
], ids=["spheres", "ortho", "cycles-5.0"])
def test_zip_read_as_pxr24_is_counted_not_shaded_to_nan(work, capsys, sample, scene, needles):
    """The finding: ZIP chunks read as PXR24 decode without error to garbage (NaN,
    ±3.4e38, tens of thousands of negatives); the output had NaN (in A, from a NaN
    coverage, or from a negative shininess next to a NaN) with exit 0. Now: NaN and
    implausible pixels background, one line with their counts (per channel for the
    implausible), negatives clamped on a second line; the output finite; refused,
    one line, under --nonfinite error."""
    src, out = work
    bad = _recompressed_as(SAMPLES / sample, src / "pxr24.exr", 5)
    line = warns(render_argv(src, out, gbuffer=bad, scene=SAMPLES / scene), capsys, src.parent,
                 "pxr24.exr", "non-finite G-buffer values left unshaded as background",
                 "also implausibly large G-buffer values", *needles, lines=2)
    assert "\n" not in line
    (out / "beauty.exr").unlink()
    fails(render_argv(src, out, gbuffer=bad, scene=SAMPLES / scene, extra=["--nonfinite", "error"]),
          capsys, src.parent, "pxr24.exr", "non-finite (NaN/Inf) G-buffer values",
          "implausibly large G-buffer values", *needles)


def _typed_exr(path, types: dict, compression="zip"):
    """The 9 channels of _gbuffer_planes written by OpenImageIO, channel ``n`` as
    ``types.get(n, "float")``."""
    planes = _gbuffer_planes()
    names = list(planes)
    data = np.ascontiguousarray(np.stack([np.asarray(planes[n], np.float32) for n in names], -1))
    spec = oiio.ImageSpec(W, H, len(names), oiio.TypeDesc("float"))
    spec.channelnames = tuple(names)
    spec.channelformats = tuple(oiio.TypeDesc(types.get(n, "float")) for n in names)
    spec.attribute("compression", compression)
    o = oiio.ImageOutput.create(str(path))
    assert o.open(str(path), spec), o.geterror()
    assert o.write_image(data) and o.close()
    return path


def test_a_vector_with_one_half_channel_warns_with_the_types(work, capsys):
    """P.X half while P.Y, P.Z float (what a flipped pixel-type byte makes, in a file
    whose chunks still decode) was read silently. Now one warning line naming the
    file, buffer, channels and types; a whole layer in another type (half albedo,
    float position) stays silent: renderers write that."""
    src, out = work
    path = _typed_exr(src / "mixed.exr", {"P.X": "half"})
    warns(render_argv(src, out, gbuffer=path), capsys, src.parent, "mixed.exr",
          "(position: P.X as half and P.Y, P.Z as float)", "flipped pixel-type byte")
    layer = _typed_exr(src / "layers.exr", {f"albedo.{c}": "half" for c in "RGB"})
    assert cli(render_argv(src, out, gbuffer=layer)) == 0
    assert capsys.readouterr().err == ""


def test_a_pixel_type_byte_flipped_float_to_half_names_the_channel(work, capsys):
    """FLOAT -> HALF in one channel's header entry: every ZIP chunk is then the wrong
    size and the read failed with OpenImageIO's 'missing or corrupted' alone. Now the
    line names the channel and the types."""
    src, out = work
    data = bytearray((src / "gbuf.exr").read_bytes())
    at = data.find(b"P.Y\x00")
    assert at >= 0 and data[at + 4:at + 8] == b"\x02\x00\x00\x00"     # FLOAT
    data[at + 4] = 1                                                   # HALF
    (src / "flipped.exr").write_bytes(bytes(data))
    fails(render_argv(src, out, gbuffer=src / "flipped.exr"), capsys, src.parent, "flipped.exr",
          "failed: ", "(position: P.Y as half and P.X, P.Z as float): a flipped pixel-type byte?")


def test_inspect_escapes_control_bytes_in_its_table(tmp_path, capsys):
    """`inspect` prints a table of the file's channels: a channel named with terminal
    control bytes (ESC[2K ESC[1G erases the line on a terminal) is shown escaped on
    stdout too, as every stderr line is (the layout of the table is kept)."""
    path = tmp_path / "ctl.exr"
    spec = oiio.ImageSpec(4, 3, 3, "float")
    spec.channelnames = ("\x1b[2K\x1b[1G.R", "\x1b[2K\x1b[1G.G", "\x1b[2K\x1b[1G.B")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.zeros((3, 4, 3), np.float32))
    out.close()
    assert main(["inspect", str(path)]) == 0
    shown = capsys.readouterr().out
    assert "\\x1b[2K\\x1b[1G.R" in shown
    assert not any(ord(c) < 32 and c != "\n" for c in shown)


def test_coverage_outside_zero_one_is_clipped_before_shading_and_counted(work, capsys):
    """A coverage of -1 or -0.5 was shaded at full strength and written with A = 0 (colour
    where alpha says nothing is there), silently. Now it is clipped before shading: below
    0 is background, above 1 is 1, each side counted in the out-of-range warning; -0.0
    is background as 0 is, a subnormal coverage a (flushed) partial one. The output is
    held to the float64 reference of the clipped G-buffer within the error model; under
    --nonfinite error the frame is refused with the counts."""
    from clphong.io.gbuffer import read_gbuffer
    from clphong.model.scene import load_scene
    from clphong.reference import shading as reference

    src, out = work
    gb = random_gbuffer(np.random.default_rng(21), H, W, background_fraction=0.0)
    cov = np.ones((H, W), np.float32)
    cov[0, :6] = [-1.0, -0.5, -0.0, 1.5, 1e-40, 0.5]      # 1e-40: a float32 subnormal
    cov[1, 0] = 3.0
    write_gbuffer(src / "cov.exr", gb.position, gb.normal, gb.albedo, coverage=cov)
    assert cli(render_argv(src, out, gbuffer=src / "cov.exr")) == 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "coverage outside [0, 1] clipped" in err, err
    assert "below 0 2, above 1 2 pixel(s)" in err, err
    rgba = oiio.ImageBuf(str(out / "beauty.exr")).get_pixels(oiio.FLOAT)
    clipped = read_gbuffer(src / "cov.exr")
    clipped = type(clipped)(**{**clipped.__dict__, "coverage": np.clip(clipped.coverage, 0, 1)})
    scene = load_scene(src / "scene.toml")
    ref = reference.shade(scene, clipped)
    bound, _ = reference.error_bound(scene, clipped)
    assert np.all(np.abs(rgba[..., :3] - ref) <= bound + 1e-38)   # + FLT_MIN/100: the flushed subnormal
    assert np.all(rgba[0, :3, :3] == 0.0) and np.all(rgba[0, :3, 3] == 0.0)   # background, A = 0
    assert rgba[0, 3, 3] == 1.0 and rgba[1, 0, 3] == 1.0
    (out / "beauty.exr").unlink()
    fails(render_argv(src, out, gbuffer=src / "cov.exr", extra=["--nonfinite", "error"]), capsys,
          src.parent, "coverage outside [0, 1]", "below 0 2, above 1 2 pixel(s)")


def test_relights_failure_lines_are_cut_like_error_lines(work, capsys):
    """A failed frame's line quotes its paths: with a long folder name it reached 2,127
    characters and more; every line relight prints is cut at MAX_LINE as error lines are."""
    from clphong.core.errors import MAX_LINE

    src, out = work
    deep = src.joinpath(*["e" * 200] * 12)
    deep.mkdir(parents=True)
    shutil.copy(src / "gbuf.exr", deep / "seq.0001.exr")
    (deep / "seq.0002.exr").write_bytes((src / "gbuf.exr").read_bytes()[:300])   # cut short
    rc = cli(["relight", deep / "seq.####.exr", "--rig", src / "scene.toml", "-o", out / "o.####.exr"])
    err = capsys.readouterr().err
    assert rc == 1, err
    lines = err.splitlines()
    assert any("frame 2" in ln for ln in lines), err
    assert max(len(ln) for ln in lines) <= MAX_LINE + len("… (99999 more characters)"), \
        [len(ln) for ln in lines]
    assert any(ln.endswith("more characters)") for ln in lines)


def test_a_scene_saved_with_a_byte_order_mark_is_read(work, capsys):
    """A scene saved with a UTF-8 byte-order mark got "invalid TOML: Invalid statement" at
    1:1; it is read past, as the lights CSV's is."""
    src, out = work
    (src / "bom.toml").write_bytes(b"\xef\xbb\xbf" + SCENE.encode())
    assert cli(render_argv(src, out, scene=src / "bom.toml")) == 0, capsys.readouterr().err


@pytest.mark.parametrize("op, white, needle", [
    ("hable", "1e-300", "must map above 0, got W = 1e-300 for 'hable'"),
    ("reinhard-extended", "1e-300", "must be at least 5.42e-20 (1/W² a float32), got 1e-300"),
    ("reinhard-extended", "1e-21", "got 1e-21"),
])
def test_a_white_point_the_kernel_cannot_take_names_the_file_and_key(work, capsys, op, white, needle):
    """render.white_point = 1e-300 with Hable was refused at the first frame by a message
    naming neither the scene file nor the key."""
    src, out = work
    (src / "wp.toml").write_text(SCENE + f'\n[render]\ntonemap = "{op}"\nwhite_point = {white}\n')
    line = fails(render_argv(src, out, scene=src / "wp.toml", extra=["--sdr", out / "o.png"]),
                 capsys, src.parent, "wp.toml: render.white_point: ", needle)
    assert "\n" not in line


def _relight_argv(src, out, template, rig=None):
    return ["relight", src / "seq.####.exr", "--rig", rig or src / "scene.toml", "-o", template]


@pytest.fixture
def seq(work):
    src, out = work
    for f in (1, 2):
        shutil.copy(src / "gbuf.exr", src / f"seq.{f:04d}.exr")
    return src, out


@pytest.mark.parametrize("template, needle", [
    ("missing/../o.####.exr", "output folder DIR/out/missing/..: DIR/out/missing does not exist, "
                              "so '..' after it cannot be resolved"),
    ("new/sub/../o.####.exr", "DIR/out/new does not exist"),
    ("afile/o.####.exr", "output folder DIR/out/afile: DIR/out/afile is a file, not a folder"),
])
def test_output_folders_are_checked_before_any_frame(seq, capsys, template, needle):
    """`-o missing/../o.exr` passed the checks, shaded every frame, then failed with
    "cannot replace the file: No such file or directory"; now one line before any frame."""
    src, out = seq
    (out / "afile").write_text("")
    fails(_relight_argv(src, out, out / template), capsys, src.parent, needle.replace("DIR", str(src.parent)))
    assert sorted(p.name for p in out.iterdir()) == ["afile"]


def test_render_to_a_folder_through_a_missing_one_is_one_line(work, capsys):
    src, out = work
    fails(render_argv(src, out, output=out / "missing" / ".." / "o.exr"), capsys, src.parent,
          "folder", "missing/.. does not exist")


@pytest.mark.parametrize("name", ["../../x", "a/b", "..", ".", "a\x1bb", "tab\there"])
def test_rig_names_are_one_printable_path_component(seq, capsys, name):
    """A rig named ../../x made folders outside the output tree; names may not hold '/'
    or control bytes either. Checked at the door, one line, nothing written."""
    src, out = seq
    argv = _relight_argv(src, out, out / "{rig}" / "o.####.exr", rig=f"{name}={src / 'scene.toml'}")
    fails(argv, capsys, src.parent, "rig name", "must be one folder or file name of printable characters")
    assert not list(out.iterdir()) and not (src.parent.parent / "x").exists()


_SLOW_WRITER = """
import sys, time
from clphong.io import atomic
real = atomic._write_in_strips
def slow(out, spec, data):
    sys.stderr.write("writing\\n"); sys.stderr.flush()
    time.sleep(float(sys.argv[1]))
    return real(out, spec, data)
atomic._write_in_strips = slow
from clphong.console.cli import main
sys.exit(main(sys.argv[2:]))
"""


def _until(cond, timeout=120.0):
    import time

    t0 = time.perf_counter()
    while not cond():
        assert time.perf_counter() - t0 < timeout, "timed out"
        time.sleep(0.02)


@pytest.mark.parametrize("command", ["render", "relight"])
def test_a_second_run_never_removes_a_live_runs_temporary_file(work, command):
    """Two real processes writing the same output: the second took the first's temporary
    file for a leftover of an interrupted run and removed it; the first died with a
    FileNotFoundError traceback and its frame was lost. Now a live writer's file is
    locked and left alone: both runs end 0, with no traceback, and the last writer's
    file stands whole (a valid EXR equal to what both shaded)."""
    src, out = work
    if command == "render":
        argv = [str(a) for a in render_argv(src, out)]
        target = out / "beauty.exr"
    else:
        shutil.copy(src / "gbuf.exr", src / "seq.0001.exr")
        argv = ["relight", str(src / "seq.####.exr"), "--rig", str(src / "scene.toml"),
                "-o", str(out / "{rig}.####.exr"), "--skip-existing"]
        target = out / "scene.0001.exr"
    first = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, "4", *argv],
                             stderr=subprocess.PIPE, text=True)
    _until(lambda: [p for p in out.iterdir() if ".tmp-" in p.name])     # the first is writing
    second = subprocess.run([sys.executable, "-m", "clphong", *argv], capture_output=True,
                            text=True, timeout=300)
    assert second.returncode == 0, second.stderr
    assert "removed" not in second.stderr            # nothing taken for a leftover
    _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert "Traceback" not in err and "Traceback" not in second.stderr
    assert not [p for p in out.iterdir() if ".tmp-" in p.name]
    rgba = oiio.ImageBuf(str(target)).get_pixels(oiio.FLOAT)
    assert rgba is not None and np.isfinite(rgba).all()


def test_a_leftover_of_a_killed_writer_is_still_removed(work, capsys):
    """The lock is the proof: a writer killed with SIGKILL holds none, so the next run
    removes its temporary file (with a warning), as before."""
    src, out = work
    proc = subprocess.Popen([sys.executable, "-c", _SLOW_WRITER, "60",
                             *[str(a) for a in render_argv(src, out)]], stderr=subprocess.PIPE, text=True)
    _until(lambda: [p for p in out.iterdir() if ".tmp-" in p.name])
    proc.kill()
    proc.wait(timeout=30)
    assert [p for p in out.iterdir() if ".tmp-" in p.name]
    assert cli(render_argv(src, out)) == 0
    err = capsys.readouterr().err
    assert "removed 1 temporary file(s) an interrupted earlier run left" in err, err
    assert [p.name for p in out.iterdir()] == ["beauty.exr"]


# ======================================================= long names and values (issue 26)

@pytest.mark.parametrize("where", ["toml-key", "toml-value", "option"])
def test_a_huge_name_or_value_is_quoted_in_at_most_about_200_characters(work, capsys, where):
    """A 100,000-character unknown TOML key gave a 2,041-character line: a message quotes
    at most QUOTE_MAX characters of one word, cut around an ellipsis with its length, and
    the API's exception says the same as the CLI."""
    from clphong.core.errors import QUOTE_MAX, ClphongError, abbreviate
    from clphong.model.scene import load_scene

    src, out = work
    huge = "k" * 100_000
    extra = ()
    if where == "toml-key":
        (src / "scene.toml").write_text(SCENE.replace("[material]\n", f"[material]\n{huge} = 1\n", 1))
    elif where == "toml-value":
        (src / "scene.toml").write_text(SCENE.replace('model = "phong"', f'model = "{huge}"', 1))
    else:
        extra = ("--tonemap", huge)
    line = fails(render_argv(src, out, extra=extra), capsys, src.parent)
    assert "…" in line or "..." in line          # (a TOML value was cut at 60 characters already)
    assert len(line) <= 2 * QUOTE_MAX + 250, len(line)
    assert max(len(w) for w in line.split()) <= QUOTE_MAX, line
    if where != "option":
        with pytest.raises(ClphongError) as e:
            load_scene(src / "scene.toml")
        assert "clphong: error: " + str(e.value) == line
    # short words are left alone; the cut keeps both ends
    assert abbreviate("a b c") == "a b c"
    cut = abbreviate("x" * 150 + "y" * 150)
    assert cut.startswith("x" * 150) and "…" in cut and cut.split(" (")[0].endswith("y" * 25)
    assert "(300 characters)" in cut

"""The clphong command, in-process (main(argv)) and once as a subprocess."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import GBUFFERS, patch_everywhere, read_rgb

from clphong.console.cli import main

SPHERES = [str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]


def _read(path):
    return read_rgb(path, spec=True)


def test_render_single_file_in_process(tmp_path):
    import OpenImageIO as oiio

    out = tmp_path / "out.exr"
    assert main(["render", *SPHERES, "-o", str(out)]) == 0
    spec, px = _read(out)
    assert list(spec.channelnames) == ["R", "G", "B", "A"]        # A: coverage, RGB premultiplied
    assert spec.format == oiio.FLOAT
    from clphong.io.gbuffer import read_gbuffer
    inp = oiio.ImageInput.open(str(out))
    alpha = np.asarray(inp.read_image(0, 0, 3, 4, oiio.FLOAT))[..., 0]
    inp.close()
    gb = read_gbuffer(SPHERES[1])
    assert np.array_equal(alpha, np.where(gb.background_mask(), 0.0, 1.0))
    # OIIO may read the tag back under another alias of the same OCIO space.
    assert oiio.ColorConfig().equivalent(spec.getattribute("oiio:ColorSpace"),
                                         "Linear Rec.709 (sRGB)")
    assert np.allclose(spec.getattribute("chromaticities"),
                       (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290))
    # Same pixels as the API.
    import clphong
    rgb = clphong.render(clphong.load_scene(SPHERES[0]), clphong.read_gbuffer(SPHERES[1]))
    assert np.array_equal(px, rgb)
    assert [p.name for p in tmp_path.iterdir()] == ["out.exr"]


def test_render_separate_files(tmp_path):
    import clphong
    from clphong.io.atomic import write_exr

    gb = clphong.read_gbuffer(SPHERES[1])
    # one plain-RGB file per buffer; background carried by a zero normal
    N = gb.normal.copy()
    N[gb.background_mask()] = 0
    for name, arr in (("P", gb.position), ("N", N), ("A", gb.albedo)):
        write_exr(tmp_path / f"{name}.exr", arr)
    out = tmp_path / "out.exr"
    assert main(["render", SPHERES[0], "--position", str(tmp_path / "P.exr"), "--normal",
                 str(tmp_path / "N.exr"), "--albedo", str(tmp_path / "A.exr"), "-o", str(out)]) == 0
    _, px = _read(out)
    whole = clphong.render(clphong.load_scene(SPHERES[0]), gb)
    assert np.array_equal(px, whole)


def test_help_shows_examples(capsys):
    with pytest.raises(SystemExit) as e:
        main(["render", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "clphong render gbuffers/spheres.toml" in out


@pytest.mark.parametrize("argv, words", [
    (["render", SPHERES[0], "-o", "X/x.exr"], "give a G-buffer file"),
    (["render", *SPHERES], "give at least one output"),
    (["render", *SPHERES, "-o", "X/x.exr", "--lanes", "3"], "argument --lanes: invalid choice: 3"),
    (["render", *SPHERES, "-o", "X/x.exr", "--tonemapp", "agx"], "did you mean --tonemap?"),
    (["render", *SPHERES, "-o", "X/x.exr", "--exposure", "two"], "argument --exposure: invalid float"),
])
def test_usage_error_exits_2_with_one_line(argv, words, capsys, tmp_path):
    """The project rule: one line on stderr, not argparse's whole usage block."""
    argv = [a.replace("X/", f"{tmp_path}/") for a in argv]
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("clphong render: error: ") and err.count("\n") == 1, err
    assert words in err and err.endswith(" (see clphong render --help)\n"), err
    assert "usage:" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, prog", [([], "clphong"), (["rendr"], "clphong"),
                                        (["diff", "a.exr"], "clphong diff")])
def test_usage_errors_of_the_top_parser_and_other_commands_are_one_line(argv, prog, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{prog}: error: ") and err.count("\n") == 1, err
    assert err.endswith(f" (see {prog} --help)\n")


@pytest.mark.parametrize("case", ["missing-gbuffer", "missing-scene", "bad-scene", "overwrite-input",
                                  "missing-folder"])
def test_errors_are_one_line_and_leave_no_file(case, tmp_path, capsys):
    out = tmp_path / "out.exr"
    scene, gbuf = SPHERES
    if case == "missing-gbuffer":
        argv, needle = ["render", scene, str(tmp_path / "nope.exr"), "-o", str(out)], "nope.exr"
    elif case == "missing-scene":
        argv, needle = ["render", str(tmp_path / "nope.toml"), gbuf, "-o", str(out)], "nope.toml"
    elif case == "bad-scene":
        bad = tmp_path / "bad.toml"
        bad.write_text((GBUFFERS / "spheres.toml").read_text().replace("k_d = 0.7", "k_dd = 0.7"))
        argv, needle = ["render", str(bad), gbuf, "-o", str(out)], "k_dd"
    elif case == "overwrite-input":
        copy = tmp_path / "in.exr"
        shutil.copy(gbuf, copy)
        out = copy
        argv, needle = ["render", scene, str(copy), "-o", str(copy)], "overwrite"
    else:
        out = tmp_path / "no" / "such" / "out.exr"
        argv, needle = ["render", scene, gbuf, "-o", str(out)], str(out)
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith("clphong: error: ") and err.count("\n") == 1, err
    assert needle in err
    after = sorted(p.name for p in tmp_path.iterdir())
    assert after == before        # nothing written, no temporary left
    if case == "overwrite-input":
        assert open(out, "rb").read() == open(gbuf, "rb").read()


def test_plan_command_explains_the_variant(capsys):
    assert main(["plan", str(GBUFFERS / "ortho.toml"), str(GBUFFERS / "ortho.exr")]) == 0
    out = capsys.readouterr().out
    assert "-DMODEL_BLINN=1" in out and "-DCAMERA_ORTHO=1" in out and "-DBLINN_CONST_H=1" in out
    assert "-DMAP_KS=1" in out and "-DMAP_H=1" in out and "-DHAS_POINT=0" in out
    # the plan printed is the one 'render' compiles on this device
    from clphong.device.selection import get_runtime
    assert f"-DLANES={get_runtime().lanes} " in out


def test_path_fast_through_the_cli(tmp_path, capsys):
    """--path fast: the plan says what it compiles (float power, naive sum), and the
    rendered file holds that variant's error bound against the float64 reference."""
    from clphong.device.renderer import Renderer, prepare_frame
    from clphong.io.gbuffer import read_gbuffer
    from clphong.model.scene import load_scene
    from clphong.reference import shading as reference

    assert main(["plan", *SPHERES, "--path", "fast"]) == 0
    out = capsys.readouterr().out
    assert "-DPOW_FP32=1" in out and "-DDIRECTIONS_FP64=0" in out and "-DCOMPENSATED_SUM=0" in out
    assert main(["render", *SPHERES, "-o", str(tmp_path / "fast.exr"), "--path", "fast"]) == 0
    got = read_gbuffer(str(tmp_path / "fast.exr"),
                       channels={"position": "R,G,B", "normal": "R,G,B", "albedo": "R,G,B"}).albedo
    scene, gb = load_scene(SPHERES[0]), read_gbuffer(SPHERES[1])
    r = Renderer(scene, path="fast")
    frame = prepare_frame(gb, lanes=r.lanes)
    bound, _ = reference.error_bound(scene, gb, origin=frame.origin, plan=r.plan_for(frame.map_names))
    assert np.all(np.abs(got - reference.shade(scene, gb)) <= bound)
    with pytest.raises(SystemExit) as info:
        main(["render", *SPHERES, "-o", str(tmp_path / "x.exr"), "--path", "fastest"])
    assert info.value.code == 2
    assert "invalid choice: 'fastest'" in capsys.readouterr().err


@pytest.mark.parametrize("path", ["float", "fast"])
def test_obvious_kernel_takes_any_path(tmp_path, path):
    """--kernel obvious with --path: the baseline kernel renders (it has no path of its
    own); a regression once raised a traceback here."""
    assert main(["render", *SPHERES, "-o", str(tmp_path / "o.exr"), "--kernel", "obvious",
                 "--path", path]) == 0
    assert (tmp_path / "o.exr").exists()


def test_render_as_a_subprocess(tmp_path):
    out = tmp_path / "o.exr"
    exe = shutil.which("clphong") or None
    cmd = [exe] if exe else [sys.executable, "-m", "clphong"]
    r = subprocess.run(cmd + ["render", *SPHERES, "-o", str(out), "--stats"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert out.exists() and "kernel" in r.stderr
    bad = subprocess.run(cmd + ["render", SPHERES[0], str(tmp_path / "missing.exr"), "-o", str(tmp_path / "x.exr")],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 1
    assert bad.stderr.count("\n") == 1 and "missing.exr" in bad.stderr
    assert not (tmp_path / "x.exr").exists()


def test_programs_come_from_pocls_cache_in_a_second_process(tmp_path):
    """A second process with the same scene compiles nothing: it loads the binary kept
    in clphong's store (beside PoCL's kernel cache on PoCL, in clphong's cache folder
    elsewhere) and reuses the self-test's verdict."""
    cache = tmp_path / "pocl-cache"
    env = dict(os.environ, POCL_CACHE_DIR=str(cache), CLPHONG_CACHE_DIR=str(tmp_path / "clphong"))
    code = ("import clphong, sys; s = clphong.load_scene(sys.argv[1]); r = clphong.Renderer(s); "
            "print(r.runtime.compiled, r.runtime.is_pocl)")
    runs, compiled = [], []
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", code, SPHERES[0]], env=env, capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        n, is_pocl = r.stdout.split()
        compiled.append(int(n))
        # PoCL's built programs are <hash>/<hash>/program.bc; clphong's binaries *.poclbin
        # and *.clbin, its verdicts selftest/*.json
        runs.append({str(p.relative_to(tmp_path)): p.stat().st_mtime_ns
                     for pattern in ("program.bc", "*.poclbin", "*.clbin", "*.json")
                     for p in tmp_path.rglob(pattern)})
    assert compiled == [1, 0]
    assert runs[0], "nothing was kept for the second process"
    if is_pocl == "True":
        assert any(k.endswith("program.bc") for k in runs[0]), "PoCL wrote no program to its cache"
    assert runs[1] == runs[0], "the second process built the program again"


# ------------------------------------------------------------------ first-use problems


def _one_error_line(err: str) -> str:
    assert err.startswith("clphong: error: ") and err.count("\n") == 1, err
    return err


@pytest.mark.parametrize("command", ["render", "plan"])
def test_scene_and_gbuffer_swapped_says_so(command, tmp_path, capsys):
    scene, gbuf = SPHERES
    argv = [command, gbuf, scene] + (["-o", str(tmp_path / "x.exr")] if command == "render" else [])
    assert main(argv) == 1
    err = _one_error_line(capsys.readouterr().err)
    assert (f"{gbuf}: this is an OpenEXR image, not a scene file; give the scene .toml first: "
            "clphong render SCENE.toml GBUFFER.exr") in err
    assert "invalid TOML" not in err
    assert list(tmp_path.iterdir()) == []


def test_relight_rig_that_is_an_image_says_so(tmp_path, capsys):
    gbuf = SPHERES[1]
    assert main(["relight", gbuf, "--rig", gbuf, "-o", str(tmp_path / "{rig}.####.exr")]) == 1
    assert "this is an OpenEXR image, not a scene file" in _one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize("argv, usage, hint", [
    (["render", "s.toml", "g.exr", "--tonemapp", "agx"], "clphong render: error: ",
     "unrecognized arguments: --tonemapp agx; did you mean --tonemap?"),
    (["render", "s.toml", "g.exr", "--tonemapp=agx", "--sdrr", "x.png"], "clphong render: error: ",
     "did you mean --tonemap (for --tonemapp), --sdr (for --sdrr)?"),
    (["relight", "seq", "--rig", "k.toml", "-o", "o.exr", "--skip-exisitng"], "clphong relight: error: ",
     "did you mean --skip-existing?"),
    (["inspect", "f.exr", "--jsno"], "clphong inspect: error: ", "did you mean --json?"),
    (["render", "s.toml", "g.exr", "--frobnicate"], "clphong render: error: ",
     "unrecognized arguments: --frobnicate (see"),
])
def test_unknown_option_is_reported_by_the_subcommand_with_a_suggestion(argv, usage, hint, capsys):
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(usage) and err.count("\n") == 1, err
    assert "usage:" not in err
    assert hint in err, err


def test_stats_prints_the_plan_that_ran_and_splits_shade_and_write(tmp_path, capsys):
    png = tmp_path / "agx.png"
    assert main(["render", *SPHERES, "--sdr", str(png), "--tonemap", "agx", "--stats"]) == 0
    err = capsys.readouterr().err
    # the shading plan, then the display program's defines (not the shading kernel's)
    plan, display = err.split("display: kernels/tonemap_apply.cl")
    assert "DISPLAY_OUT" not in plan and "-DDISPLAY_OUT=1" in display
    assert "-DTONEMAP=" in display
    timing = [ln for ln in err.splitlines() if ln.startswith("384x256: ")]
    assert len(timing) == 1, err
    import re
    fields = dict(re.findall(r"(read|setup|shade|write|total) ([0-9.]+) s", timing[0]))
    assert set(fields) == {"read", "setup", "shade", "write", "total"}, timing
    assert "(sdr " in timing[0]
    assert float(fields["write"]) > 0          # the PNG's encoding and write, not under shade
    parts = sum(float(fields[k]) for k in ("read", "setup", "shade", "write"))
    assert abs(parts - float(fields["total"])) < 0.01, timing
    assert png.exists()


def test_stats_without_display_output_shows_display_off(tmp_path, capsys):
    assert main(["render", *SPHERES, "-o", str(tmp_path / "o.exr"), "--stats"]) == 0
    err = capsys.readouterr().err
    assert "DISPLAY_OUT" not in err and "tonemap_apply.cl" not in err and "(exr " in err


def test_samples_refuses_a_missing_folder_unless_parents(tmp_path, capsys):
    target = tmp_path / "no" / "such"
    assert main(["samples", str(target)]) == 1
    err = _one_error_line(capsys.readouterr().err)
    assert f"folder {target} does not exist; create it first, or give -p" in err
    assert list(tmp_path.iterdir()) == []
    assert main(["samples", "-p", str(target)]) == 0
    assert sorted(p.name for p in target.iterdir()) == ["ortho.exr", "spheres.exr"]
    capsys.readouterr()
    afile = tmp_path / "file"
    afile.write_text("x")
    assert main(["samples", str(afile)]) == 1
    assert "is a file, not a folder" in _one_error_line(capsys.readouterr().err)


class _ClosedPipe:
    """A stdout whose reader has gone (``| head -1`` after its line)."""

    def write(self, text):
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self):
        raise BrokenPipeError(32, "Broken pipe")


@pytest.mark.parametrize("argv", [["inspect", SPHERES[1]], ["inspect", "--json", SPHERES[1]],
                                  ["plan", SPHERES[0]], ["devices"], ["displays"]])
def test_broken_pipe_ends_quietly_in_process(argv, capsys, monkeypatch):
    from clphong.console.cli import EXIT_BROKEN_PIPE

    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert main(argv) == EXIT_BROKEN_PIPE == 141
    assert capsys.readouterr().err == ""


def test_broken_pipe_ends_quietly_as_a_subprocess():
    """The reader closes the pipe before clphong writes: no traceback, exit 141."""
    exe = shutil.which("clphong") or None
    cmd = [exe] if exe else [sys.executable, "-m", "clphong"]
    p = subprocess.Popen(cmd + ["inspect", "--json", SPHERES[1]], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()                   # no reader left: every write fails with EPIPE
    err = p.stderr.read().decode()
    assert p.wait(timeout=300) == 141, err
    assert err == "", err


def test_bench_output_runs_without_a_checkout_and_cleans_up(tmp_path, monkeypatch, capsys):
    """python -m clphong.tools.output_bench: its frame is built from clphong.tools.samples (no gbuffers/
    folder needed); its temporary folder is removed unless --keep; a bad --folder is one line."""
    from clphong.tools import commands as bench_cli
    from clphong.tools import output_bench as bench_output

    made = []

    def mkdtemp(prefix=""):
        made.append(tmp_path / f"{prefix}{len(made)}")
        made[-1].mkdir()
        return str(made[-1])

    def fake_time(args, folder):          # the timing itself is not a test
        (folder / "a.exr").write_bytes(b"x")
        return 0

    monkeypatch.setattr(bench_cli.tempfile, "mkdtemp", mkdtemp)
    monkeypatch.setattr(bench_output, "_time_outputs", fake_time)
    assert bench_output.main([]) == 0
    assert not made[0].exists()
    assert bench_output.main(["--keep"]) == 0
    assert (made[1] / "a.exr").exists()
    capsys.readouterr()
    assert bench_output.main(["--folder", str(tmp_path / "nodir")]) == 1
    err = _one_error_line(capsys.readouterr().err)
    assert f"--folder {tmp_path / 'nodir'}: does not exist" in err
    with pytest.raises(SystemExit) as info:
        bench_output.main(["--scene", SPHERES[0]])
    assert info.value.code == 2


def test_bench_output_frame_is_the_spheres_sample_from_memory(monkeypatch):
    import clphong
    from clphong.model.scene import load_scene
    from clphong.tools import output_bench as bench_output
    from clphong.tools import samples

    # the in-memory scene and G-buffer are those of gbuffers/ (so no checkout is needed)
    assert samples.spheres_scene().to_dict() == load_scene(SPHERES[0]).to_dict()
    gb, disk = samples.spheres_gbuffer(), clphong.read_gbuffer(SPHERES[1])
    for name in ("position", "normal", "albedo"):
        assert np.array_equal(getattr(gb, name), getattr(disk, name)), name
    # and the frame does not read gbuffers/ at all
    patch_everywhere(monkeypatch, clphong.io.gbuffer, "read_gbuffer", None)
    frame = bench_output._frame()
    assert frame.shape == (1080, 1920, 3) and np.isfinite(frame).all() and frame.max() > 0


def test_render_channels_maps_channels_as_the_api_does(tmp_path):
    """--channels (explicit mapping): the same pixels as the API reading the file with the
    same mapping; a decoy 'P' layer that detection would take is ignored."""
    import clphong
    from clphong.io.atomic import write_exr
    from clphong.io.gbuffer import parse_channel_mapping

    gb = clphong.read_gbuffer(SPHERES[1])
    planes = {"Pw.x": gb.position[..., 0], "Pw.y": gb.position[..., 1], "Pw.z": gb.position[..., 2],
              "P.X": gb.normal[..., 0], "P.Y": gb.normal[..., 1], "P.Z": gb.normal[..., 2],
              "nrm.X": gb.normal[..., 0], "nrm.Y": gb.normal[..., 1], "nrm.Z": gb.normal[..., 2],
              "col.R": gb.albedo[..., 0], "col.G": gb.albedo[..., 1], "col.B": gb.albedo[..., 2],
              "A": gb.coverage}
    src = tmp_path / "renamed.exr"
    write_exr(src, np.stack(list(planes.values()), axis=-1), channel_names=tuple(planes))
    items = ["position=Pw.x,Pw.y,Pw.z", "normal=nrm", "albedo=col.R,col.G,col.B", "coverage=A"]
    out = tmp_path / "out.exr"
    argv = ["render", SPHERES[0], str(src), "-o", str(out)]
    for item in items:
        argv += ["--channels", item]
    assert main(argv) == 0
    _, px = _read(out)
    scene = clphong.load_scene(SPHERES[0])
    api = clphong.render(scene, clphong.read_gbuffer(str(src), channels=parse_channel_mapping(items)))
    assert np.array_equal(px, api)
    assert np.array_equal(px, clphong.render(scene, gb))      # the mapping took the right planes


@pytest.mark.parametrize("outputs", [
    ["--sdr", "o/a.png", "--hdr", "o/a.png"],
    ["--sdr", "o/x.png", "--contact-sheet", "o/x.png"],
    ["--sdr", "o/a.png", "--sdr", "o/./a.png"],
    ["-o", "o/a.exr", "--sdr", "o/b.png", "--hdr", "o/../o/b.png"],
])
def test_two_outputs_with_one_path_are_refused_before_any_work(outputs, tmp_path, capsys):
    (tmp_path / "o").mkdir()
    argv = ["render", *SPHERES] + [str(tmp_path / a) if "/" in a else a for a in outputs]
    assert main(argv) == 1
    err = _one_error_line(capsys.readouterr().err)
    assert "one would replace the other" in err
    assert err.startswith(f"clphong: error: {tmp_path / 'o'}/"), err
    assert list((tmp_path / "o").iterdir()) == []


def test_outputs_that_would_not_fit_in_memory_are_refused_before_shading(tmp_path, capsys,
                                                                          monkeypatch):
    """With 7.8 MiB usable the 384x256 sample is read (7.5 MiB), shades in row bands
    and its EXR is written; its SDR and HDR PQ files as well would need
    1.25·(12 + 38 + 18) B/px = 7.97 MiB (clphong.core.memory.output_bytes): one line with
    both figures, exit 1, no file at all."""
    from clphong.console import cli
    from clphong.core.memory import output_bytes

    monkeypatch.setenv("CLPHONG_MAX_MEMORY", "7.8M")
    assert output_bytes((256, 384), ["exr"]) < 7.8 * 2 ** 20 < output_bytes((256, 384), ["exr", "sdr", "hdr"])
    assert cli.main(["render", *SPHERES, "-o", str(tmp_path / "a.exr")]) == 0
    capsys.readouterr()
    argv = ["render", *SPHERES, "-o", str(tmp_path / "b.exr"), "--sdr", str(tmp_path / "b.png"),
            "--hdr", str(tmp_path / "c.png")]
    assert cli.main(argv) == 1
    err = _one_error_line(capsys.readouterr().err)
    assert "writing the outputs (exr, hdr, sdr) of a 384x256 frame needs about" in err
    assert "CLPHONG_MAX_MEMORY" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.exr"]


@pytest.mark.parametrize("extra,warned", [
    (["--hdr", "x.png", "--tonemap", "agx"], "--tonemap agx applies to the SDR output (--sdr) only; "
                                             "the HDR output is tone-mapped by its OCIO view"),
    (["--tonemap", "agx"], "--tonemap agx applies to the SDR output (--sdr) only; no SDR output"),
    (["--sdr", "x.png", "--tonemap", "agx", "--white", "3"], "--white 3 has no effect: 'agx'"),
    (["--sdr", "x.png", "--tonemap", "reinhard-extended", "--white", "3"], None),
    (["--sdr", "x.png", "--tonemap", "agx"], None),
])
def test_colour_options_no_output_uses_are_warned_about(extra, warned, tmp_path, capsys):
    from clphong.console import cli

    argv = ["render", *SPHERES, "-o", str(tmp_path / "a.exr")]
    argv += [str(tmp_path / a) if a.endswith(".png") else a for a in extra]
    assert cli.main(argv) == 0
    err = capsys.readouterr().err
    if warned is None:
        assert "warning" not in err, err
    else:
        assert warned in err and err.count("\n") == 1, err


@pytest.mark.parametrize("args, needle", [
    (["--sdr", "w.png", "--aov", "diffuse"], "--aov adds EXR layers, and no EXR is written (-o)"),
    (["-o", "w.exr", "--alpha"], "--alpha applies to the --sdr and --hdr outputs only"),
])
def test_an_option_no_output_uses_warns_in_one_line(args, needle, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["render", *SPHERES, *args]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"clphong: warning: {needle}"), err

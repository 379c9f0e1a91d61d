"""The clphong command, in-process (main(argv)) and once as a subprocess."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from clphong.cli import main

from conftest import GBUFFERS

SPHERES = [str(GBUFFERS / "spheres.toml"), str(GBUFFERS / "spheres.exr")]


def _read(path):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    spec = inp.spec()
    px = inp.read_image(oiio.FLOAT)
    inp.close()
    return spec, px


def test_render_single_file_in_process(tmp_path):
    import OpenImageIO as oiio

    out = tmp_path / "out.exr"
    assert main(["render", *SPHERES, "-o", str(out)]) == 0
    spec, px = _read(out)
    assert list(spec.channelnames) == ["R", "G", "B"]
    assert spec.format == oiio.FLOAT
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
    from clphong.output import write_exr

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


def test_usage_error_exits_2(capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["render", SPHERES[0], "-o", str(tmp_path / "x.exr")])
    assert e.value.code == 2
    assert not (tmp_path / "x.exr").exists()


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
    from clphong.runtime import get_runtime
    assert f"-DLANES={get_runtime().lanes} " in out


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
    """A second process with the same scene finds the program in PoCL's kernel cache."""
    cache = tmp_path / "pocl-cache"
    env = dict(os.environ, POCL_CACHE_DIR=str(cache))
    code = ("import clphong, sys; s = clphong.load_scene(sys.argv[1]); r = clphong.Renderer(s); "
            "print(r.runtime.build_seconds)")
    runs = []
    for _ in range(2):
        r = subprocess.run([sys.executable, "-c", code, SPHERES[0]], env=env, capture_output=True,
                           text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        # PoCL also leaves scratch files (tempfile_*) at the top; the built
        # programs are <hash>/<hash>/program.bc.
        runs.append({str(p.relative_to(cache)): p.stat().st_mtime_ns
                     for p in cache.rglob("program.bc")})
    assert runs[0], "PoCL wrote no program to its cache"
    assert runs[1] == runs[0], "the second process built the program again"

"""Behaviour kept through the house's rebuild (issue 26): the samples' renders and a
relight give the same pixels and the same image files as the tree before the split.

``BEFORE`` is the last commit before issue 26 split the README, the device layer, the
bench, the G-buffer reader and the scene parser into rooms (d44daee and after). Its
``clphong/`` and ``kernels/`` are taken from this repository's history with
``git archive`` and run beside the current tree, each as ``python -m clphong`` in a
process of its own, on the same device and width, with a cache folder of its own.
Pixels are compared exactly (EXR), files byte for byte (PNG).

What is left out, and why:

* Intel's runtime on an AVX2 host: the comparison runs on PoCL there
  (:data:`AVX2_INTEL`).
* ``--path fast``: its 1/√x became ``native_rsqrt`` with a Newton step where measured
  within 2 ulp (issue 31, after the split), which moves its pixels by up to ~1e-6 on
  purpose.
* EXR files byte for byte: their header holds the time of writing (``DateTime``).
* The bench scenes: the bench's output is timings; its scenes are the renderer's, and
  the renderer's pixels are what this compares.
* An environment's default probes: since issue 25's frame probes (2026-12-07) the sky is
  resolved on the frame's own pixels, fewer lights on purpose; the sky case asks the
  current tree for ``--env-probes all``, the one way the tree before had (:data:`NOW_ONLY`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SAMPLES = REPO / "gbuffers"
#: The tree before issue 26's first split (the README's, d44daee).
BEFORE = "5683b04"
#: Why an AVX2 host compares on PoCL, not Intel's runtime.
AVX2_INTEL = ("on an AVX2 host Intel's runtime forms the accurate path's 1/√x by clphong's "
              "inline steps since 2026-12-07, not the builtin (Zen 3: 1.19x faster), which "
              "moves its pixels within the error model on purpose")


def _archive(dest: Path) -> bool:
    """Unpack BEFORE's clphong/ and kernels/ into ``dest``; False where the commit is
    not in this checkout's history (a source archive, a shallow clone)."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        return False
    ok = subprocess.run(["git", "-C", str(REPO), "cat-file", "-e", BEFORE + "^{commit}"],
                        capture_output=True)
    if ok.returncode != 0:
        return False
    tar = dest / "before.tar"
    with open(tar, "wb") as f:
        subprocess.run(["git", "-C", str(REPO), "archive", BEFORE, "clphong", "kernels"],
                       stdout=f, check=True)
    with tarfile.open(tar) as t:
        # our own history's files; the "data" filter where this Python has it (3.11.4+)
        kw = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}
        t.extractall(dest / "tree", **kw)
    return True


def _device_args() -> list[str]:
    """The current default device and width, named so that both trees take them; on an
    AVX2 host, PoCL where the default is Intel's runtime (:data:`AVX2_INTEL`)."""
    from clphong.core.errors import DeviceError
    from clphong.device.hostrule import host
    from clphong.device.selection import get_runtime

    rt = get_runtime()
    if rt.kind == "intel-cpu" and not host().avx512:
        try:
            rt = get_runtime("pocl")
        except DeviceError:
            pytest.skip(AVX2_INTEL + "; no PoCL device to compare on")
    platform = rt.device.platform.name
    dev = ("intel" if "Intel" in platform else "pocl" if "Portable" in platform
           else rt.device.name)
    return ["--device", dev, "--lanes", str(rt.lanes)]


#: (name, clphong arguments; {out} is the output prefix, {seq} the two-frame sequence)
CASES = [
    ("spheres", ["render", "{g}/spheres.toml", "{g}/spheres.exr", "-o", "{out}.exr",
                 "--sdr", "{out}.png", "--hdr", "{out}-hdr.png"]),
    ("ortho", ["render", "{g}/ortho.toml", "{g}/ortho.exr", "-o", "{out}.exr",
               "--tonemap", "hable", "--exposure", "0.5", "--sdr", "{out}.png"]),
    ("spot", ["render", "{g}/spheres_spot.toml", "{g}/spheres.exr", "-o", "{out}.exr",
              "--exr-type", "half"]),
    ("sky", ["render", "{g}/spheres_sky.toml", "{g}/spheres.exr", "-o", "{out}.exr",
             "--sdr", "{out}.png"]),
    ("relight", ["relight", "{seq}", "--rig", "key={g}/spheres.toml",
                 "--rig", "spot={g}/spheres_spot.toml", "-o", "{out}-{{rig}}.####.exr",
                 "--sdr", "{out}-{{rig}}.####.png", "-q"]),
]


#: Arguments only the current tree is given: options since BEFORE that select its behaviour.
NOW_ONLY = {"sky": ["--env-probes", "all"]}


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """Every case's outputs from both trees: {tree: folder}."""
    root = tmp_path_factory.mktemp("behaviour")
    if not _archive(root):
        pytest.skip(f"commit {BEFORE} (the tree before issue 26's split) is not in this "
                    "checkout's history: nothing to compare with")
    for k in (1, 2):
        shutil.copy(SAMPLES / "spheres.exr", root / f"seq.{k:04d}.exr")
    device = _device_args()
    folders = {}
    for tree, path in (("before", root / "tree"), ("now", REPO)):
        out = root / tree
        out.mkdir()
        env = {**os.environ, "PYTHONPATH": str(path), "CLPHONG_CACHE_DIR": str(root / f"cache-{tree}")}
        for name, args in CASES:
            argv = [a.format(g=SAMPLES, out=out / name, seq=root / "seq.####.exr") for a in args]
            if tree == "now":
                argv += NOW_ONLY.get(name, [])
            r = subprocess.run([sys.executable, "-m", "clphong", *argv, *device], cwd=root,
                               env=env, capture_output=True, text=True, timeout=600)
            assert r.returncode == 0, (tree, name, r.stderr[-2000:])
        folders[tree] = out
    return folders


def _pixels(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    assert not buf.has_error, buf.geterror()
    return buf.get_pixels(oiio.FLOAT)


def test_the_same_files_come_out(outputs):
    names = sorted(p.name for p in outputs["before"].iterdir())
    assert names == sorted(p.name for p in outputs["now"].iterdir())
    # every case wrote what it was asked for: 3 + 2 + 1 + 2 + 2 rigs x 2 frames x 2 files
    assert len(names) == 16, names


@pytest.mark.parametrize("name", [n for n, _ in CASES])
def test_the_same_pixels_and_image_files(outputs, name):
    before = sorted(outputs["before"].glob(name + "*"))
    assert before, name
    for f in before:
        g = outputs["now"] / f.name
        if f.suffix == ".exr":
            a, b = _pixels(f), _pixels(g)
            assert a.shape == b.shape and np.array_equal(a, b, equal_nan=True), f.name
        else:
            assert f.read_bytes() == g.read_bytes(), f.name

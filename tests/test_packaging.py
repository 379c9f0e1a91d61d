"""The kernels are found from a built wheel and from an editable install."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

PROBE = (
    "import sys, clphong, clphong.device.runtime as rt; "
    "print(clphong.__file__); print(rt.kernel_dir()); "
    "s = clphong.load_scene(sys.argv[1]); g = clphong.read_gbuffer(sys.argv[2]); "
    "print(float(clphong.render(s, g).max()))"
)


def _offline_build() -> list[str]:
    """``--no-build-isolation`` where this environment can build clphong itself (setuptools
    68 or later, and wheel): pip then fetches no build dependencies, which a machine with no
    package index (the GPU machine) cannot; elsewhere pip's isolated build, as a user's."""
    try:
        from importlib.metadata import version

        major = int(version("setuptools").split(".")[0])
        version("wheel")
    except Exception:     # not installed, or an odd version string
        return []
    return ["--no-build-isolation"] if major >= 68 else []


def _pip(*args, cwd=None):
    if args[0] in ("wheel", "install"):
        args = (args[0], *_offline_build(), *args[1:])
    r = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True,
                       cwd=cwd, timeout=600)
    if r.returncode != 0:
        pytest.fail(f"pip {' '.join(args)} failed:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    return r


def _probe(site: Path, tmp_path: Path, *, editable: bool):
    """Import clphong from ``site`` in a fresh interpreter, whatever the test
    environment holds: clphong in its site-packages (CI), or an editable install
    of another checkout (a developer's venv).

    The interpreter starts with -S, so no .pth file of the environment has run,
    and ``site`` goes first on sys.path. For an editable install its .pth file is
    then processed first: the finder module it imports is named after the project
    and version only (``__editable___clphong_0_1_0_finder``), the same in every
    editable install of this version, so whichever .pth runs first decides which
    checkout is imported; the environment's own .pth, run by site.main() (which
    adds its site-packages, for the dependencies), then finds that module already
    imported and installed. The editable finder is appended to sys.meta_path,
    behind the path finder that would find a non-editable clphong in
    site-packages: it is moved to the front, as if it were the only install,
    which is what a user of -e has.
    """
    pre = f"import site, sys; sys.path.insert(0, {str(site)!r}); "
    if editable:
        pre += f"site.addsitedir({str(site)!r}); "
    pre += "site.main(); "
    if editable:
        pre += "sys.meta_path.sort(key=lambda f: '__editable__' not in repr(f)); "
    # Run outside the repo so the checkout's clphong/ is not on sys.path.
    r = subprocess.run([sys.executable, "-S", "-c", pre + PROBE,
                        str(REPO / "gbuffers/spheres.toml"), str(REPO / "gbuffers/spheres.exr")],
                       capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    module, kdir, peak = r.stdout.split("\n")[:3]
    return Path(module), Path(kdir), float(peak)


def test_kernels_found_from_a_built_wheel(tmp_path):
    _pip("wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"), str(REPO))
    wheel = next((tmp_path / "dist").glob("clphong-*.whl"))
    import zipfile
    names = zipfile.ZipFile(wheel).namelist()
    assert "clphong/kernels/shade.cl" in names and "clphong/kernels/include/clphong.h" in names
    site = tmp_path / "site"
    _pip("install", "--no-deps", "-q", "--target", str(site), str(wheel))
    module, kdir, peak = _probe(site, tmp_path, editable=False)
    assert site in module.parents and site in kdir.parents
    assert peak > 0


def test_kernels_found_from_an_editable_install(tmp_path):
    # --target, not --prefix: with --prefix pip would first uninstall the
    # clphong that the test environment itself runs.
    site = tmp_path / "site"
    _pip("install", "--no-deps", "-q", "-e", str(REPO), "--target", str(site))
    module, kdir, peak = _probe(site, tmp_path, editable=True)
    assert module == REPO / "clphong" / "__init__.py"
    assert kdir == REPO / "kernels"
    assert peak > 0

"""Shared fixtures: scenes and G-buffers built in memory."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
GBUFFERS = REPO / "gbuffers"


# Scene and G-buffer builders shared with the hard-case suite (make_scene
# bypasses the file validation, so tests may use c0 = 0).
from clphong.tools.hardcases import make_gbuffer, make_scene  # noqa: E402,F401


#: The bad-input catalogue: (case, exit code, the one error line) of every case of
#: tests/test_hostile.py that runs the CLI through its fails(); printed as a Markdown
#: table at the end of the run when CLPHONG_CATALOGUE is set:
#: ``CLPHONG_CATALOGUE=1 python -m pytest -q tests/test_hostile.py``.
CATALOGUE: list[tuple[str, int, str]] = []


def pytest_terminal_summary(terminalreporter):
    if os.environ.get("CLPHONG_CATALOGUE") and CATALOGUE:
        from clphong.tools.commands import markdown_table

        terminalreporter.write_line(f"\nbad-input catalogue ({len(CATALOGUE)} cases):")
        rows = [(case, f"`{msg}`".replace("|", "\\|"), code) for case, code, msg in CATALOGUE]
        terminalreporter.write_line(markdown_table(["case", "message", "exit code"], rows))


def random_gbuffer(rng, h=24, w=40, *, spread=3.0, background_fraction=0.1, maps=()):
    """Random positions on a slab, random normals facing +z mostly, random albedo."""
    P = rng.uniform(-spread, spread, (h, w, 3))
    P[..., 2] = rng.uniform(-0.5, 0.5, (h, w))
    N = rng.normal(size=(h, w, 3))
    N[..., 2] = np.abs(N[..., 2]) + 0.3
    N *= rng.uniform(0.5, 2.0, (h, w, 1))            # not unit: the host normalises
    C = rng.uniform(0.0, 1.0, (h, w, 3))
    cov = (rng.uniform(size=(h, w)) > background_fraction).astype(np.float32)
    return make_gbuffer(P, N, C, cov, random_maps(rng, h, w, maps))


def random_maps(rng, h, w, maps):
    """Random material maps, only those named in ``maps``."""
    ranges = {"k_d": (1.0, ()), "k_s": (1.0, ()), "h": (200.0, ()), "specular_color": (1.0, (3,))}
    return {name: rng.uniform(0, top, (h, w) + extra)
            for name, (top, extra) in ranges.items() if name in maps}


def random_lights(rng, n_point=3, n_dir=1, n_amb=1):
    lights = []
    for _ in range(n_point):
        lights.append(dict(type="point", position=tuple(rng.uniform(-4, 4, 3) + [0, 0, 3]),
                           color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(1, 20)),
                           attenuation=(1.0, float(rng.uniform(0, 0.3)), float(rng.uniform(0, 0.1)))))
    for _ in range(n_dir):
        lights.append(dict(type="directional", direction=tuple(rng.normal(size=3) - [0, 0, 1.5]),
                           color=tuple(rng.uniform(0.2, 1, 3)), intensity=float(rng.uniform(0.5, 3))))
    for _ in range(n_amb):
        lights.append(dict(type="ambient", color=tuple(rng.uniform(0.2, 1, 3)), intensity=1.0))
    return lights


def check_against_reference(scene, gbuffer, *, kernel="lanes", lanes=None, compensated=None,
                            fp64_directions=None, int_pow=True):
    """Render, compare with the float64 reference, assert |err| ≤ the error bound.

    Returns (rgb, ref, bound, band) for further checks.
    """
    from clphong.reference import shading as reference
    from clphong.device.renderer import Renderer, prepare_frame

    r = Renderer(scene, kernel=kernel, lanes=lanes, compensated=compensated,
                 fp64_directions=fp64_directions, int_pow=int_pow)
    frame = prepare_frame(gbuffer, lanes=r.lanes)
    result = r.shade(frame)
    rgb, plan = result.image, result.plan      # plan: the variant that ran
    ref = reference.shade(scene, gbuffer)
    bound, band = reference.error_bound(scene, gbuffer, origin=frame.origin, plan=plan)
    assert np.all(np.isfinite(rgb))
    err = np.abs(rgb.astype(np.float64) - ref)
    worst = np.unravel_index(np.argmax(err - bound), err.shape)
    assert np.all(err <= bound), (
        f"|kernel − reference| exceeds the error bound at pixel {worst[:2]} channel {worst[2]}: "
        f"err {err[worst]:.3g} > bound {bound[worst]:.3g} (kernel {rgb[worst]!r}, reference {ref[worst]!r})")
    return rgb, ref, bound, band


@pytest.fixture(scope="session")
def samples_dir():
    return GBUFFERS


def patch_everywhere(monkeypatch, module, name, replacement):
    """Replace ``module.name`` and every clphong module's own reference to the same object
    (modules import functions by name at the top, so patching one module is not enough)."""
    import sys

    original = getattr(module, name)
    for mod_name, mod in list(sys.modules.items()):
        if (mod_name == "clphong" or mod_name.startswith("clphong.")) and \
                getattr(mod, name, None) is original:
            monkeypatch.setattr(mod, name, replacement)

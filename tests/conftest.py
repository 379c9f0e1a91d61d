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
        from clphong.tools.report import markdown_table

        terminalreporter.write_line(f"\nbad-input catalogue ({len(CATALOGUE)} cases):")
        rows = [(case, f"`{msg}`".replace("|", "\\|"), code) for case, code, msg in CATALOGUE]
        terminalreporter.write_line(markdown_table(["case", "message", "exit code"], rows))


def read_rgb(path, *, spec=False):
    """An output file's R, G, B as float32 (an EXR's A, the coverage, is checked on its
    own); with ``spec``, (its ImageSpec, the pixels)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    assert inp, oiio.geterror()
    s = inp.spec()
    px = np.asarray(inp.read_image(0, 0, 0, 3, oiio.FLOAT))
    inp.close()
    return (s, px) if spec else px


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


def heightfield(rng, h=37, w=45, *, offset=(0.0, 0.0, 0.0), bumps=0.3, maps=()):
    """A wavy surface seen from above: spatially coherent P and N, so tiles are small."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) * 0.1
    z = bumps * np.sin(xs * 1.7) * np.cos(ys * 1.3)
    P = np.stack([xs, ys, z], -1) + np.asarray(offset)
    dzdx = bumps * 1.7 * np.cos(xs * 1.7) * np.cos(ys * 1.3)
    dzdy = -bumps * 1.3 * np.sin(xs * 1.7) * np.sin(ys * 1.3)
    N = np.stack([-dzdx, -dzdy, np.ones_like(z)], -1)
    C = rng.uniform(0.1, 1.0, (h, w, 3))
    cov = (rng.uniform(size=(h, w)) > 0.05).astype(np.float32)
    return make_gbuffer(P, N, C, cov, random_maps(rng, h, w, maps))


def point_lights(rng, n, *, extent=(4.5, 3.7), height=(0.05, 0.6), att=(1.0, 0.0, 300.0),
                 offset=(0.0, 0.0, 0.0), intensity=(0.5, 3.0)):
    out = []
    for _ in range(n):
        pos = np.array([rng.uniform(-0.3, extent[0]), rng.uniform(-0.3, extent[1]),
                        rng.uniform(*height)]) + offset
        out.append(dict(type="point", position=tuple(pos), color=tuple(rng.uniform(0.2, 1, 3)),
                        intensity=float(rng.uniform(*intensity)), attenuation=att))
    return out


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


def skip_unless_lanes(lanes, device=None):
    """Skip where the host rule does not give ``device`` (None: the default) ``lanes`` lanes:
    a GPU runs one pixel a work-item, and refuses other widths in one line (tested in
    tests/device/test_runtime.py); None, the device's own width, always runs."""
    from clphong.device.selection import get_runtime

    rt = get_runtime(device)
    widths = rt.decision.widths
    if lanes is not None and lanes not in widths:
        pytest.skip(f"{rt.name} takes {' or '.join(map(str, widths))} lane(s) only: "
                    f"{rt.decision.why()}")


def check_against_reference(scene, gbuffer, *, kernel="lanes", lanes=None, compensated=None,
                            fp64_directions=None, int_pow=None, device=None, path=None):
    """Render, compare with the float64 reference, assert |err| ≤ the error bound.

    ``device``: a device selector (the ``device`` fixture's "P:D"); None, the default device.
    ``path``: the Renderer's named path ("float", "fast"), instead of the number options.
    Returns (rgb, ref, bound, band) for further checks.
    """
    from clphong.device.renderer import Renderer, prepare_frame
    from clphong.reference import shading as reference

    skip_unless_lanes(lanes, device)
    r = Renderer(scene, kernel=kernel, lanes=lanes, compensated=compensated,
                 fp64_directions=fp64_directions, int_pow=int_pow, device=device, path=path)
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


def record_calls(monkeypatch, owner, name) -> list:
    """Wrap ``owner.name`` so that each call's result is appended to the list returned
    (and still returned to the caller): which passes ran, what they gave."""
    real, calls = getattr(owner, name), []

    def recorded(*args, **kw):
        calls.append(real(*args, **kw))
        return calls[-1]

    monkeypatch.setattr(owner, name, recorded)
    return calls


# ------------------------------------------------------------------------- OpenCL devices
#
# In the style of PyOpenCL's ``pytest_generate_tests_for_pyopencl``: a test that takes a
# ``device`` argument runs once per OpenCL device present, and gets a selector string
# ("P:D", platform and device index) that clphong.device.selection.get_runtime and
# Renderer(..., device=...) accept. Ids name the platform and device kind ("pocl-cpu").
# With no device at all it is parametrised with one skipped case.

def _device_ids(plat, dev):
    import pyopencl as cl

    from clphong.device.platforms import platform_kind

    pname = plat.name.lower()
    kind = platform_kind(plat.name)
    short = ({"intel-cpu": "intel"}.get(kind, kind) if kind != "other"
             else pname.split()[0] if pname.split() else "platform")
    kinds = [k for k, flag in (("cpu", cl.device_type.CPU), ("gpu", cl.device_type.GPU),
                               ("accelerator", cl.device_type.ACCELERATOR)) if dev.type & flag]
    return f"{short}-{kinds[0] if kinds else 'device'}"


def opencl_devices():
    """[(selector "P:D", id, why not)] of every OpenCL device present, ``why not`` the
    one-line reason the device cannot be used on this host (the host rule or its
    self-test: the test is skipped there), else None; [] when none (or no pyopencl)."""
    try:
        from clphong.device.platforms import register_pip_runtimes

        register_pip_runtimes()        # Intel's pip runtime is a platform, as for a user
        import pyopencl as cl

        platforms = cl.get_platforms()
    except Exception:                    # no pyopencl, no ICD loader, no platform
        return []
    out = []
    for pi, plat in enumerate(platforms):
        try:
            devs = plat.get_devices()
        except Exception:
            devs = []
        for di, dev in enumerate(devs):
            out.append((f"{pi}:{di}", _device_ids(plat, dev)))
    # ids unique: a second device of the same kind gets its index appended
    seen: dict[str, int] = {}
    for _, ident in out:
        seen[ident] = seen.get(ident, 0) + 1
    return [(sel, ident if seen[ident] == 1 else f"{ident}-{sel.replace(':', '.')}", _unusable(sel))
            for sel, ident in out]


def _unusable(selector):
    """Why clphong refuses this device here (one line), or None."""
    from clphong.core.errors import DeviceError
    from clphong.device.selection import get_runtime

    try:
        get_runtime(selector)
    except DeviceError as exc:
        return str(exc).split("; choose another device")[0]
    return None


_DEVICES = None


def pytest_generate_tests(metafunc):
    global _DEVICES
    if "device" not in metafunc.fixturenames:
        return
    if _DEVICES is None:
        _DEVICES = opencl_devices()
    if _DEVICES:
        metafunc.parametrize("device", [
            sel if why is None else pytest.param(sel, marks=pytest.mark.skip(
                reason=f"not usable on this host: {why}"))
            for sel, _, why in _DEVICES], ids=[ident for _, ident, _ in _DEVICES])
    else:
        metafunc.parametrize("device", [pytest.param(None, marks=pytest.mark.skip(
            reason="no OpenCL device found"))], ids=["no-device"])


#: A rig scene file for the batch tests: one point light at x = {x}, and ambient.
RIG_SCENE = """\
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
position = [{x}, 5.0, 4.0]
intensity = 20.0
[[light]]
type = "ambient"
"""


@pytest.fixture(autouse=True, scope="session")
def _environment_cache_of_the_session(tmp_path_factory):
    """Environment conversions made in the test process are kept in a folder of the session
    (clphong.io.envmap's disk cache), not in the user's cache folder."""
    from clphong.core.cache import Store
    from clphong.io import envmap

    saved = envmap._DISK, envmap._TABLE_DISK
    envmap._DISK = Store(str(tmp_path_factory.mktemp("environment-cache")), ".npz", envmap.DISK_KEEP)
    envmap._TABLE_DISK = Store(str(tmp_path_factory.mktemp("environment-tables")), ".npz",
                               envmap.DISK_KEEP)
    yield
    envmap._DISK, envmap._TABLE_DISK = saved


@pytest.fixture
def signals_not_ignored():
    """SIGINT and SIGQUIT as an interactive shell leaves them, for the tests that send them.

    A command run in the background by a shell without job control (``cmd &`` in a
    script) starts with both ignored (POSIX), and clphong keeps an ignored signal
    ignored (clphong.core.signals.terminating_signals), so a test that sends one would
    see nothing happen. Set to Python's defaults for the test, restored after it."""
    import signal

    defaults = {signal.SIGINT: signal.default_int_handler, signal.SIGQUIT: signal.SIG_DFL}
    saved = {sig: signal.getsignal(sig) for sig in defaults}
    for sig, handler in defaults.items():
        if saved[sig] is signal.SIG_IGN:
            signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)

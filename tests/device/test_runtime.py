"""clphong.device.runtime: the program cache and the choice of OpenCL device."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_scene, random_gbuffer, random_lights

from clphong.device import hostrule
from clphong.device.renderer import Renderer

ZEN3 = hostrule.Host("zen3", "AuthenticAMD", 25, 1, frozenset({"avx2", "fma"}))


def test_programs_are_built_once_per_variant(monkeypatch):
    from clphong.device.selection import get_runtime

    rt = get_runtime()
    monkeypatch.setattr(rt, "_programs", {})     # start from an empty cache; restored afterwards
    rng = np.random.default_rng(0)
    scene = make_scene(random_lights(rng, 2, 1), h=7.0, model="blinn-phong")
    before = rt.builds
    Renderer(scene)
    assert rt.builds == before + 1
    before = rt.builds
    Renderer(scene).render(random_gbuffer(rng, 4, 4)).image
    Renderer(make_scene(random_lights(rng, 3, 1), h=7.0, model="blinn-phong")).render(random_gbuffer(rng, 4, 4)).image
    assert rt.builds == before        # same variant: no rebuild, whatever the light values
    Renderer(make_scene(random_lights(rng, 2, 0), k_s=0.0))
    assert rt.builds == before + 1    # a new variant builds once
    # a whole exponent is compiled in (SPEC_K: the powering unrolls): another one is
    # another variant, built once
    before = rt.builds
    Renderer(make_scene(random_lights(rng, 2, 1), h=9.0, model="blinn-phong"))
    Renderer(make_scene(random_lights(rng, 4, 1), h=9.0, model="blinn-phong"))
    assert rt.builds == before + 1


class _FakePlatform:
    def __init__(self, name, devices):
        self.name = name
        self._devices = [_FakeDevice(dname, dtype, self) for dname, dtype in devices]

    def get_devices(self):
        return self._devices


class _FakeDevice:
    def __init__(self, name, dtype, platform):
        self.name, self.type, self.platform = name, dtype, platform
        pocl = platform.name == "Portable Computing Language"
        self.version = ("OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-znver3"
                        if pocl else "OpenCL 3.0")


class _FakeContext:
    def __init__(self, devices):
        self.devices = list(devices)


@pytest.fixture
def fake_platforms(monkeypatch):
    """Two OpenCL platforms, PoCL second with its CPU device second, as pyopencl lists
    them (get_platforms, also what pyopencl's PYOPENCL_CTX parsing reads); contexts and
    queues are stand-ins, and no runtime is cached."""
    import pyopencl as cl

    from clphong.device import selection

    cpu, gpu = cl.device_type.CPU, cl.device_type.GPU
    platforms = [_FakePlatform("NVIDIA CUDA", [("NVIDIA H100 80GB HBM3", gpu)]),
                 _FakePlatform("Portable Computing Language",
                               [("cuda-NVIDIA H100 80GB HBM3", gpu), ("pthread-AMD EPYC 9654", cpu)])]
    monkeypatch.setattr(cl, "get_platforms", lambda: platforms)
    monkeypatch.setattr(cl, "Context", _FakeContext)
    monkeypatch.setattr(cl, "CommandQueue", lambda ctx, properties=None: ("queue", ctx))
    monkeypatch.setattr(selection, "_RUNTIMES", {})
    # every width passes its self-test on a Zen 3 host (the rule's own table is
    # tested in test_hostrule.py, the self-test in test_selftest.py)
    monkeypatch.setattr(selection, "verify", lambda rt, width: {"ok": True, "worst": 0.0, "detail": ""})
    monkeypatch.setattr(hostrule, "host", lambda: ZEN3)
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    monkeypatch.delenv("PYOPENCL_TEST", raising=False)
    return platforms


def test_default_device_is_pocl_cpu_even_when_listed_last(fake_platforms, monkeypatch):
    """The module docstring's order: --device, then PYOPENCL_CTX, then the preferred CPU
    device, here PoCL's (not the first platform's first device, nor PoCL's first device)."""
    from clphong.device import selection

    nvidia, = fake_platforms[0].get_devices()
    pocl_gpu, pocl_cpu = fake_platforms[1].get_devices()

    def chosen(device=None):
        rt = selection.get_runtime(device)
        assert rt.context.devices == [rt.device]
        return rt.device

    assert chosen() is pocl_cpu
    assert selection.get_runtime().name == "Portable Computing Language / pthread-AMD EPYC 9654"
    assert chosen("0:0") is nvidia and chosen("1") is pocl_gpu and chosen("1:1") is pocl_cpu
    assert chosen("nvidia") is nvidia and chosen("pthread") is pocl_cpu
    monkeypatch.setenv("PYOPENCL_CTX", "0")
    assert chosen() is nvidia
    monkeypatch.setenv("PYOPENCL_CTX", "1:0")
    assert chosen() is pocl_gpu
    assert chosen("1:1") is pocl_cpu                      # --device overrides PYOPENCL_CTX
    monkeypatch.delenv("PYOPENCL_CTX")
    assert chosen() is pocl_cpu                           # cached, still the default


@pytest.mark.parametrize("gpu_rate, winner", [(9e10, "gpu"), (4e8, "cpu"),
                                               (1.2e9 * 1.2, "cpu"), (1.2e9 * 1.3, "gpu")])
def test_default_device_is_the_fastest_that_passes(gpu_rate, winner, fake_platforms, monkeypatch):
    """Issue 29: with a GPU and a CPU platform both present, the default is the device
    whose self-test passes and whose calibration frame ran faster (the verdict's
    pair_rate); the choice says so, with each rate. --device still wins. A later
    candidate (the GPU after the CPU) must be RATE_MARGIN (1.25) times faster: 1.2x
    keeps the CPU, 1.3x takes the GPU."""
    from clphong.device import selection

    nvidia, = fake_platforms[0].get_devices()
    pocl_gpu, pocl_cpu = fake_platforms[1].get_devices()
    rates = {nvidia.name: gpu_rate, pocl_gpu.name: gpu_rate / 3, pocl_cpu.name: 1.2e9}
    monkeypatch.setattr(selection, "verify", lambda rt, width: {
        "ok": True, "worst": 0.0, "detail": "", "pair_rate": rates[rt.device.name]})
    rt = selection.get_runtime()
    assert rt.device is (nvidia if winner == "gpu" else pocl_cpu)
    assert rt.pair_rate == rates[rt.device.name]
    assert rt.choice.startswith("the fastest of 3 devices that passed their self-tests")
    assert "1.2 GPLE/s" in rt.choice and f"{gpu_rate / 1e9:.3g} GPLE/s" in rt.choice
    assert selection.get_runtime("pthread").device is pocl_cpu
    # a device that fails its self-test is not chosen, however fast
    monkeypatch.setattr(selection, "_RUNTIMES", {})
    monkeypatch.setattr(selection, "verify", lambda rt, width: {
        "ok": rt.device is not nvidia, "worst": 0.0, "detail": "x",
        "pair_rate": rates[rt.device.name]})
    second = rates[pocl_gpu.name] > selection.RATE_MARGIN * rates[pocl_cpu.name]
    assert selection.get_runtime().device is (pocl_gpu if second else pocl_cpu)


def test_default_device_without_a_cpu_is_the_first(fake_platforms, monkeypatch):
    import pyopencl as cl

    from clphong.device import selection

    monkeypatch.setattr(cl, "get_platforms", lambda: fake_platforms[:1])
    assert selection.get_runtime().device is fake_platforms[0].get_devices()[0]


def test_default_prefers_intels_cpu_runtime_and_pocl_matches_its_alias(fake_platforms, monkeypatch):
    """Intel's CPU runtime comes first among CPU devices (platforms.PREFERENCE); "pocl"
    and "intel" name their platforms though neither name holds the word."""
    import pyopencl as cl

    from clphong.device import selection

    intel = _FakePlatform("Intel(R) OpenCL", [("AMD EPYC 9654", cl.device_type.CPU)])
    monkeypatch.setattr(cl, "get_platforms", lambda: fake_platforms + [intel])
    rt = selection.get_runtime()
    assert rt.device is intel.get_devices()[0] and rt.lanes == 16
    assert selection.get_runtime("pocl").device is fake_platforms[1].get_devices()[0]
    assert selection.get_runtime("intel").device is intel.get_devices()[0]


def test_a_width_that_fails_its_self_test_falls_back_with_a_warning(fake_platforms, monkeypatch):
    from clphong.core.errors import DeviceError, DeviceWarning
    from clphong.device import selection

    monkeypatch.setattr(selection, "verify", lambda rt, width: {
        "ok": width == 4, "worst": 0.5 if width == 4 else 7.0, "detail": "blinn-many: pixel (3, 1)"})
    with pytest.warns(DeviceWarning, match=r"at 16 lane\(s\) failed its self-test .*trying 8"):
        rt = selection.get_runtime("1:1")
    assert rt.lanes == 4
    monkeypatch.setattr(selection, "_RUNTIMES", {})
    monkeypatch.setattr(selection, "verify", lambda rt, width: {"ok": False, "worst": 9.0, "detail": "x"})
    with pytest.warns(DeviceWarning), pytest.raises(DeviceError, match="passed its self-test at no lane width"):
        selection.get_runtime("1:1")


def test_no_usable_cpu_device_is_one_line_naming_the_rule(fake_platforms, monkeypatch):
    """Zen 5 with pip's PoCL alone: LLVM 14 says 'generic', the rule refuses PoCL, and the
    default falls to the GPUs; without them the error names the reason and the cure."""
    import pyopencl as cl

    from clphong.core.errors import DeviceError
    from clphong.device import selection

    zen5 = hostrule.Host("x86_64_v4", "AuthenticAMD", 26, 2, frozenset({"avx2", "avx512f"}))
    monkeypatch.setattr(hostrule, "host", lambda: zen5)
    pocl = fake_platforms[1]
    for dev in pocl.get_devices():
        dev.version = "OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-generic"
    cpu_only = _FakePlatform("Portable Computing Language", [("pthread-AMD EPYC", cl.device_type.CPU)])
    cpu_only.get_devices()[0].version = pocl.get_devices()[0].version
    monkeypatch.setattr(cl, "get_platforms", lambda: [cpu_only])
    with pytest.raises(DeviceError) as err:
        selection.get_runtime()
    msg = str(err.value)
    assert "\n" not in msg and "generic" in msg and 'pip install "clphong[intel]"' in msg
    with pytest.raises(DeviceError, match="cannot be used on this CPU"):
        selection.get_runtime("pocl")


def test_an_unsafe_lanes_value_is_refused_in_one_line(fake_platforms, monkeypatch):
    """Zen 4 with PoCL 3.0 (target znver3, AVX-512 host): 16 and 8 lanes are refused."""
    from clphong.core.errors import DeviceError
    from clphong.device import selection

    zen4 = hostrule.Host("zen4", "AuthenticAMD", 25, 17, frozenset({"avx2", "avx512f"}))
    monkeypatch.setattr(hostrule, "host", lambda: zen4)
    rt = selection.get_runtime("1:1")
    assert rt.lanes == 4
    for lanes in (16, 8):
        with pytest.raises(DeviceError, match=rf"--lanes {lanes} is not safe on .*use --lanes 4 or 1"):
            selection.check_width(rt, lanes)
    selection.check_width(rt, 1)


def test_a_default_whose_compiler_dies_gives_way_to_the_next(fake_platforms, monkeypatch):
    """next_default: the default device passed over (its compiler died at every width)
    for the next candidate; a device the user chose is not the default to replace."""
    import pyopencl as cl

    from clphong.device import selection

    intel = _FakePlatform("Intel(R) OpenCL", [("AMD EPYC 9654", cl.device_type.CPU)])
    monkeypatch.setattr(cl, "get_platforms", lambda: fake_platforms + [intel])
    monkeypatch.setattr(selection, "_CRASHED", [])
    first = selection.get_runtime()
    assert first.device is intel.get_devices()[0]
    second = selection.next_default(first)
    assert second.device is fake_platforms[1].get_devices()[1]          # PoCL's CPU device
    assert selection.get_runtime() is second
    assert selection.next_default(selection.get_runtime("nvidia")) is None


def test_children_are_told_the_device_by_its_full_name(fake_platforms, monkeypatch):
    """A child process is given PLATFORM / DEVICE (with #N for a second device of the same
    name), not "P:D": the indices differ in the child when this process listed the
    platforms before Intel's pip runtime was registered."""
    import pyopencl as cl

    from clphong.device import runtime, selection

    twin = _FakePlatform("Portable Computing Language",
                         [("pthread-AMD EPYC 9654", cl.device_type.CPU),
                          ("pthread-AMD EPYC 9654", cl.device_type.CPU)])
    monkeypatch.setattr(cl, "get_platforms", lambda: [twin])
    first, second = twin.get_devices()
    assert runtime._selector(first) == "Portable Computing Language / pthread-AMD EPYC 9654"
    assert runtime._selector(second) == "Portable Computing Language / pthread-AMD EPYC 9654 #2"
    assert selection._choose(runtime._selector(second)) is second
    assert selection._choose(runtime._selector(first)) is first

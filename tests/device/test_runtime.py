"""clphong.device.runtime: the program cache and the choice of OpenCL device."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import make_scene, random_gbuffer, random_lights

from clphong.device.renderer import Renderer


def test_programs_are_built_once_per_variant(monkeypatch):
    from clphong.device.runtime import get_runtime

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


class _FakeContext:
    def __init__(self, devices):
        self.devices = list(devices)


@pytest.fixture
def fake_platforms(monkeypatch):
    """Two OpenCL platforms, PoCL second with its CPU device second, as pyopencl lists
    them (get_platforms, also what pyopencl's PYOPENCL_CTX parsing reads); contexts and
    queues are stand-ins, and no runtime is cached."""
    import pyopencl as cl

    from clphong.device import runtime

    cpu, gpu = cl.device_type.CPU, cl.device_type.GPU
    platforms = [_FakePlatform("NVIDIA CUDA", [("NVIDIA H100 80GB HBM3", gpu)]),
                 _FakePlatform("Portable Computing Language",
                               [("cuda-NVIDIA H100 80GB HBM3", gpu), ("pthread-AMD EPYC 9654", cpu)])]
    monkeypatch.setattr(cl, "get_platforms", lambda: platforms)
    monkeypatch.setattr(cl, "Context", _FakeContext)
    monkeypatch.setattr(cl, "CommandQueue", lambda ctx, properties=None: ("queue", ctx))
    monkeypatch.setattr(runtime, "_RUNTIMES", {})
    monkeypatch.delenv("PYOPENCL_CTX", raising=False)
    monkeypatch.delenv("PYOPENCL_TEST", raising=False)
    return platforms


def test_default_device_is_pocl_cpu_even_when_listed_last(fake_platforms, monkeypatch):
    """The module docstring's order: --device, then PYOPENCL_CTX, then PoCL's CPU device
    (not the first platform's first device, nor PoCL's first device)."""
    from clphong.device import runtime

    nvidia, = fake_platforms[0].get_devices()
    pocl_gpu, pocl_cpu = fake_platforms[1].get_devices()

    def chosen(device=None):
        rt = runtime.get_runtime(device)
        assert rt.context.devices == [rt.device]
        return rt.device

    assert chosen() is pocl_cpu
    assert runtime.get_runtime().name == "Portable Computing Language / pthread-AMD EPYC 9654"
    assert chosen("0:0") is nvidia and chosen("1") is pocl_gpu and chosen("1:1") is pocl_cpu
    assert chosen("nvidia") is nvidia and chosen("pthread") is pocl_cpu
    monkeypatch.setenv("PYOPENCL_CTX", "0")
    assert chosen() is nvidia
    monkeypatch.setenv("PYOPENCL_CTX", "1:0")
    assert chosen() is pocl_gpu
    assert chosen("1:1") is pocl_cpu                      # --device overrides PYOPENCL_CTX
    monkeypatch.delenv("PYOPENCL_CTX")
    assert chosen() is pocl_cpu                           # cached, still the default


def test_default_device_without_pocl_is_the_first(fake_platforms, monkeypatch):
    import pyopencl as cl

    from clphong.device import runtime

    monkeypatch.setattr(cl, "get_platforms", lambda: fake_platforms[:1])
    assert runtime.get_runtime().device is fake_platforms[0].get_devices()[0]

"""clphong.device.platforms: platform kinds, --device aliases, and registering Intel's
pip-installed CPU runtime with the ICD loader."""

from __future__ import annotations

import pytest

from clphong.device import platforms


def test_kinds_and_aliases():
    assert platforms.platform_kind("Portable Computing Language") == "pocl"
    assert platforms.platform_kind("Intel(R) OpenCL") == "intel-cpu"
    assert platforms.platform_kind("NVIDIA CUDA") == "nvidia"
    assert platforms.platform_kind("Clover") == "other"
    assert platforms.matches("pocl", "Portable Computing Language", "pthread-AMD EPYC")
    assert platforms.matches("POCL", "Portable Computing Language", "cpu")
    assert platforms.matches("intel", "Intel(R) OpenCL", "AMD EPYC")
    assert platforms.matches("epyc", "Intel(R) OpenCL", "AMD EPYC")
    assert not platforms.matches("intel", "Portable Computing Language", "pthread-AMD EPYC")


@pytest.fixture
def fresh(monkeypatch, tmp_path):
    monkeypatch.setattr(platforms, "registered", None)
    monkeypatch.setenv("CLPHONG_CACHE_DIR", str(tmp_path / "cache"))
    # set first, so that monkeypatch restores its absence after a test registered one
    monkeypatch.setenv("OCL_ICD_VENDORS", "")
    monkeypatch.delenv("OCL_ICD_VENDORS")
    return tmp_path


def test_intel_runtime_is_registered_beside_the_system_drivers(fresh, monkeypatch):
    lib = fresh / "lib" / "libintelocl.so"
    lib.parent.mkdir()
    lib.write_bytes(b"")
    vendors = fresh / "vendors"
    vendors.mkdir()
    (vendors / "nvidia.icd").write_text("libnvidia-opencl.so.1\n")
    monkeypatch.setattr(platforms, "intel_cpu_runtime", lambda: lib)
    monkeypatch.setattr(platforms, "_SYSTEM_VENDORS", vendors)
    import os

    folder = platforms.register_pip_runtimes()
    assert os.environ["OCL_ICD_VENDORS"] == folder
    icds = {p.name: p.read_text().strip() for p in (fresh / "cache").glob("icd-*/*.icd")}
    assert icds == {"clphong-intel-cpu.icd": str(lib), "system-nvidia.icd": "libnvidia-opencl.so.1"}
    # once per process
    assert platforms.register_pip_runtimes() == folder


def test_a_users_icd_vendors_is_left_alone(fresh, monkeypatch):
    import os

    monkeypatch.setenv("OCL_ICD_VENDORS", "/opt/my-icds")
    monkeypatch.setattr(platforms, "intel_cpu_runtime", lambda: fresh / "libintelocl.so")
    assert platforms.register_pip_runtimes() == "user"
    assert os.environ["OCL_ICD_VENDORS"] == "/opt/my-icds"
    assert not (fresh / "cache").exists()


def test_nothing_to_register_without_intels_runtime(fresh, monkeypatch):
    import os

    monkeypatch.setattr(platforms, "intel_cpu_runtime", lambda: None)
    assert platforms.register_pip_runtimes() == ""
    assert "OCL_ICD_VENDORS" not in os.environ


def test_intels_runtime_is_a_platform_when_installed():
    """With the test extras (clphong[intel]) on Linux x86-64, Intel's CPU runtime is listed
    beside pip's PoCL, as for a user."""
    import platform
    import sys

    if not (sys.platform == "linux" and platform.machine() == "x86_64"):
        pytest.skip("Intel's CPU runtime is installed on Linux x86-64 only")
    if platforms.intel_cpu_runtime() is None:
        pytest.skip("Intel's CPU runtime is not installed (pip install \"clphong[intel]\")")
    from clphong.device.runtime import _all_devices

    kinds = {platforms.platform_kind(plat.name) for _, _, plat, _ in _all_devices()}
    assert "intel-cpu" in kinds

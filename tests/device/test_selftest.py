"""The self-test and the compiling child: a wrong lane is caught, an aborting compiler
costs one line and a narrower width, never the process.

Each fault is simulated: a lane made wrong in the kernel (SELFTEST_FAULT, test-only),
a child that aborts as LLVM does, and fake host/target pairs (test_hostrule.py)."""

from __future__ import annotations

import os
import sys
import textwrap

import numpy as np
import pytest
from conftest import make_scene, random_gbuffer, random_lights

from clphong.core.errors import DeviceError, DeviceWarning
from clphong.device import isolate, selection, selftest
from clphong.device.renderer import Renderer
from clphong.model.taylor import THETA_POINTS


def test_the_self_test_passes_at_the_chosen_width(device):
    rt = selection.get_runtime(device)
    verdict = selftest.check(device, rt.lanes)
    assert verdict["ok"], verdict["detail"]
    assert 0.0 <= verdict["worst"] <= 1.0


@pytest.mark.parametrize("fault", [1e-4, -3e-5])
def test_one_wrong_lane_is_caught(device, fault, monkeypatch):
    """The last lane of each work-item scaled by 1 + fault (kernels/shade.cl SELFTEST_FAULT):
    a relative error of 3e-5 is several times the accurate path's bound, and caught."""
    rt = selection.get_runtime(device)
    monkeypatch.setattr(rt, "extra_defines", {})      # check() sets it; restored afterwards
    verdict = selftest.check(device, rt.lanes, fault=fault)
    assert not verdict["ok"]
    assert verdict["worst"] > 1.0 and "pixel" in verdict["detail"]


def test_a_wrong_variant_is_never_used(device, tmp_path, monkeypatch):
    """Through the child processes, as at first use: with every width wrong, the device
    is refused in one line after a warning per width, and nothing renders."""
    monkeypatch.setenv("CLPHONG_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv(selftest.FAULT_ENV, "1e-3")
    monkeypatch.setattr(selection, "_RUNTIMES", {})
    monkeypatch.setattr(selection, "_VERDICTS", {})
    with pytest.warns(DeviceWarning, match="failed its self-test"):
        with pytest.raises(DeviceError, match="passed its self-test at no lane width") as err:
            selection.get_runtime(device)
    assert "\n" not in str(err.value)
    # the verdicts were kept: a second process would not run the child again
    assert list(tmp_path.glob("selftest/*.json"))


@pytest.fixture
def aborting_compiler(tmp_path, monkeypatch):
    """A compiling child that reads a request, says what LLVM says, and aborts."""
    (tmp_path / "abort_like_llvm.py").write_text(textwrap.dedent("""\
        import os, sys
        sys.stdin.readline()
        sys.stderr.write("LLVM ERROR: Cannot select: 0x5581 v16f32 = fsqrt\\n")
        sys.stderr.flush()
        os.abort()
    """))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), *sys.path]))
    monkeypatch.setattr(isolate.BuildChild, "module", "abort_like_llvm")
    children = {}
    monkeypatch.setattr(isolate, "_CHILDREN", children)
    yield tmp_path
    for child in children.values():
        child.close()


def test_an_aborting_compiler_is_one_line_naming_the_variant(aborting_compiler):
    child = isolate.build_child("0:0")
    with pytest.raises(isolate.VariantCrash) as err:
        child.build("shade.cl", ["-DLANES=16"], str(aborting_compiler / "out.bin"),
                    "kernels/shade.cl at 16 lane(s) on a device")
    msg = str(err.value)
    assert "\n" not in msg
    assert "kernels/shade.cl at 16 lane(s)" in msg and "SIGABRT" in msg and "Cannot select" in msg
    assert not err.value.transient


def test_an_aborting_compiler_moves_the_renderer_to_a_narrower_width(device, aborting_compiler,
                                                                      monkeypatch):
    """At construction a crash at the chosen width warns and retries one width down (the
    fake child aborts once; the narrower variant compiles in a real child)."""
    rt = selection.get_runtime(device)
    if len(rt.decision.widths) < 2:
        pytest.skip(f"{rt.name} has one width only")
    monkeypatch.setattr(rt, "_programs", {})
    monkeypatch.setattr(rt, "_binary_path", lambda *a: None)     # nothing cached: compile
    real_build = isolate.BuildChild.build
    calls = []

    def build_once_aborting(self, entry, opts, out, what):
        calls.append(what)
        if len(calls) == 1:
            return real_build(self, entry, opts, out, what)      # the fake child: aborts
        monkeypatch.setattr(self, "module", "clphong.device.buildchild")
        return real_build(self, entry, opts, out, what)

    monkeypatch.setattr(isolate.BuildChild, "build", build_once_aborting)
    rng = np.random.default_rng(3)
    scene = make_scene(random_lights(rng, 3, 1), h=11.0)
    with pytest.warns(DeviceWarning, match=rf"at {rt.lanes} lane\(s\).*SIGABRT.*; using \d+ lane"):
        r = Renderer(scene, device=device)
    assert r.lanes < rt.lanes and r.lanes in rt.decision.widths
    img = r.render(random_gbuffer(rng, 5, 7)).image
    assert np.isfinite(img).all()


def test_a_pinned_width_is_not_changed_behind_the_users_back(device, aborting_compiler, monkeypatch):
    rt = selection.get_runtime(device)
    monkeypatch.setattr(rt, "_programs", {})
    monkeypatch.setattr(rt, "_binary_path", lambda *a: None)
    rng = np.random.default_rng(4)
    with pytest.raises(isolate.VariantCrash, match="SIGABRT"):
        Renderer(make_scene(random_lights(rng, 2, 1), h=13.0), device=device, lanes=rt.lanes)


def test_run_child_reports_a_signal_and_a_timeout(aborting_compiler):
    with pytest.raises(isolate.VariantCrash, match=r"the self-test: the child process ended by SIGABRT"):
        isolate.run_child("abort_like_llvm", [], timeout=60, what="the self-test")
    (aborting_compiler / "sleepy.py").write_text("import time; time.sleep(30)\n")
    with pytest.raises(isolate.VariantCrash, match="no answer in 1 s") as err:
        isolate.run_child("sleepy", [], timeout=1, what="x")
    assert err.value.transient


def test_the_double_rate_is_timed_at_widths_the_kernels_take():
    """measure_fp64_ratio's shapes are widths lanes.h builds (1, 4, 8, 16): halving 4
    gave LANES=2, and the self-test of every 4-lane device failed (PoCL on Zen 3, with
    its --lanes 4). Double is also timed at half the lanes (the same register bytes), and
    at the float widths."""
    from clphong.device.peak import ratio_shapes

    for lanes in (1, 4, 8, 16):
        single, double = ratio_shapes(lanes)
        assert {n for n, _ in single + double} <= {1, 4, 8, 16}, (lanes, single, double)
        assert set(single) <= set(double) and (lanes, 12) in single
    assert (8, 12) in ratio_shapes(16)[1] and (4, 12) in ratio_shapes(8)[1]


def test_the_double_rate_is_measured_and_chooses_the_plan(device, monkeypatch):
    """Issue 29: the plan's double forms follow the device's measured double-to-float
    rate, not its type. A CPU measures about 1/2; the same device made to look like a
    consumer GPU (1/32) gets float sums, weights and the exp form, still within the error
    model's bound, and 'plan' says what that costs."""
    from conftest import check_against_reference

    from clphong.device.peak import FAST_FP64_RATIO, measure_fp64_ratio

    import pyopencl as cl

    rt = selection.get_runtime(device)
    ratio = measure_fp64_ratio(rt)
    if rt.has_fp64:
        assert 0.0 < ratio < 1.5
        if rt.device.type & cl.device_type.CPU:
            # every x86-64 vector unit runs double at half the float rate, so a CPU that
            # reads under 1/4 was timed through spills (Intel's runtime at 16 lanes on
            # Zen 3's AVX2 read 0.2 before ratio_shapes)
            assert ratio >= FAST_FP64_RATIO, ratio
        assert rt.fp64_ratio is not None and rt.fast_fp64 == (rt.fp64_ratio >= FAST_FP64_RATIO)
    else:
        assert ratio == 0.0 and not rt.fast_fp64
    rng = np.random.default_rng(9)
    scene = make_scene(random_lights(rng, 5, 2), h=32.0, model="blinn-phong")
    gb = random_gbuffer(rng, 9, 11)
    for slow, want in ((1 / 32, 0), (0.5, int(rt.has_fp64))):
        monkeypatch.setattr(rt, "fp64_ratio", slow)
        d = Renderer(scene, device=device).plan_for(()).defines
        assert (d["SUM_FP64"], d["SPEC_INT_POW"], d["WEIGHTS_FP64"]) == (want, want, want), slow
        check_against_reference(scene, gb, device=device)     # the bound holds either way
        line = rt.double_line()
        assert ("under 0.25" in line) == (slow < FAST_FP64_RATIO and rt.has_fp64), line


def test_the_tree_kernels_compile_with_intels_own_vectoriser(device, monkeypatch):
    """kernels/node_bound.cl (one scalar work-item at a time) compiles in a child of
    Intel's vectoriser mode 0, the hand-vectorised kernels in one of mode 1; the mode is
    in the program's options (PyOpenCL's cache keys on them) and a user's setting holds."""
    monkeypatch.delenv(isolate.INTEL_VECTORIZER_ENV, raising=False)
    assert isolate.intel_vectorizer_mode() == "1"
    assert isolate.intel_vectorizer_mode(implicit=True) == "0"
    assert isolate._child_env("0")[isolate.INTEL_VECTORIZER_ENV] == "0"
    assert isolate._child_env()[isolate.INTEL_VECTORIZER_ENV] == "1"
    monkeypatch.setenv(isolate.INTEL_VECTORIZER_ENV, "16")
    assert isolate.intel_vectorizer_mode(implicit=True) == "16"
    monkeypatch.delenv(isolate.INTEL_VECTORIZER_ENV)
    rt = selection.get_runtime(device)
    modes = []
    real = isolate.build_child
    monkeypatch.setattr(rt, "_programs", {})
    monkeypatch.setattr(rt, "_binary_path", lambda *a, **k: None)       # compile, not load
    monkeypatch.setattr("clphong.device.runtime.build_child",
                        lambda sel, mode=None: modes.append(mode) or real(sel, mode))
    defines = dict(N_ONE=2, N_TWO=3, LOBE=1, BLINN=1, FRESNEL=0, PERSPECTIVE=1,
                   THETA_POINTS=THETA_POINTS)
    prog = rt.program("node_bound.cl", defines)
    intel = rt.kind == "intel-cpu"                   # elsewhere the mode means nothing
    assert prog is not None and modes == ["0" if intel else None], modes
    assert ("node_bound.cl",) == tuple(k[0] for k in rt._programs)
    assert ("-DCLPHONG_VECTORIZER=0" in next(iter(rt._programs))[1]) == intel
    rt.program("peak.cl", {"LANES": 1, "CHAINS": 8, "PEAK_DOUBLE": 0})
    assert modes[1:] == [None], "the hand-vectorised kernels keep the default child"

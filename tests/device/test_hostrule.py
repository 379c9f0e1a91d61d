"""clphong.device.hostrule: the table that turns (platform, compiler target, host) into widths.

Fed fake host/target pairs: each measured class gets the widths its entry states, and
the table's reasons name their measurement."""

from __future__ import annotations

import pytest

from clphong.device import hostrule
from clphong.device.hostrule import Host, decide

ZEN3 = Host("zen3", "AuthenticAMD", 25, 1, frozenset({"avx2", "fma"}))
ZEN4 = Host("zen4", "AuthenticAMD", 25, 17, frozenset({"avx2", "fma", "avx512f"}))
ZEN5 = Host("x86_64_v4", "AuthenticAMD", 26, 2, frozenset({"avx2", "fma", "avx512f"}))
ICELAKE = Host("icelake", "GenuineIntel", 6, 106, frozenset({"avx2", "fma", "avx512f"}))


@pytest.mark.parametrize("kind, target, h, widths", [
    # Zen 4 under PoCL 3.0: LLVM 14 says znver3 and uses AVX-512: 16 wrong, 8 aborts
    ("pocl", "znver3", ZEN4, (4, 1)),
    # Zen 5 under PoCL 3.0: LLVM 14 says generic, which its clang refuses
    ("pocl", "generic", ZEN5, ()),
    ("pocl", "", ZEN5, ()),
    # the classes where 16 lanes were measured right and fastest
    ("pocl", "icelake-server", ICELAKE, (16, 8, 4, 1)),
    ("pocl", "znver3", ZEN3, (16, 8, 4, 1)),
    ("pocl", "skylake-avx512", ZEN4, (16, 8, 4, 1)),      # Debian's PoCL 3.1 on Zen 4
    # an AVX2 target the rule has no measurement for keeps 8
    ("pocl", "haswell", ZEN3, (8, 4, 1)),
    # a target name the rule does not know, on an AVX-512 host: not trusted with AVX-512
    ("pocl", "znver9", ZEN5, (4, 1)),
    ("intel-cpu", "host", ZEN4, (16, 8, 4, 1)),
    ("intel-cpu", "host", ZEN5, (16, 8, 4, 1)),
    ("gpu", "NVIDIA H200", ZEN4, (1,)),
    ("other", "x", ZEN3, (8, 4, 1)),
    ("no-such-kind", "x", ZEN3, (8, 4, 1)),
])
def test_each_class_gets_the_widths_measured_for_it(kind, target, h, widths):
    d = decide(kind, target, h)
    assert d.widths == widths
    assert d.refused == (widths == ())
    assert d.rule.reason and d.why().startswith(d.rule.when)


def test_every_rule_names_its_measurement_and_widths_are_lane_counts():
    from clphong.model.options import LANES

    for platform, when, widths, reason in hostrule.table():
        assert platform and when and len(reason) > 20
    for rule in hostrule.RULES:
        assert set(rule.widths) <= set(LANES)
        assert list(rule.widths) == sorted(rule.widths, reverse=True)   # best (widest) first


def test_target_features():
    assert hostrule.target_has_avx512("icelake-client") is True
    assert hostrule.target_has_avx512("znver4") is True
    assert hostrule.target_has_avx512("znver3") is False
    assert hostrule.target_has_avx512("generic") is None


def test_the_host_is_read_once_and_cached_on_disk(tmp_path, monkeypatch):
    """archspec names the CPU (0.3 s); the answer is kept keyed by /proc/cpuinfo."""
    import archspec.cpu

    monkeypatch.setenv("CLPHONG_CACHE_DIR", str(tmp_path))
    hostrule.host.cache_clear()
    try:
        first = hostrule.host()
        if not list(tmp_path.glob("host/*.json")):
            pytest.skip("no /proc/cpuinfo here: nothing to key the cache by")
        hostrule.host.cache_clear()
        monkeypatch.setattr(archspec.cpu, "host", lambda: pytest.fail("archspec asked again"))
        assert hostrule.host() == first
        assert first.features and first.name
    finally:
        hostrule.host.cache_clear()

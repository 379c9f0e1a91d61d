"""clphong.tools.device_probe: the whole-frame rows by light loop, and the culling rows."""

import json

from clphong.tools import device_probe


def test_probe_rows_on_a_small_frame(tmp_path):
    out = tmp_path / "p.json"
    assert device_probe.main(["--size", "96x54", "--lights", "70", "--tiles", "0,64",
                              "--repeats", "1", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    loops = report["loops"]
    assert [(r["path"], r["tile"]) for r in loops] == [("accurate", 0), ("accurate", 64),
                                                        ("fast", 0), ("fast", 64)]
    assert all(r["lights"] == 70 and r["gple_per_s"] > 0 for r in loops)
    assert [r["scene"] for r in report["culling"]] == ["wide", "small", "clusters"]
    small = report["culling"][1]
    assert small["kept_fraction"] < 0.5 and small["lists_s"] > 0 and not small["brute"]

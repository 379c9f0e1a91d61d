"""``clphong bench --commands`` (clphong.tools.commands' whole-command timings): the
report is well formed on a tiny frame. Correctness only: no figure is checked."""

from __future__ import annotations

import json

import pytest

from clphong.core.errors import ClphongError
from clphong.tools import commands


def test_parse_stats_reads_every_stage_and_output_kind():
    err = ("plan ...\ndevice: PoCL\n"
           "1920x1080: read 0.254 s, setup 0.061 s, shade 0.178 s (kernel 0.0200 s), "
           "write 0.389 s (exr 0.300 s, sdr 0.089 s), total 0.882 s\n")
    assert commands.parse_stats(err) == {"read": 0.254, "setup": 0.061, "shade": 0.178,
                                         "kernel": 0.02, "write": 0.389, "exr": 0.3,
                                         "sdr": 0.089, "total": 0.882}
    with pytest.raises(ClphongError, match="no timing line"):
        commands.parse_stats("device: PoCL\n")


def test_bench_commands_on_a_tiny_frame_writes_a_well_formed_report(tmp_path, capsys):
    """Every case runs (clphong render, oiiotool, each display output and OpenImageIO's
    own); the tables have their rows and the JSON every figure, finite."""
    from clphong.console.cli import main
    from clphong.deliver.writers import jpegxl_available

    report = tmp_path / "c.json"
    assert main(["bench", "--commands", "--sizes", "32x16", "--repeats", "1",
                 "--json", str(report)]) == 0
    out = capsys.readouterr().out
    data = json.loads(report.read_text())
    assert data["size"] == [32, 16] and data["runs"] == 1
    c = data["command"]
    for key in ("clphong_wall_s", "clphong_cpu_s", "oiiotool_wall_s", "oiiotool_cpu_s",
                "oiiotool_rewrite_wall_s", "read_s", "setup_s", "shade_s", "kernel_s", "write_s",
                "total_s", "ratio", "cpu_ratio"):
        assert c[key] >= 0, key
    assert c["ratio"] == pytest.approx(c["clphong_wall_s"] / (c["oiiotool_wall_s"] + c["kernel_s"]))
    assert c["target"] == commands.COMMAND_TARGET
    assert "--ch R=albedo.R,G=albedo.G,B=albedo.B,A=A" in c["oiiotool_command"]
    assert "--compression zip" in c["oiiotool_command"] and "--exr-compression zip" in c["clphong_command"]
    assert all(len(t["wall"]) == len(t["cpu"]) == 1 for t in c["times"].values())
    kinds = ["sdr.png", "pq.png"] + (["pq.jxl"] if jpegxl_available() else [])
    assert [r["file"] for r in data["displays"]] == kinds
    for r in data["displays"]:
        assert r["oiio_s"] > 0 and r["write_s"] >= 0 and r["target"] == commands.DISPLAY_TARGET
        assert r["ratio"] == pytest.approx(r["added_s"] / r["oiio_s"])
    rows = [line for line in out.splitlines() if line.startswith("| ") and "---" not in line]
    # two headers; clphong and two oiiotool rows; one row per display output
    assert len(rows) == 2 + 3 + len(kinds), out
    assert rows[1].startswith("| clphong render --stats |") and rows[1].count("|") == 12
    assert all(r.count("|") == 12 for r in rows[:4]) and all(r.count("|") == 8 for r in rows[4:])
    assert f"report: {report}" in out


def test_whole_command_usage_and_folder_errors(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        commands.main(["whole", "--runs", "0"])
    assert info.value.code == 2 and "--runs must be >= 1" in capsys.readouterr().err
    assert commands.main(["whole", "--folder", str(tmp_path / "none")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not exist" in err[0]


def test_environment_commands_time_the_sky_against_its_yardsticks(tmp_path, capsys):
    """Issue 25's whole commands on a tiny frame: every case timed, the cold run converting
    (it empties the environment caches first) and the warm one not, and the ratios the
    issue sets computed from the same medians."""
    from clphong.tools import commands

    assert commands.main(["environment", "--runs", "1", "--size", "64x36", "--models", "phong",
                          "--folder", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| sky phong warm |" in out and "| sky phong cold |" in out
    rows = commands.bench_environment(tmp_path, 1, ("phong",), (64, 36))
    by = {r["case"]: r for r in rows}
    assert set(by) == {"sky phong warm", "sky phong cold", "256 point lights phong",
                       "one directional light phong"}
    p256 = by["256 point lights phong"]["wall_s"]
    for r in rows:
        assert r["wall_s"] > 0 and abs(r["ratio_256_point"] - r["wall_s"] / p256) < 1e-12
    assert (tmp_path / "cache" / "envtables").is_dir()

"""The layer benchmark runs and reports every variant (its figures are not checked here)."""

from clphong.tools import layer_bench


def test_layer_bench_reports_every_variant(capsys):
    assert layer_bench.main(["--size", "64x32", "--lights", "4", "--runs", "1"]) == 0
    out = capsys.readouterr().out
    for name, _, _ in layer_bench.VARIANTS:
        assert name in out
    assert "1.000x beauty" in out

"""Frames as Dask tasks on a LocalCluster of 2 workers; local batches never import Dask."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import read_rgb
from test_batch import _check_outputs, _no_temporaries, shot  # noqa: F401 - fixture

from clphong.console.cli import main

try:
    import distributed
except ImportError:          # the optional extra: these tests need it, test_scheduler_without_dask does not
    distributed = None
needs_dask = pytest.mark.skipif(distributed is None, reason="needs dask[distributed] (clphong[dask])")


def _worker_state():
    """On a worker: (relighters cached, programs built, rigs) of this process."""
    from clphong.device.selection import _RUNTIMES
    from clphong.pipeline.relighter import _CACHE

    relighters = [v for k, v in _CACHE.items() if k != "__lock__"]
    builds = sum(rt.builds for rt in _RUNTIMES.values())
    return len(relighters), builds


@needs_dask
def test_dask_local_cluster_two_workers(shot, tmp_path, capsys):  # noqa: F811
    root, expected = shot
    out = tmp_path / "out"
    # Worker processes (not threads), so each one really builds its own relighter;
    # one thread each, as on a farm where PoCL uses the node's cores.
    # The client here only inspects the workers; it is not the default client, so the
    # CLI must work with its own (as it does on a farm).
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=40) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:
        args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
                "--rig", str(root / "fill.toml"), "-o", str(out / "{rig}" / "{name}.####.exr"),
                "--scheduler", cluster.scheduler_address]
        assert main(args) == 0
        state = client.run(_worker_state)
        # A second batch on the same cluster reuses the relighters: nothing new is built
        # but the kernel variant of the fused SDR output (tone mapping in the store).
        again = ["--frames", "1-24x6", "-o", str(tmp_path / "again" / "{rig}.####.exr"),
                 "--sdr", str(tmp_path / "again" / "{rig}.####.png")]
        assert main(args[:-2] + ["--scheduler", cluster.scheduler_address, *again]) == 0
        state2 = client.run(_worker_state)
    assert "48 written, 0 skipped (exist), 0 failed" in capsys.readouterr().err
    # The Dask path writes every output kind as a local run does, byte for byte.
    local = [a.replace(str(tmp_path / "again"), str(tmp_path / "local")) for a in again]
    assert main(args[:-2] + local) == 0
    pngs = sorted((tmp_path / "again").glob("*.png"))
    assert [p.name for p in pngs] == [f"{r}.{f:04d}.png" for r in ("fill", "key") for f in (1, 7, 13, 19)]
    for p in pngs:
        assert p.read_bytes() == (tmp_path / "local" / p.name).read_bytes(), p
    _check_outputs(out, expected)
    _no_temporaries(out)
    assert len(state) == 2
    for addr, (relighters, builds) in state.items():
        # Each worker that ran tasks holds one relighter per rig, compiled once: both
        # rigs share one kernel variant, so at most 2 builds (plan variants), for 24 frames.
        assert relighters in (0, 2) and builds <= 2, state
        if relighters:                    # it ran tasks: the second batch reused what it built
            assert state2[addr][0] == relighters, (state, state2)
            assert state2[addr][1] <= builds + 1, (state, state2)     # + the SDR variant
        else:                             # it got no task (load balancing): it may build now, once
            assert state2[addr][0] in (0, 2) and state2[addr][1] <= 3, state2
    assert sum(r for r, _ in state.values()) >= 2


def test_local_batch_does_not_import_dask(shot, tmp_path):  # noqa: F811
    root, _ = shot
    code = (
        "import sys\n"
        "from clphong.console.cli import main\n"
        f"rc = main(['relight', {str(root / 'seq')!r}, '--rig', {str(root / 'key.toml')!r}, '-q', "
        f"'--frames', '1-2', '-o', {str(tmp_path / '{stem}.out.exr')!r}])\n"
        "assert rc == 0, rc\n"
        "assert 'dask' not in sys.modules and 'distributed' not in sys.modules, 'dask was imported'\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in tmp_path.glob("*.out.exr")) == ["shot.0001.out.exr", "shot.0002.out.exr"]


def test_scheduler_without_dask_is_one_line(shot, tmp_path, capsys, monkeypatch):  # noqa: F811
    """--scheduler without Dask installed: the install hint, not a ModuleNotFoundError traceback."""
    root, _ = shot
    monkeypatch.setitem(sys.modules, "distributed", None)      # 'import distributed' now fails
    out = tmp_path / "out"
    args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "--frames", "1-2", "-o", str(out / "{rig}.####.exr"), "--scheduler", "tcp://127.0.0.1:8786"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert err == ("clphong: error: --scheduler needs Dask: pip install 'clphong[dask]' "
                   "(dask[distributed])\n"), err
    assert not out.exists()


def _worker_renderers():
    """On a worker: the renderer options of every relighter this process cached."""
    from clphong.pipeline.relighter import _CACHE

    return sorted((r.renderer.fp64_directions, r.renderer.plan_for(()).defines["DIRECTIONS_FP64"],
                   r.renderer.max_error, r.renderer.nonfinite)
                  for k, r in _CACHE.items() if k != "__lock__")


@needs_dask
def test_dask_workers_get_the_renderer_options(shot, tmp_path, capsys):  # noqa: F811
    root, _ = shot
    out, local = tmp_path / "dask", tmp_path / "local"
    args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
            "--frames", "1-6", "--path", "float", "--max-error", "0", "--nonfinite", "error"]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, silence_logs=40) as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:
        assert main(args + ["-o", str(out / "{rig}.####.exr"), "--scheduler", cluster.scheduler_address]) == 0
        state = client.run(_worker_renderers)
    assert main(args + ["-o", str(local / "{rig}.####.exr")]) == 0
    seen = [r for rs in state.values() for r in rs]
    assert seen and set(seen) == {(False, 0, 0.0, "error")}, state
    for f in range(1, 7):        # the pixels (the EXR header holds a time stamp)
        assert np.array_equal(*(read_rgb(d / f"key.{f:04d}.exr") for d in (out, local))), f


def _loopback_server(behaviour):
    """A server on 127.0.0.1 (never any other address) that accepts and then either stays
    silent or closes at once; (address, stop)."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    srv.settimeout(0.2)
    stop = threading.Event()
    held = []

    def serve():
        while not stop.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                continue
            if behaviour == "close":
                conn.close()
            else:
                held.append(conn)                 # accepted, never a byte

    t = threading.Thread(target=serve, daemon=True)
    t.start()

    def close():
        stop.set()
        t.join(5)
        for c in held:
            c.close()
        srv.close()

    return f"tcp://127.0.0.1:{srv.getsockname()[1]}", close


@pytest.mark.parametrize("behaviour, needle", [
    ("silent", "it accepted the connection but sent nothing in 1.5 s"),
    ("close", "closed the connection without a handshake"),
])
def test_a_scheduler_that_does_not_answer_is_one_line_in_time(shot, tmp_path, capsys,  # noqa: F811
                                                             behaviour, needle):
    """A peer that accepts and never speaks held relight --scheduler for as long as it held
    the connection (Dask's own client has no limit there). Now --scheduler-timeout bounds
    it: one line naming the address and the cause, nothing after it, exit 1."""
    import time

    root, _ = shot
    address, close = _loopback_server(behaviour)
    try:
        args = ["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
                "-o", str(tmp_path / "out" / "{rig}.####.exr"), "--scheduler", address,
                "--scheduler-timeout", "1.5"]
        t0 = time.perf_counter()
        assert main(args) == 1
        took = time.perf_counter() - t0
    finally:
        close()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("clphong: error: ") and address in err, err
    assert needle in err
    assert took < 1.5 + 5.0                    # the timeout, and the plan's own second or so
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_scheduler_timeout_is_checked_at_the_door(shot, tmp_path, capsys):  # noqa: F811
    root, _ = shot
    for bad in ("0", "-1", "nan", "inf"):
        with pytest.raises(SystemExit) as ex:
            main(["relight", str(root / "seq" / "shot.####.exr"), "--rig", str(root / "key.toml"),
                  "-o", str(tmp_path / "o.####.exr"), "--scheduler", "tcp://127.0.0.1:1",
                  "--scheduler-timeout", bad])
        assert ex.value.code == 2
        assert "--scheduler-timeout: expected a finite number > 0" in capsys.readouterr().err


def test_the_api_refuses_a_bad_timeout_with_the_clis_words():
    from clphong.pipeline.distributed import SchedulerError, run_on_dask

    for bad in (float("nan"), 0.0, -1.0, float("inf")):
        with pytest.raises(SchedulerError, match="--scheduler-timeout: expected a finite number > 0"):
            run_on_dask([], {}, "tcp://127.0.0.1:1", lambda outs: None, timeout=bad)

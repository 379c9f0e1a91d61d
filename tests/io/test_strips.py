"""Outputs are written in strips of rows (clphong.io.atomic.STRIP_ROWS), so that a
terminating signal takes effect while a large file is being written (Python runs its
handlers only between calls into OpenImageIO; one write_image call of a 4096×4096 float
EXR took ~10 s), and the strips give the same file as one call."""

from __future__ import annotations

import signal
import time

import numpy as np
import OpenImageIO as oiio
import pytest

from clphong.io import atomic


@pytest.mark.parametrize("fmt, tiled", [("exr", False), ("exr", True), ("png", False), ("tif", False)])
def test_strips_write_the_same_pixels(tmp_path, fmt, tiled, monkeypatch):
    monkeypatch.setattr(atomic, "STRIP_ROWS", 16)            # many strips, and a ragged last one
    rng = np.random.default_rng(0)
    data = rng.uniform(0, 1, (301, 37, 3)).astype(np.float32)
    spec = oiio.ImageSpec(37, 301, 3, "uint8" if fmt == "png" else "float")
    if tiled:
        spec.tile_width = spec.tile_height = 32
    path = str(tmp_path / f"a.{fmt}")
    atomic.write_image_atomically(path, spec, data)
    got = oiio.ImageBuf(path).get_pixels(oiio.FLOAT)
    want = np.round(data * 255) / 255 if fmt == "png" else data
    assert np.allclose(got, want, atol=1e-6 if fmt != "png" else 0.5 / 255)
    assert [p.name for p in tmp_path.iterdir()] == [f"a.{fmt}"]


def test_a_signal_during_a_long_write_takes_effect_between_strips(tmp_path):
    """A timer signal raises in the middle of writing a large EXR: the exception arrives
    within one strip's time (well under the whole write), and no file is left."""
    data = np.random.default_rng(1).uniform(0, 1, (1536, 1536, 3)).astype(np.float32)
    spec = oiio.ImageSpec(1536, 1536, 3, "float")
    spec.attribute("compression", "zip")
    path = tmp_path / "big.exr"
    t0 = time.perf_counter()
    atomic.write_image_atomically(str(path), spec, data)     # the whole write, for scale
    whole = time.perf_counter() - t0
    path.unlink()

    def stop(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, stop)
    try:
        signal.setitimer(signal.ITIMER_REAL, whole / 4)
        t0 = time.perf_counter()
        with pytest.raises(KeyboardInterrupt):
            atomic.write_image_atomically(str(path), spec, data)
        late = time.perf_counter() - t0 - whole / 4
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert list(tmp_path.iterdir()) == []
    assert late < whole / 2, f"handled {late:.2f} s after the signal; the whole write takes {whole:.2f} s"

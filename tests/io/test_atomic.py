"""Tests of clphong.io.atomic: atomic writes and write_exr."""

from __future__ import annotations

import os

import numpy as np
import OpenImageIO as oiio
import pytest

from clphong.core.errors import OutputError
from clphong.io import atomic as output
from clphong.io.atomic import atomic_path, write_exr


def _read(path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    pix = inp.read_image(0, 0, 0, spec.nchannels, "float")
    inp.close()
    return spec, np.asarray(pix)


def _rgb(h=5, w=7, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.standard_normal((h, w, 3)) * 10.0 ** rng.integers(-6, 5, (h, w, 3))).astype(np.float32)


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


# --------------------------------------------------------------------------- write_exr


def test_write_exr_float_roundtrip_exact(tmp_path):
    rgb = _rgb()
    out = tmp_path / "out.exr"
    write_exr(out, rgb)
    spec, pix = _read(out)
    assert spec.channelnames == ("R", "G", "B")
    assert spec.format == oiio.TypeDesc("float")
    assert spec.get_string_attribute("compression") == "zip"
    assert spec.tile_width == 0
    assert pix.dtype == np.float32 and np.array_equal(pix, rgb)
    assert _listing(tmp_path) == ["out.exr"]


def test_write_exr_half_rounds_like_numpy(tmp_path):
    rgb = _rgb(seed=1)
    rgb[0, 0] = [70000.0, 1e-8, -3e-6]      # beyond the half range, underflow, subnormal half
    out = tmp_path / "half.exr"
    # In range: numpy's rounding. Beyond ±65504: clamped with a warning (the
    # documented policy), never an unannounced Inf.
    expected = np.clip(rgb, -65504.0, 65504.0).astype(np.float16).astype(np.float32)
    from clphong.core.errors import OutputWarning
    with pytest.warns(OutputWarning, match="1 value"):
        write_exr(out, rgb, pixel_type="half", compression="piz")
    spec, pix = _read(out)
    assert spec.format == oiio.TypeDesc("half")
    assert spec.get_string_attribute("compression") == "piz"
    assert np.array_equal(pix, expected)


def test_write_exr_custom_channels_tiled_and_2d(tmp_path):
    data = np.arange(5 * 7 * 4, dtype=np.float32).reshape(5, 7, 4)
    write_exr(tmp_path / "rgba.exr", data, channel_names=("R", "G", "B", "A"), tiled=True)
    spec, pix = _read(tmp_path / "rgba.exr")
    assert spec.channelnames == ("R", "G", "B", "A") and spec.alpha_channel == 3
    assert (spec.tile_width, spec.tile_height) == (64, 64)
    assert np.array_equal(pix, data)
    plane = np.linspace(0, 1, 35, dtype=np.float32).reshape(5, 7)
    write_exr(tmp_path / "y.exr", plane, channel_names=("Y",))
    spec, pix = _read(tmp_path / "y.exr")
    assert spec.channelnames == ("Y",) and np.array_equal(pix[..., 0], plane)


def test_write_exr_attributes(tmp_path):
    chroma = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
    w2c = np.arange(16, dtype=np.float64).reshape(4, 4)
    write_exr(tmp_path / "a.exr", _rgb(), attributes={
        "chromaticities": chroma, "oiio:ColorSpace": "Linear Rec.709 (sRGB)", "Software": "clphong",
        "clphong:int": 3, "clphong:float": 0.5, "worldToCamera": w2c, "clphong:flag": True,
        "clphong:ints": [1, 2, 3], "clphong:strings": ("a", "b")})
    spec, _ = _read(tmp_path / "a.exr")
    assert np.allclose(spec.getattribute("chromaticities"), chroma)
    assert spec.get_string_attribute("Software") == "clphong"
    assert spec.get_int_attribute("clphong:int") == 3
    assert spec.get_float_attribute("clphong:float") == 0.5
    assert spec.get_int_attribute("clphong:flag") == 1
    assert tuple(spec.getattribute("worldToCamera")) == tuple(float(v) for v in range(16))
    assert tuple(spec.getattribute("clphong:ints")) == (1, 2, 3)


def test_write_exr_unsupported_attribute(tmp_path):
    with pytest.raises(OutputError, match="attribute 'bad'"):
        write_exr(tmp_path / "a.exr", _rgb(), attributes={"bad": object()})
    assert _listing(tmp_path) == []


@pytest.mark.parametrize("shape,names", [((5, 7), ("R", "G", "B")), ((5, 7, 4), ("R", "G", "B")),
                                         ((5, 7, 3, 1), ("R", "G", "B")), ((0, 7, 3), ("R", "G", "B"))])
def test_write_exr_bad_shape(tmp_path, shape, names):
    out = tmp_path / "bad.exr"
    with pytest.raises(OutputError, match="bad.exr"):
        write_exr(out, np.zeros(shape, np.float32), channel_names=names)
    assert _listing(tmp_path) == []


def test_write_exr_bad_pixel_type(tmp_path):
    with pytest.raises(OutputError, match=r"x\.exr: pixel type 'uint8'"):
        write_exr(tmp_path / "x.exr", _rgb(), pixel_type="uint8")
    with pytest.raises(OutputError, match="duplicate channel"):
        write_exr(tmp_path / "x.exr", _rgb(), channel_names=("R", "R", "B"))


def test_write_exr_missing_folder(tmp_path):
    out = tmp_path / "no" / "such" / "out.exr"
    with pytest.raises(OutputError) as exc:
        write_exr(out, _rgb())
    assert str(out) in str(exc.value) and "does not exist" in str(exc.value)
    assert "\n" not in str(exc.value)


def test_write_exr_directory_in_the_way(tmp_path):
    (tmp_path / "out.exr").mkdir()
    with pytest.raises(OutputError, match="out.exr: is a directory"):
        write_exr(tmp_path / "out.exr", _rgb())
    assert _listing(tmp_path) == ["out.exr"] and (tmp_path / "out.exr").is_dir()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root ignores folder permissions")
def test_write_exr_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="cannot write in folder"):
            write_exr(folder / "out.exr", _rgb())
        assert _listing(folder) == []
    finally:
        folder.chmod(0o755)


def test_write_exr_unwritable_folder_simulated(tmp_path, monkeypatch):
    real_open = os.open

    def deny(name, flags, mode=0o777, *a, **k):
        if ".tmp-" in os.fspath(name):
            raise PermissionError(13, "Permission denied", name)
        return real_open(name, flags, mode, *a, **k)

    monkeypatch.setattr(output.os, "open", deny)
    with pytest.raises(OutputError) as exc:
        write_exr(tmp_path / "out.exr", _rgb())
    assert "out.exr" in str(exc.value) and "Permission denied" in str(exc.value)
    assert _listing(tmp_path) == []


class _FailingOutput:
    """Stands in for oiio.ImageOutput: opens fine, then the pixel write fails (stage
    "silent": every call returns True, as OpenImageIO's writers can on a full disk,
    and the file is left as open() wrote it)."""

    stage = "write"

    @classmethod
    def create(cls, name):
        return None if cls.stage == "create" else cls()

    def open(self, name, spec):
        with open(name, "wb") as fh:          # leave a partial file, as a real failure might
            fh.write(b"v/1\x01partial")
        return self.stage != "open"

    def write_image(self, data):
        return self.stage != "write"

    def close(self):
        return self.stage != "close"

    def geterror(self):
        return f"simulated {self.stage} failure\nsecond line"


@pytest.mark.parametrize("stage", ["create", "open", "write", "close", "silent"])
def test_write_exr_oiio_failure_leaves_nothing(tmp_path, monkeypatch, stage):
    out = tmp_path / "out.exr"
    write_exr(out, np.ones((5, 7, 3), np.float32))          # an existing good file
    before = out.read_bytes()
    monkeypatch.setattr(_FailingOutput, "stage", stage)
    monkeypatch.setattr(output.oiio, "ImageOutput", _FailingOutput)
    with pytest.raises(OutputError) as exc:
        write_exr(out, _rgb())
    msg = str(exc.value)
    assert msg.startswith(str(out)) and "\n" not in msg
    if stage == "silent":
        assert "the write failed (disk full?): the file written is incomplete" in msg
    elif stage != "create":
        assert f"simulated {stage} failure; second line" in msg
    assert _listing(tmp_path) == ["out.exr"]
    assert out.read_bytes() == before


def test_write_exr_flush_failure_keeps_the_previous_file(tmp_path, monkeypatch):
    """A file system that reports the full disk only at fsync (NFS, quotas)."""
    import errno

    out = tmp_path / "out.exr"
    write_exr(out, np.ones((5, 7, 3), np.float32))
    before = out.read_bytes()

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(output.os, "fsync", full)
    with pytest.raises(OutputError, match=r"out\.exr: the write failed: No space left on device$"):
        write_exr(out, _rgb())
    assert _listing(tmp_path) == ["out.exr"]
    assert out.read_bytes() == before


def _whole_image(path, kind):
    """A 40x50 noise image (several PNG IDAT chunks, several EXR scanline blocks)."""
    rgb = np.random.default_rng(3).random((40, 50, 3)).astype(np.float32)
    if kind == "exr-tiled":
        write_exr(path, rgb, pixel_type="half", tiled=True)
        return
    fmt = oiio.HALF if kind == "exr" else oiio.UINT16
    output.write_image_atomically(str(path), oiio.ImageSpec(50, 40, 3, fmt), rgb)


@pytest.mark.parametrize("kind", ["png", "exr", "exr-tiled", "tif", "jxl"])
def test_check_image_written_refuses_a_file_cut_anywhere(tmp_path, monkeypatch, kind):
    """What a disk that fills up leaves: the file cut short. Every cut is found, even
    those OpenImageIO's readers accept (a PNG without its IEND chunk); the whole
    file passes, read back a band at a time."""
    from clphong.deliver.writers import jpegxl_available

    if kind == "jxl" and not jpegxl_available():
        pytest.skip("this OpenImageIO has no JPEG XL writer")
    ext = kind.split("-")[0]
    whole = tmp_path / f"whole.{ext}"
    _whole_image(whole, kind)
    monkeypatch.setattr(output, "READ_BACK_BYTES", 1)       # one row (of tiles) at a time
    output.check_image_written(str(whole))
    data = whole.read_bytes()
    cut = tmp_path / f"cut.{ext}"
    for n in sorted({0, 1, 8, len(data) // 3, len(data) // 2, len(data) - 12, len(data) - 1}):
        cut.write_bytes(data[:n])
        with pytest.raises(OutputError) as exc:
            output.check_image_written(str(cut), f"out.{ext}")
        msg = str(exc.value)
        assert msg.startswith(f"out.{ext}: the write failed (disk full?): the file written is "
                              "incomplete: "), (n, msg)
        assert "\n" not in msg


def test_write_exr_permissions_follow_umask(tmp_path):
    old = os.umask(0o022)
    try:
        write_exr(tmp_path / "p.exr", _rgb())
    finally:
        os.umask(old)
    assert (tmp_path / "p.exr").stat().st_mode & 0o777 == 0o644


# --------------------------------------------------------------------------- atomic_path


def test_atomic_path_temp_name_and_replace(tmp_path):
    dest = tmp_path / "result.exr"
    dest.write_text("old")
    with atomic_path(dest) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path)
        name = os.path.basename(tmp)
        assert name.startswith(".result.tmp-") and name.endswith(".exr")
        assert os.path.exists(tmp) and dest.read_text() == "old"
        with open(tmp, "w") as fh:
            fh.write("new")
    assert dest.read_text() == "new"
    assert _listing(tmp_path) == ["result.exr"]


def test_atomic_path_accepts_str_and_relative(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with atomic_path("rel.txt") as tmp:
        with open(tmp, "w") as fh:
            fh.write("x")
    assert (tmp_path / "rel.txt").read_text() == "x"


@pytest.mark.parametrize("exc_type", [RuntimeError, KeyboardInterrupt, OutputError])
def test_atomic_path_exception_removes_temp(tmp_path, exc_type):
    dest = tmp_path / "result.exr"
    dest.write_text("old")
    with pytest.raises(exc_type):
        with atomic_path(dest) as tmp:
            with open(tmp, "w") as fh:
                fh.write("partial")
            raise exc_type("boom")
    assert dest.read_text() == "old"
    assert _listing(tmp_path) == ["result.exr"]


def test_interrupt_between_create_and_with_block_is_cleaned_up(tmp_path, monkeypatch):
    """An interrupt that lands after the temporary file exists but before the
    ``with`` body runs (where atomic_path's own except cannot see it) -- the
    window a batch SIGTERM hit in CI -- leaves a name remove_live_temporaries()
    knows; another thread's write in flight is left alone."""
    import threading

    real_name = output._name
    calls = []

    def name_then_interrupt(born, candidate):
        real_name(born, candidate)       # the locked file gets its temporary name
        calls.append(candidate)
        raise KeyboardInterrupt          # as a signal handler would, right after the create

    other_ready, other_go = threading.Event(), threading.Event()
    other = {}

    def other_writer():
        with atomic_path(tmp_path / "other.exr") as tmp:
            other["tmp"] = tmp
            other_ready.set()
            other_go.wait(10)
            with open(tmp, "w") as fh:
                fh.write("other")

    t = threading.Thread(target=other_writer)
    t.start()
    assert other_ready.wait(10)
    monkeypatch.setattr(output, "_name", name_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(tmp_path / "result.exr"):
            pass  # pragma: no cover - never entered
    monkeypatch.setattr(output, "_name", real_name)
    assert calls
    mine = [n for n in _listing(tmp_path) if n.startswith(".result.tmp-")]
    assert len(mine) == 1                # the window is real: the file exists, nothing removed it
    assert output.remove_live_temporaries() == 1
    assert output.remove_live_temporaries() == 0
    assert os.path.exists(other["tmp"])  # another thread's write is not this interrupt's business
    other_go.set()
    t.join(10)
    assert _listing(tmp_path) == ["other.exr"]
    assert not output._LIVE


def test_atomic_path_temp_deleted_by_body(tmp_path):
    with pytest.raises(OutputError, match="gone.exr: the write failed: No such file"):
        with atomic_path(tmp_path / "gone.exr") as tmp:
            os.remove(tmp)
    assert _listing(tmp_path) == []


def test_atomic_path_missing_folder(tmp_path):
    with pytest.raises(OutputError, match="missing/x.exr: folder .* does not exist"):
        with atomic_path(tmp_path / "missing" / "x.exr"):
            pass  # pragma: no cover


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_a_swallowed_signal_is_raised_again_before_the_file_is_put_in_place(tmp_path, sig,
                                                                               signals_not_ignored):
    """clphong render's handlers (signals_as_interrupt) record what they raise: when C code
    drops the exception, the commit raises it, and neither the file nor its temporary stays."""
    import signal

    from clphong.core import signals

    out = tmp_path / "frame.exr"
    signum = getattr(signal, sig)
    with signals.signals_as_interrupt():
        with pytest.raises(signals.Terminated if sig == "SIGTERM" else KeyboardInterrupt) as caught:
            with atomic_path(out) as tmp:
                with open(tmp, "wb") as f:
                    f.write(b"a whole file")
                try:
                    signal.raise_signal(signum)             # the handler raises here...
                except KeyboardInterrupt:
                    pass                                    # ...and the exception is dropped
    assert getattr(caught.value, "signum", signal.SIGINT) == signum
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert os.listdir(tmp_path) == []
    signals.raise_pending()                                 # acted on: nothing left to raise
    with atomic_path(out) as tmp:                           # and the next write is whole
        with open(tmp, "wb") as f:
            f.write(b"x")
    assert out.read_bytes() == b"x"

"""Writing results safely: atomic EXR output through OpenImageIO.

Every file clphong writes goes through :func:`atomic_path`: the data are
written to a hidden temporary file in the destination folder (same extension,
so OpenImageIO picks the same format) and renamed onto the destination only
when the write succeeded and the file is on the disk (``fsync``); an image
is also checked whole first (:func:`check_image_written`: OpenImageIO's writers
do not report every write error, e.g. a disk that fills while a PNG is
closed). A failed or interrupted write therefore never leaves a partial or
truncated file behind, and never clobbers an existing good file.

Public functions
----------------
check_output_path
    Check an output name and its folder before any work is done.
atomic_path
    Context manager yielding a temporary name that is renamed into place.
check_image_written
    Check that an image file just written is whole.
write_image_atomically
    Write an array with an OpenImageIO spec through :func:`atomic_path`.
remove_live_temporaries
    After an interrupt, remove the temporary files of this thread's writes in flight.
write_exr
    Write an (H, W, C) array to an OpenEXR file with explicit channel names,
    pixel type, compression and header attributes.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import threading
import zlib
from collections.abc import Iterator, Mapping, Sequence

import numpy as np
import OpenImageIO as oiio

from ..core.errors import OutputError, OutputWarning
from ..core.signals import raise_pending

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no locks, leftovers by name alone
    fcntl = None

__all__ = ["atomic_path", "check_image_written", "remove_live_temporaries", "writer_gone", "written_here",
           "check_output_path",
           "write_image_atomically", "write_exr", "set_attribute", "PIXEL_TYPES", "check_pixel_type"]

#: Pixel types accepted by :func:`write_exr` and ``write_gbuffer``.
PIXEL_TYPES = ("float", "half")


def check_pixel_type(pixel_type, where: str | None = None, error: type[Exception] = OutputError) -> str:
    """``pixel_type`` if it is one of :data:`PIXEL_TYPES`; else ``error`` naming ``where`` (a file)."""
    if pixel_type in PIXEL_TYPES:
        return pixel_type
    subject = f"{where}: pixel type" if where else "EXR pixel type"
    raise error(f"{subject} {pixel_type!r} is not one of {', '.join(PIXEL_TYPES)}")


def same_file(a, b) -> bool:
    """Whether two paths name the same file (through links too); by absolute path
    when either does not exist yet."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def _one_line(text: str, most: int = 3) -> str:
    """Collapse a (possibly multi-line) library message onto one line of at most
    ``most`` of its distinct lines (a failing write can repeat its complaint per
    block, OpenImageIO a failed open once per attempt)."""
    parts = list(dict.fromkeys(p.strip() for p in str(text).splitlines() if p.strip()))
    if len(parts) > most:
        parts = [*parts[:most - 1], f"... ({len(parts) - most + 1} more)"]
    return "; ".join(parts) if parts else "unknown error"


def _remove_quietly(name: str) -> None:
    with contextlib.suppress(OSError):
        os.remove(name)


#: Temporary names :func:`atomic_path` has reserved and not yet renamed or
#: removed, each with the thread that owns it. A name is registered *before*
#: the file is created and dropped only *after* the rename, so an interrupt that
#: lands between two bytecodes of ``atomic_path`` (where its own ``except``
#: cannot see the file yet) still leaves the name here for
#: :func:`remove_live_temporaries`.
_LIVE: dict[str, int] = {}


def remove_live_temporaries() -> int:
    """Remove the temporary files of this thread's writes in flight; return how many existed.

    Call it where an interrupt (``KeyboardInterrupt``, SIGTERM turned into an
    exception) is caught. Other threads' writes are left alone: they may still
    finish. A name whose file is already gone (renamed into place, or never
    created) is simply forgotten.
    """
    me = threading.get_ident()
    removed = 0
    for name, owner in list(_LIVE.items()):
        if owner == me:
            with contextlib.suppress(OSError):
                os.remove(name)
                removed += 1
            _LIVE.pop(name, None)
    return removed


def check_output_path(path: str | os.PathLike, *, exr: bool = False) -> None:
    """Check, before any work, that ``path`` can be an output file.

    Parameters
    ----------
    path : str or os.PathLike
        The destination file.
    exr : bool
        Also require the ``.exr`` extension (OpenImageIO picks the format
        from it: ``out.png`` would be written as 8-bit PNG, silently clipping
        scene-linear values).

    Raises
    ------
    OutputError
        One line naming ``path``: not a file name, a directory, a folder that
        is missing (or a path through a regular file), or (``exr``) a name
        not ending in ``.exr``. Writability is checked when the temporary file
        is created (:func:`atomic_path`).
    """
    path = os.fspath(path)
    # the folder as the system resolves it, not normalised: "missing/.." is no folder to the
    # kernel (it needs "missing"), though abspath() would make it the current one
    folder = os.path.dirname(path) or os.curdir
    name = os.path.basename(path)
    if not name:
        raise OutputError(f"{path}: not a file name")
    if os.path.isdir(path):
        raise OutputError(f"{path}: is a directory; give a file name")
    if exr and os.path.splitext(name)[1].lower() != ".exr":
        display = os.path.splitext(name)[1].lower() in (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".jxl")
        raise OutputError(f"{path}: output files are OpenEXR; give a name ending in .exr"
                          + ("; for a display image use --sdr (PNG, TIFF, JPEG) or --hdr (PNG, "
                             "JPEG XL)" if display else ""))
    if not os.path.isdir(folder):
        # Name the first part of the folder's path that is missing or not a folder.
        part = folder
        while not os.path.exists(part) and os.path.dirname(part) not in (part, ""):
            part = os.path.dirname(part)
        if os.path.exists(part) and not os.path.isdir(part):
            raise OutputError(f"{path}: {part} is a file, not a folder; choose another output folder")
        raise OutputError(f"{path}: folder {folder} does not exist; create it first")


#: Bytes of pixels :func:`check_image_written` decodes at a time (bounds its memory).
READ_BACK_BYTES = 64 << 20
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _read_back(name: str) -> str | None:
    """Decode every pixel of image ``name``, a band at a time; OpenImageIO's complaint, or None."""
    inp = oiio.ImageInput.open(name)
    if inp is None:
        return _one_line(oiio.geterror())
    try:
        spec = inp.spec()
        step = max(1, spec.tile_height)                 # bands of whole tile rows
        rows = max(1, READ_BACK_BYTES // max(1, spec.scanline_bytes()) // step) * step
        z0, z1 = spec.z, spec.z + max(1, spec.depth)
        for y in range(spec.y, spec.y + spec.height, rows):
            y1 = min(y + rows, spec.y + spec.height)
            if spec.tile_width:
                px = inp.read_tiles(0, 0, spec.x, spec.x + spec.width, y, y1, z0, z1,
                                    0, spec.nchannels, oiio.UNKNOWN)
            else:
                px = inp.read_scanlines(0, 0, y, y1, z0, 0, spec.nchannels, oiio.UNKNOWN)
            if px is None or inp.has_error:
                return _one_line(inp.geterror())
        return None
    finally:
        inp.close()


def _png_problem(name: str) -> str | None:
    """Walk the chunks of PNG ``name``: each whole, with a good CRC, up to IEND at the
    end of the file; what is wrong, or None. (Reading the pixels back with libpng
    would print its complaint on stderr, and stops before IEND.)"""
    with open(name, "rb") as f:
        if f.read(8) != _PNG_SIGNATURE:
            return "no PNG signature"
        while True:
            head = f.read(8)
            n, kind = int.from_bytes(head[:4], "big"), head[4:]
            body, crc = f.read(n), f.read(4)
            if len(head) < 8 or len(body) < n or len(crc) < 4:
                return "the file ends before its IEND chunk"
            if zlib.crc32(body, zlib.crc32(kind)) != int.from_bytes(crc, "big"):
                return f"bad CRC in chunk {kind.decode('latin-1')!r}"
            if kind == b"IEND":
                return "data after the IEND chunk" if f.read(1) else None


_EXR_MAGIC = b"\x76\x2f\x31\x01"
#: Scanlines per chunk of each OpenEXR compression (its code in the header): none, rle,
#: zips, zip, piz, pxr24, b44, b44a, dwaa, dwab. Other codes (e.g. OpenEXR 3.4's HTJ2K)
#: are checked by decoding the file (:func:`_read_back`).
_EXR_LINES_PER_CHUNK = (1, 1, 1, 16, 32, 16, 32, 32, 32, 256)
#: The version-field flags of a tiled, deep or multi-part file (those are decoded instead).
_EXR_TILED, _EXR_DEEP, _EXR_MULTIPART = 0x200, 0x800, 0x1000


class _Cut(Exception):
    """The file ends inside what is being read."""


def _exr_layout_problem(name: str) -> str | None:
    """Walk the structure of the single-part scanline OpenEXR file ``name``: its header,
    its offset table, and every chunk's header and length, each inside the file, none
    overlapping another, the last ending where the file ends (what a disk that fills
    leaves: a file cut short, or an offset table never written). What is wrong, None
    if nothing is, or ``"?"`` for a file of another kind (tiled, deep, multi-part, an
    unknown compression), which :func:`check_image_written` decodes instead.

    Reads the header and 8 bytes per chunk, not the pixels: 1080p float RGBA with zip
    in about 1 ms instead of 70-140 ms to decode it.
    """
    import struct

    size = os.path.getsize(name)
    with open(name, "rb") as f:
        def read(n: int) -> bytes:
            b = f.read(n)
            if len(b) < n:
                raise _Cut()
            return b

        def cstring() -> bytes:
            out = bytearray()
            while True:
                c = read(1)
                if c == b"\0":
                    return bytes(out)
                out += c
                if len(out) > 255:
                    raise ValueError("an attribute name longer than 255 bytes")

        try:
            if read(4) != _EXR_MAGIC:
                return "no OpenEXR magic number"
            version = struct.unpack("<i", read(4))[0]
            if version & (_EXR_TILED | _EXR_DEEP | _EXR_MULTIPART):
                return "?"
            window = compression = chunks = None
            while True:
                attr = cstring()
                if not attr:
                    break
                cstring()                                     # the type name
                n = struct.unpack("<i", read(4))[0]
                if n < 0:
                    return f"attribute {attr!r} has a negative size"
                value = read(n)
                if attr == b"dataWindow" and n == 16:
                    window = struct.unpack("<4i", value)
                elif attr == b"compression" and n == 1:
                    compression = value[0]
                elif attr == b"chunkCount" and n == 4:
                    chunks = struct.unpack("<i", value)[0]
            if window is None or compression is None:
                return "the header lacks dataWindow or compression"
            if compression >= len(_EXR_LINES_PER_CHUNK):
                return "?"
            lines = _EXR_LINES_PER_CHUNK[compression]
            y0, y1 = window[1], window[3]
            expected = (y1 - y0 + lines) // lines
            if chunks is not None and chunks != expected:
                return f"chunkCount {chunks}, but the data window holds {expected} chunks"
            if expected < 1 or f.tell() + 8 * expected > size:
                return "the file ends inside its offset table"
            offsets = struct.unpack(f"<{expected}Q", read(8 * expected))
            start = f.tell()
            ends = []
            for k, at in sorted(zip(range(expected), offsets), key=lambda item: item[1]):
                if at < start:
                    return f"chunk {k}'s offset {at} is not past the offset table (never written?)"
                if at + 8 > size:
                    return f"chunk {k} lies beyond the end of the file"
                f.seek(at)
                y, n = struct.unpack("<ii", read(8))
                if y != y0 + k * lines:
                    return f"chunk {k} starts at line {y}, not {y0 + k * lines}"
                if n < 0 or at + 8 + n > size:
                    return f"chunk {k} (line {y}) is cut short"
                if ends and at < ends[-1]:
                    return f"chunk {k} overlaps the one before it"
                ends.append(at + 8 + n)
            if (ends[-1] if ends else start) != size:
                return "data after the last chunk"
            return None
        except _Cut:
            return "the file ends inside its header or offset table"
        except (ValueError, struct.error) as exc:
            return f"a malformed header ({exc})"


_JXL_CONTAINER = b"\x00\x00\x00\x0cJXL \r\n\x87\n"


def _jxl_layout_problem(name: str) -> str | None:
    """Walk the boxes of the JPEG XL container ``name`` (ISO/IEC 18181-2): each box
    whole, the last ending where the file ends, and the codestream whole (a ``jxlc``
    box, or ``jxlp`` parts up to the one flagged last). What is wrong, None, or ``"?"``
    for a bare codestream or a box that runs to the end of the file, with no length to
    check (:func:`check_image_written` decodes those instead)."""
    import struct

    size = os.path.getsize(name)
    with open(name, "rb") as f:
        if f.read(12) != _JXL_CONTAINER:
            return "?"
        at, codestream = 12, False
        while at < size:
            f.seek(at)
            head = f.read(16)
            if len(head) < 8:
                return "the file ends inside a box header"
            n, kind = struct.unpack(">I4s", head[:8])
            header = 8
            if n == 0:
                return "?"
            if n == 1:
                if len(head) < 16:
                    return "the file ends inside a box header"
                n, header = struct.unpack(">Q", head[8:])[0], 16
            if n < header or at + n > size:
                return f"box {kind.decode('latin-1')!r} is cut short"
            if kind == b"jxlc":
                codestream = True
            elif kind == b"jxlp":                   # a part; bit 31 of its index: the last
                if n < header + 4:
                    return "a jxlp box without its index"
                f.seek(at + header)
                codestream = bool(f.read(1)[0] & 0x80)
            at += n
        return None if codestream else "the codestream is cut short (no last part)"


def check_image_written(name: str, display: str | None = None) -> None:
    """Check that the image file ``name`` just written is whole.

    A PNG must be a whole chain of chunks up to IEND (OpenImageIO's PNG writer
    reports no error when the disk fills while it closes the file); a scanline
    EXR a whole header, offset table and chain of chunks up to the end of the file
    (:func:`_exr_layout_problem`; its writer can miss such an error too), and a JPEG XL
    container a whole chain of boxes holding the whole codestream
    (:func:`_jxl_layout_problem`); any other image (a tiled EXR, a TIFF) is read back
    completely.

    Raises
    ------
    OutputError
        One line naming ``display`` (default ``name``): the write failed.
    """
    ext = os.path.splitext(name)[1].lower()
    if ext == ".png":
        problem = _png_problem(name)
    elif ext == ".exr" and (problem := _exr_layout_problem(name)) != "?":
        pass
    elif ext == ".jxl" and (problem := _jxl_layout_problem(name)) != "?":
        pass
    else:
        problem = _read_back(name)
    if problem is not None:
        raise OutputError(f"{name if display is None else display}: the write failed (disk full?): "
                          f"the file written is incomplete: {problem}")


def _sync(name: str, display: str) -> None:
    """Flush file ``name`` to the disk: a file system may report a full disk only
    now, and a crash after the rename must not leave an empty file."""
    try:
        fd = os.open(name, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        raise OutputError(f"{display}: the write failed: {exc.strerror or exc}") from exc


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """Yield a temporary file name that replaces ``path`` on success.

    The temporary file lies in the same folder as ``path`` (so the final
    :func:`os.replace` is an atomic rename on the same file system) and has
    the same extension, e.g. ``.out.tmp-1f2e3d4c.exr`` for ``out.exr``. It is
    created empty (with the permissions the umask allows) to reserve the name
    and to check that the folder is writable.

    Parameters
    ----------
    path : str or os.PathLike
        The destination file.

    Yields
    ------
    str
        The temporary file name to write to.

    Raises
    ------
    OutputError
        If the folder of ``path`` is missing or not writable, if ``path`` is
        a directory, if flushing the file to the disk fails (e.g. the disk
        is full), or if the final rename fails. The temporary file is removed
        in every failure case.

    Notes
    -----
    On any exception raised inside the ``with`` block (including
    ``KeyboardInterrupt``) the temporary file is deleted and the exception
    re-raised; ``path`` is left untouched. An interrupt can also land in the
    few bytecodes between creating the temporary file and entering the
    ``with`` block, where no ``except`` sees it; the name is registered before
    the file is created, so the code that catches the interrupt removes it
    with :func:`remove_live_temporaries`.

    Examples
    --------
    >>> with atomic_path("out.exr") as tmp:          # doctest: +SKIP
    ...     write_the_image(tmp)
    """
    path = os.fspath(path)
    check_output_path(path)
    folder = os.path.dirname(os.path.abspath(path))
    stem, ext = os.path.splitext(os.path.basename(path))
    me = threading.get_ident()
    tmp = None
    for _ in range(100):
        candidate = os.path.join(folder, f".{stem}.tmp-{secrets.token_hex(4)}{ext}")
        # Created as NAME.born and locked before it gets the temporary name, so that every
        # file under that name is locked while its writer lives (writer_gone)
        born = candidate + ".born"
        _LIVE[candidate] = _LIVE[born] = me   # before the files exist: see _LIVE
        try:
            fd = os.open(born, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            # someone else's file: never ours to remove. (An interrupt between the
            # failed open and this pop would leave it registered: that needs a
            # 32-bit name collision as well, and is accepted.)
            _LIVE.pop(candidate, None)
            _LIVE.pop(born, None)
            continue
        except OSError as exc:
            _LIVE.pop(candidate, None)
            _LIVE.pop(born, None)
            raise OutputError(f"{path}: cannot write in folder {folder}: {exc.strerror or exc}") from exc
        _lock(fd)          # held until the rename into place: proves that this writer lives
        if not _name(born, candidate):
            _remove_quietly(born)
            os.close(fd)
            _LIVE.pop(candidate, None)
            _LIVE.pop(born, None)
            continue
        _LIVE.pop(born, None)
        tmp = candidate
        break
    if tmp is None:  # pragma: no cover - 100 collisions of 32 random bits
        raise OutputError(f"{path}: could not create a temporary file in {folder}")
    try:
        try:
            yield tmp
            _sync(tmp, path)
            raise_pending()        # a signal C code swallowed: the file is not put in place
        except BaseException:
            _remove_quietly(tmp)
            raise
        try:
            os.replace(tmp, path)
        except OSError as exc:
            _remove_quietly(tmp)
            if isinstance(exc, FileNotFoundError) and not os.path.exists(tmp):
                raise OutputError(f"{path}: the temporary file {os.path.basename(tmp)} was removed "
                                  "by another program while it was written; nothing was "
                                  "replaced, write it again") from exc
            raise OutputError(f"{path}: cannot replace the file: {exc.strerror or exc}") from exc
    finally:
        _LIVE.pop(tmp, None)
        os.close(fd)       # releases the lock


def _name(born: str, candidate: str) -> bool:
    """Give the locked file ``born`` the name ``candidate``, only if no file has it (a hard
    link, then the first name removed); False if one has. Where hard links are not
    supported, a rename (a 32-bit name collision could then replace another's file)."""
    try:
        os.link(born, candidate)
    except FileExistsError:
        return False
    except OSError:
        os.replace(born, candidate)
        return True
    _remove_quietly(born)
    return True


def _lock(fd: int) -> None:
    """An exclusive lock on the open temporary file (POSIX flock); the system drops it when
    the writer's process ends, however it ends, so a leftover is one nobody locks."""
    if fcntl is not None:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def written_here(tmp: str) -> bool:
    """Whether ``tmp`` is a temporary file of a write in flight in this process (whose own
    lock :func:`writer_gone` sees as another writer's)."""
    return tmp in _LIVE


def writer_gone(tmp: str) -> bool:
    """Whether the process that wrote temporary file ``tmp`` (:func:`atomic_path`) is gone,
    so that the file is a leftover to remove: nobody holds its lock (a file gets its
    temporary name only once locked). A second run to the same output removed a live
    run's file as a leftover, and that run died with a traceback."""
    if fcntl is None:                      # no locks: the old rule, every match is a leftover
        return True
    try:
        fd = os.open(tmp, os.O_RDONLY)
    except OSError:
        return False                       # gone already, or not ours to read
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False                   # locked: its writer lives
        return True
    finally:
        os.close(fd)                       # and with it the lock just taken


def set_attribute(spec: oiio.ImageSpec, name: str, value: object) -> None:
    """Set one header attribute on an ImageSpec, choosing its type.

    Parameters
    ----------
    spec : OpenImageIO.ImageSpec
        The spec to modify.
    name : str
        Attribute name, e.g. ``"chromaticities"`` or ``"worldToCamera"``.
    value : object
        ``int``, ``float``, ``str`` (and numpy scalars) are set directly.
        A ``(TypeDesc, value)`` pair is set with that type. A 4x4 array, or
        16 numbers, becomes a ``matrix``; a 3x3 array a ``matrix33``; any
        other sequence of numbers ``int[n]`` or ``float[n]`` (e.g. the 8
        ``chromaticities``); a sequence of strings ``string[n]``.

    Raises
    ------
    OutputError
        If the value has no representable type.
    """
    if isinstance(value, tuple) and len(value) == 2 and isinstance(value[0], oiio.TypeDesc):
        spec.attribute(name, value[0], value[1])
        return
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        spec.attribute(name, int(value))
        return
    if isinstance(value, (int, float, str)):
        spec.attribute(name, value)
        return
    if isinstance(value, Sequence | np.ndarray) and len(value) > 0:
        if all(isinstance(v, str) for v in value):
            spec.attribute(name, oiio.TypeDesc(f"string[{len(value)}]"), tuple(value))
            return
        arr = np.asarray(value)
        if arr.dtype.kind in "iub" or arr.dtype.kind == "f":
            flat = arr.reshape(-1)
            if arr.shape == (4, 4) or (arr.ndim == 1 and arr.size == 16):
                spec.attribute(name, oiio.TypeDesc("matrix"), tuple(float(v) for v in flat))
            elif arr.shape == (3, 3):
                spec.attribute(name, oiio.TypeDesc("matrix33"), tuple(float(v) for v in flat))
            elif arr.dtype.kind in "iub":
                spec.attribute(name, oiio.TypeDesc(f"int[{flat.size}]"), tuple(int(v) for v in flat))
            else:
                spec.attribute(name, oiio.TypeDesc(f"float[{flat.size}]"), tuple(float(v) for v in flat))
            return
    raise OutputError(f"attribute {name!r}: cannot store a value of type {type(value).__name__} "
                      "in an image header")


#: Rows written per call (a multiple of the EXR compressions' 16- and 32-line
#: blocks): a 4096-wide float RGB strip takes ~0.15 s, so a terminating signal,
#: which Python handles only between calls into OpenImageIO, takes effect within
#: about that long instead of after the whole write (~10 s at 4096×4096).
STRIP_ROWS = 64


def _write_in_strips(out, spec, data: np.ndarray) -> bool:
    """``out.write_image(data)`` in strips of :data:`STRIP_ROWS` rows (whole tile
    rows for a tiled file), so that signals are handled while a large file is written."""
    h = int(spec.height)
    if data.ndim < 3 or h <= STRIP_ROWS:
        return out.write_image(data)
    tile_h = int(spec.tile_height or 0)
    step = STRIP_ROWS if not tile_h else max(1, STRIP_ROWS // tile_h) * tile_h
    for y in range(0, h, step):
        y1 = min(y + step, h)
        if tile_h:
            ok = out.write_tiles(spec.x, spec.x + spec.width, spec.y + y, spec.y + y1,
                                 spec.z, spec.z + max(int(spec.depth), 1), data[y:y1])
        else:
            ok = out.write_scanlines(spec.y + y, spec.y + y1, spec.z, data[y:y1])
        if not ok:
            return False
    return True


def write_image_atomically(display: str, spec, data: np.ndarray, *, what: str = "a writer") -> None:
    """Write ``data`` with ``spec`` to ``display`` through a temporary file.

    The file appears under its name only when open, write and close all
    succeeded and it passes :func:`check_image_written`; otherwise an
    :class:`OutputError` names the step and carries OpenImageIO's message, and
    no file (partial or temporary) is left.
    """
    with atomic_path(display) as tmp:
        out = oiio.ImageOutput.create(tmp)
        if out is None:
            raise OutputError(f"{display}: OpenImageIO cannot create {what}: "
                              f"{_one_line(oiio.geterror())}")
        ok = False
        try:
            if not out.open(tmp, spec):
                raise OutputError(f"{display}: cannot open for writing: {_one_line(out.geterror())}")
            if not _write_in_strips(out, spec, np.ascontiguousarray(data)):
                raise OutputError(f"{display}: writing the pixels failed: {_one_line(out.geterror())}")
            ok = True
        finally:
            closed = out.close()
        if ok and not closed:
            raise OutputError(f"{display}: closing the file failed: {_one_line(out.geterror())}")
        # Writers that failed to write can still return True (and TIFF's sets
        # has_error when all went well): look at the file itself.
        check_image_written(tmp, display)


#: The largest finite half-float value.
HALF_MAX = 65504.0


def _fit_half(data: np.ndarray, display: str, policy: str) -> np.ndarray:
    """Clamp finite values beyond ±HALF_MAX (policy "clamp") or refuse ("error")."""
    import warnings

    if policy not in ("clamp", "error"):
        raise OutputError(f"{display}: half_overflow {policy!r} is not one of clamp, error")
    over = np.isfinite(data) & (np.abs(data) > HALF_MAX)
    n = int(over.sum())
    if not n:
        return data
    peak = float(np.abs(data[over]).max())
    if policy == "error":
        raise OutputError(f"{display}: {n} value(s) exceed the half-float range (max {peak:g} > "
                          f"{HALF_MAX:g}); write float, or lower the exposure")
    warnings.warn(f"{display}: {n} value(s) above the half-float range (max {peak:g}) clamped to "
                  f"±{HALF_MAX:g}", OutputWarning, stacklevel=3)
    return np.clip(data, -HALF_MAX, HALF_MAX)


def write_exr(path: str | os.PathLike, rgb: np.ndarray, *, pixel_type: str = "float",
              compression: str = "zip", attributes: Mapping[str, object] | None = None,
              channel_names: Sequence[str] = ("R", "G", "B"), tiled: bool = False,
              half_overflow: str = "clamp") -> None:
    """Write an image to an OpenEXR file atomically.

    Parameters
    ----------
    path : str or os.PathLike
        Destination ``.exr`` file. It is replaced only if the write succeeds.
    rgb : numpy.ndarray
        (H, W, C) array with ``C == len(channel_names)`` (3 for the default
        R, G, B), or (H, W) when there is one channel name. Converted to
        float32; OpenImageIO rounds to half when ``pixel_type="half"``.
    pixel_type : {"float", "half"}
        Pixel type stored in the file.
    compression : str
        EXR compression (``"zip"``, ``"zips"``, ``"piz"``, ``"none"``,
        ``"dwaa"``, ...), stored as the ``compression`` attribute.
    attributes : mapping, optional
        Header attributes, each applied with :func:`set_attribute` (so
        ``spec.attribute(k, v)`` for scalars and strings), after
        ``compression``.
    channel_names : sequence of str
        Names of the channels, in the order of the last axis of ``rgb``.
    tiled : bool
        Write a tiled file with 64x64 tiles instead of scanlines.
    half_overflow : {"clamp", "error"}
        Finite values beyond the half range (|x| > 65504) would become ±Inf in
        a half file. ``"clamp"`` (default) clamps them to ±65504 and warns
        (:class:`~clphong.core.errors.OutputWarning`, with the count);
        ``"error"`` refuses to write. Never an unannounced Inf.

    Raises
    ------
    OutputError
        One-line message naming ``path``: a name not ending in ``.exr``, a bad
        array shape or pixel type, a missing or read-only folder, or any OpenImageIO failure (with its
        message). No partial file is left behind.
    """
    display = os.fspath(path)
    check_output_path(display, exr=True)
    names = [str(n) for n in channel_names]
    arr = np.asarray(rgb)
    if arr.ndim == 2 and len(names) == 1:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] != len(names) or len(names) == 0:
        raise OutputError(f"{display}: expected an (H, W, {len(names)}) array for channels "
                          f"{','.join(names)}, got shape {arr.shape}")
    if len(set(names)) != len(names):
        raise OutputError(f"{display}: duplicate channel names {','.join(names)}")
    check_pixel_type(pixel_type, display)
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise OutputError(f"{display}: cannot write an empty {arr.shape[1]}x{arr.shape[0]} image")
    data = np.ascontiguousarray(arr, dtype=np.float32)
    if pixel_type == "half":
        data = _fit_half(data, display, half_overflow)
    h, w, c = data.shape

    spec = oiio.ImageSpec(w, h, c, oiio.TypeDesc(pixel_type))
    spec.channelnames = tuple(names)
    spec.alpha_channel = names.index("A") if "A" in names else -1
    spec.attribute("compression", str(compression))
    if tiled:
        spec.tile_width = 64
        spec.tile_height = 64
        spec.tile_depth = 1
    for key, value in (attributes or {}).items():
        set_attribute(spec, str(key), value)
    # A colorInteropID copied from another image's header (OpenImageIO keeps the
    # source's on converted buffers) would mislabel the file: drop it, and
    # OpenImageIO writes the one that matches oiio:ColorSpace.
    spec.erase_attribute("colorInteropID")

    write_image_atomically(display, spec, data, what="an EXR writer")

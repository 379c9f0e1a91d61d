"""File kinds by their first bytes and by their names."""

from __future__ import annotations

import os

__all__ = ["image_signature", "image_kind", "not_regular", "open_regular"]

#: Magic numbers of the image files a scene argument (or an EXR input) is most
#: often confused with.
_IMAGE_MAGIC = (
    (b"\x76\x2f\x31\x01", "an OpenEXR"),
    (b"\x89PNG\r\n\x1a\n", "a PNG"),
    (b"II*\x00", "a TIFF"), (b"MM\x00*", "a TIFF"),
    (b"\xff\xd8\xff", "a JPEG"),
    (b"\xff\x0a", "a JPEG XL"), (b"\x00\x00\x00\x0cJXL \r\n\x87\n", "a JPEG XL"),
    (b"GIF8", "a GIF"), (b"BM", "a BMP"),
)


def image_signature(raw: bytes) -> str | None:
    """'an OpenEXR', 'a PNG' (etc.) when ``raw`` starts with that format's magic number."""
    return next((kind for magic, kind in _IMAGE_MAGIC if raw.startswith(magic)), None)
IMAGE_EXTENSIONS = {".exr": "an OpenEXR", ".png": "a PNG", ".tif": "a TIFF", ".tiff": "a TIFF",
                     ".jpg": "a JPEG", ".jpeg": "a JPEG", ".jxl": "a JPEG XL", ".hdr": "a Radiance HDR"}


def image_kind(source: str, raw: bytes) -> str | None:
    """'an OpenEXR' (etc.) when ``raw`` is an image file (magic bytes), or is not
    UTF-8 and named like one; None otherwise (a scene, or a bad scene)."""
    kind = image_signature(raw)
    if kind is not None:
        return kind
    kind = IMAGE_EXTENSIONS.get(os.path.splitext(source)[1].lower())
    if kind is not None:
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError:
            return kind
    return None


def _kind_of_mode(mode: int) -> str:
    import stat

    for test, kind in ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


def not_regular(path) -> str | None:
    """What ``path`` is when it exists and is not a regular file ("a FIFO (named
    pipe)", "a character device", "a directory", ...), following links; None for a
    regular file or a path that does not exist (the open then says so)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    return None if stat.S_ISREG(mode) else _kind_of_mode(mode)


def open_regular(path, error, what: str):
    """Open ``path`` for reading in binary only if it is a regular file: opened
    without blocking (a FIFO would wait for a writer forever), then checked on
    the open descriptor. Anything else raises ``error`` (an exception class) with
    one line ``"<path>: cannot read <what>: it is a FIFO (named pipe); give a
    regular file"``; other failures are the OSError of the open."""
    import stat

    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise error(f"{os.fsdecode(path)}: cannot read {what}: it is {_kind_of_mode(mode)}; "
                        "give a regular file")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise

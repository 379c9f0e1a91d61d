"""File kinds by their first bytes and by their names."""

from __future__ import annotations

import os

__all__ = ["image_signature", "image_kind"]

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

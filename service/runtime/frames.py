"""The encoded inputs of one detection (:class:`Frame`) and the checks made before decoding.

Reading an image's size from its PNG or JPEG header is cheap, so a transport can refuse a
huge image (413) on its own thread before any worker decodes it.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas import DetectParams
from service.runtime.errors import RequestError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@dataclass(frozen=True)
class Frame:
    """The encoded inputs of one detection, as they arrived."""

    image: bytes
    params: DetectParams
    mask: bytes | None = None


def check_declared_size(data: bytes, max_pixels: int) -> None:
    """413 when the PNG/JPEG header announces more than ``max_pixels`` pixels."""
    size = image_size(data)
    if size is not None:
        check_pixels(*size, max_pixels)


def check_pixels(width: int, height: int, max_pixels: int) -> None:
    """413 ``image_too_large`` when ``width x height`` is more than ``max_pixels``."""
    if width * height > max_pixels:
        raise RequestError(
            413,
            "image_too_large",
            f"image is {width}x{height} = {width * height / 1e6:.1f} megapixels, "
            f"more than the limit of {max_pixels / 1e6:g}",
        )


def image_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG or JPEG header, without decoding; None otherwise.

    Lets a huge image be refused (413) before it is decoded. Other formats, and headers
    this does not understand, are checked after decoding instead.
    """
    if data.startswith(PNG_SIGNATURE) and data[12:16] == b"IHDR" and len(data) >= 24:
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data.startswith(b"\xff\xd8"):
        return _jpeg_size(data)
    return None


_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""Start-of-frame markers (baseline, progressive, lossless...): they hold the size."""


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    position = 2
    while position + 4 <= len(data):
        if data[position] != 0xFF:
            return None
        marker = data[position + 1]
        if marker == 0xFF:  # fill byte
            position += 1
            continue
        if 0xD0 <= marker <= 0xD9 or marker == 0x01:  # markers without a payload
            position += 2
            continue
        length = int.from_bytes(data[position + 2 : position + 4], "big")
        if marker in _JPEG_FRAME_MARKERS:
            if position + 9 > len(data):
                return None
            height = int.from_bytes(data[position + 5 : position + 7], "big")
            width = int.from_bytes(data[position + 7 : position + 9], "big")
            return width, height
        if marker == 0xDA or length < 2:  # scan data before any frame header: give up
            return None
        position += 2 + length
    return None

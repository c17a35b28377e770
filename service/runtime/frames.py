"""The encoded inputs of one detection (:class:`Frame`) and the checks made before decoding.

Reading an image's size from its PNG or JPEG header is cheap, so a transport can refuse a
huge image (413) on its own thread before any worker decodes it. Every upload the service
decodes (image, mask, depth image) is checked so (:func:`check_upload`): the service takes
PNG and JPEG only, the two formats whose size it reads from the header, so that nothing
(say a 100 KB PNG that claims 30000x30000 pixels, 5 GB once decoded) is decompressed
before it is known to fit.
"""

from __future__ import annotations

from dataclasses import dataclass

from schemas import DetectParams
from service.imageio import (
    JPEG_SIGNATURE,
    PNG_SIGNATURE,
    image_size,
    jpeg_is_complete,
    png_is_complete,
)
from service.runtime.errors import RequestError

__all__ = ["PNG_SIGNATURE", "Frame", "check_frame", "check_pixels", "check_upload", "image_size"]

_OTHER_IMAGE_SIGNATURES = (
    (b"BM", "BMP"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"GIF8", "GIF"),
    (b"\x00\x00\x00\x0cjP  ", "JPEG 2000"),
    (b"\xff\x4f\xff\x51", "JPEG 2000"),
    (b"#?RADIANCE", "Radiance HDR"),
    (b"\x76\x2f\x31\x01", "OpenEXR"),
)
"""Leading bytes of image formats OpenCV could decode but the service does not take."""


@dataclass(frozen=True)
class Frame:
    """The encoded inputs of one detection, as they arrived."""

    image: bytes
    params: DetectParams
    mask: bytes | None = None


def check_frame(frame: Frame, max_pixels: int) -> None:
    """:func:`check_upload` of the image and the mask, and their sizes compared: all
    from the headers, before anything is decoded.

    Raises
    ------
    RequestError
        As :func:`check_upload`; 422 ``invalid_mask`` for a mask declaring another size
        than the image.
    """
    image = check_upload(frame.image, "image", max_pixels)
    if frame.mask is None:
        return
    mask = check_upload(frame.mask, "mask", max_pixels)
    if image is not None and mask is not None and mask != image:
        raise RequestError(
            422,
            "invalid_mask",
            f"mask: mask is {mask[0]}x{mask[1]} but the image is {image[0]}x{image[1]}",
        )


def check_upload(data: bytes, name: str, max_pixels: int) -> tuple[int, int] | None:
    """Check an uploaded image from its header alone, before it is ever decoded.

    Parameters
    ----------
    data : bytes
        The encoded upload.
    name : str
        What it is (``image``, ``mask``, ``depth``): messages and error codes say it.
    max_pixels : int
        The most pixels it may have.

    Returns
    -------
    (width, height) or None
        The size its header declares; None for an empty upload (the decoder says so).

    Raises
    ------
    RequestError
        413 ``<name>_too_large`` over ``max_pixels``; 415 ``unsupported_media_type`` for
        an image format other than PNG and JPEG; 422 ``invalid_<name>`` for a PNG or JPEG
        whose header gives no size, or for bytes that are no image at all.
    """
    if not data:
        return None
    size = image_size(data)
    if size is not None:
        check_pixels(*size, max_pixels, name)
        return size
    if data.startswith(PNG_SIGNATURE) or data.startswith(JPEG_SIGNATURE):
        kind = "PNG" if data.startswith(PNG_SIGNATURE) else "JPEG"
        whole = png_is_complete(data) if kind == "PNG" else jpeg_is_complete(data)
        problem = "damaged {} file: its header gives no size" if whole else "truncated {} file"
        raise RequestError(422, f"invalid_{name}", f"{name}: {problem.format(kind)}")
    other = next((kind for start, kind in _OTHER_IMAGE_SIGNATURES if data.startswith(start)), None)
    if other is None and data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        other = "WebP"
    if other is not None:
        raise RequestError(
            415,
            "unsupported_media_type",
            f"{name}: a {other} file; the service takes PNG and JPEG (their size is checked "
            "before they are decoded): convert it",
        )
    raise RequestError(
        422, f"invalid_{name}", f"{name}: not an image (the service takes PNG and JPEG)"
    )


def check_pixels(width: int, height: int, max_pixels: int, name: str = "image") -> None:
    """413 ``<name>_too_large`` when ``width x height`` is more than ``max_pixels``."""
    if width * height > max_pixels:
        raise RequestError(
            413,
            f"{name}_too_large",
            f"{name} is {width}x{height} = {width * height / 1e6:.1f} megapixels, "
            f"more than the limit of {max_pixels / 1e6:g}",
        )

"""Reading images and masks from files or memory (uploads), writing PNGs, expanding paths.

Every problem with an input file becomes an :class:`ImageFileError` (an
:class:`~service.perception.InvalidInputError`) whose one-line message names the
file and the problem, e.g. ``img.png: truncated PNG file``. Nothing from OpenCV
or the operating system leaks out as another exception type.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterable, Iterator
from pathlib import Path

import cv2
import numpy as np

from service.perception import InvalidInputError

IMAGE_SUFFIXES = (".bmp", ".jpeg", ".jpg", ".png", ".tif", ".tiff", ".webp")
"""File name endings (lower case) that :func:`list_images` picks from a directory."""

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SIGNATURE = b"\xff\xd8\xff"

_DECODE_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH
"""Three BGR channels (grey expanded, alpha dropped, EXIF orientation applied), and
16-bit samples kept as 16-bit so that they can be scaled rather than truncated."""


class ImageFileError(InvalidInputError):
    """An input file cannot be used; ``str()`` is ``"<path>: <problem>"``.

    Parameters
    ----------
    path : str or Path
        The offending file, as the caller named it.
    problem : str
        What is wrong with it, one line, lower case.
    """

    def __init__(self, path: str | os.PathLike[str], problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{path}: {problem}")


class OutputWriteError(OSError):
    """An output file cannot be written; ``str()`` names the file and the reason."""


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file as a BGR ``uint8`` array.

    Grey images are expanded to three channels, an alpha channel is dropped,
    16-bit samples are scaled to 8 bits (``round(v / 257)``, the full 16-bit range
    onto the full 8-bit range) and the EXIF orientation of JPEGs is applied.

    Parameters
    ----------
    path : str or Path
        The image file (PNG, JPEG, BMP, TIFF, WebP or anything else OpenCV decodes).

    Returns
    -------
    np.ndarray
        ``(H, W, 3)`` ``uint8`` array in BGR order.

    Raises
    ------
    ImageFileError
        The file is missing, a directory, unreadable, empty, not an image,
        truncated, or decodes to an image without pixels.
    """
    image, _ = _decode_file(path)
    return _to_uint8(path, image)


def read_mask(path: str | os.PathLike[str], shape: tuple[int, ...]) -> np.ndarray:
    """Read a foreground mask file as a boolean array of the image's size.

    A pixel is foreground when any channel is non-zero; in JPEG masks, whose
    compression smears the edges, when any channel is above half the range.

    Parameters
    ----------
    path : str or Path
        The mask file, any format :func:`read_image` accepts.
    shape : tuple of int
        Shape of the image the mask belongs to; only ``shape[:2]`` (H, W) is used.

    Returns
    -------
    np.ndarray
        ``(H, W)`` ``bool`` array, True on the cable(s).

    Raises
    ------
    ImageFileError
        The file cannot be read as an image, or its size differs from ``shape``.
    """
    image, is_jpeg = _decode_file(path)
    return _binary_mask(path, image, is_jpeg, shape)


def decode_image(data: bytes, name: str = "image") -> np.ndarray:
    """Decode an encoded image held in memory (an upload) as :func:`read_image` does a file.

    Parameters
    ----------
    data : bytes
        The encoded image (PNG, JPEG, or anything else OpenCV decodes).
    name : str
        What to call the input in error messages, e.g. ``"image"``.

    Returns
    -------
    np.ndarray
        ``(H, W, 3)`` ``uint8`` array in BGR order.

    Raises
    ------
    ImageFileError
        ``data`` is empty, not an image, truncated, or decodes to no pixels;
        ``str()`` is ``"<name>: <problem>"``.
    """
    image, _ = _decode_buffer(name, np.frombuffer(data, dtype=np.uint8))
    return _to_uint8(name, image)


def decode_mask(data: bytes, shape: tuple[int, ...], name: str = "mask") -> np.ndarray:
    """Decode a mask held in memory as :func:`read_mask` reads a file.

    Raises
    ------
    ImageFileError
        ``data`` cannot be decoded, or its size differs from ``shape``.
    """
    image, is_jpeg = _decode_buffer(name, np.frombuffer(data, dtype=np.uint8))
    return _binary_mask(name, image, is_jpeg, shape)


def _binary_mask(
    name: str | os.PathLike[str], image: np.ndarray, is_jpeg: bool, shape: tuple[int, ...]
) -> np.ndarray:
    height, width = shape[:2]
    if image.shape[:2] != (height, width):
        raise ImageFileError(
            name,
            f"mask is {image.shape[1]}x{image.shape[0]} but the image is {width}x{height}",
        )
    if image.dtype.kind == "f":
        threshold = 0.5 if is_jpeg else 0.0
    else:
        threshold = np.iinfo(image.dtype).max // 2 if is_jpeg else 0
    return np.asarray(image.max(axis=2) > threshold)


def write_png(path: str | os.PathLike[str], array: np.ndarray) -> None:
    """Write ``array`` to ``path`` as a PNG file, atomically.

    Parameters
    ----------
    path : str or Path
        Destination; its directory must exist. An existing file is replaced.
    array : np.ndarray
        ``uint8`` or ``uint16`` image, ``(H, W)`` or ``(H, W, C)`` with C in 1, 3, 4
        (BGR(A) order).

    Raises
    ------
    ValueError
        ``array`` has a type or shape PNG cannot hold.
    OutputWriteError
        The file cannot be written (missing directory, permissions, full disk...).
    """
    array = np.asarray(array)
    if array.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"PNG holds uint8 or uint16 samples, not {array.dtype}")
    if array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] not in (1, 3, 4)):
        raise ValueError(f"PNG cannot hold an array of shape {array.shape}")
    if array.size == 0:
        raise ValueError("PNG cannot hold an image without pixels")
    try:
        encoded_ok, encoded = cv2.imencode(".png", array)
    except cv2.error as exc:
        raise OutputWriteError(f"cannot encode {path} as PNG: {_one_line(exc)}") from exc
    if not encoded_ok:
        raise OutputWriteError(f"cannot encode {path} as PNG")
    _write_atomically(path, encoded.tobytes())


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically.

    Raises
    ------
    OutputWriteError
        The file cannot be written.
    """
    _write_atomically(path, text.encode("utf-8"))


def list_images(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Expand directories into the image files they hold.

    Parameters
    ----------
    paths : iterable of str or Path
        Files and directories, in the order given.

    Returns
    -------
    list of Path
        For a directory: its files whose name ends in one of :data:`IMAGE_SUFFIXES`
        (any case), sorted by name, not recursing and skipping hidden files. Any
        other path is kept as given, even when it does not exist or has an odd
        extension, so that reading it reports the problem for that file alone.
    """
    images: list[Path] = []
    for path in map(Path, paths):
        if path.is_dir():
            images.extend(_images_in_directory(path))
        else:
            images.append(path)
    return images


def _images_in_directory(directory: Path) -> list[Path]:
    try:
        entries = list(directory.iterdir())
    except OSError:
        return []
    return sorted(
        entry
        for entry in entries
        if entry.suffix.lower() in IMAGE_SUFFIXES
        and not entry.name.startswith(".")
        and entry.is_file()
    )


def _decode_file(path: str | os.PathLike[str]) -> tuple[np.ndarray, bool]:
    """Read and decode ``path`` with :data:`_DECODE_FLAGS`, checking every failure.

    Returns the ``(H, W, 3)`` image (any depth) and whether the file is a JPEG.
    """
    file_path = Path(path)
    if not file_path.exists():
        raise ImageFileError(path, "no such file or directory")
    if file_path.is_dir():
        raise ImageFileError(path, "is a directory, not an image file")
    try:
        buffer = np.fromfile(file_path, dtype=np.uint8)
    except OSError as exc:
        raise ImageFileError(path, f"cannot read: {exc.strerror or exc}") from exc
    return _decode_buffer(path, buffer)


def _decode_buffer(name: str | os.PathLike[str], buffer: np.ndarray) -> tuple[np.ndarray, bool]:
    """Decode ``buffer`` (``uint8`` encoded bytes) read from ``name``; as :func:`_decode_file`."""
    path = name
    if buffer.size == 0:
        raise ImageFileError(path, "empty file (0 bytes)")

    head = buffer[:8].tobytes()
    is_jpeg = head.startswith(JPEG_SIGNATURE)
    if head.startswith(PNG_SIGNATURE) and not _png_is_complete(buffer.tobytes()):
        raise ImageFileError(path, "truncated PNG file")
    if is_jpeg and not _jpeg_is_complete(buffer.tobytes()):
        raise ImageFileError(path, "truncated JPEG file")

    try:
        with _opencv_quiet():
            image = cv2.imdecode(buffer, _DECODE_FLAGS)
    except cv2.error as exc:
        raise ImageFileError(path, f"cannot decode image: {_one_line(exc)}") from exc
    if image is None:
        raise ImageFileError(path, "not an image, or a format OpenCV cannot decode")
    if image.size == 0:
        raise ImageFileError(path, "empty image (no pixels)")
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return image, is_jpeg


def _to_uint8(path: str | os.PathLike[str], image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        return np.round(image / 257.0).astype(np.uint8)
    if image.dtype.kind == "f":
        finite = np.nan_to_num(image.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        scale = 255.0 if finite.max(initial=0.0) <= 1.0 else 1.0
        return np.clip(np.round(finite * scale), 0, 255).astype(np.uint8)
    raise ImageFileError(path, f"unsupported sample type {image.dtype}")


def _png_is_complete(data: bytes) -> bool:
    """Walk the PNG chunks; True when the IEND chunk is reached whole."""
    position = len(PNG_SIGNATURE)
    while position + 8 <= len(data):
        chunk_length = int.from_bytes(data[position : position + 4], "big")
        chunk_type = data[position + 4 : position + 8]
        chunk_end = position + 12 + chunk_length  # length, type, data, CRC
        if chunk_type == b"IEND":
            return chunk_end <= len(data)
        position = chunk_end
    return False


def _jpeg_is_complete(data: bytes) -> bool:
    """Walk the JPEG markers; True when the end-of-image marker (FFD9) is reached.

    Data after the end-of-image marker (camera trailers) is allowed. When the
    layout is not what the walk expects, the file is given the benefit of the doubt
    (True) and left to the decoder; False means the data runs out before FFD9.
    """
    size = len(data)
    position = 2  # after the start-of-image marker FFD8
    while True:
        if position >= size:
            return False
        if data[position] != 0xFF:
            return True
        while position < size and data[position] == 0xFF:  # fill bytes
            position += 1
        if position >= size:
            return False
        marker = data[position]
        position += 1
        if marker == 0xD9:
            return True
        if 0xD0 <= marker <= 0xD7 or marker in (0x01, 0xD8):
            continue  # markers without a payload
        if position + 2 > size:
            return False
        segment_length = int.from_bytes(data[position : position + 2], "big")
        if segment_length < 2:
            return True
        position += segment_length
        if marker == 0xDA:  # start of scan: entropy-coded data up to the next marker
            position = _end_of_entropy_coded_data(data, position)
            if position < 0:
                return False


def _end_of_entropy_coded_data(data: bytes, position: int) -> int:
    """Index of the first marker after ``position`` that ends a scan, or -1."""
    while True:
        position = data.find(b"\xff", position)
        if position < 0 or position + 1 >= len(data):
            return -1
        following = data[position + 1]
        if following == 0x00 or 0xD0 <= following <= 0xD7:  # stuffed byte, restart
            position += 2
            continue
        return position


def _write_atomically(path: str | os.PathLike[str], data: bytes) -> None:
    """Write to a hidden sibling file, then rename it over ``path``."""
    destination = Path(path)
    temporary = destination.with_name(f".{destination.name}.{os.getpid()}.tmp")
    try:
        with open(temporary, "wb") as stream:
            stream.write(data)
        os.replace(temporary, destination)
    except OSError as exc:
        with contextlib.suppress(OSError):
            temporary.unlink(missing_ok=True)
        raise OutputWriteError(f"cannot write {path}: {exc.strerror or exc}") from exc


@contextlib.contextmanager
def _opencv_quiet() -> Iterator[None]:
    """Silence OpenCV's own log lines (the caller reports problems itself)."""
    previous = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        cv2.utils.logging.setLogLevel(previous)


def _one_line(exc: BaseException) -> str:
    text = " ".join(line.strip() for line in str(exc).splitlines() if line.strip())
    return text or type(exc).__name__

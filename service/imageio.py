"""Reading images and masks from files or memory (uploads), writing PNGs, expanding paths.

Every problem with an input file becomes an :class:`ImageFileError` (an
:class:`~service.perception.InvalidInputError`) whose one-line message names the
file and the problem, e.g. ``img.png: truncated PNG file``. Nothing from OpenCV
or the operating system leaks out as another exception type.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys
import tempfile
import threading
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

PNG_MAX_SIDE = 1_000_000
"""The longest side libpng decodes (its default user limit); checked from the header."""
DECODER_MAX_SIDE = int(os.environ.get("OPENCV_IO_MAX_IMAGE_WIDTH", 1 << 20))
DECODER_MAX_PIXELS = int(os.environ.get("OPENCV_IO_MAX_IMAGE_PIXELS", 1 << 30))
"""OpenCV's limits on what it decodes (its defaults, or the variables that set them)."""


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
    image, is_jpeg = _decode_file(path, shape)
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
        ``data`` cannot be decoded, or its size differs from ``shape`` (from its PNG or
        JPEG header, before decoding, when it has one).
    """
    image, is_jpeg = _decode_buffer(name, np.frombuffer(data, dtype=np.uint8), shape)
    return _binary_mask(name, image, is_jpeg, shape)


def _binary_mask(
    name: str | os.PathLike[str], image: np.ndarray, is_jpeg: bool, shape: tuple[int, ...]
) -> np.ndarray:
    _check_mask_size(name, image.shape[1], image.shape[0], shape)
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
            images.extend(images_in_directory(path)[0])
        else:
            images.append(path)
    return images


def images_in_directory(directory: str | os.PathLike[str]) -> tuple[list[Path], list[str]]:
    """The image files of one directory, and what was passed over that a user may miss.

    Returns
    -------
    images : list of Path
        As :func:`list_images` expands a directory: files whose name ends in one of
        :data:`IMAGE_SUFFIXES`, sorted by name, hidden ones and subdirectories left out.
    skipped : list of str
        One line per subdirectory (not searched) and per broken symbolic link with an
        image's name, e.g. ``shots/old: a folder, not searched (name it to include it)``.
    """
    directory = Path(directory)
    try:
        entries = sorted(directory.iterdir())
    except OSError:
        return [], []
    images, skipped = [], []
    for entry in entries:
        if entry.name.startswith("."):
            continue
        if entry.is_dir():
            skipped.append(f"{entry}: a folder, not searched (name it to include it)")
        elif entry.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        elif entry.is_file():
            images.append(entry)
        elif entry.is_symlink() and not entry.exists():
            skipped.append(f"{entry}: broken symbolic link (to {os.readlink(entry)}), skipped")
    return images, skipped


def _check_mask_size(
    name: str | os.PathLike[str], width: int, height: int, shape: tuple[int, ...]
) -> None:
    if (height, width) != tuple(shape[:2]):
        raise ImageFileError(
            name, f"mask is {width}x{height} but the image is {shape[1]}x{shape[0]}"
        )


def _decode_file(
    path: str | os.PathLike[str], mask_of: tuple[int, ...] | None = None
) -> tuple[np.ndarray, bool]:
    """Read and decode ``path`` with :data:`_DECODE_FLAGS`, checking every failure.

    Returns the ``(H, W, 3)`` image (any depth) and whether the file is a JPEG. What the
    image libraries print on stderr meanwhile (libpng's warnings) is kept off the terminal
    and, when decoding fails, said in the error instead.
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
    failure = None
    with _native_stderr_kept() as native_lines:
        try:
            decoded = _decode_buffer(path, buffer, mask_of)
        except ImageFileError as exc:
            failure = exc
    if failure is None:
        return decoded
    if not native_lines:
        raise failure
    said = "; ".join(native_lines)  # e.g. "libpng error: IDAT: CRC error"
    head = buffer[:8].tobytes()
    kind = (
        "PNG"
        if head.startswith(PNG_SIGNATURE)
        else "JPEG"
        if head.startswith(JPEG_SIGNATURE)
        else ""
    )
    problem = (
        f"damaged {kind} file"
        if kind and failure.problem.startswith("not an image")
        else failure.problem
    )
    raise ImageFileError(path, f"{problem} ({said})")


def _decode_buffer(
    name: str | os.PathLike[str], buffer: np.ndarray, mask_of: tuple[int, ...] | None = None
) -> tuple[np.ndarray, bool]:
    """Decode ``buffer`` (``uint8`` encoded bytes) read from ``name``; as :func:`_decode_file`.

    The size a PNG or JPEG header declares is checked first, against the decoders' limits
    and, for the mask of an image of ``mask_of`` shape, against that image's: nothing too
    large for the decoder, and no mask of the wrong size, is ever decompressed.
    """
    path = name
    if buffer.size == 0:
        raise ImageFileError(path, "empty file (0 bytes)")

    head = buffer[:8].tobytes()
    is_jpeg = head.startswith(JPEG_SIGNATURE)
    if head.startswith(PNG_SIGNATURE) and not png_is_complete(buffer.tobytes()):
        raise ImageFileError(path, "truncated PNG file")
    if is_jpeg and not jpeg_is_complete(buffer.tobytes()):
        raise ImageFileError(path, "truncated JPEG file")
    declared = image_size(buffer[:65536].tobytes())
    if declared is not None:
        _check_decodable(path, *declared, is_png=head.startswith(PNG_SIGNATURE))
        if mask_of is not None:
            _check_mask_size(path, *declared, mask_of)

    try:
        with _opencv_quiet():
            image = cv2.imdecode(buffer, _DECODE_FLAGS)
    except cv2.error as exc:
        raise ImageFileError(path, _decoder_problem(exc)) from exc
    if image is None:
        raise ImageFileError(path, "not an image, or a format OpenCV cannot decode")
    if image.size == 0:
        raise ImageFileError(path, "empty image (no pixels)")
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    return image, is_jpeg


def image_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` from a PNG or JPEG header, without decoding; None otherwise.

    Lets a huge image be refused before it is decoded (the service's 413, the decoder's
    limits in :func:`read_image`). None for other formats and for headers this does not
    understand.
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


def _check_decodable(path: str | os.PathLike[str], width: int, height: int, is_png: bool) -> None:
    """One-line errors, from the header, for images the decoders would refuse or choke on."""
    size = f"image is {width}x{height} px"
    if width == 0 or height == 0:
        raise ImageFileError(path, f"{size}: empty image (no pixels)")
    if is_png and max(width, height) > PNG_MAX_SIDE:
        raise ImageFileError(
            path, f"{size}: too large, the PNG decoder takes at most {PNG_MAX_SIDE} px a side"
        )
    if max(width, height) > DECODER_MAX_SIDE or width * height > DECODER_MAX_PIXELS:
        raise ImageFileError(path, f"{size}: {_too_large_to_decode()}")


def _too_large_to_decode() -> str:
    return (
        f"too large to decode (at most {DECODER_MAX_PIXELS / 1e6:.1f} megapixels and "
        f"{DECODER_MAX_SIDE} px a side)"
    )


def _decoder_problem(exc: cv2.error) -> str:
    """OpenCV's exception as a problem statement, without its source file and line."""
    text = _one_line(exc)
    if "validateInputImageSize" in text:
        return f"image {_too_large_to_decode()}"
    # "OpenCV(5.0.0) /io/opencv/.../loadsave.cpp:79: error: (-215:Assertion failed) x in
    # function 'f'" -> "x"
    match = re.search(r"error: \([-\d]+:[^)]*\) (.*?)(?: in function '[^']*')?$", text)
    return f"cannot decode image: {match.group(1) if match else text}"


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


def png_is_complete(data: bytes) -> bool:
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


def jpeg_is_complete(data: bytes) -> bool:
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


_NATIVE_STDERR_LOCK = threading.Lock()


@contextlib.contextmanager
def _native_stderr_kept() -> Iterator[list[str]]:
    """Keep what C libraries (libpng, libjpeg) write to file descriptor 2 meanwhile.

    Yields a list that holds those lines, stripped, once the block ends. Used around
    decoding a file (the command line's inputs), where libpng prints warnings such as
    ``libpng warning: iCCP: known incorrect sRGB profile`` straight to the terminal; the
    service decodes uploads from memory without it (other threads write to stderr too).
    """
    lines: list[str] = []
    with _NATIVE_STDERR_LOCK, tempfile.TemporaryFile() as sink:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (AttributeError, OSError, ValueError):  # no file descriptor 2 to borrow
            yield lines
            return
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", errors="replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())


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

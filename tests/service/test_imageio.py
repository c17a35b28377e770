"""Reading images and masks, writing PNGs and expanding input paths."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from service.imageio import (
    ImageFileError,
    OutputWriteError,
    list_images,
    read_image,
    read_mask,
    write_png,
)
from service.perception import InvalidInputError


def cable_picture(width: int = 96, height: int = 64) -> np.ndarray:
    """A bright thick curve on a dark background, BGR uint8."""
    image = np.full((height, width, 3), 20, np.uint8)
    curve = np.array([[5, 10], [30, 50], [60, 20], [90, 55]], np.int32)
    cv2.polylines(image, [curve], isClosed=False, color=(200, 220, 240), thickness=7)
    return image


def encoded(image: np.ndarray, extension: str) -> bytes:
    encode_ok, data = cv2.imencode(extension, image)
    assert encode_ok
    return data.tobytes()


def write_bytes(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_png_round_trip_is_exact(tmp_path: Path) -> None:
    image = cable_picture()
    path = write_bytes(tmp_path / "cable.png", encoded(image, ".png"))
    loaded = read_image(path)
    assert loaded.dtype == np.uint8
    np.testing.assert_array_equal(loaded, image)


def test_jpeg_is_decoded_to_bgr(tmp_path: Path) -> None:
    path = write_bytes(tmp_path / "cable.jpg", encoded(cable_picture(), ".jpg"))
    loaded = read_image(path)
    assert loaded.shape == (64, 96, 3)
    assert loaded.dtype == np.uint8


def test_jpeg_with_data_after_the_end_marker_is_accepted(tmp_path: Path) -> None:
    path = write_bytes(tmp_path / "trailer.jpg", encoded(cable_picture(), ".jpg") + b"TRAILER")
    assert read_image(path).shape == (64, 96, 3)


def test_grey_image_gets_three_channels(tmp_path: Path) -> None:
    grey = cv2.cvtColor(cable_picture(), cv2.COLOR_BGR2GRAY)
    path = write_bytes(tmp_path / "grey.png", encoded(grey, ".png"))
    loaded = read_image(path)
    assert loaded.shape == (64, 96, 3)
    np.testing.assert_array_equal(loaded[:, :, 1], grey)


def test_sixteen_bit_image_is_scaled_to_eight_bits(tmp_path: Path) -> None:
    deep = np.zeros((4, 5), np.uint16)
    deep[0, 0] = 65535
    deep[1, 1] = 257 * 100
    path = write_bytes(tmp_path / "deep.png", encoded(deep, ".png"))
    loaded = read_image(path)
    assert loaded.dtype == np.uint8
    assert loaded[0, 0].tolist() == [255, 255, 255]
    assert loaded[1, 1].tolist() == [100, 100, 100]
    assert loaded[2, 2].tolist() == [0, 0, 0]


def test_alpha_channel_is_dropped(tmp_path: Path) -> None:
    image = cable_picture()
    with_alpha = np.dstack([image, np.full(image.shape[:2], 128, np.uint8)])
    path = write_bytes(tmp_path / "alpha.png", encoded(with_alpha, ".png"))
    np.testing.assert_array_equal(read_image(path), image)


PNG_BYTES = encoded(cable_picture(), ".png")
JPEG_BYTES = encoded(cable_picture(), ".jpg")

UNUSABLE_FILES = {
    # case: (file name, content: bytes, "dir" or None for no file, words of the message)
    "missing": ("missing.png", None, "no such file"),
    "directory": ("folder.png", "dir", "directory"),
    "zero bytes": ("empty.png", b"", "empty file"),
    "text": ("notes.png", b"just some text\n", "not an image"),
    "truncated png": ("cut.png", PNG_BYTES[: len(PNG_BYTES) // 2], "truncated PNG"),
    "png without its end": ("noend.png", PNG_BYTES[:-12], "truncated PNG"),
    "truncated jpeg": ("cut.jpg", JPEG_BYTES[: len(JPEG_BYTES) // 2], "truncated JPEG"),
    "jpeg without its end": ("noend.jpg", JPEG_BYTES[:-2], "truncated JPEG"),
}


@pytest.mark.parametrize("case", sorted(UNUSABLE_FILES))
def test_unusable_file_gives_one_line_error_naming_it(tmp_path: Path, case: str) -> None:
    name, content, expected_words = UNUSABLE_FILES[case]
    path = tmp_path / name
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content)
    with pytest.raises(ImageFileError) as caught:
        read_image(path)
    message = str(caught.value)
    assert isinstance(caught.value, InvalidInputError)
    assert message.startswith(f"{path}: ")
    assert expected_words in message
    assert "\n" not in message
    assert caught.value.path == path


def test_mask_is_boolean_and_true_where_non_zero(tmp_path: Path) -> None:
    mask = np.zeros((64, 96), np.uint8)
    mask[10:20, 30:40] = 1
    path = write_bytes(tmp_path / "mask.png", encoded(mask, ".png"))
    loaded = read_mask(path, (64, 96, 3))
    assert loaded.dtype == bool
    np.testing.assert_array_equal(loaded, mask > 0)


def test_jpeg_mask_ignores_compression_noise(tmp_path: Path) -> None:
    mask = np.zeros((64, 96), np.uint8)
    mask[10:40, 30:70] = 255
    path = write_bytes(tmp_path / "mask.jpg", encoded(mask, ".jpg"))
    loaded = read_mask(path, (64, 96))
    assert loaded[15:35, 35:65].all()
    assert not loaded[50:, :].any()


def test_mask_of_another_size_is_refused(tmp_path: Path) -> None:
    path = write_bytes(tmp_path / "mask.png", encoded(np.zeros((10, 20), np.uint8), ".png"))
    with pytest.raises(ImageFileError, match=r"mask is 20x10 but the image is 96x64") as caught:
        read_mask(path, (64, 96, 3))
    assert str(caught.value).startswith(f"{path}: ")


def test_write_png_keeps_sixteen_bits(tmp_path: Path) -> None:
    labels = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    path = tmp_path / "labels.png"
    write_png(path, labels)
    loaded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert loaded.dtype == np.uint16
    np.testing.assert_array_equal(loaded, labels)
    assert [entry.name for entry in tmp_path.iterdir()] == ["labels.png"]


def test_write_png_into_a_missing_directory_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere" / "out.png"
    with pytest.raises(OutputWriteError, match=r"cannot write .*out\.png"):
        write_png(path, np.zeros((2, 2), np.uint8))


def test_write_png_refuses_arrays_png_cannot_hold(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="float"):
        write_png(tmp_path / "x.png", np.zeros((2, 2), np.float32))


def test_list_images_expands_directories_and_keeps_explicit_paths(tmp_path: Path) -> None:
    folder = tmp_path / "folder"
    (folder / "nested").mkdir(parents=True)
    for name in ("b.jpg", "a.PNG", "c.tiff", "notes.txt", ".hidden.png", "nested/deep.png"):
        (folder / name).write_bytes(b"x")
    odd = tmp_path / "picture.dat"
    odd.write_bytes(b"x")
    missing = tmp_path / "missing.png"

    found = list_images([folder, odd, missing])

    assert found == [folder / "a.PNG", folder / "b.jpg", folder / "c.tiff", odd, missing]


def with_thumbnail_segment(jpeg: bytes) -> bytes:
    """``jpeg`` with an APP1 segment holding a complete small JPEG, as EXIF does."""
    thumbnail = encoded(cable_picture(16, 12), ".jpg")
    payload = b"Exif\x00\x00" + thumbnail
    segment = b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload
    return jpeg[:2] + segment + jpeg[2:]


def test_truncated_jpeg_with_a_thumbnail_is_still_truncated(tmp_path: Path) -> None:
    whole = with_thumbnail_segment(JPEG_BYTES)
    assert read_image(write_bytes(tmp_path / "whole.jpg", whole)).shape == (64, 96, 3)
    cut = write_bytes(tmp_path / "cut.jpg", whole[: len(whole) - len(JPEG_BYTES) // 2])
    with pytest.raises(ImageFileError, match="truncated JPEG"):
        read_image(cut)


def test_progressive_jpeg_is_accepted(tmp_path: Path) -> None:
    encode_ok, data = cv2.imencode(".jpg", cable_picture(), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    assert encode_ok
    path = write_bytes(tmp_path / "progressive.jpg", data.tobytes())
    assert read_image(path).shape == (64, 96, 3)


def test_folders_say_what_they_hold_besides_images(tmp_path: Path) -> None:
    from service.imageio import images_in_directory

    (tmp_path / "sub").mkdir()
    (tmp_path / "a.png").write_bytes(b"x")
    (tmp_path / "gone.jpg").symlink_to(tmp_path / "nowhere.jpg")
    (tmp_path / "gone.txt").symlink_to(tmp_path / "nowhere.txt")  # not an image's name
    (tmp_path / ".hidden").mkdir()
    images, skipped = images_in_directory(tmp_path)
    assert images == [tmp_path / "a.png"]
    assert skipped == [
        f"{tmp_path / 'gone.jpg'}: broken symbolic link (to {tmp_path / 'nowhere.jpg'}), skipped",
        f"{tmp_path / 'sub'}: a folder, not searched (name it to include it)",
    ]


def test_a_mask_of_another_size_is_refused_from_its_header(tmp_path: Path) -> None:
    from tests.helpers import blank_png

    path = write_bytes(tmp_path / "mask.png", blank_png(30_000, 30_000))
    with pytest.raises(ImageFileError, match="mask is 30000x30000 but the image is 96x64"):
        read_mask(path, (64, 96, 3))


@pytest.mark.parametrize(
    "width, height, problem",
    [
        (1, 5_000_000, "image is 1x5000000 px: too large, the PNG decoder takes at most"),
        (40_000, 40_000, "image is 40000x40000 px: too large to decode (at most 1073.7"),
        (0, 10, "empty image"),
    ],
)
def test_images_too_large_to_decode_are_refused_from_the_header(
    tmp_path: Path, width: int, height: int, problem: str
) -> None:
    from tests.helpers import blank_png

    path = write_bytes(tmp_path / "big.png", blank_png(width, height))
    with pytest.raises(ImageFileError) as refused:
        read_image(path)
    assert problem in str(refused.value)

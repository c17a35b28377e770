"""Processing image files one at a time: read, detect, write the three outputs.

These are the plain functions behind the ``dlo`` command line; they print nothing.
"""

from __future__ import annotations

import json
import os
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from schemas import CameraModel, Detection, DetectParams
from schemas.model import CablePhysics
from service.geometry3d import LiftError, lift
from service.geometry3d.depth import check_depth_image, read_depth_file
from service.imageio import (
    IMAGE_SUFFIXES,
    ImageFileError,
    OutputWriteError,
    images_in_directory,
    read_image,
    read_mask,
    write_png,
    write_text,
)
from service.interrupts import interrupts_held
from service.perception import InvalidInputError, detect_full, render_labels, render_overlay
from service.perception.segmenter import Segmenter
from service.simulation import ModelError, to_mjcf
from service.simulation.mjcf import with_surface

IMAGE_OUTPUTS = ("json", "labels", "overlay")
"""The outputs written per image by default."""
OUTPUT_KINDS = (*IMAGE_OUTPUTS, "mjcf", "mcap")
"""Every output, as named on the command line (``--outputs``); ``mjcf`` (the MuJoCo model)
needs a camera model, and is then written by default too; ``mcap`` (a ROS 2 recording of all
the images, or of each video or camera) is written only when asked for."""


class InvalidParametersError(ValueError):
    """Detection parameters failed validation; ``str()`` is one line naming the options."""


@dataclass(frozen=True)
class OutputPaths:
    """Where the outputs for one input image go."""

    detection_json: Path
    """``<stem>.json``: the :class:`schemas.Detection`, indented JSON."""
    labels_png: Path
    """``<stem>.labels.png``: 16-bit label image, pixel value = chain id + 1, 0 elsewhere."""
    overlay_png: Path
    """``<stem>.overlay.png``: the chains drawn over the input image."""
    mjcf_xml: Path
    """``<stem>.mjcf.xml``: the MuJoCo model of the lifted chains (with a camera model)."""

    @classmethod
    def for_input(
        cls, image_path: str | os.PathLike[str], out_dir: str | os.PathLike[str]
    ) -> OutputPaths:
        """Output paths in ``out_dir`` named after the stem of ``image_path``."""
        stem = Path(image_path).stem
        directory = Path(out_dir)
        return cls(
            detection_json=directory / f"{stem}.json",
            labels_png=directory / f"{stem}.labels.png",
            overlay_png=directory / f"{stem}.overlay.png",
            mjcf_xml=directory / f"{stem}.mjcf.xml",
        )

    def all(self) -> tuple[Path, Path, Path]:
        """The three image outputs' paths, in the order they are written (JSON last)."""
        return (self.labels_png, self.overlay_png, self.detection_json)


def build_params(base: DetectParams | None = None, **options: Any) -> DetectParams:
    """Validate detection options given on a command line into :class:`DetectParams`.

    Parameters
    ----------
    base : DetectParams, optional
        Parameters given as a whole (``--params``, :func:`read_params`); the fields it
        sets are kept unless an option sets them too.
    **options
        :class:`DetectParams` fields; those that are None are left as ``base`` has them
        (by default, at their default).

    Returns
    -------
    DetectParams

    Raises
    ------
    InvalidParametersError
        A value is out of range or inconsistent; the message is one line such as
        ``--segment-length: Input should be greater than 0.5``.
    """
    given = {} if base is None else base.model_dump(exclude_unset=True)
    given.update((name, value) for name, value in options.items() if value is not None)
    try:
        return DetectParams(**given)
    except ValidationError as exc:
        raise InvalidParametersError(describe_validation_error(exc)) from None


def read_params(text: str) -> DetectParams:
    """``--params``: :class:`DetectParams` from a JSON object, or from a file holding one.

    Parameters
    ----------
    text : str
        A JSON object such as ``{"gap_curve": "natural"}`` (it starts with ``{``), else
        the path of a file holding one.

    Raises
    ------
    InvalidParametersError
        Neither a JSON object nor a readable file, or invalid parameters; one line
        starting with ``--params:``.
    """
    source = text
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            shown = text if len(text) <= 80 else text[:77] + "..."
            raise InvalidParametersError(f"--params: {shown!r} is neither a JSON object nor a file")
        try:
            source = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InvalidParametersError(f"--params: cannot read {text}: {exc}") from None
    try:
        return DetectParams.model_validate_json(source)
    except ValidationError as exc:
        problems = describe_json_validation_error(exc, "value")
        raise InvalidParametersError(f"--params: {_one_line(problems)}") from None


def parse_outputs(text: str) -> frozenset[str]:
    """Parse an ``--outputs`` value such as ``json,overlay`` into output names.

    Parameters
    ----------
    text : str
        Comma-separated names from :data:`OUTPUT_KINDS`, any case, spaces allowed.

    Returns
    -------
    frozenset of str

    Raises
    ------
    InvalidParametersError
        An unknown name, or no name at all; the message is one line.

    Examples
    --------
    >>> sorted(parse_outputs("JSON, overlay"))
    ['json', 'overlay']
    """
    names = [part.strip().lower() for part in text.split(",") if part.strip()]
    choices = ", ".join(OUTPUT_KINDS)
    for name in names:
        if name not in OUTPUT_KINDS:
            raise InvalidParametersError(
                f"--outputs: unknown output {name!r}; choose from {choices}"
            )
    if not names:
        raise InvalidParametersError(f"--outputs: name at least one of {choices}")
    return frozenset(names)


def describe_json_validation_error(error: ValidationError, whole: str) -> str:
    """Summarise a pydantic validation error of a JSON object on one line, fields as keys.

    ``whole`` names the object itself, for errors that belong to no field (bad JSON).
    """
    return "; ".join(
        f"{'.'.join(str(part) for part in detail['loc']) or whole}: {detail['msg']}"
        for detail in error.errors(include_url=False)
    )


def describe_validation_error(error: ValidationError) -> str:
    """Summarise a pydantic validation error on one line, fields as option names."""
    parts = []
    for detail in error.errors(include_url=False):
        message = str(detail["msg"]).removeprefix("Value error, ")
        location = detail["loc"]
        if location:
            option = "--" + str(location[0]).replace("_", "-")
            parts.append(f"{option}: {message}")
        else:
            parts.append(message)
    return _one_line("; ".join(parts))


def expand_inputs(
    paths: Iterable[str | os.PathLike[str]],
) -> tuple[list[Path], list[str], list[str]]:
    """Turn command-line paths into the image files to process.

    Parameters
    ----------
    paths : iterable of str or Path
        Files and directories as given by the user.

    Returns
    -------
    files : list of Path
        See :func:`service.imageio.list_images`; missing paths are kept so that
        processing them reports the problem.
    problems : list of str
        One-line messages for directories that hold no image.
    skipped : list of str
        One-line notes for what directories hold but is not processed: subdirectories
        and broken symbolic links (:func:`service.imageio.images_in_directory`).
    """
    files: list[Path] = []
    problems: list[str] = []
    skipped: list[str] = []
    for path in map(Path, paths):
        if not path.is_dir():
            files.append(path)
            continue
        found, passed_over = images_in_directory(path)
        skipped.extend(passed_over)
        if not found:
            suffixes = " ".join(IMAGE_SUFFIXES)
            problems.append(f"{path}: directory holds no image ({suffixes})")
        files.extend(found)
    return files, problems, skipped


def find_output_clashes(files: Sequence[Path]) -> dict[Path, Path]:
    """Inputs whose outputs would overwrite those of an earlier input.

    Outputs are named after the file stem, so ``a/x.png`` and ``b/x.jpg`` clash.

    Returns
    -------
    dict
        Later input -> the earlier input with the same stem.
    """
    first_with_stem: dict[str, Path] = {}
    clashes: dict[Path, Path] = {}
    for path in files:
        earlier = first_with_stem.setdefault(path.stem, path)
        if earlier is not path:
            clashes[path] = earlier
    return clashes


def process_file(
    path: str | os.PathLike[str],
    params: DetectParams | None,
    out_dir: str | os.PathLike[str] | None,
    mask_path: str | os.PathLike[str] | None = None,
    outputs: Collection[str] = IMAGE_OUTPUTS,
    camera: CameraModel | None = None,
    depth_path: str | os.PathLike[str] | None = None,
    physics: CablePhysics | None = None,
    segmenter: Segmenter | None = None,
) -> Detection:
    """Detect the DLOs in one image file and write the outputs.

    Parameters
    ----------
    path : str or Path
        The input image.
    params : DetectParams or None
        Detection parameters; None for the defaults.
    out_dir : str or Path or None
        Existing directory for the files of :class:`OutputPaths`; None writes
        nothing.
    mask_path : str or Path, optional
        Foreground mask file of the image's size; replaces segmentation.
    outputs : collection of str
        Which of :data:`OUTPUT_KINDS` to write in ``out_dir`` (:data:`IMAGE_OUTPUTS` by
        default); the images that are not asked for are not rendered. ``mjcf`` needs
        ``camera``; ``mcap`` is the caller's (one recording holds many images).
    camera : CameraModel, optional
        Lift the chains to the robot base frame (``points_3d``, ``radius_m``).
    depth_path : str or Path, optional
        The depth image (16-bit PNG or ``.npy``) when the camera's surface is a depth image.
    physics : CablePhysics, optional
        The cables' physics in ``<stem>.mjcf.xml``; the defaults when None.
    segmenter : callable, optional
        The segmenter for ``params.segmentation == "model"`` (see
        :mod:`service.perception.segmenter`).

    Returns
    -------
    Detection
        Lifted when ``camera`` is given.

    Raises
    ------
    InvalidInputError
        The image, mask or depth image cannot be used; an :class:`ImageFileError` when the
        message already names the file.
    LiftError
        The chains cannot be lifted with this camera (its image size differs).
    ModelError
        The physics would make an unstable model.
    OutputWriteError
        An output cannot be written.
    """
    image = read_image(path)
    mask = None if mask_path is None else read_mask(mask_path, image.shape)
    depth = None if depth_path is None or camera is None else read_depth(depth_path, camera)
    result = detect_full(image, params, mask=mask, segmenter=segmenter)
    detection = result.detection
    if camera is not None:
        detection = lift(detection, camera, depth)
    if out_dir is not None:
        paths = OutputPaths.for_input(path, out_dir)
        # Ctrl-C waits until this image's outputs are whole (see service.interrupts).
        with interrupts_held():
            if "labels" in outputs:
                write_png(paths.labels_png, render_labels(detection, result.mask, image))
            if "overlay" in outputs:
                write_png(paths.overlay_png, render_overlay(image, detection))
            if "mjcf" in outputs and camera is not None:
                model = to_mjcf(detection, **with_surface(physics, camera).model_dump())
                write_text(paths.mjcf_xml, model)
            if "json" in outputs:
                write_text(paths.detection_json, detection_to_json(detection) + "\n")
    return detection


def read_depth(path: str | os.PathLike[str], camera: CameraModel) -> np.ndarray:
    """The depth image at ``path`` checked against ``camera``.

    Raises
    ------
    ImageFileError
        It cannot be read, is not a usable depth image or does not fit the camera.
    """
    from service.geometry3d import DepthImageError

    try:
        return check_depth_image(camera, read_depth_file(path))
    except OSError as error:
        raise ImageFileError(path, f"cannot read depth image: {error.strerror or error}") from None
    except DepthImageError as error:
        raise ImageFileError(path, str(error)) from None


def detection_to_json(detection: Detection) -> str:
    """A detection as JSON for people and files: one line per field, per chain and per
    crossing, no trailing newline.

    Indenting every level (``model_dump_json(indent=2)``) would put each coordinate on a
    line of its own, a thousand lines for a photograph; on one line per chain it reads
    at a glance, diffs by chain, and any JSON reader (``jq``) takes it as it is.
    """
    fields = detection.model_dump(mode="json")
    lines = []
    for key, value in fields.items():
        if isinstance(value, list) and value:
            items = [f"    {_compact_json(item)}," for item in value]
            items[-1] = items[-1].removesuffix(",")
            lines.append(f'  "{key}": [\n' + "\n".join(items) + "\n  ],")
        else:
            lines.append(f'  "{key}": {_compact_json(value)},')
    lines[-1] = lines[-1].removesuffix(",")
    return "{\n" + "\n".join(lines) + "\n}"


def _compact_json(value: Any) -> str:
    return json.dumps(value, separators=(", ", ": "), allow_nan=False)


def failure_message(path: str | os.PathLike[str], error: BaseException) -> str:
    """One line telling which file failed and why, for any exception.

    Parameters
    ----------
    path : str or Path
        The input being processed.
    error : BaseException
        What :func:`process_file` raised.

    Returns
    -------
    str
        ``"<file>: <problem>"``; the file is the mask when the mask was the problem.
        Exceptions other than bad input or unwritable output are reported as
        ``"<file>: internal error: <type>: <message>"``.
    """
    if isinstance(error, ImageFileError):
        message = str(error)
    elif isinstance(error, InvalidInputError | OutputWriteError | LiftError | ModelError):
        message = f"{path}: {error}"
    else:
        message = f"{path}: internal error: {type(error).__name__}: {error}"
    return _one_line(message)


def _one_line(text: str) -> str:
    return " ".join(line.strip() for line in text.splitlines() if line.strip())

"""The segmenter plug-in point: a learned model, or any callable, makes step 1's mask.

``DetectParams(segmentation="model")`` hands the image to a *segmenter*: any callable
that takes the image as :func:`service.perception.detect` got it (``(H, W, 3)`` BGR
``uint8``) and returns the foreground mask of the same height and width. The mask may
be ``bool``, an integer array (non-zero is cable) or a float array of probabilities
(above 0.5 is cable); ``(H, W, 1)`` is taken as ``(H, W)``. The pipeline then cleans it
(``min_component_area``, ``max_hole_area``) as it cleans a caller's mask.

:class:`OnnxSegmenter` is such a callable for a model file in the ONNX format, run with
onnxruntime (the optional extra ``dlo-service[onnx]``). Its conventions:

input
    One tensor ``N x 3 x H x W`` (NCHW), RGB. ``float32``: values 0..1 (the image's
    0..255 divided by 255); ``uint8``: values 0..255. ``N`` is 1 (or free). A fixed
    ``H x W`` gets the image resized to it; free dimensions get the image as it is.
output
    The model's first output, one map per image: ``1 x 1 x h x w``, ``1 x h x w`` or
    ``h x w``, or two channels ``1 x 2 x h x w`` (background, cable: cable where the
    second is larger, as a softmax above 0.5 would say). A single map of ``float``
    values is read as probabilities and cut at 0.5 when every value lies in 0..1, else
    as logits and cut at 0 (the same as a sigmoid above 0.5); integer or boolean maps
    are cable where non-zero. The map is resized back to the image (bilinear for
    scores, nearest for labels) before it is cut.

Bad input gets a one-line error: :class:`SegmenterModelError` for a model file that is
missing, not ONNX, or whose input is not ``N x 3 x H x W`` of ``float32`` or ``uint8``;
:class:`~service.perception.errors.InvalidInputError` for a segmenter that returns
something that is not a mask of the image's size.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from service.perception.errors import InvalidInputError

Segmenter = Callable[[np.ndarray], np.ndarray]
"""``segmenter(image_bgr) -> mask``: see the module docstring."""

ONNX_EXTRA_HINT = "pip install 'dlo-service[onnx]'"


class SegmenterModelError(ValueError):
    """A segmenter model file that cannot be used; the message is one line."""


def run_segmenter(segmenter: Segmenter | None, image_bgr: np.ndarray) -> np.ndarray:
    """Call ``segmenter`` on the image and check what it returns.

    Returns
    -------
    ndarray of bool
        ``(H, W)``, True on cable pixels.

    Raises
    ------
    InvalidInputError
        There is no segmenter, or it returned something that is not a mask of the
        image's height and width.
    """
    if segmenter is None:
        raise InvalidInputError(
            "segmentation 'model' needs a segmenter: --segmenter-model FILE.onnx, or "
            "detect(..., segmenter=callable) in Python"
        )
    if not callable(segmenter):
        raise InvalidInputError(f"segmenter must be callable, not {type(segmenter).__name__}")
    mask = segmenter(image_bgr)
    height, width = image_bgr.shape[:2]
    if not isinstance(mask, np.ndarray):
        raise InvalidInputError(
            f"segmenter returned {type(mask).__name__}, not a numpy array (the mask)"
        )
    if mask.ndim == 3 and mask.shape[2] == 1:
        mask = mask[:, :, 0]
    if mask.ndim != 2:
        raise InvalidInputError(
            f"segmenter returned an array of shape {mask.shape}, not a (H, W) mask"
        )
    if mask.shape != (height, width):
        raise InvalidInputError(
            f"segmenter returned a {mask.shape[1]}x{mask.shape[0]} mask for a "
            f"{width}x{height} image"
        )
    if mask.dtype == np.bool_:
        return mask
    if np.issubdtype(mask.dtype, np.integer):
        return mask != 0
    if np.issubdtype(mask.dtype, np.floating):
        if not np.isfinite(mask).all():
            raise InvalidInputError("segmenter returned a mask with NaN or infinite values")
        return mask > 0.5
    raise InvalidInputError(
        f"segmenter returned a mask of type {mask.dtype}: use bool, integers or "
        "probabilities (float)"
    )


class OnnxSegmenter:
    """A segmenter from an ONNX model file, run with onnxruntime on the CPU.

    Parameters
    ----------
    path : str or Path
        The ``.onnx`` file (conventions in the module docstring).
    threads : int
        onnxruntime's threads within one inference; 1 keeps a detection on one core,
        as the rest of the pipeline is.

    Raises
    ------
    SegmenterModelError
        The file is missing, is not an ONNX model, or its input is not ``N x 3 x H x W``
        of ``float32`` or ``uint8``; or onnxruntime is not installed.

    Examples
    --------
    >>> from service.perception import detect  # doctest: +SKIP
    >>> segmenter = OnnxSegmenter("cables.onnx")  # doctest: +SKIP
    >>> detect(image, DetectParams(segmentation="model"), segmenter=segmenter)  # doctest: +SKIP
    """

    def __init__(self, path: str | os.PathLike[str], threads: int = 1) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            reason = "is a directory" if self.path.is_dir() else "no such file"
            raise SegmenterModelError(f"segmenter model {self.path}: {reason}")
        try:
            import onnxruntime
        except ImportError:
            raise SegmenterModelError(
                f"segmenter model {self.path}: running ONNX models needs onnxruntime "
                f"({ONNX_EXTRA_HINT})"
            ) from None
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3  # errors only: no warnings on stderr per session
        try:
            self._session = onnxruntime.InferenceSession(
                str(self.path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own exception types
            detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise SegmenterModelError(
                f"segmenter model {self.path}: not a valid ONNX model"
                + (f" ({detail[:160]})" if detail else "")
            ) from None
        inputs = self._session.get_inputs()
        if len(inputs) != 1:
            raise SegmenterModelError(
                f"segmenter model {self.path}: takes {len(inputs)} inputs; one "
                "N x 3 x H x W image is expected"
            )
        model_input = inputs[0]
        self._input_name = model_input.name
        shape = list(model_input.shape)
        if len(shape) != 4 or shape[1] != 3 or (isinstance(shape[0], int) and shape[0] != 1):
            raise SegmenterModelError(
                f"segmenter model {self.path}: input of shape {_shape_text(shape)}; "
                "1 x 3 x H x W (NCHW, RGB) is expected"
            )
        if model_input.type == "tensor(float)":
            self._dtype = np.float32
        elif model_input.type == "tensor(uint8)":
            self._dtype = np.uint8
        else:
            raise SegmenterModelError(
                f"segmenter model {self.path}: input of type {model_input.type}; float32 "
                "(RGB 0..1) or uint8 (RGB 0..255) is expected"
            )
        height, width = shape[2], shape[3]
        self._size = (width, height) if isinstance(height, int) and isinstance(width, int) else None

    def __call__(self, image_bgr: np.ndarray) -> np.ndarray:
        """The model's mask of ``image_bgr`` (``(H, W)`` bool)."""
        height, width = image_bgr.shape[:2]
        rgb = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2RGB)
        if self._size is not None and self._size != (width, height):
            rgb = cv2.resize(rgb, self._size, interpolation=cv2.INTER_AREA)
        tensor = np.ascontiguousarray(rgb.transpose(2, 0, 1)[None])
        if self._dtype is np.float32:
            tensor = tensor.astype(np.float32) * np.float32(1.0 / 255.0)
        try:
            output = self._session.run(None, {self._input_name: tensor})[0]
        except Exception as exc:  # a model that fails on this input
            detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise InvalidInputError(
                f"segmenter model {self.path.name} failed on a {width}x{height} image"
                + (f" ({detail[:160]})" if detail else "")
            ) from None
        return self._to_mask(np.asarray(output), height, width)

    def _to_mask(self, output: np.ndarray, height: int, width: int) -> np.ndarray:
        scores = _single_map(output)
        if scores is None:
            raise InvalidInputError(
                f"segmenter model {self.path.name} returned an output of shape "
                f"{output.shape}; one map (1 x 1 x h x w, 1 x h x w or h x w) or two "
                "channels (1 x 2 x h x w) are expected"
            )
        if scores.dtype == np.bool_ or np.issubdtype(scores.dtype, np.integer):
            labels = (scores != 0).astype(np.uint8)
            if labels.shape != (height, width):
                labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST)
            return labels.astype(bool)
        scores = scores.astype(np.float32)
        if not np.isfinite(scores).all():
            raise InvalidInputError(
                f"segmenter model {self.path.name} returned NaN or infinite scores"
            )
        cut = 0.5 if scores.min() >= 0.0 and scores.max() <= 1.0 else 0.0
        if scores.shape != (height, width):
            scores = cv2.resize(scores, (width, height), interpolation=cv2.INTER_LINEAR)
        return scores > cut


def _single_map(output: np.ndarray) -> np.ndarray | None:
    """The model's output as one 2-D map of scores (or labels); None when it is not one."""
    if output.ndim == 4 and output.shape[0] == 1:
        if output.shape[1] == 1:
            return output[0, 0]
        if output.shape[1] == 2:
            # Cable where the cable channel beats the background one: softmax > 0.5.
            return (output[0, 1] > output[0, 0]).astype(np.uint8)
        return None
    if output.ndim == 3 and output.shape[0] == 1:
        return output[0]
    if output.ndim == 2:
        return output
    return None


def _shape_text(shape: list) -> str:
    return " x ".join(str(dim) if isinstance(dim, int) else "?" for dim in shape)

"""The segmenter plug-in point: callables and ONNX models (built here, nothing downloaded).

The tiny models say "cable" where red exceeds green: a 1x1 convolution of the RGB input
with weights (1, -1, 0) and a bias, then a sigmoid (or not, for logits), so that what
they return can be checked exactly on a red line drawn on grey.
"""

from pathlib import Path

import cv2
import numpy as np
import pytest

from schemas import DetectParams, SegmentationMethod
from service.perception import InvalidInputError, detect, detect_full
from service.perception.segmenter import OnnxSegmenter, SegmenterModelError, run_segmenter

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper  # noqa: E402

MODEL = DetectParams(segmentation=SegmentationMethod.model)


def red_line_image(width=160, height=120):
    image = np.full((height, width, 3), 128, np.uint8)
    cv2.line(image, (10, 60), (150, 60), (0, 0, 230), 9)  # BGR red
    truth = np.zeros((height, width), np.uint8)
    cv2.line(truth, (10, 60), (150, 60), 1, 9)
    return image, truth > 0


def build_model(
    path: Path,
    *,
    size=("height", "width"),
    input_type=TensorProto.FLOAT,
    channels=3,
    output="probability",
) -> Path:
    """An ONNX model of 'red minus green' (see the module docstring), saved at ``path``."""
    nodes, initializers = [], []
    current = "image"
    if input_type != TensorProto.FLOAT:
        nodes.append(helper.make_node("Cast", ["image"], ["as_float"], to=TensorProto.FLOAT))
        current = "as_float"
    if input_type == TensorProto.UINT8:
        initializers.append(helper.make_tensor("inv255", TensorProto.FLOAT, [], [1 / 255]))
        nodes.append(helper.make_node("Mul", ["as_float", "inv255"], ["scaled"]))
        current = "scaled"
    out_channels = 2 if output == "two_channels" else 1
    weights = [1.0, -1.0, 0.0][:channels] + [0.0] * (channels - 3) if channels >= 3 else [1.0]
    if out_channels == 2:
        weights = [-w for w in weights] + weights
    initializers.append(
        helper.make_tensor("w", TensorProto.FLOAT, [out_channels, channels, 1, 1], weights)
    )
    initializers.append(
        helper.make_tensor("b", TensorProto.FLOAT, [out_channels], [0.3, -0.3][-out_channels:])
    )
    nodes.append(helper.make_node("Conv", [current, "w", "b"], ["score"]))
    initializers.append(helper.make_tensor("gain", TensorProto.FLOAT, [], [20.0]))
    nodes.append(helper.make_node("Mul", ["score", "gain"], ["logit"]))
    final = "logit"
    if output == "probability":
        nodes.append(helper.make_node("Sigmoid", ["logit"], ["probability"]))
        final = "probability"
    graph = helper.make_graph(
        nodes,
        "red_cables",
        [helper.make_tensor_value_info("image", input_type, [1, channels, *size])],
        [helper.make_tensor_value_info(final, TensorProto.FLOAT, None)],
        initializers,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


def dice(mask, truth):
    return 2.0 * (mask & truth).sum() / (mask.sum() + truth.sum())


# --------------------------------------------------------------------------- callables


@pytest.mark.parametrize(
    "convert",
    [
        lambda mask: mask,  # bool
        lambda mask: mask.astype(np.uint8) * 255,  # 0/255
        lambda mask: mask.astype(np.float32) * 0.9,  # probabilities
        lambda mask: mask[:, :, None],  # (H, W, 1)
    ],
    ids=["bool", "uint8", "probabilities", "HxWx1"],
)
def test_a_callable_segmenter_makes_the_mask(convert):
    image, truth = red_line_image()
    result = detect_full(image, MODEL, segmenter=lambda bgr: convert(truth.copy()))
    assert len(result.detection.chains) == 1
    assert dice(result.mask, truth) > 0.99
    # The segmenter gets the image as detect got it: BGR uint8.
    seen = []
    detect(image, MODEL, segmenter=lambda bgr: seen.append(bgr) or truth)
    np.testing.assert_array_equal(seen[0], image)


@pytest.mark.parametrize(
    ("returned", "message"),
    [
        (
            lambda image: np.zeros((60, 80), bool),
            "segmenter returned a 80x60 mask for a 160x120 image",
        ),
        (lambda image: [[0, 1]], "segmenter returned list, not a numpy array"),
        (lambda image: np.zeros((120, 160, 3), bool), "not a (H, W) mask"),
        (
            lambda image: np.zeros((120, 160), complex),
            "segmenter returned a mask of type complex128",
        ),
        (lambda image: np.full((120, 160), np.nan), "NaN or infinite"),
    ],
    ids=["wrong size", "not an array", "three channels", "complex", "nan"],
)
def test_a_callable_returning_no_mask_of_the_image_gets_a_one_line_error(returned, message):
    image, _ = red_line_image()
    with pytest.raises(
        InvalidInputError, match=message.replace("(", r"\(").replace(")", r"\)")
    ) as error:
        detect(image, MODEL, segmenter=returned)
    assert "\n" not in str(error.value)


def test_segmentation_model_without_a_segmenter_says_how_to_give_one():
    image, _ = red_line_image()
    with pytest.raises(InvalidInputError, match="needs a segmenter: --segmenter-model"):
        detect(image, MODEL)
    with pytest.raises(InvalidInputError, match="must be callable"):
        run_segmenter("model.onnx", image)


# --------------------------------------------------------------------------- ONNX


@pytest.mark.parametrize(
    ("options", "name"),
    [
        ({}, "probabilities, float32 input of any size"),
        ({"output": "logit"}, "logits"),
        ({"input_type": TensorProto.UINT8}, "uint8 input"),
        ({"size": (48, 64)}, "a fixed input size: resized there and back"),
        ({"output": "two_channels"}, "background and cable channels"),
    ],
)
def test_an_onnx_model_makes_the_mask(tmp_path, options, name):
    image, truth = red_line_image()
    segmenter = OnnxSegmenter(build_model(tmp_path / "model.onnx", **options))
    mask = segmenter(image)
    assert mask.shape == truth.shape and mask.dtype == bool
    assert dice(mask, truth) > 0.9, name
    detection = detect(image, MODEL, segmenter=segmenter)
    assert len(detection.chains) == 1


def test_bad_model_files_get_one_line_errors(tmp_path):
    with pytest.raises(SegmenterModelError, match=r"missing\.onnx: no such file"):
        OnnxSegmenter(tmp_path / "missing.onnx")
    with pytest.raises(SegmenterModelError, match="is a directory"):
        OnnxSegmenter(tmp_path)
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"this is not a model\n" * 10)
    with pytest.raises(SegmenterModelError, match=r"junk\.onnx: not a valid ONNX model") as error:
        OnnxSegmenter(junk)
    assert "\n" not in str(error.value)
    one_channel = build_model(tmp_path / "grey.onnx", channels=1)
    with pytest.raises(SegmenterModelError, match=r"input of shape 1 x 1 x \? x \?; 1 x 3 x H x W"):
        OnnxSegmenter(one_channel)
    doubles = build_model(tmp_path / "double.onnx", input_type=TensorProto.DOUBLE)
    with pytest.raises(SegmenterModelError, match=r"input of type tensor\(double\)"):
        OnnxSegmenter(doubles)


def test_a_model_with_an_output_that_is_no_mask_gets_a_one_line_error(tmp_path):
    graph = helper.make_graph(
        [helper.make_node("Identity", ["image"], ["same"])],  # three channels out
        "identity",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, "h", "w"])],
        [helper.make_tensor_value_info("same", TensorProto.FLOAT, None)],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, tmp_path / "identity.onnx")
    image, _ = red_line_image()
    with pytest.raises(InvalidInputError, match=r"output of shape \(1, 3, 120, 160\)"):
        detect(image, MODEL, segmenter=OnnxSegmenter(tmp_path / "identity.onnx"))

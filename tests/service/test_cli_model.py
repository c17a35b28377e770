"""``dlo detect IMAGE --camera CAMERA.json [--depth DEPTH.png]``: 3-D chains and the MJCF."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from schemas import Detection
from service.synthetic.scene3d import make_scene_3d

from .test_cli import assert_no_traceback, error_lines, run_dlo

mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A flat scene with its plane camera, and a box scene with its depth camera and depth."""
    folder = tmp_path_factory.mktemp("scenes")
    flat = make_scene_3d("down", seed=7, width=640, height=480, focal=700.0)
    box = make_scene_3d("box", seed=7, width=640, height=480, focal=700.0)
    cv2.imwrite(str(folder / "flat.png"), flat.image)
    cv2.imwrite(str(folder / "box.png"), box.image)
    flat.camera.to_json_file(folder / "camera.json")
    surface = {"kind": "depth", "depth_scale": 0.001}
    (folder / "depth_camera.json").write_text(
        json.dumps({**box.camera.model_dump(mode="json"), "surface": surface})
    )
    cv2.imwrite(str(folder / "box_depth.png"), box.depth_mm_png())
    return folder, flat, box


def test_a_camera_model_adds_points_3d_and_the_mjcf(files, tmp_path) -> None:
    folder, flat, _ = files
    result = run_dlo(
        "detect", folder / "flat.png", "--camera", folder / "camera.json", "--out-dir", tmp_path
    )
    assert result.exit_code == 0, result.output
    detection = Detection.model_validate_json((tmp_path / "flat.json").read_text())
    assert detection.chains
    for chain in detection.chains:
        assert len(chain.points_3d) == len(chain.points)
        assert chain.radius_m == pytest.approx(0.003, abs=0.0015)
        errors = flat.distance_to_centrelines(np.array(chain.points_3d))
        assert np.median(errors) < 1.5e-3  # 0.5 mm pixels at this camera's 700 px focal length
    for suffix in (".labels.png", ".overlay.png", ".mjcf.xml"):
        assert (tmp_path / f"flat{suffix}").exists()
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "flat.mjcf.xml"))
    assert model.nbody - 1 == sum(len(chain.points) - 1 for chain in detection.chains)


def test_depth_image_and_chosen_outputs(files, tmp_path) -> None:
    folder, _, box = files
    result = run_dlo(
        "detect",
        folder / "box.png",
        "--camera",
        folder / "depth_camera.json",
        "--depth",
        folder / "box_depth.png",
        "--out-dir",
        tmp_path,
        "--outputs",
        "json,mjcf",
        "--physics",
        '{"mass_per_metre": 0.08}',
    )
    assert result.exit_code == 0, result.output
    assert sorted(path.name for path in tmp_path.iterdir()) == ["box.json", "box.mjcf.xml"]
    detection = Detection.model_validate_json((tmp_path / "box.json").read_text())
    heights = [point[2] for chain in detection.chains for point in chain.points_3d if point]
    assert max(heights) == pytest.approx(box.box.high[2] + 0.0035, abs=2e-3)
    text = (tmp_path / "box.mjcf.xml").read_text()
    model = mujoco.MjModel.from_xml_string(text)
    # Each capsule's mass is the given mass per metre times its length.
    capsules = range(1, model.ngeom)
    lengths = [2 * model.geom_size[g, 1] for g in capsules]
    masses = [model.body_mass[model.geom_bodyid[g]] for g in capsules]
    np.testing.assert_allclose(masses, 0.08 * np.array(lengths), rtol=1e-6)


def test_without_a_camera_model_the_json_has_no_3d_fields(files) -> None:
    folder, _, _ = files
    result = run_dlo("detect", folder / "flat.png")
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    assert data["chains"] and "points_3d" not in data["chains"][0]
    assert "radius_m" not in data["chains"][0]


@pytest.mark.parametrize(
    ("arguments", "words"),
    [
        (["--outputs", "mjcf"], "needs a camera model"),
        (["--depth", "{folder}/box_depth.png"], "needs a camera model"),
        (["--camera", "{folder}/depth_camera.json"], "give --depth"),
        (["--camera", "{folder}/camera.json", "--depth", "{folder}/box_depth.png"], "plane"),
        (["--camera", "{folder}/camera.json", "--physics", '{"stiff": 1}'], "--physics"),
        (["--camera", "{folder}/missing.json"], "missing.json"),
    ],
)
def test_usage_errors(files, tmp_path, arguments, words) -> None:
    folder, _, _ = files
    arguments = [argument.replace("{folder}", str(folder)) for argument in arguments]
    result = run_dlo("detect", folder / "flat.png", *arguments, "--out-dir", tmp_path)
    assert result.exit_code == 2, result.output
    assert_no_traceback(result)
    assert any(words in line for line in error_lines(result)), result.output


def test_a_camera_model_of_another_size_fails_the_image(files, tmp_path) -> None:
    folder, flat, _ = files
    other = flat.camera.model_copy(update={"width": 320, "height": 240})
    other.to_json_file(tmp_path / "small.json")
    result = run_dlo(
        "detect", folder / "flat.png", "--camera", tmp_path / "small.json", "--out-dir", tmp_path
    )
    assert result.exit_code == 1
    assert_no_traceback(result)
    assert any("320x240" in line for line in error_lines(result)), result.output

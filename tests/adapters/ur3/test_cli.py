"""``dlo ur3 plan|pick``: selection options, camera files (JSON and YAML), dry runs, picks.

Picks run against the in-process :class:`FakeRobot`, injected through
:func:`build_ur3_app`; nothing here needs a robot or the network.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import typer
import yaml
from typer.testing import CliRunner

from adapters.ur3.cli import build_ur3_app
from adapters.ur3.fakes import FakeRobot
from schemas import CameraModel, Chain, DepthSurface, Detection
from service.synthetic import make_scene
from tests.adapters.builders import looking_down

W, H = 640, 480
FX = FY = 800.0
CX, CY = 320.0, 240.0
TOL = 1e-4  # 0.1 mm
EXAMPLES = Path(__file__).resolve().parents[3] / "docs" / "examples"
LABELS = ["approach", "descend", "close_gripper", "lift"]


def camera(origin=(0.3, 0.1, 0.5), width=W, height=H) -> CameraModel:
    """Straight down over the table ``z = 0``."""
    return looking_down(origin, fx=FX, fy=FY, cx=CX, cy=CY, width=width, height=height)


def detection(inferred=(False, False)) -> Detection:
    """One horizontal chain of two segments through the principal point."""
    chain = Chain(
        id=4,
        points=[(CX - 60, CY), (CX, CY), (CX + 60, CY)],
        radius=3.0,
        inferred=list(inferred),
    )
    return Detection(width=W, height=H, segment_length=60.0, chains=[chain])


@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
    camera().to_json_file(tmp_path / "camera.json")
    (tmp_path / "det.json").write_text(detection().model_dump_json())
    return {"camera": tmp_path / "camera.json", "detection": tmp_path / "det.json"}


def invoke(*args: str, robot: FakeRobot | None = None):
    """Run ``dlo ur3 ARGS`` with the fake robot (a fresh one unless given)."""
    app = typer.Typer()
    app.add_typer(build_ur3_app((robot or FakeRobot()).connect), name="ur3")
    return CliRunner().invoke(app, ["ur3", *args])


def assert_usage_error(result, *words: str) -> None:
    assert result.exit_code == 2, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr + result.stdout
    assert result.stdout == ""
    for word in words:
        assert word in result.stderr, result.stderr


# --- planning (dry runs) ------------------------------------------------------------------


@pytest.mark.parametrize("command", [["plan"], ["pick", "--dry-run"]])
def test_dry_run_prints_the_target_and_the_motions(files, command):
    args = [*command, str(files["detection"]), "--camera", str(files["camera"])]
    result = invoke(*args, "--fraction", "0.75")
    assert result.exit_code == 0, result.stderr
    plan = json.loads(result.stdout)
    # 3/4 along the chain is pixel (CX + 30, CY): 30 px * 0.5 m / 800 px further along +x.
    assert plan["target"]["position_m"] == pytest.approx([0.3 + 30 * 0.5 / FX, 0.1, 0.0], abs=TOL)
    assert plan["target"]["chain_id"] == 4 and plan["target"]["segment_index"] == 1
    assert [motion["label"] for motion in plan["motions"]] == LABELS
    assert plan["within_workspace"] is True and "refusal" not in plan
    assert plan["motions"][2] == {"label": "close_gripper", "kind": "gripper", "output_value": True}


@pytest.mark.parametrize(
    "options, segment, pixel",
    [
        (["--segment", "0"], 0, (CX - 30, CY)),
        (["--pixel", "350", "200"], 1, (350.0, CY)),
        (["--end", "end"], 1, (CX + 60, CY)),
        (["--end", "start", "--chain", "4"], 0, (CX - 60, CY)),
    ],
)
def test_each_selector_option_chooses_its_point(files, options, segment, pixel):
    result = invoke("plan", str(files["detection"]), "-c", str(files["camera"]), *options)
    assert result.exit_code == 0, result.stderr
    target = json.loads(result.stdout)["target"]
    assert target["segment_index"] == segment
    assert target["pixel"] == pytest.approx(pixel)


def test_pick_dry_run_detects_an_image_and_needs_no_robot(tmp_path):
    scene = make_scene(W, H, 1, seed=3, loops=False)
    image_path = tmp_path / "cell.png"
    assert cv2.imwrite(str(image_path), scene.image)
    camera().to_json_file(tmp_path / "camera.json")
    robot = FakeRobot()
    result = invoke(
        "pick", str(image_path), "--camera", str(tmp_path / "camera.json"), "--dry-run",
        "--allow-inferred", robot=robot,
    )  # fmt: skip
    assert result.exit_code == 0, result.stderr
    plan = json.loads(result.stdout)
    assert [motion["label"] for motion in plan["motions"]] == LABELS
    assert plan["target"]["position_m"][2] == pytest.approx(0.0, abs=TOL)
    assert robot.calls == []


def test_inferred_segment_is_refused_unless_allowed(tmp_path, files):
    (tmp_path / "det.json").write_text(detection(inferred=(False, True)).model_dump_json())
    args = ["plan", str(tmp_path / "det.json"), "-c", str(files["camera"]), "--end", "end"]
    assert_usage_error(invoke(*args), "segment 1 was inferred")
    assert invoke(*args, "--allow-inferred").exit_code == 0


def test_a_target_outside_the_workspace_is_planned_with_a_warning(tmp_path, files):
    camera(origin=(0.6, 0.3, 0.5)).to_json_file(tmp_path / "far.json")
    result = invoke("pick", "--dry-run", str(files["detection"]), "-c", str(tmp_path / "far.json"))
    assert result.exit_code == 0, result.stderr
    plan = json.loads(result.stdout)
    assert plan["within_workspace"] is False and "beyond" in plan["refusal"]
    assert "warning: a pick would refuse this plan" in result.stderr


# --- usage errors: exit 2, one line, no traceback -------------------------------------------


@pytest.mark.parametrize(
    "options, named",
    [
        (["--fraction", "0.5", "--segment", "1"], "--fraction and --segment"),
        (["--segment", "1", "--pixel", "3", "4"], "--segment and --pixel"),
        (["--pixel", "3", "4", "--end", "start"], "--pixel and --end"),
        (["--fraction", "0.1", "--end", "end"], "--fraction and --end"),
    ],
)
def test_more_than_one_point_option_is_a_usage_error(files, options, named):
    args = ["pick", "--dry-run", str(files["detection"]), "-c", str(files["camera"]), *options]
    assert_usage_error(invoke(*args), "give at most one of", named)


@pytest.mark.parametrize(
    "options, words",
    [
        (["--fraction", "1.5"], ["--fraction", "less than or equal to 1"]),
        (["--end", "middle"], ["--end: must be 'start' or 'end'"]),
        (["--chain", "first"], ["--chain: must be a chain id"]),
        (["--chain", "7"], ["no chain with id 7; the ids are [4]"]),
    ],
)
def test_bad_selections_are_usage_errors(files, options, words):
    args = ["plan", str(files["detection"]), "-c", str(files["camera"]), *options]
    assert_usage_error(invoke(*args), *words)


def test_pick_without_robot_ip_or_dry_run_is_a_usage_error(files):
    robot = FakeRobot()
    result = invoke("pick", str(files["detection"]), "-c", str(files["camera"]), robot=robot)
    assert_usage_error(result, "--robot-ip is required")
    assert robot.calls == []


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("missing.json", None, ["camera file", "No such file"]),
        ("camera.json", "{not json", ["camera file", "Invalid JSON"]),
        ("camera.yaml", "fx: [1, 2\n", ["camera file", "not valid YAML"]),
        ("camera.yaml", "- just\n- a list\n", ["camera file", "valid dictionary"]),
        ("camera.txt", "{}", ["camera file", "must be .json, .yaml or .yml"]),
        ("camera.json", '{"fx": 1}', ["camera file", "fy: Field required"]),
    ],
)
def test_bad_camera_files_are_reported_on_one_line(tmp_path, files, name, content, words):
    path = tmp_path / name
    if content is not None:
        path.write_text(content)
    result = invoke("plan", str(files["detection"]), "--camera", str(path))
    assert_usage_error(result, *words)
    assert len(result.stderr.strip().splitlines()) == 1


def test_a_rotation_that_is_not_rigid_is_named(tmp_path, files):
    data = camera().model_dump(mode="json")
    data["T_base_camera"][0][0] = 2.0
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump(data))
    result = invoke("plan", str(files["detection"]), "-c", str(tmp_path / "camera.yaml"))
    assert_usage_error(result, "T_base_camera", "not orthonormal")


def test_bad_inputs_are_usage_errors(tmp_path, files):
    (tmp_path / "broken.json").write_text('{"width": 3}')
    (tmp_path / "noise.png").write_bytes(b"not a png")
    camera_args = ["-c", str(files["camera"])]
    assert_usage_error(invoke("plan", str(tmp_path / "broken.json"), *camera_args), "Detection")
    assert_usage_error(invoke("plan", str(tmp_path / "noise.png"), *camera_args), "noise.png")
    size_mismatch = camera(width=320, height=240)
    size_mismatch.to_json_file(tmp_path / "small.json")
    result = invoke("plan", str(files["detection"]), "-c", str(tmp_path / "small.json"))
    assert_usage_error(result, "640x480 px but the camera model is 320x240 px")
    result = invoke("plan", str(files["detection"]), *camera_args, "--segment-length", "5")
    assert_usage_error(result, "apply to an image")


# --- camera files in YAML -------------------------------------------------------------------


def test_the_yaml_example_is_the_json_example():
    assert CameraModel.from_file(EXAMPLES / "camera.yaml") == CameraModel.from_file(
        EXAMPLES / "camera.json"
    )


@pytest.mark.parametrize("suffix", [".yaml", ".yml", ".YAML"])
def test_a_yaml_camera_plans_like_its_json_twin(tmp_path, files, suffix):
    path = tmp_path / f"camera{suffix}"
    path.write_text(yaml.safe_dump(camera().model_dump(mode="json")))
    assert CameraModel.from_file(path) == camera()
    from_yaml = invoke("plan", str(files["detection"]), "-c", str(path))
    from_json = invoke("plan", str(files["detection"]), "-c", str(files["camera"]))
    assert from_yaml.exit_code == 0, from_yaml.stderr
    assert from_yaml.stdout == from_json.stdout


def test_yaml_syntax_errors_are_value_errors(tmp_path):
    path = tmp_path / "camera.yml"
    path.write_text("fx: 800\n  fy: 800\n")
    with pytest.raises(ValueError, match=r"camera\.yml: not valid YAML"):
        CameraModel.from_file(path)


# --- picking with the fake robot --------------------------------------------------------------


def test_pick_sends_the_planned_motions_and_prints_the_report(files):
    robot = FakeRobot()
    args = ["pick", "--robot-ip", "10.0.0.9", str(files["detection"]), "-c", str(files["camera"])]
    planned = json.loads(invoke("plan", *args[3:]).stdout)
    result = invoke(*args, robot=robot)
    assert result.exit_code == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["ok"] is True
    assert [step["motion"]["label"] for step in report["steps"]] == LABELS
    moves = [call.args[0] for call in robot.calls if call.method == "moveL"]
    expected = [motion["pose"] for motion in planned["motions"] if motion["kind"] == "moveL"]
    assert moves == [pytest.approx(pose) for pose in expected]
    assert robot.digital_outputs == {("tool", 0): True}


def test_pick_outside_the_workspace_sends_nothing(tmp_path, files):
    camera(origin=(0.6, 0.3, 0.5)).to_json_file(tmp_path / "far.json")
    robot = FakeRobot()
    far = str(tmp_path / "far.json")
    args = ["pick", "--robot-ip", "10.0.0.9", str(files["detection"]), "-c", far]
    assert_usage_error(invoke(*args, robot=robot), "refused, nothing sent", "beyond")
    assert robot.calls == []


def test_pick_refused_by_the_robot_exits_2_without_motion(files):
    robot = FakeRobot(protective_stopped=True)
    args = ["pick", "--robot-ip", "10.0.0.9", str(files["detection"]), "-c", str(files["camera"])]
    assert_usage_error(invoke(*args, robot=robot), "refused, nothing sent", "protective")
    assert [call for call in robot.calls if call.method in ("moveL", "setToolDigitalOut")] == []


def test_dlo_registers_ur3_and_no_longer_grasp():
    from service.cli import app

    runner = CliRunner()
    assert runner.invoke(app, ["ur3", "--help"]).exit_code == 0
    assert "pick" in runner.invoke(app, ["ur3", "--help"]).stdout
    assert runner.invoke(app, ["grasp", "--help"]).exit_code == 2


# --- a depth-image surface ----------------------------------------------------------------------


def depth_camera(depth_scale=0.001) -> CameraModel:
    """:func:`camera` 0.5 m above the table, its surface a depth image."""
    return camera().model_copy(
        update={"surface": DepthSurface(kind="depth", depth_scale=depth_scale)}
    )


@pytest.fixture
def depth_files(tmp_path, files) -> dict[str, Path]:
    """A depth camera, and the depth of a 5 cm box under the chain as PNG (mm) and .npy (m)."""
    depth_camera().to_json_file(tmp_path / "depth_camera.json")
    depth_camera(depth_scale=1.0).to_json_file(tmp_path / "depth_camera_m.json")
    millimetres = np.full((H, W), 500, np.uint16)
    millimetres[200:280, 280:360] = 450  # the box top, around the principal point
    millimetres[238:243, 318:323] = 0  # a hole right at the grasp point, filled by the window
    assert cv2.imwrite(str(tmp_path / "depth.png"), millimetres)
    np.save(tmp_path / "depth.npy", millimetres.astype(np.float32) / 1000)
    return {
        **files,
        "depth_camera": tmp_path / "depth_camera.json",
        "depth_camera_m": tmp_path / "depth_camera_m.json",
        "png": tmp_path / "depth.png",
        "npy": tmp_path / "depth.npy",
    }


@pytest.mark.parametrize(
    ("command", "camera_key", "depth_key"),
    [
        (["plan"], "depth_camera", "png"),
        (["pick", "--dry-run"], "depth_camera_m", "npy"),
    ],
)
def test_a_depth_image_puts_the_grasp_on_the_box(depth_files, command, camera_key, depth_key):
    args = [*command, str(depth_files["detection"]), "-c", str(depth_files[camera_key])]
    result = invoke(*args, "--depth", str(depth_files[depth_key]), "--fraction", "0.75")
    assert result.exit_code == 0, result.stderr
    target = json.loads(result.stdout)["target"]
    # Pixel (CX + 30, CY) on the box top 0.45 m below the camera, 0.05 m above the table.
    assert target["position_m"] == pytest.approx([0.3 + 30 * 0.45 / FX, 0.1, 0.05], abs=TOL)
    assert target["yaw_rad"] == pytest.approx(np.pi / 2)


def test_a_flat_depth_image_plans_as_the_plane(tmp_path, files):
    depth_camera().to_json_file(tmp_path / "depth_camera.json")
    assert cv2.imwrite(str(tmp_path / "flat.png"), np.full((H, W), 500, np.uint16))
    args = ["plan", str(files["detection"]), "--fraction", "0.3"]
    on_plane = invoke(*args, "-c", str(files["camera"]))
    on_depth = invoke(
        *args, "-c", str(tmp_path / "depth_camera.json"), "--depth", str(tmp_path / "flat.png")
    )
    assert on_depth.exit_code == 0, on_depth.stderr
    plane_plan, depth_plan = json.loads(on_plane.stdout), json.loads(on_depth.stdout)
    assert depth_plan["target"]["position_m"] == pytest.approx(
        plane_plan["target"]["position_m"], abs=TOL
    )
    for from_depth, from_plane in zip(depth_plan["motions"], plane_plan["motions"], strict=True):
        assert from_depth.get("pose") == pytest.approx(from_plane.get("pose"), abs=TOL)


def test_depth_file_problems_are_one_line_usage_errors(tmp_path, depth_files):
    (tmp_path / "noise.png").write_bytes(b"not a png")
    (tmp_path / "noise.npy").write_bytes(b"not numpy")
    assert cv2.imwrite(str(tmp_path / "eight.png"), np.full((H, W), 50, np.uint8))
    assert cv2.imwrite(str(tmp_path / "small.png"), np.full((240, 320), 500, np.uint16))
    np.save(tmp_path / "colour.npy", np.ones((H, W, 3), np.float32))
    detection_path, depth_cam = str(depth_files["detection"]), str(depth_files["depth_camera"])
    cases = [
        (depth_cam, None, ["surface is a depth image", "--depth"]),
        (str(depth_files["camera"]), depth_files["png"], ["--depth", "surface is the plane"]),
        (depth_cam, tmp_path / "missing.png", ["depth file", "No such file"]),
        (depth_cam, tmp_path, ["depth file", "Is a directory"]),
        (depth_cam, tmp_path / "noise.png", ["depth file", "not an image"]),
        (depth_cam, tmp_path / "noise.npy", ["depth file", "not a NumPy .npy array"]),
        (depth_cam, tmp_path / "eight.png", ["depth file", "8-bit samples"]),
        (depth_cam, tmp_path / "small.png", ["320x240 px but the camera model is 640x480 px"]),
        (depth_cam, tmp_path / "colour.npy", ["depth file", "one channel, not 3 channels"]),
    ]
    for camera_path, depth_path, words in cases:
        depth_args = [] if depth_path is None else ["--depth", str(depth_path)]
        result = invoke("plan", detection_path, "-c", camera_path, *depth_args)
        assert_usage_error(result, *words)
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def test_a_depth_hole_wider_than_the_window_is_no_grasp(tmp_path, depth_files):
    holed = np.full((H, W), 500, np.uint16)
    holed[200:280, 280:360] = 0
    assert cv2.imwrite(str(tmp_path / "holed.png"), holed)
    args = ["plan", str(depth_files["detection"]), "-c", str(depth_files["depth_camera"])]
    result = invoke(*args, "--depth", str(tmp_path / "holed.png"))
    assert_usage_error(result, "no valid depth at pixel (320.0, 240.0)", "5x5 px window")

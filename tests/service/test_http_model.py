"""POST /v1/model through a real uvicorn server on a loopback port: a rendered 3-D scene and
its camera model in, an MJCF that the real MuJoCo engine loads out; bad input 4xx."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Iterator

import httpx
import numpy as np
import pytest

from service.http import Settings
from service.synthetic.scene3d import make_scene_3d

from .test_http import assert_error, encode, running_server

mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with running_server(Settings(workers=2, queue_size=4, zenoh=False)) as base:
        yield base


@pytest.fixture(scope="module")
def flat():
    return make_scene_3d("down", seed=4, width=640, height=480, focal=700.0)


@pytest.fixture(scope="module")
def box():
    return make_scene_3d("box", seed=4, width=640, height=480, focal=700.0)


def post(base: str, image: bytes, fields: dict, files: dict | None = None, **kwargs):
    parts = {"image": ("scene.png", image, "image/png"), **(files or {})}
    return httpx.post(f"{base}/v1/model", files=parts, data=fields, timeout=60, **kwargs)


def depth_camera(scene) -> str:
    surface = {"kind": "depth", "depth_scale": 0.001}
    return json.dumps({**scene.camera.model_dump(mode="json"), "surface": surface})


def depth_png(scene) -> tuple[str, bytes, str]:
    return ("depth.png", encode(scene.depth_mm_png()), "image/png")


def test_plane_camera_gives_an_mjcf_that_mujoco_loads(server, flat) -> None:
    response = post(
        server,
        encode(flat.image),
        {"camera": flat.camera.model_dump_json(), "physics": '{"bending_stiffness": 1e-3}'},
        params={"segment_length": 20},
    )
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("application/xml")
    model = mujoco.MjModel.from_xml_string(response.text)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.nbody > 10
    # On the table of the camera model, every body one cable radius above it.
    assert model.geom("surface").pos[2] == pytest.approx(0.0)
    radii = model.geom_size[model.geom_type == mujoco.mjtGeom.mjGEOM_CAPSULE, 0]
    heights = data.xpos[1:, 2]
    assert np.all(np.abs(heights - np.median(radii)) < 1.5e-3)
    balls = ET.fromstring(response.text).findall(".//joint[@type='ball']")
    span = np.linalg.norm(np.diff(data.xpos[1:3], axis=0))
    assert float(balls[0].get("stiffness")) == pytest.approx(1e-3 / span, rel=0.5)


def test_depth_camera_with_its_depth_image(server, box) -> None:
    response = post(
        server,
        encode(box.image),
        {"camera": depth_camera(box)},
        {"depth": depth_png(box)},
        params={"segment_length": 20},
    )
    assert response.status_code == 200, response.text
    model = mujoco.MjModel.from_xml_string(response.text)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    # The cable on the box lies about its height up (0.06 m and a radius).
    assert data.xpos[1:, 2].max() == pytest.approx(0.06 + 0.0035, abs=2e-3)


def test_refusals_say_what_is_wrong(server, flat, box) -> None:
    image = encode(flat.image)
    camera = flat.camera.model_dump_json()
    assert_error(post(server, image, {}), 422, "camera")
    assert_error(post(server, image, {"camera": "{"}), 422, "camera")
    bad = assert_error(post(server, image, {"camera": camera, "physics": '{"stiff": 1}'}), 422)
    assert bad["error"] == "invalid_physics"
    unstable = '{"bending_stiffness": 1.0, "damping": 1e-9}'
    body = assert_error(post(server, image, {"camera": camera, "physics": unstable}), 422)
    assert body["error"] == "invalid_physics" and "damping" in body["detail"]
    body = assert_error(post(server, image, {"camera": camera}, {"depth": depth_png(flat)}), 422)
    assert body["error"] == "invalid_depth"
    body = assert_error(post(server, image, {"camera": depth_camera(flat)}), 422, "depth")
    assert body["error"] == "invalid_depth"
    wrong_size = ("depth.png", encode(np.zeros((10, 10), np.uint16)), "image/png")
    body = assert_error(
        post(server, image, {"camera": depth_camera(flat)}, {"depth": wrong_size}), 422
    )
    assert body["error"] == "invalid_depth"
    other = json.dumps({**json.loads(camera), "width": 320, "height": 240})
    body = assert_error(post(server, image, {"camera": other}), 422, "320x240")
    assert body["error"] == "invalid_camera"
    assert_error(
        httpx.post(f"{server}/v1/model", content=image, headers={"content-type": "image/png"}),
        415,
    )

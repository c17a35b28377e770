"""POST /v1/grasp through a real uvicorn server on a loopback port, talked to with httpx.

Two request shapes: a multipart form (image detected in the worker pool, camera and
selector as JSON fields) and a JSON body with a saved detection. Neither moves a robot.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest

from schemas import Chain, Detection
from service.http import Settings
from service.perception import detect as real_detect
from service.synthetic import make_scene
from tests.adapters.builders import looking_down
from tests.helpers import wait_until

from .test_http import assert_error, encode, metric, running_server

W, H = 480, 320
F = 600.0
TOL = 1e-4  # 0.1 mm
LABELS = ["approach", "descend", "close_gripper", "lift"]


def camera(origin=(0.25, 0.0, 0.3), width=W, height=H) -> dict:
    """A camera looking straight down from ``origin``, as JSON; image rows along base -y.

    At 0.3 m the 480x320 image covers x 0.13..0.37 and y -0.08..0.08 around the default
    origin: inside the UR3's default workspace wherever the cable lies.
    """
    model = looking_down(origin, fx=F, fy=F, cx=W / 2, cy=H / 2, width=width, height=height)
    return model.model_dump(mode="json")


def detection(*chains: Chain) -> dict:
    if not chains:
        chains = (horizontal_chain(),)
    return Detection(width=W, height=H, segment_length=60.0, chains=list(chains)).model_dump(
        mode="json"
    )


def horizontal_chain(chain_id=2, inferred=(False, False)) -> Chain:
    """Through the principal point, two 60 px segments along +x."""
    points = [(W / 2 - 60, H / 2), (W / 2, H / 2), (W / 2 + 60, H / 2)]
    return Chain(id=chain_id, points=points, radius=3.0, inferred=list(inferred))


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with running_server(Settings(workers=2, queue_size=4, zenoh=False)) as base:
        yield base


@pytest.fixture(scope="module")
def png() -> bytes:
    return encode(make_scene(W, H, 2, seed=5, loops=False).image)


def post_json(base: str, body: object, **kwargs) -> httpx.Response:
    return httpx.post(f"{base}/v1/grasp", json=body, timeout=30, **kwargs)


def post_form(base: str, png: bytes, fields: dict[str, str], **kwargs) -> httpx.Response:
    files = {"image": ("cell.png", png, "image/png")}
    return httpx.post(f"{base}/v1/grasp", files=files, data=fields, timeout=30, **kwargs)


# --- application/json: a saved detection ------------------------------------------------------


def test_json_body_gives_the_target_and_the_motions(server) -> None:
    selector = {"chain": 2, "point": {"kind": "fraction", "value": 0.75}}
    response = post_json(
        server, {"detection": detection(), "camera": camera(), "selector": selector}
    )
    assert response.status_code == 200, response.text
    plan = response.json()
    # 3/4 along is 30 px right of the centre: 30 px * 0.3 m / 600 px along base +x.
    assert plan["target"]["position_m"] == pytest.approx([0.25 + 30 * 0.3 / F, 0.0, 0.0], abs=TOL)
    assert plan["target"]["yaw_rad"] == pytest.approx(np.pi / 2)  # across a cable along x
    assert plan["target"]["chain_id"] == 2 and plan["target"]["segment_index"] == 1
    assert [motion["label"] for motion in plan["motions"]] == LABELS
    assert plan["motions"][0]["pose"][2] == pytest.approx(0.0 + 0.015 + 0.10)
    assert plan["within_workspace"] is True and "refusal" not in plan


def test_json_selector_defaults_to_the_middle_of_the_longest_chain(server) -> None:
    short = Chain(id=0, points=[(10.0, 10.0), (20.0, 10.0)], radius=2.0, inferred=[False])
    body = {"detection": detection(short, horizontal_chain(chain_id=5)), "camera": camera()}
    plan = post_json(server, body).json()
    assert plan["target"]["chain_id"] == 5
    assert plan["target"]["pixel"] == pytest.approx([W / 2, H / 2])


@pytest.mark.parametrize(
    "point, segment, pixel",
    [
        ({"kind": "segment", "index": 0}, 0, [W / 2 - 30, H / 2]),
        ({"kind": "pixel", "x": 250.0, "y": 100.0}, 1, [250.0, H / 2]),
        ({"kind": "end", "end": "start"}, 0, [W / 2 - 60, H / 2]),
    ],
)
def test_every_kind_of_point(server, point, segment, pixel) -> None:
    body = {"detection": detection(), "camera": camera(), "selector": {"point": point}}
    target = post_json(server, body).json()["target"]
    assert target["segment_index"] == segment
    assert target["pixel"] == pytest.approx(pixel)


def test_a_target_outside_the_workspace_is_planned_and_flagged(server) -> None:
    far = camera(origin=(0.6, 0.3, 0.3))
    response = post_json(server, {"detection": detection(), "camera": far})
    assert response.status_code == 200, response.text
    plan = response.json()
    assert plan["within_workspace"] is False
    assert "beyond" in plan["refusal"]
    assert [motion["label"] for motion in plan["motions"]] == LABELS


def test_inferred_segments_are_refused_unless_allowed(server) -> None:
    inferred = detection(horizontal_chain(inferred=(True, True)))
    body = {"detection": inferred, "camera": camera()}
    refused = post_json(server, body)
    assert assert_error(refused, 422, "was inferred", "allow_inferred")["error"] == (
        "inferred_segment"
    )
    allowed = post_json(server, {**body, "selector": {"allow_inferred": True}})
    assert allowed.status_code == 200
    assert allowed.json()["target"]["inferred"] is True


@pytest.mark.parametrize(
    "change, code, words",
    [
        ({"selector": {"chain": 9}}, "ungraspable", ["no chain with id 9", "[2]"]),
        (
            {"detection": {"width": W, "height": H, "segment_length": 10}},
            "ungraspable",
            ["no chains"],
        ),
        ({"camera": camera(width=640, height=480)}, "ungraspable", ["480x320 px", "640x480 px"]),
        ({"selector": {"point": {"kind": "segment", "index": 5}}}, "ungraspable", ["no segment 5"]),
        ({"camera": camera(origin=(0.25, 0.0, -0.3))}, "ungraspable", ["behind the camera"]),
    ],
)
def test_no_grasp_is_422_saying_why(server, change, code, words) -> None:
    body = {"detection": detection(), "camera": camera(), **change}
    assert assert_error(post_json(server, body), 422, *words)["error"] == code


def test_invalid_parts_are_422_naming_the_part(server) -> None:
    tilted = camera()
    tilted["T_base_camera"][0][0] = 2.0
    cases = [
        ({"camera": tilted}, "invalid_camera", ["camera.t_base_camera", "not orthonormal"]),
        ({"camera": {"fx": 1}}, "invalid_camera", ["camera.fy: field required"]),
        ({"selector": {"point": {"kind": "fraction", "value": 2}}}, "invalid_selector", ["value"]),
        ({"selector": {"chain": "shortest"}}, "invalid_selector", ["selector.chain"]),
        ({"detection": {"width": 0}}, "invalid_detection", ["detection.width"]),
        ({"extra": 1}, "invalid_body", ["extra: extra inputs are not permitted"]),
    ]
    for change, code, words in cases:
        body = {"detection": detection(), "camera": camera(), **change}
        assert assert_error(post_json(server, body), 422, *words)["error"] == code
    missing = post_json(server, {"detection": detection()})
    assert assert_error(missing, 422, "camera: field required")["error"] == "invalid_camera"
    for raw in (b"{not json", b"[]", b""):
        response = httpx.post(
            f"{server}/v1/grasp", content=raw, headers={"Content-Type": "application/json"}
        )
        assert_error(response, 422)


def test_absurd_coordinates_are_422_not_500(server) -> None:
    huge = Chain(id=0, points=[(1e300, 0.0), (-1e300, 5.0)], radius=1.0, inferred=[False])
    response = post_json(server, {"detection": detection(huge), "camera": camera()})
    assert assert_error(response, 422)["error"] == "ungraspable"
    grazing = camera(origin=(0.25, 0.0, 1e-300))
    response = post_json(server, {"detection": detection(), "camera": grazing})
    assert response.status_code in (200, 422), response.text


def test_query_parameters_with_a_json_body_are_422(server) -> None:
    body = {"detection": detection(), "camera": camera()}
    response = post_json(server, body, params={"segment_length": 8})
    assert_error(response, 422, "segment_length", "json body")


def test_other_content_types_are_415(server, png) -> None:
    response = httpx.post(f"{server}/v1/grasp", content=png, headers={"Content-Type": "image/png"})
    assert_error(response, 415, "multipart/form-data", "application/json")


# --- multipart/form-data: an image detected in the pool ----------------------------------------


def test_image_form_plans_on_what_detect_sees(server, png) -> None:
    selector = {"point": {"kind": "fraction", "value": 0.3}, "allow_inferred": True}
    fields = {"camera": json.dumps(camera()), "selector": json.dumps(selector)}
    response = post_form(server, png, fields, params={"segment_length": 12})
    assert response.status_code == 200, response.text
    plan = response.json()
    assert [motion["label"] for motion in plan["motions"]] == LABELS
    assert plan["within_workspace"] is True
    # The same plan from the detection /v1/detect returns, sent as JSON.
    detected = httpx.post(
        f"{server}/v1/detect",
        content=png,
        params={"segment_length": 12},
        headers={"Content-Type": "image/png"},
        timeout=30,
    ).json()
    body = {"detection": detected, "camera": camera(), "selector": selector}
    assert post_json(server, body).json() == plan


def test_camera_and_selector_may_come_as_files(server, png) -> None:
    files = {
        "image": ("cell.png", png, "image/png"),
        "camera": ("camera.json", json.dumps(camera()).encode(), "application/json"),
        "selector": ("selector.json", b'{"allow_inferred": true}', "application/json"),
    }
    response = httpx.post(f"{server}/v1/grasp", files=files, timeout=30)
    assert response.status_code == 200, response.text


def test_bad_forms_are_422_saying_what(server, png) -> None:
    good = json.dumps(camera())
    cases = [
        ({}, "invalid_camera", ["no 'camera' field"]),
        ({"camera": "{not json"}, "invalid_camera", ["camera: invalid json"]),
        ({"camera": json.dumps({"fx": -1})}, "invalid_camera", ["camera: fx"]),
        ({"camera": good, "selector": '{"chain": -1}'}, "invalid_selector", ["chain id"]),
        ({"camera": good, "detection": "{}"}, "invalid_form", ["unexpected form field"]),
        ({"camera": json.dumps(camera(width=64))}, "ungraspable", ["64x320 px"]),
    ]
    for fields, code, words in cases:
        response = post_form(server, png, fields)
        assert assert_error(response, 422, *words)["error"] == code
    unreadable = post_form(server, b"not a png", {"camera": good})
    assert assert_error(unreadable, 422)["error"] == "invalid_image"
    no_image = httpx.post(f"{server}/v1/grasp", data={"camera": good}, files={"mask": b"x"})
    assert_error(no_image, 422, "no 'image'")
    bad_query = post_form(server, png, {"camera": good}, params={"segment_length": -1})
    assert_error(bad_query, 422, "segment_length")


def test_busy_pool_answers_503_at_once(png) -> None:
    gate = threading.Event()

    def held_detect(image, params, mask, deadline) -> Detection:
        assert gate.wait(timeout=20), "test gate never opened"
        return real_detect(image, params, mask, deadline=deadline)

    settings = Settings(workers=1, queue_size=0, zenoh=False)
    gate.set()  # let the warm-up through
    with running_server(settings, held_detect) as base:
        gate.clear()
        fields = {"camera": json.dumps(camera()), "selector": '{"allow_inferred": true}'}
        with ThreadPoolExecutor(1) as client:
            held = client.submit(post_form, base, png, fields)
            wait_until(
                lambda: metric(base, "dlo_detections_in_flight") == 1,
                "the first request to be admitted",
            )
            refused = post_form(base, png, fields)
            assert_error(refused, 503, "busy")
            assert refused.headers["retry-after"] == "1"
            json_refused = post_json(base, {"detection": detection(), "camera": camera()})
            assert_error(json_refused, 503, "busy")
            gate.set()
            assert held.result().status_code == 200


def test_openapi_documents_both_request_shapes(server) -> None:
    schema = httpx.get(f"{server}/openapi.json").json()
    operation = schema["paths"]["/v1/grasp"]["post"]
    content = operation["requestBody"]["content"]
    assert set(content) == {"application/json", "multipart/form-data"}
    assert content["application/json"]["schema"]["required"] == ["detection", "camera"]
    assert content["multipart/form-data"]["schema"]["required"] == ["image", "camera"]
    assert "$ref" not in json.dumps(content)
    assert {"200", "415", "422", "503"} <= set(operation["responses"])


# --- multipart/form-data with a depth image -------------------------------------------------


def depth_camera(**surface) -> dict:
    """:func:`camera` with a depth-image surface in millimetres."""
    model = camera()
    model["surface"] = {"kind": "depth", "depth_scale": 0.001, **surface}
    return model


def depth_png(millimetres: int = 300, width: int = W, height: int = H) -> bytes:
    return encode(np.full((height, width), millimetres, np.uint16))


def post_depth(base: str, png: bytes, depth: bytes | None, model: dict) -> httpx.Response:
    files = {"image": ("cell.png", png, "image/png")}
    if depth is not None:
        files["depth"] = ("depth.png", depth, "image/png")
    fields = {"camera": json.dumps(model), "selector": '{"allow_inferred": true}'}
    return httpx.post(f"{base}/v1/grasp", files=files, data=fields, timeout=30)


def test_a_flat_depth_image_plans_as_the_table_plane(server, png) -> None:
    on_plane = post_form(
        server, png, {"camera": json.dumps(camera()), "selector": '{"allow_inferred": true}'}
    )
    on_depth = post_depth(server, png, depth_png(300), depth_camera())
    assert on_depth.status_code == 200, on_depth.text
    plane_target, depth_target = on_plane.json()["target"], on_depth.json()["target"]
    assert depth_target["position_m"] == pytest.approx(plane_target["position_m"], abs=TOL)
    assert depth_target["yaw_rad"] == pytest.approx(plane_target["yaw_rad"], abs=1e-6)


def test_a_raised_depth_lifts_the_grasp_along_its_ray(server, png) -> None:
    plane_target = post_form(
        server, png, {"camera": json.dumps(camera()), "selector": '{"allow_inferred": true}'}
    ).json()["target"]
    response = post_depth(server, png, depth_png(250), depth_camera())  # 5 cm above the table
    assert response.status_code == 200, response.text
    target = response.json()["target"]
    x, y, _ = plane_target["position_m"]
    # Straight down from (0.25, 0, 0.3): the same pixel at 0.25 m instead of 0.3 m.
    expected = [0.25 + (x - 0.25) * 0.25 / 0.3, y * 0.25 / 0.3, 0.05]
    assert target["position_m"] == pytest.approx(expected, abs=TOL)


def test_depth_problems_are_422_invalid_depth(server, png) -> None:
    truncated = depth_png()[:200]
    cases = [
        (None, depth_camera(), "invalid_depth", ["surface is a depth image", "'depth'"]),
        (depth_png(), camera(), "invalid_depth", ["surface is the plane z = 0.0 m"]),
        (b"", depth_camera(), "invalid_depth", ["depth: empty file"]),
        (b"not a png", depth_camera(), "invalid_depth", ["depth: not a png file"]),
        (truncated, depth_camera(), "invalid_depth", ["depth: truncated or corrupt png"]),
        (encode(np.full((H, W), 30, np.uint8)), depth_camera(), "invalid_depth", ["8-bit"]),
        (
            encode(np.full((H, W, 3), 300, np.uint16)),
            depth_camera(),
            "invalid_depth",
            ["3 channels"],
        ),
        (
            depth_png(width=W // 2),
            depth_camera(),
            "invalid_depth",
            ["240x320 px but the camera model is 480x320 px"],
        ),
        (depth_png(0), depth_camera(), "ungraspable", ["no valid depth at pixel"]),
        (depth_png(300), depth_camera(max_depth_m=0.2), "ungraspable", ["<= 0.2 m"]),
    ]
    for depth, model, code, words in cases:
        response = post_depth(server, png, depth, model)
        assert assert_error(response, 422, *words)["error"] == code


def test_a_json_body_cannot_carry_a_depth_surface(server) -> None:
    response = post_json(server, {"detection": detection(), "camera": depth_camera()})
    body = assert_error(response, 422, "depth image", "multipart/form-data", "'depth'")
    assert body["error"] == "invalid_depth"


def test_openapi_documents_the_depth_part(server) -> None:
    schema = httpx.get(f"{server}/openapi.json").json()
    form = schema["paths"]["/v1/grasp"]["post"]["requestBody"]["content"]["multipart/form-data"]
    depth = form["schema"]["properties"]["depth"]
    assert depth["format"] == "binary" and "16-bit PNG" in depth["description"]
    camera_schema = schema["paths"]["/v1/grasp"]["post"]["requestBody"]["content"][
        "application/json"
    ]["schema"]["properties"]["camera"]
    kinds = {
        json.dumps(option["properties"]["kind"])
        for option in camera_schema["properties"]["surface"]["oneOf"]
    }
    assert any('"depth"' in kind for kind in kinds) and any('"plane"' in kind for kind in kinds)

"""The MJCF of lifted chains in the real MuJoCo engine: it loads, starts where the cables
were seen, settles on the table, and a cable lifted by one end hangs as a chain does."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from pydantic import ValidationError

from schemas import Chain, Detection
from service.geometry3d import lift
from service.simulation import ModelError, to_mjcf
from tests.service.geometry3d.scenes import scene

mujoco = pytest.importorskip("mujoco")

SEGMENT_PX = 20.0
"""Coarser joints than the default keep the simulations short (MuJoCo's cost grows with
the square of a chain's length: every contact reaches back along it)."""


def lifted_scene(kind: str, seed: int = 0, mode: str = "plane") -> Detection:
    from schemas import DetectParams
    from service.perception import detect

    scene_3d = scene(kind, seed)
    found = detect(scene_3d.image, DetectParams(segment_length=SEGMENT_PX))
    if mode == "plane":
        return lift(found, scene_3d.camera)
    return lift(found, scene_3d.depth_camera, scene_3d.depth_m)


def load(tmp_path, text: str):
    path = tmp_path / "cables.mjcf.xml"
    path.write_text(text)
    model = mujoco.MjModel.from_xml_path(str(path))
    return model, mujoco.MjData(model)


def body_names(model) -> list[str]:
    return [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(1, model.nbody)]


def joint_of(detection: Detection, body: str) -> np.ndarray:
    """The lifted joint a body ``chain<C>_<K>`` starts at."""
    chain_id, index = re.fullmatch(r"chain(\d+)_(\d+)", body).groups()
    return np.array(detection.chain(int(chain_id)).points_3d[int(index)])


def simulate(model, data, seconds: float) -> None:
    for _ in range(round(seconds / model.opt.timestep)):
        mujoco.mj_step(model, data)
    assert_stable(data)


def assert_stable(data) -> None:
    """MuJoCo resets a simulation that blows up (and warns): finite positions alone prove
    nothing, so no such warning may have been raised."""
    assert data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number == 0, "the simulation blew up"


# --- structure -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kind", "mode"), [("down", "plane"), ("crossing", "plane"), ("box", "depth")]
)
def test_every_body_starts_at_its_lifted_joint(tmp_path, kind, mode):
    detection = lifted_scene(kind, mode=mode)
    model, data = load(tmp_path, to_mjcf(detection))
    mujoco.mj_forward(model, data)
    names = body_names(model)
    # One body per segment, and nothing else: the surface is a geom of the world body.
    assert len(names) == sum(len(chain.points) - 1 for chain in detection.chains)
    assert [
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g)
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == 0
    ] == ["surface"]
    assert model.geom_type[0] == mujoco.mjtGeom.mjGEOM_PLANE
    for index, name in enumerate(names, start=1):
        assert np.linalg.norm(data.xpos[index] - joint_of(detection, name)) < 1e-3
    # Capsules as long as their segments and as thick as the cable.
    for chain in detection.chains:
        points = np.array(chain.points_3d)
        for k in range(len(points) - 1):
            geom = model.geom(f"chain{chain.id}_{k}_capsule")
            assert geom.size[0] == pytest.approx(chain.radius_m, rel=1e-6)
            assert 2 * geom.size[1] == pytest.approx(
                np.linalg.norm(points[k + 1] - points[k]), rel=1e-6
            )


def test_the_model_is_plain_mjcf_with_the_physics_written_per_joint():
    detection = straight_cable(segments=4, length=0.04)
    text = to_mjcf(
        detection,
        bending_stiffness=1e-3,
        twisting_stiffness=5e-4,
        damping=2e-4,
        mass_per_metre=0.05,
    )
    root = ET.fromstring(text)
    assert root.tag == "mujoco"
    assert root.find("option").get("integrator") == "implicitfast"
    balls = root.findall(".//joint[@type='ball']")
    assert len(balls) == 3 and len(root.findall(".//freejoint")) == 1
    span = 0.01  # segments of 10 mm
    assert float(balls[0].get("stiffness")) == pytest.approx(1e-3 / span)
    assert float(balls[0].get("damping")) == pytest.approx(2e-4 / span)
    capsules = root.findall(".//geom[@type='capsule']")
    assert float(capsules[0].get("mass")) == pytest.approx(0.05 * span)
    twists = root.findall("./actuator/general")
    assert len(twists) == 3
    assert float(twists[0].get("biasprm").split()[1]) == pytest.approx((1e-3 - 5e-4) / span)


# --- physics --------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["down", "crossing"])
def test_cables_on_a_flat_table_stay_where_they_were_seen(tmp_path, kind):
    detection = lifted_scene(kind)
    model, data = load(tmp_path, to_mjcf(detection))
    mujoco.mj_forward(model, data)
    start = data.xpos[1:].copy()
    simulate(model, data, 2.0)
    assert model.opt.timestep == pytest.approx(0.002)
    assert np.isfinite(data.xpos).all()
    moved = np.linalg.norm(data.xpos[1:] - start, axis=1)
    assert moved.max() < 10e-3, f"a body moved {moved.max() * 1e3:.2f} mm"


def straight_cable(segments: int = 30, length: float = 0.3, radius: float = 0.003) -> Detection:
    """A lifted detection by hand: one straight cable along base x, lying on z = 0."""
    xs = np.linspace(0.2, 0.2 + length, segments + 1)
    points = [(float(x), 0.0, radius) for x in xs]
    chain = Chain(
        id=0,
        points=[(10.0 * k, 100.0) for k in range(segments + 1)],
        radius=3.0,
        inferred=[False] * segments,
        points_3d=points,
        radius_m=radius,
    )
    return Detection(width=400, height=200, segment_length=10.0, chains=[chain])


def lifted_by_one_end(physics: dict, height: float = 0.15, seconds: float = 3.0):
    """Simulate the straight cable with its first body pulled up to ``height`` above its
    start (over the first second) and held there; the bodies' final positions."""
    spec = mujoco.MjSpec.from_string(to_mjcf(straight_cable(), **physics))
    start = np.array([0.2, 0.0, 0.003])
    spec.worldbody.add_body(name="hand", mocap=True, pos=start)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_CONNECT,
        name1="chain0_0",
        name2="hand",
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        data=np.zeros(12),
    )
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for step in range(round(seconds / model.opt.timestep)):
        rise = min(step * model.opt.timestep / 1.0, 1.0)
        data.mocap_pos[0] = start + np.array([0.0, 0.0, height * rise])
        mujoco.mj_step(model, data)
    assert_stable(data)
    names = body_names(model)
    cable = [model.body(name).id for name in names if name.startswith("chain0_")]
    return data.xpos[cable].copy(), start + np.array([0.0, 0.0, height])


def test_a_cable_lifted_by_one_end_hangs_like_a_chain():
    limp = {"bending_stiffness": 1e-6, "twisting_stiffness": 1e-6, "damping": 2e-6}
    bodies, top = lifted_by_one_end(limp)
    assert np.isfinite(bodies).all()
    assert np.linalg.norm(bodies[0] - top) < 5e-3  # the end is where it was pulled
    heights = bodies[:, 2]
    hanging = heights > 0.01
    first_down = int(np.argmin(hanging))  # the first body back on the table
    assert first_down > 5
    # Hanging: height falls all the way from the hand to the table, never rising again ...
    assert np.all(np.diff(heights[:first_down]) < 1e-4)
    # ... its length (a chain does not stretch) at least the height it hangs from ...
    links = np.linalg.norm(np.diff(bodies, axis=0), axis=1)
    np.testing.assert_allclose(links, 0.01, atol=2e-4)
    assert links[:first_down].sum() >= 0.15 - 0.01
    # ... in a catenary's shape (what a hanging chain takes) down to the table.
    off = heights > 0.012  # clear of the table (and of the last link leaving it)
    across = np.linalg.norm(bodies[off, :2] - bodies[0, :2], axis=1)
    assert catenary_misfit(across, heights[off]) < 0.1e-3
    # The rest still lies on the table.
    assert np.all(heights[first_down + 2 :] < 0.006)


def catenary_misfit(across: np.ndarray, heights: np.ndarray) -> float:
    """RMS height difference (m) from the best catenary ``z0 + a (cosh((x - x0) / a) - 1)``."""
    from scipy.optimize import least_squares

    def residuals(parameters):
        a, x0, z0 = parameters
        return z0 + a * (np.cosh(np.clip((across - x0) / a, -50, 50)) - 1.0) - heights

    best = min(
        (
            least_squares(
                residuals, (a, across.max(), heights.min()), bounds=([1e-4, -1, -1], [10, 2, 1])
            )
            for a in (0.01, 0.03, 0.1, 0.3)
        ),
        key=lambda fit: fit.cost,
    )
    return float(np.sqrt(np.mean(best.fun**2)))


def test_damping_at_the_stable_minimum_is_stable():
    """The refusal's bound is where it should be: at damping = stiffness x timestep a
    stiff cable pulled about still does not blow up (a fifth of it does)."""
    bodies, top = lifted_by_one_end({"bending_stiffness": 1e-2, "damping": 1e-2 * 0.002})
    assert np.linalg.norm(bodies[0] - top) < 5e-3


def test_a_stiffer_cable_bends_less_when_lifted():
    limp, _ = lifted_by_one_end({"bending_stiffness": 1e-6, "damping": 2e-6})
    stiff, _ = lifted_by_one_end({"bending_stiffness": 5e-3})

    # The stiff one stands off further from the hand before it reaches the table.
    def reach(bodies):
        down = int(np.argmin(bodies[:, 2] > 0.01))
        return float(np.linalg.norm(bodies[down, :2] - bodies[0, :2]))

    assert reach(stiff) > reach(limp) + 0.02


# --- refusals -------------------------------------------------------------------------


def test_a_detection_not_lifted_is_refused():
    detection = straight_cable()
    plain = detection.model_copy(
        update={"chains": [detection.chains[0].model_copy(update={"points_3d": None})]}
    )
    with pytest.raises(ModelError, match="lift the detection"):
        to_mjcf(plain)


def test_unstable_physics_are_refused_with_the_reason():
    with pytest.raises(ModelError, match=r"damping .* below .* timestep"):
        to_mjcf(straight_cable(), bending_stiffness=1e-2, damping=1e-6)
    with pytest.raises(ValidationError):
        to_mjcf(straight_cable(), stiffness=1.0)
    with pytest.raises(ValidationError):
        to_mjcf(straight_cable(), mass_per_metre=-1.0)


def test_null_points_are_interpolated_inside_and_cut_at_the_ends():
    detection = straight_cable(segments=10)
    points = list(detection.chains[0].points_3d)
    points[0] = points[4] = points[5] = None
    holes = detection.model_copy(
        update={"chains": [detection.chains[0].model_copy(update={"points_3d": points})]}
    )
    root = ET.fromstring(to_mjcf(holes))
    names = [body.get("name") for body in root.iter("body")]
    assert names[0] == "chain0_1"  # the null first joint is left out
    assert "chain0_4" in names and "chain0_5" in names  # filled in between 3 and 6
    model = mujoco.MjModel.from_xml_string(to_mjcf(holes))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    np.testing.assert_allclose(
        data.xpos[model.body("chain0_4").id], (0.2 + 4 * 0.03, 0, 0.003), atol=1e-9
    )
    assert math.isclose(model.opt.timestep, 0.002)

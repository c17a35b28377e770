"""The README's picture of the MuJoCo model: a rendered scene, its model, and the model
after a simulated hand lifted one cable by an end.

``python -m service.evaluation.model_figure docs/images/model.png`` (needs the ``mujoco``
package: ``pip install -e '.[sim]'``). It renders with MuJoCo's offscreen renderer (EGL by
default, ``MUJOCO_GL`` chooses); where no OpenGL is available it draws the bodies seen from
the side with OpenCV instead.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

from schemas import DetectParams
from service.geometry3d import lift
from service.perception import detect, render_overlay
from service.simulation.mjcf import to_mjcf
from service.synthetic.scene3d import make_scene_3d

PANEL = (640, 480)
"""Width and height of each panel, pixels."""
LIFT_HEIGHT = 0.12
"""How high the hand lifts the first cable's first joint, metres."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="PNG to write")
    parser.add_argument("--seed", type=int, default=2, help="scene seed (default 2)")
    parser.add_argument("--seconds", type=float, default=3.0, help="simulated time (default 3)")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        import mujoco
    except ImportError:
        print("error: the figure needs mujoco: pip install -e '.[sim]'", file=sys.stderr)
        return 1
    scene = make_scene_3d("crossing", seed=args.seed, width=960, height=720, focal=1050.0)
    detection = detect(scene.image, DetectParams(segment_length=15.0))
    lifted = lift(detection, scene.camera)
    spec = mujoco.MjSpec.from_string(to_mjcf(lifted, plane_z=0.0))
    first = f"chain{lifted.chains[0].id}_0"
    start = np.array(lifted.chains[0].points_3d[0])
    spec.worldbody.add_body(name="hand", mocap=True, pos=start)
    spec.add_equality(
        type=mujoco.mjtEq.mjEQ_CONNECT,
        name1=first,
        name2="hand",
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        data=np.zeros(12),
    )
    spec.visual.global_.offwidth, spec.visual.global_.offheight = PANEL
    spec.worldbody.add_light(pos=[0.3, -0.3, 1.0], dir=[0.0, 0.3, -1.0], diffuse=[0.7] * 3)
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    view = _render(mujoco, model, data, scene)
    as_seen = view()
    for step in range(round(args.seconds / model.opt.timestep)):
        rise = min(step * model.opt.timestep / (0.5 * args.seconds), 1.0)
        data.mocap_pos[0] = start + np.array([0.0, 0.0, LIFT_HEIGHT * rise])
        mujoco.mj_step(model, data)
    lifted_view = view()
    photo = cv2.resize(render_overlay(scene.image, detection), PANEL, interpolation=cv2.INTER_AREA)
    panels = [photo, as_seen, lifted_view]
    labels = ["detected in the image", "MuJoCo model as lifted", "one end lifted 12 cm"]
    for panel, label in zip(panels, labels, strict=True):
        cv2.putText(panel, label, (12, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(args.out), np.hstack(panels)):
        print(f"error: {args.out}: cannot write", file=sys.stderr)
        return 1
    print(args.out)
    return 0


def _render(mujoco, model, data, scene):
    """A function drawing the model now: MuJoCo's renderer from an oblique view, or, with
    no OpenGL, the bodies from the side with OpenCV."""
    try:
        renderer = mujoco.Renderer(model, PANEL[1], PANEL[0])
    except Exception as exc:  # no OpenGL platform here: draw the bodies instead
        print(f"note: MuJoCo cannot render here ({exc}); drawing a side view", file=sys.stderr)
        return lambda: _side_view(data.xpos[1:].copy())
    camera = mujoco.MjvCamera()
    camera.lookat[:] = data.xpos[1:].mean(axis=0) + np.array([0.0, 0.0, 0.03])
    camera.distance, camera.azimuth, camera.elevation = 0.36, -70.0, -30.0

    def draw() -> np.ndarray:
        renderer.update_scene(data, camera)
        return cv2.cvtColor(renderer.render(), cv2.COLOR_RGB2BGR)

    return draw


def _side_view(points: np.ndarray) -> np.ndarray:
    """Bodies seen along base +y (x right, z up), 2 px per millimetre."""
    canvas = np.full((PANEL[1], PANEL[0], 3), 40, np.uint8)
    ground = PANEL[1] - 40
    cv2.line(canvas, (0, ground), (PANEL[0], ground), (150, 150, 150), 1)
    for x, _, z in points:
        centre = (int(PANEL[0] / 2 + (x - 0.3) * 2000), int(ground - z * 2000))
        cv2.circle(canvas, centre, 3, (60, 180, 240), -1)
    return canvas


if __name__ == "__main__":
    raise SystemExit(main())

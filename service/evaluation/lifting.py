"""How close ``points_3d`` comes to the true centreline: the table in docs/BENCHMARKS.md.

``python -m service.evaluation.lifting [--seeds 0-4] [--lighting ring|side]`` renders every
kind of :mod:`service.synthetic.scene3d` scene, detects the cables in the image, lifts them with
the plane camera (cables on the bare table) and with the depth image (every kind), and
prints per case the share of joints within 1 mm of the closed-form centreline, the median
and 95th percentile error and the radius error. ``--perfect`` lifts the true chains
instead (each centreline projected, joints 10 px apart): the lifting's own error.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable

import cv2
import numpy as np

from schemas import Chain, Crossing, Detection
from service.geometry3d import lift
from service.perception import detect
from service.synthetic.scene3d import SCENE_KINDS, Scene3D, distance_to_polylines, make_scene_3d

BOX_KINDS = ("box", "box_tilted")
PERFECT_SEGMENT_PX = 10.0


def evaluate(seeds: Iterable[int], lighting: str, perfect: bool) -> list[dict]:
    rows = []
    for kind in SCENE_KINDS:
        modes = ("depth",) if kind in BOX_KINDS else ("plane", "depth")
        errors = {mode: [] for mode in modes}
        radius_errors = {mode: [] for mode in modes}
        for seed in seeds:
            scene = make_scene_3d(kind, seed=seed, lighting=lighting)
            detection = perfect_detection(scene) if perfect else detect(scene.image)
            for mode in modes:
                if mode == "plane":
                    lifted = lift(detection, scene.camera)
                else:
                    lifted = lift(detection, scene.depth_camera, scene.depth_m)
                for chain in lifted.chains:
                    points = np.array(
                        [p if p is not None else (np.nan,) * 3 for p in chain.points_3d]
                    )
                    distance = scene.distance_to_centrelines(points)
                    errors[mode].extend(distance.tolist())
                    if chain.radius_m is not None:
                        cable = nearest_cable(scene, points)
                        radius_errors[mode].append(chain.radius_m - cable.radius)
        for mode in modes:
            values = np.array(errors[mode])
            located = values[np.isfinite(values)]
            rows.append(
                {
                    "kind": kind,
                    "surface": mode,
                    "joints": len(values),
                    "null": int(np.sum(~np.isfinite(values))),
                    "within_1mm": float(np.mean(located <= 1e-3)),
                    "p50_mm": float(np.median(located) * 1e3),
                    "p95_mm": float(np.percentile(located, 95) * 1e3),
                    "radius_error_mm": float(np.mean(radius_errors[mode]) * 1e3),
                }
            )
    return rows


def nearest_cable(scene_3d: Scene3D, points: np.ndarray):
    """The cable of the scene that lifted points (``(N, 3)``, NaN rows) lie along."""
    return min(
        scene_3d.cables,
        key=lambda cable: np.nanmedian(distance_to_polylines(points, [cable.centreline])),
    )


def project(scene_3d: Scene3D, points: np.ndarray) -> np.ndarray:
    """Base-frame points to pixels, with OpenCV's projection (the camera model's definition)."""
    camera = scene_3d.camera
    transform = np.asarray(camera.T_base_camera)
    rotation, origin = transform[:3, :3], transform[:3, 3]
    K = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    in_camera = (points - origin) @ rotation
    pixels, _ = cv2.projectPoints(in_camera, np.zeros(3), np.zeros(3), K, np.array(camera.dist))
    return pixels.reshape(-1, 2)


def perfect_detection(scene_3d: Scene3D) -> Detection:
    """A perfect detection: each true centreline projected, joints 10 px apart along it,
    its radius the projected radius (median along the cable); where two cross, the
    crossing (the higher one on top) and the lower one's segments under the upper one's
    band inferred, as the detector reports them."""
    camera = scene_3d.camera
    chains = []
    for index, cable in enumerate(scene_3d.cables):
        pixels = project(scene_3d, cable.centreline)
        steps = np.linalg.norm(np.diff(pixels, axis=0), axis=1)
        along = np.concatenate(([0.0], np.cumsum(steps)))
        stations = np.arange(0.0, along[-1], PERFECT_SEGMENT_PX)
        joints = np.column_stack([np.interp(stations, along, pixels[:, axis]) for axis in range(2)])
        transform = np.asarray(camera.T_base_camera)
        depth = ((cable.centreline - transform[:3, 3]) @ transform[:3, :3])[:, 2]
        radius_px = float(np.median(camera.fx * cable.radius / depth))
        chains.append(
            Chain(
                id=index,
                points=[tuple(point) for point in joints],
                radius=radius_px,
                inferred=[False] * (len(joints) - 1),
            )
        )
    crossings = []
    for over_index, under_index in ((1, 0), (0, 1)):
        if max(over_index, under_index) >= len(chains):
            continue
        found = _crossing(scene_3d, chains, over_index, under_index)
        if found is not None:
            crossings.append(found)
    for crossing in crossings:
        under, over = chains[crossing.under], chains[crossing.over]
        joints = np.asarray(under.points)
        middles = 0.5 * (joints[:-1] + joints[1:])
        band = np.asarray(over.points)
        covered = _distances(middles, band) <= over.radius
        chains[crossing.under] = under.model_copy(
            update={
                "inferred": [a or bool(b) for a, b in zip(under.inferred, covered, strict=True)]
            }
        )
    return Detection(
        width=camera.width,
        height=camera.height,
        segment_length=PERFECT_SEGMENT_PX,
        chains=chains,
        crossings=crossings,
    )


def _crossing(scene_3d: Scene3D, chains, over_index: int, under_index: int) -> Crossing | None:
    """Where chain ``over_index`` crosses ``under_index`` in the image, if it lies higher."""
    over, under = np.asarray(chains[over_index].points), np.asarray(chains[under_index].points)
    for i in range(len(over) - 1):
        for j in range(len(under) - 1):
            p, r = over[i], over[i + 1] - over[i]
            q, s = under[j], under[j + 1] - under[j]
            denominator = r[0] * s[1] - r[1] * s[0]
            if denominator == 0:
                continue
            t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denominator
            u = ((q - p)[0] * r[1] - (q - p)[1] * r[0]) / denominator
            if 0 <= t < 1 and 0 <= u < 1:
                at = p + t * r
                heights = [float(np.max(cable.centreline[:, 2])) for cable in scene_3d.cables]
                if heights[over_index] <= heights[under_index]:
                    return None
                return Crossing(
                    x=float(at[0]),
                    y=float(at[1]),
                    over=over_index,
                    under=under_index,
                    over_segment=i,
                    under_segment=j,
                    confidence=1.0,
                )
    return None


def _distances(queries: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    starts, steps = polyline[:-1], np.diff(polyline, axis=0)
    t = np.einsum("qsj,sj->qs", queries[:, None] - starts[None], steps) / np.einsum(
        "sj,sj->s", steps, steps
    )
    closest = starts[None] + np.clip(t, 0, 1)[..., None] * steps[None]
    return np.linalg.norm(queries[:, None] - closest, axis=2).min(axis=1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-4", help="seed range, e.g. 0-4 (default)")
    parser.add_argument("--lighting", choices=("ring", "side"), default="ring")
    parser.add_argument("--perfect", action="store_true", help="lift the true chains")
    args = parser.parse_args(argv)
    first, _, last = args.seeds.partition("-")
    seeds = range(int(first), int(last or first) + 1)
    rows = evaluate(seeds, args.lighting, args.perfect)
    source = "true chains" if args.perfect else "detected chains"
    print(f"seeds {args.seeds}, lighting {args.lighting}, {source}")
    print("| scene | surface | joints | null | within 1 mm | p50 mm | p95 mm | radius error mm |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['kind']} | {row['surface']} | {row['joints']} | {row['null']} | "
            f"{row['within_1mm']:.1%} | {row['p50_mm']:.2f} | {row['p95_mm']:.2f} | "
            f"{row['radius_error_mm']:+.2f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

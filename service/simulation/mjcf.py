"""A MuJoCo model (MJCF) of lifted chains: capsules joined by ball joints on a plane.

Structure (names use the chain id ``C`` and the joint index ``K`` of the detection)::

    <worldbody>
      <geom name="surface" type="plane"/>                 the table, z = plane_z
      <body name="chainC_K0" pos="joint K0">              one body per segment, at its
        <freejoint name="chainC_free"/>                   first joint (base frame, m)
        <geom name="chainC_K0_capsule" type="capsule" fromto="0 0 0 ..." size="r"/>
        <body name="chainC_K1" pos="joint K1 - joint K0">
          <joint name="chainC_K1_ball" type="ball" stiffness damping/>
          <geom .../>
          ...
    <actuator>
      <general name="chainC_K1_twist" .../>               only when twisting differs

Every body's frame is the base frame's orientation at the body's first joint, so at the
start every body is exactly at its lifted joint, and each ball joint's rest orientation is
the shape the cable was seen in (a cable lying on a table keeps its curves). The physics
(:class:`schemas.model.CablePhysics`, per metre of cable) are divided among the segments:
a joint between segments of lengths ``a`` and ``b`` has stiffness ``EI / l`` and damping
``D / l`` with ``l = (a + b) / 2``; a segment of length ``a`` has mass ``mu a``. MuJoCo's
ball-joint spring is the same about every axis, so it is set to the bending stiffness, and
where the twisting stiffness differs a passive ``general`` actuator on the ball joint (no
gain: its control does nothing) adds ``(GJ - EI) / l`` about the cable's axis.

Null points (no valid depth at a seen joint): inside a chain, the point is interpolated
along the chain (by the image arc length between the located neighbours); at a chain's
ends, those joints are left out (the modelled cable is shorter there: extrapolating would
be a guess). A chain with fewer than two located joints is left out. Joints closer than a
fifth of the radius to the previous one are merged into it. Capsules of one chain closer
along it than their diameter do not collide with each other (they would touch wherever the
cable bends); all other pairs do.

Generating the model needs no MuJoCo; loading and simulating it does (tested with
MuJoCo 4.0, from its ``mujoco`` wheel).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from typing import Any

import numpy as np

from schemas import CameraModel, Chain, Detection, PlaneSurface
from schemas.model import CablePhysics, ResolvedPhysics

INTEGRATOR = "implicitfast"
"""Integrates the joint damping implicitly, which keeps the stiff short segments stable."""
MERGE_FRACTION = 0.2
"""Joints closer than this many radii to the previous kept joint are merged into it."""
COLOURS = ((0.85, 0.2, 0.2), (0.95, 0.85, 0.2), (0.25, 0.75, 0.3), (0.2, 0.45, 0.9))
"""Capsule colours, chain after chain (RGB)."""


class ModelError(ValueError):
    """The detection cannot be modelled: not lifted, or physics that would not be stable."""


def to_mjcf(detection: Detection, **physics: Any) -> str:
    """The MJCF text of the lifted chains of ``detection`` on their surface plane.

    Parameters
    ----------
    detection
        A detection lifted to 3-D (:func:`service.geometry3d.lift`): every chain has
        ``points_3d`` and ``radius_m``.
    **physics
        :class:`schemas.model.CablePhysics` fields: ``bending_stiffness`` (N m^2),
        ``twisting_stiffness`` (N m^2), ``damping`` (N m^2 s), ``mass_per_metre`` (kg/m),
        ``friction``, ``timestep`` (s), ``plane_z`` (m).

    Raises
    ------
    ModelError
        A chain was not lifted, or the damping is below the stable minimum (the larger
        stiffness times the timestep).
    pydantic.ValidationError
        An unknown or out-of-range physics parameter.
    """
    settings = physics_of(physics)
    chains = []
    for chain in detection.chains:
        if chain.points_3d is None:
            raise ModelError(
                f"chain {chain.id} has no points_3d: lift the detection to 3-D first "
                "(service.geometry3d.lift with a camera model)"
            )
        chains.append((chain, _modelled_joints(chain)))
    plane_z = settings.plane_z
    if plane_z is None:
        lows = [
            float(points[:, 2].min()) - chain.radius_m
            for chain, (_, points) in chains
            if len(points) >= 2 and chain.radius_m is not None
        ]
        plane_z = min(lows) if lows else 0.0
    root = ET.Element("mujoco", model="detected_cables")
    root.append(
        ET.Comment(
            " dlo-service: the detected cables, one capsule body per segment joined by ball "
            "joints; base frame, metres. "
        )
    )
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", timestep=_num(settings.timestep), integrator=INTEGRATOR)
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(
        world,
        "geom",
        name="surface",
        type="plane",
        pos=_vector((0.0, 0.0, plane_z)),
        size="0 0 0.05",
        rgba="0.55 0.55 0.55 1",
    )
    contact = ET.Element("contact")
    actuators = ET.Element("actuator")
    every_point = []
    for index, (chain, (indices, points)) in enumerate(chains):
        if len(points) < 2 or chain.radius_m is None:
            world.append(ET.Comment(f" chain {chain.id}: fewer than two located joints, left out "))
            continue
        resolved = settings.for_radius(chain.radius_m)
        _check_stable(chain.id, resolved)
        world.append(ET.Comment(f" chain {chain.id}: {_describe(chain.radius_m, resolved)} "))
        _add_chain(world, contact, actuators, chain, indices, points, resolved, index)
        every_point.append(points)
    if len(contact):
        root.append(contact)
    if len(actuators):
        root.append(actuators)
    if every_point:
        stacked = np.vstack(every_point)
        low, high = stacked.min(axis=0), stacked.max(axis=0)
        ET.SubElement(
            root,
            "statistic",
            center=_vector((low + high) / 2.0),
            extent=_num(max(float(np.linalg.norm(high - low)), 0.05)),
        )
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def with_surface(physics: CablePhysics | None, camera: CameraModel) -> CablePhysics:
    """``physics`` (the defaults when None) with the plane at the camera's table plane when
    its surface is a plane and no ``plane_z`` was given."""
    physics = physics or CablePhysics()
    if physics.plane_z is None and isinstance(camera.surface, PlaneSurface):
        return physics.model_copy(update={"plane_z": camera.surface.plane_z})
    return physics


def physics_of(physics: Mapping[str, Any] | CablePhysics) -> CablePhysics:
    """``physics`` as :class:`CablePhysics` (validated)."""
    if isinstance(physics, CablePhysics):
        return physics
    return CablePhysics(**physics)


def _modelled_joints(chain: Chain) -> tuple[list[int], np.ndarray]:
    """The joint indices and 3-D points the model uses (nulls filled or cut, close ones merged)."""
    assert chain.points_3d is not None
    located = np.array([point is not None for point in chain.points_3d])
    if located.sum() < 2:
        return [], np.zeros((0, 3))
    pixels = np.asarray(chain.points, dtype=float)
    along = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.diff(pixels, axis=0), axis=1))))
    known = np.array([point for point in chain.points_3d if point is not None], dtype=float)
    first, last = np.flatnonzero(located)[[0, -1]]
    kept = np.arange(first, last + 1)
    points = np.column_stack(
        [np.interp(along[kept], along[located], known[:, axis]) for axis in range(3)]
    )
    radius = chain.radius_m or 0.0
    indices, merged = [int(kept[0])], [points[0]]
    for index, point in zip(kept[1:], points[1:], strict=True):
        if np.linalg.norm(point - merged[-1]) < MERGE_FRACTION * radius:
            continue
        indices.append(int(index))
        merged.append(point)
    return indices, np.array(merged)


def _check_stable(chain_id: int, physics: ResolvedPhysics) -> None:
    stiffest = max(physics.bending_stiffness, physics.twisting_stiffness)
    minimum = stiffest * physics.timestep
    if physics.damping < minimum:
        raise ModelError(
            f"chain {chain_id}: damping {physics.damping:.3g} N m^2 s is below "
            f"{minimum:.3g} (the stiffness {stiffest:.3g} N m^2 times the timestep "
            f"{physics.timestep:g} s); the model would not be stable: raise the damping or "
            "lower the timestep"
        )


def _add_chain(world, contact, actuators, chain, indices, points, physics, colour_index):
    """The nested bodies of one chain, its contact exclusions and twist actuators."""
    name = f"chain{chain.id}"
    radius = chain.radius_m
    segments = np.diff(points, axis=0)
    lengths = np.linalg.norm(segments, axis=1)
    rgba = " ".join(_num(v) for v in (*COLOURS[colour_index % len(COLOURS)], 1.0))
    parent, previous = world, np.zeros(3)
    bodies = []
    for number, (index, start) in enumerate(zip(indices[:-1], points[:-1], strict=True)):
        body_name = f"{name}_{index}"
        body = ET.SubElement(parent, "body", name=body_name, pos=_vector(start - previous))
        if number == 0:
            ET.SubElement(body, "freejoint", name=f"{name}_free")
        else:
            span = 0.5 * (lengths[number - 1] + lengths[number])
            joint = f"{body_name}_ball"
            ET.SubElement(
                body,
                "joint",
                name=joint,
                type="ball",
                stiffness=_num(physics.bending_stiffness / span),
                damping=_num(physics.damping / span),
            )
            extra = (physics.twisting_stiffness - physics.bending_stiffness) / span
            if abs(extra) > 1e-9 * physics.bending_stiffness / span:
                axis = segments[number] / lengths[number]
                ET.SubElement(
                    actuators,
                    "general",
                    name=f"{body_name}_twist",
                    joint=joint,
                    gear=_vector((*axis, 0.0, 0.0, 0.0)),
                    gainprm="0",
                    biastype="affine",
                    biasprm=f"0 {_num(-extra)} 0",
                )
        ET.SubElement(
            body,
            "geom",
            name=f"{body_name}_capsule",
            type="capsule",
            fromto=_vector((0.0, 0.0, 0.0, *segments[number])),
            size=_num(radius),
            mass=_num(physics.mass_per_metre * lengths[number]),
            friction=f"{_num(physics.friction)} 0.005 0.0001",
            rgba=rgba,
        )
        bodies.append(body_name)
        parent, previous = body, start
    reach = 1 + math.ceil(2.0 * radius / max(float(lengths.mean()), 1e-9))
    for first in range(len(bodies)):
        for second in range(first + 2, min(first + reach + 1, len(bodies))):
            ET.SubElement(contact, "exclude", body1=bodies[first], body2=bodies[second])


def _describe(radius: float, physics: ResolvedPhysics) -> str:
    return (
        f"radius {radius * 1000:.2f} mm, bending stiffness {physics.bending_stiffness:.3g} "
        f"N m^2, twisting stiffness {physics.twisting_stiffness:.3g} N m^2, damping "
        f"{physics.damping:.3g} N m^2 s, {physics.mass_per_metre * 1000:.3g} g/m"
    )


def _num(value: float) -> str:
    return f"{float(value):.9g}"


def _vector(values) -> str:
    return " ".join(_num(value) for value in values)

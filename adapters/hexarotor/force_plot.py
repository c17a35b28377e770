"""The picture of ``dlo feasibility --plot``: the forces a hovering hexarotor can exert."""

from __future__ import annotations

import math

import cv2
import numpy as np

from adapters.hexarotor.wrench import (
    HexarotorGeometry,
    PullFeasibility,
    slice_axis_for,
    slice_polygon,
)

PLOT_SIZE = (760, 720)
PLOT_MARGIN = (90, 60, 30, 70)
"""Left, top, right, bottom margins of the plot area, px."""


def _nice_step(span: float) -> float:
    raw = span / 8.0
    magnitude = 10 ** math.floor(math.log10(raw))
    for factor in (1, 2, 5, 10):
        if factor * magnitude >= raw:
            return factor * magnitude
    return 10 * magnitude  # pragma: no cover


def draw_force_slice(
    geometry: HexarotorGeometry, pull: float, unit: np.ndarray, answer: PullFeasibility
) -> np.ndarray:
    """Draw the forces the hovering vehicle can exert in the vertical plane holding the pull.

    The plane is spanned by the pull's horizontal part and body ``z`` (body ``y`` and ``z``
    for a vertical pull, the paper's view). Returns a BGR image.
    """
    axis = slice_axis_for(unit)
    polygon = slice_polygon(geometry, axis, samples=120)
    pull_point = np.array([pull * float(unit @ axis), pull * unit[2]])
    reach_point = pull_point * (answer.max_force_n / pull) if pull > 0 else pull_point
    extent = max(float(np.abs(polygon).max()), float(np.abs(pull_point).max()), 1.0) * 1.1
    step = _nice_step(2 * extent)
    limit = math.ceil(extent / step) * step

    width, height = PLOT_SIZE
    left, top, right, bottom = PLOT_MARGIN
    side = min(width - left - right, height - top - bottom)
    scale = side / (2 * limit)
    origin = np.array([left + side / 2, top + side / 2])

    def to_pixel(point: np.ndarray) -> tuple[int, int]:
        return (
            round(origin[0] + point[0] * scale),
            round(origin[1] - point[1] * scale),
        )

    image = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    grey, dark = (225, 225, 225), (40, 40, 40)
    ticks = np.arange(-limit, limit + step / 2, step)
    for tick in ticks:
        x0, y0 = to_pixel(np.array([tick, -limit]))
        x1, y1 = to_pixel(np.array([tick, limit]))
        cv2.line(image, (x0, y0), (x1, y1), grey, 1)
        cv2.putText(image, f"{tick:g}", (x0 - 12, y0 + 22), font, 0.45, dark, 1, cv2.LINE_AA)
        x0, y0 = to_pixel(np.array([-limit, tick]))
        x1, y1 = to_pixel(np.array([limit, tick]))
        cv2.line(image, (x0, y0), (x1, y1), grey, 1)
        cv2.putText(image, f"{tick:g}", (x0 - 50, y0 + 5), font, 0.45, dark, 1, cv2.LINE_AA)
    cv2.rectangle(
        image, to_pixel(np.array([-limit, limit])), to_pixel(np.array([limit, -limit])), dark, 1
    )
    cv2.line(image, to_pixel(np.array([-limit, 0])), to_pixel(np.array([limit, 0])), dark, 1)
    cv2.line(image, to_pixel(np.array([0, -limit])), to_pixel(np.array([0, limit])), dark, 1)

    outline = np.array([to_pixel(p) for p in polygon], np.int32)
    fill = image.copy()
    cv2.fillPoly(fill, [outline], (235, 200, 150))
    image = cv2.addWeighted(fill, 0.6, image, 0.4, 0)
    cv2.polylines(image, [outline], True, (160, 90, 30), 2, cv2.LINE_AA)

    colour = (40, 160, 40) if answer.feasible else (40, 40, 220)
    cv2.arrowedLine(
        image, to_pixel(np.zeros(2)), to_pixel(pull_point), colour, 2, cv2.LINE_AA, tipLength=0.06
    )
    cv2.circle(image, to_pixel(reach_point), 5, (160, 90, 30), -1, cv2.LINE_AA)

    name = _axis_name(axis)
    cv2.putText(
        image,
        f"force along {name} (N)",
        (left + side // 2 - 110, top + side + 55),
        font,
        0.55,
        dark,
        1,
        cv2.LINE_AA,
    )
    label = np.full((30, 260, 3), 255, np.uint8)
    cv2.putText(label, "force along body z (N)", (5, 20), font, 0.55, dark, 1, cv2.LINE_AA)
    rotated = cv2.rotate(label, cv2.ROTATE_90_COUNTERCLOCKWISE)
    y0 = top + side // 2 - rotated.shape[0] // 2
    image[y0 : y0 + rotated.shape[0], 8 : 8 + rotated.shape[1]] = rotated
    verdict = "feasible" if answer.feasible else "NOT feasible"
    title = (
        f"Forces on the environment while hovering, zero torque ({geometry.mass_kg:g} kg, "
        f"tilt {geometry.tilt_deg:g} deg)"
    )
    cv2.putText(image, title, (left - 60, 25), font, 0.5, dark, 1, cv2.LINE_AA)
    legend = f"pull {pull:g} N: {verdict}; max {answer.max_force_n:.2f} N (dot)"
    cv2.putText(image, legend, (left - 60, 48), font, 0.5, colour, 1, cv2.LINE_AA)
    return image


def _axis_name(axis: np.ndarray) -> str:
    for name, unit in (("body x", (1, 0, 0)), ("body y", (0, 1, 0))):
        if np.allclose(axis, unit):
            return name
        if np.allclose(axis, -np.asarray(unit)):
            return f"-{name}"
    return f"body [{axis[0]:.2f}, {axis[1]:.2f}, 0]"

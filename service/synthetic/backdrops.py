"""Backgrounds of the scene families, and the soft shadows cables cast on bright ones.

``dark-textured`` and ``dark-plain`` are :func:`make_scene`'s backgrounds (a dark table
with a faint wood grain or cutting-mat grid, or a plain grey with a slight gradient).
``paper`` is white paper under uneven light, often with the table showing along one or
two sides (dark metal or light wood), as in the ariadne photographs. ``painted`` is a
busy abstract painting: hundreds of thin strokes and splashes of many colours on a
cream, white or red ground, as in ariadne's hard images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from service.synthetic.render import _draw_background, _smooth_noise

BACKDROPS = ("dark-textured", "dark-plain", "paper", "painted")

# Paint for the painted background (BGR): black, dark brown, white, cream, yellow, ochre,
# red, dark red, grey, blue-grey.
_PAINT = (
    (25, 25, 30),
    (30, 50, 80),
    (235, 235, 235),
    (190, 215, 230),
    (60, 200, 230),
    (50, 130, 190),
    (45, 50, 200),
    (40, 30, 120),
    (140, 140, 140),
    (150, 120, 100),
)
_GROUNDS = ((200, 218, 230), (228, 230, 232), (55, 60, 175), (70, 110, 150))


@dataclass(frozen=True, eq=False)
class Backdrop:
    """A background: its kind, its float32 BGR image, and whether it is bright."""

    kind: str
    base: np.ndarray
    bright: bool


def draw_backdrop(rng, width, height, kind) -> Backdrop:
    if kind in ("dark-textured", "dark-plain"):
        grey, tint, _ = _draw_background(rng, width, height, kind.removeprefix("dark-"))
        return Backdrop(kind, grey[:, :, None] * tint[None, None, :], bright=False)
    if kind == "paper":
        return Backdrop(kind, _paper(rng, width, height), bright=True)
    if kind == "painted":
        return Backdrop(kind, _painted(rng, width, height), bright=False)
    raise ValueError(f"unknown backdrop {kind!r}; expected one of {', '.join(BACKDROPS)}")


def _paper(rng, width, height):
    """White paper under uneven light, the table showing along some sides."""
    level = rng.uniform(190.0, 240.0)
    x = np.linspace(-0.5, 0.5, width, dtype=np.float32)[None, :]
    y = np.linspace(-0.5, 0.5, height, dtype=np.float32)[:, None]
    direction = rng.uniform(0.0, 2.0 * math.pi)
    gradient = np.float32(rng.uniform(0.02, 0.08)) * (
        x * np.float32(math.cos(direction)) + y * np.float32(math.sin(direction))
    )
    light = 1.0 + gradient + 0.03 * _smooth_noise(rng, width, height, max(width, height) / 2.0)
    grey = level * light + 1.5 * _smooth_noise(rng, width, height, 3.0)
    tint = 1.0 + rng.uniform(-0.03, 0.03, 3)
    base = (grey[:, :, None] * tint[None, None, :].astype(np.float32)).astype(np.float32)
    if rng.random() < 0.5:
        n_sides = int(rng.integers(1, 3))
        for side in rng.choice(4, size=n_sides, replace=False):
            _table_strip(rng, base, int(side))
    return base


def _table_strip(rng, base, side):
    """The table along one side (0 left, 1 top, 2 right, 3 bottom): metal or light wood."""
    height, width = base.shape[:2]
    extent = width if side in (0, 2) else height
    depth = int(rng.uniform(0.04, 0.14) * extent)
    across = np.arange(extent, dtype=np.float32)
    if side in (2, 3):
        across = across[::-1].copy()
    # Soft paper edge: the table shows where ``across < depth``, blended over 2 px.
    weight = np.clip((depth - across) / 2.0 + 0.5, 0.0, 1.0)
    weight = weight[None, :] if side in (0, 2) else weight[:, None]
    if rng.random() < 0.5:
        level = rng.uniform(55.0, 100.0)
        grain = _smooth_noise(rng, max(2, width // 8), max(2, height // 8), 2.0)
        table = (
            level
            + 6.0 * cv2.resize(grain, (width, height))
            + 3.0 * _smooth_noise(rng, width, height, 4.0)
        )
        colour = np.stack([table, table, table * 1.02], axis=2)
    else:
        along = np.arange(width if side in (1, 3) else height, dtype=np.float32)
        stripes = np.sin(along * rng.uniform(0.3, 0.8) + 3.0 * np.sin(along * 0.013))
        stripes = stripes[None, :] if side in (1, 3) else stripes[:, None]
        wood = np.array([110.0, 160.0, 200.0]) * rng.uniform(0.75, 1.0)
        colour = wood[None, None, :] * (1.0 + 0.06 * stripes[:, :, None])
        colour = np.broadcast_to(colour, base.shape)
    base *= 1.0 - weight[:, :, None]
    base += weight[:, :, None] * colour.astype(np.float32)


def _painted(rng, width, height):
    """A busy painting: thin strokes and splashes of many colours on one ground."""
    ground = np.array(_GROUNDS[int(rng.integers(len(_GROUNDS)))], dtype=np.float64)
    canvas = np.empty((height, width, 3), dtype=np.uint8)
    canvas[:] = np.clip(ground + rng.integers(-10, 11, 3), 0, 255).astype(np.uint8)
    n_strokes = int(width * height / 2500 * rng.uniform(0.6, 1.4))
    for _ in range(n_strokes):
        colour = np.array(_PAINT[int(rng.integers(len(_PAINT)))]) + rng.integers(-15, 16, 3)
        colour = tuple(int(c) for c in np.clip(colour, 0, 255))
        n_steps = int(rng.integers(8, 100))
        turns = np.cumsum(rng.normal(0.0, 0.35, n_steps))
        heading = rng.uniform(0.0, 2.0 * math.pi) + turns
        steps = 4.0 * np.column_stack([np.cos(heading), np.sin(heading)])
        start = rng.uniform([0.0, 0.0], [width, height])
        points = np.rint((start + np.cumsum(steps, axis=0)) * 4.0).astype(np.int32)
        thickness = int(rng.integers(1, 5))
        cv2.polylines(canvas, [points.reshape(-1, 1, 2)], False, colour, thickness, cv2.LINE_AA, 2)
    for _ in range(n_strokes // 3):
        colour = tuple(int(c) for c in _PAINT[int(rng.integers(len(_PAINT)))])
        centre = (int(rng.integers(width)), int(rng.integers(height)))
        cv2.circle(canvas, centre, int(rng.integers(1, 7)), colour, -1, cv2.LINE_AA)
    return cv2.GaussianBlur(canvas, (0, 0), 0.7).astype(np.float32)


def cast_shadows(rng, base, curves):
    """Darken a bright background where the cables' soft shadows fall (down and right,
    away from the light), in place."""
    height, width = base.shape[:2]
    shadow = np.zeros((height, width), dtype=np.float32)
    direction = np.array([0.35, 0.45]) / math.hypot(0.35, 0.45)
    for curve in curves:
        offset = direction * rng.uniform(0.4, 0.9) * curve.radius
        points = np.rint((curve.points[::4] + offset) * 8.0).astype(np.int32)
        thickness = max(1, round(2.0 * curve.radius))
        cv2.polylines(shadow, [points.reshape(-1, 1, 2)], False, 1.0, thickness, cv2.LINE_8, 3)
    if not curves:
        return
    sigma = 0.8 * float(np.mean([curve.radius for curve in curves]))
    shadow = cv2.GaussianBlur(shadow, (0, 0), sigma)
    base *= (1.0 - rng.uniform(0.15, 0.35) * shadow)[:, :, None]

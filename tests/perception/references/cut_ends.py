"""The cut reading's middle line traced in plain Python (what ``cut_ends.middle_line``
hands to the compiled ``_shared_kernels.middle_line``), step by step as it was."""

import numpy as np

from service.perception.cut_ends import (
    CUT_NARROWING_PX,
    SECTION_STEP_PX,
    TRACE_STEP_PX,
    WIDTH_AGREES,
    _border_distance,
)
from service.perception.geometry import on_mask, unit


def _recentred(plus: float, minus: float, half_width: float) -> float:
    """The shift (px, along the normal's plus side) that puts a point half the cable's
    width in from its borders, ``plus`` and ``minus`` px away on either side: from both
    where the section is the cable's own width; where it is wider (a strand touching it, a
    crossing), from the border at about the
    cable's own distance, else none."""
    full = 2.0 * half_width
    if abs(plus + minus - full) <= WIDTH_AGREES * full:
        return 0.5 * (plus - minus)
    near = WIDTH_AGREES * full
    plus_own = abs(plus - half_width) <= near
    minus_own = abs(minus - half_width) <= near
    if plus_own and not minus_own:
        return plus - half_width
    if minus_own and not plus_own:
        return half_width - minus
    return 0.0


def _full_beyond(
    mask: np.ndarray,
    x: float,
    y: float,
    hx: float,
    hy: float,
    steps: np.ndarray,
    reach: float,
    half_width: float,
) -> bool:
    """Whether the section a step on from ``(x, y)`` along ``(hx, hy)`` is the cable's
    full width again: the narrowing at ``(x, y)`` was its borders' rounding, no cut.

    An object's border that has begun to cut the cable takes more of it a step further
    on (or all of it, past the middle: off the mask), never less. A cable's own border
    is a pixel staircase: read across at a slant, each border may fall up to half a
    pixel's diagonal (0.7 px) short, and a half width read from the skeleton a pixel
    over the cable's leaves that within :data:`CUT_NARROWING_PX` of a single section."""
    x, y = x + TRACE_STEP_PX * hx, y + TRACE_STEP_PX * hy
    if not on_mask(mask, x, y):
        return False
    plus = _border_distance(mask, x, y, -hy, hx, steps, reach)
    minus = _border_distance(mask, x, y, hy, -hx, steps, reach)
    return plus + minus >= 2.0 * half_width - CUT_NARROWING_PX


def middle_line(
    mask: np.ndarray,
    start: np.ndarray,
    heading: np.ndarray,
    curvature: float,
    half_width: float,
    limit: float,
    first_narrowing: bool = False,
) -> tuple[np.ndarray, bool, np.ndarray]:
    """:func:`service.perception.cut_ends.middle_line` as its Python loop was (same
    arguments, same returns)."""
    # Plain floats, step by step (a trace is a few dozen steps, each a few samples).
    x, y = (float(value) for value in np.asarray(start, np.float64))
    hx, hy = (float(value) for value in unit(np.asarray(heading, np.float64)))
    points = [(x, y)]
    shortfall = [0.0]
    if not on_mask(mask, x, y):
        return np.array(points), False, np.array(shortfall)
    reach = 2.5 * half_width + 2.0
    steps = np.arange(SECTION_STEP_PX, reach + 1e-9, SECTION_STEP_PX)
    cos, sin = float(np.cos(curvature * TRACE_STEP_PX)), float(np.sin(curvature * TRACE_STEP_PX))
    # The start itself (a fit's, up to a couple of pixels off the middle) put on the
    # middle at once where its section is the cable's: else the first steps, each
    # moved by at most a step, lean across the cable and tilt a short fit through them.
    nx, ny = -hy, hx
    plus = _border_distance(mask, x, y, nx, ny, steps, reach)
    minus = _border_distance(mask, x, y, -nx, -ny, steps, reach)
    if plus + minus >= 2.0 * half_width - CUT_NARROWING_PX:
        shift = _recentred(plus, minus, half_width)
        if on_mask(mask, x + shift * nx, y + shift * ny):
            x, y = x + shift * nx, y + shift * ny
            points = [(x, y)]
    for _ in range(int(limit / TRACE_STEP_PX)):
        x, y = x + TRACE_STEP_PX * hx, y + TRACE_STEP_PX * hy
        nx, ny = -hy, hx
        if on_mask(mask, x, y):
            plus = _border_distance(mask, x, y, nx, ny, steps, reach)
            minus = _border_distance(mask, x, y, -nx, -ny, steps, reach)
            if plus + minus < 2.0 * half_width - CUT_NARROWING_PX and (
                first_narrowing or not _full_beyond(mask, x, y, hx, hy, steps, reach, half_width)
            ):
                # The cut begins here, on one side or both: past it, what is left of
                # the section is no longer centred on the cable.
                return np.array(points), True, np.array(shortfall)
            narrower = max(2.0 * half_width - plus - minus, 0.0)
            shift = min(max(_recentred(plus, minus, half_width), -TRACE_STEP_PX), TRACE_STEP_PX)
            x, y = x + shift * nx, y + shift * ny
        else:
            narrower = 0.0
        if not on_mask(mask, x, y):
            return np.array(points), True, np.array(shortfall)
        points.append((x, y))
        shortfall.append(narrower)
        hx, hy = cos * hx - sin * hy, sin * hx + cos * hy
    return np.array(points), False, np.array(shortfall)

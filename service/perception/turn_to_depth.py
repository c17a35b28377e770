"""A hidden doubled-back turn built to a given depth (:func:`turn_to_depth`).

The turn pass (:mod:`.turn_joins`) builds its curves from the two cuts on: the most
compact turn the cable's tightest bend allows, and bulbs of wider bends, whose extra
length swings out sideways rather than deep. Where the region hiding the turn says how
deep the turn lies (the middle of an object's depth past the cuts), none of those curves
may reach it. A cable that went that deep ran on under the region along its strands'
own lines before it turned: this module carries each strand straight on to the depth
where the turn must begin and turns there as compactly as the cable allows, so that the
turn's apex lands at the depth asked for.

Pure geometry: the curve builders are passed in (:func:`.turn_joins.hidden_turn_curves`
and its kink test), so that this module imports nothing of the turn pass's.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

DEPTH_FITS = 3
"""How many times the depth where the turn begins is corrected by the apex's miss: the
apex moves with the carried strands one for one, less where a strand runs slanted to the
turn's axis, so a step or two lands it within a fraction of a pixel."""

CURVES_TRIED = 8
"""Of the turns built from the carried strands (most compact first), how many are tried
for one that bends as a cable: the natural curve and the tightest bulbs, each way round
and with the ends' directions tilted."""


def turn_to_depth(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    origin: np.ndarray,
    axis: np.ndarray,
    depth: float,
    cable_radius: float,
    curves: Callable[..., Iterator[np.ndarray]],
    bends: Callable[[np.ndarray, float], bool],
) -> np.ndarray | None:
    """The turn from ``start`` (leaving along ``leaving``) to ``end`` (arriving along
    ``arriving``) whose apex lies ``depth`` px past ``origin`` along ``axis`` (unit):
    each strand carried straight on along its own line until it lies at the depth where
    the turn begins (a strand already deeper is not carried), then the most compact turn
    between the two carried points that bends as a cable (``curves``: the turn pass's
    builder, :func:`.turn_joins.hidden_turn_curves`; ``bends``: its kink test), the
    straight stretches before and after it included.

    Returns
    -------
    ndarray or None
        ``(M, 2)`` samples a pixel apart from ``start`` to ``end``; None where the
        strands do not run into the turn (their lines parallel to the axis's normal), no
        built turn bends as a cable, or the apex cannot be brought within a pixel of
        ``depth``.
    """
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    leaving, arriving = np.asarray(leaving, np.float64), np.asarray(arriving, np.float64)
    origin, axis = np.asarray(origin, np.float64), np.asarray(axis, np.float64)
    # How deep each end lies, and how much deeper a pixel along its strand takes it.
    first_rate, last_rate = float(leaving @ axis), float(-arriving @ axis)
    if min(first_rate, last_rate) < 0.1:
        return None
    first_depth, last_depth = float((start - origin) @ axis), float((end - origin) @ axis)
    begins = max(first_depth, last_depth)
    for _ in range(DEPTH_FITS + 1):
        first = start + max(0.0, begins - first_depth) / first_rate * leaving
        last = end - max(0.0, begins - last_depth) / last_rate * arriving
        turn = next(
            (
                curve
                for curve in _first(curves(first, leaving, last, arriving, cable_radius))
                if bends(curve, cable_radius)
            ),
            None,
        )
        if turn is None:
            return None
        miss = depth - float(((turn - origin) @ axis).max())
        if abs(miss) <= 1.0:
            return np.concatenate(
                [_straight(start, first), turn, _straight(last, end)[1:], end[None]]
            )
        begins += miss
        if begins < max(first_depth, last_depth) - 1.0:
            return None  # the most compact turn from the cuts is already deeper
    return None


def _first(curves: Iterator[np.ndarray]) -> Iterator[np.ndarray]:
    """The first :data:`CURVES_TRIED` of ``curves``."""
    for count, curve in enumerate(curves):
        if count == CURVES_TRIED:
            return
        yield curve


def _straight(start: np.ndarray, stop: np.ndarray) -> np.ndarray:
    """Samples a pixel apart from ``start`` up to (not including) ``stop``."""
    offset = stop - start
    length = float(np.hypot(*offset))
    if length < 1e-9:
        return start[None][:0]
    return start + np.outer(np.arange(0.0, length, 1.0) / length, offset)


def bulb_to_depth(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    origin: np.ndarray,
    axis: np.ndarray,
    depth: float,
    tightest: float,
    bulbs: Callable[[float], list[np.ndarray]],
) -> np.ndarray | None:
    """The bulb from ``start`` to ``end`` (``bulbs(bend)``: the turn pass's bulbs of one
    bend radius, :func:`.turn_joins.bulb_turns`) whose apex lies ``depth`` px past
    ``origin`` along ``axis``: its bend radius, from ``tightest`` up, scaled by the
    apex's miss (a bulb's reach past its cuts grows with its radius). A cable swung
    round wider turns deeper and wider at once, as a bulb does, where one carried on
    straight (:func:`turn_to_depth`) keeps the tightest bulb's width.

    Returns
    -------
    ndarray or None
        The bulb; None where none reaches within a pixel of ``depth`` (the tightest
        already deeper, or no bulb of the radius reaches ``end``).
    """
    origin, axis = np.asarray(origin, np.float64), np.asarray(axis, np.float64)
    bend = tightest
    for _ in range(DEPTH_FITS + 1):
        shapes = bulbs(bend)
        if not shapes:
            # No bulb of this radius closes on the second end: a wider one may.
            bend *= 1.0 + 1.0 / (DEPTH_FITS + 1)
            continue
        bulb = shapes[0]
        apex = float(((bulb - origin) @ axis).max())
        if abs(depth - apex) <= 1.0:
            return bulb
        if apex <= 0 or (apex > depth and bend <= tightest):
            return None
        bend = max(tightest, bend * depth / apex)
    return None

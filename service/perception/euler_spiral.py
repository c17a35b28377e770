"""The curve across a gap where the cable turns a long way out of sight: an Euler spiral.

A cable hidden where it turns by a right angle or more (a loop under an object, a
doubled-back cable's turn) bends the way an elastic rod does: its curvature changes
smoothly along it and no more than it must. The curve through two points with given
headings whose curvature changes at a constant rate along it is the Euler spiral
(clothoid); it is the curve of shape completion Kimia, Frankel and Popescu (2003)
proposed for the contours an occluder hides, a close approximation of the elastica, and
between symmetric ends it is exactly the circular arc. It takes the turn the ends'
headings make about the line between them, which may exceed a half turn (a loop's
hidden arc turns by 190-280 degrees: the two headings alone, which only tell a turn up
to a half turn either way, read it as the short way round), and it shares the turn
between the two ends as their headings ask, where the cubic of :func:`.paths.gap_curve`
spreads it over both alike.

Measured from the line between the ends (chord), the heading along the spiral is
``theta(t) = theta_0 + (D - A) t + A t^2`` for ``t`` in ``[0, 1]``, with ``theta_0`` and
``theta_1 = theta_0 + D`` the two ends' headings measured from the chord, each within a
half turn of it. The spiral ends on the chord when ``integral sin(theta) dt = 0`` (one
equation in ``A``); its length is then the gap over ``integral cos(theta) dt``. Of the
solutions, the one bending least (the least elastic energy, ``(D^2 + A^2 / 3) / length``)
is the curve.

The search for ``A`` (a scan of 97 rates for sign changes, then Newton's steps kept in each
bracket) and the sampling run compiled (:mod:`._euler_spiral_kernels`, about 0.04 ms a curve
where NumPy took 0.4); this module checks the ends and keeps the public functions. Plain
version: ``tests/perception/references/euler_spiral.py``.
"""

from __future__ import annotations

import functools

import numpy as np

from service.perception import _euler_spiral_kernels
from service.perception.geometry import rotated

LARGE_TURN = 0.5 * np.pi
"""Gaps whose ends' headings turn by at least this (radians) about the line between them
take the spiral; gentler ones keep the cubic (:func:`.paths.gap_curve`), which follows
them as closely."""


TILT_STEP = np.radians(2.0)
"""The grid (radians) the ends' headings are turned on in :func:`headings_within_bend`."""


def chord_turn(
    start: np.ndarray, leaving: np.ndarray, end: np.ndarray, arriving: np.ndarray
) -> tuple[float, float, float, float]:
    """The gap's length, the chord's angle, and the two headings measured from the chord.

    Returns
    -------
    distance, chord_angle, first, last : float
        ``first`` and ``last`` (radians, each in ``[-pi, pi)``) are the angles of
        ``leaving`` and ``arriving`` from the chord ``end - start``; ``last - first`` is
        the turn a curve bending one way across the gap makes (up to a full turn).
    """
    gap = np.asarray(end, np.float64) - np.asarray(start, np.float64)
    distance = float(np.hypot(gap[0], gap[1]))
    chord = float(np.arctan2(gap[1], gap[0]))
    first = _wrapped(float(np.arctan2(leaving[1], leaving[0])) - chord)
    last = _wrapped(float(np.arctan2(arriving[1], arriving[0])) - chord)
    return distance, chord, first, last


def is_large_turn(
    start: np.ndarray, leaving: np.ndarray, end: np.ndarray, arriving: np.ndarray
) -> bool:
    """Whether the ends' headings turn by :data:`LARGE_TURN` or more about their chord."""
    distance, _, first, last = chord_turn(start, leaving, end, arriving)
    return distance > 1e-9 and abs(last - first) >= LARGE_TURN


def euler_spiral(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    step: float = 1.0,
) -> np.ndarray | None:
    """The Euler spiral from ``start`` heading along ``leaving`` to ``end`` heading along
    ``arriving`` (see the module's notes).

    Parameters
    ----------
    start, end : array_like (2,)
        ``[x, y]`` of the two ends.
    leaving, arriving : array_like (2,)
        Unit headings at ``start`` and at ``end`` (along the curve, from start to end).
    step : float
        Spacing of the returned samples (about).

    Returns
    -------
    ndarray or None
        ``(M, 2)`` samples from ``start`` to ``end`` inclusive; None when the ends
        coincide or no spiral joins them.
    """
    shape = spiral_shape(start, leaving, end, arriving)
    if shape is None:
        return None
    first, turn, rate, length, chord = shape
    count = max(2, int(np.ceil(length / step)) + 1)
    start = np.asarray(start, np.float64)
    end = np.asarray(end, np.float64)
    return _euler_spiral_kernels.spiral_samples(
        first,
        turn,
        rate,
        length,
        chord,
        float(start[0]),
        float(start[1]),
        float(end[0]),
        float(end[1]),
        count,
    )


def spiral_shape(
    start: np.ndarray, leaving: np.ndarray, end: np.ndarray, arriving: np.ndarray
) -> tuple[float, float, float, float, float] | None:
    """The Euler spiral's parameters: ``(first, turn, rate, length, chord)``: the heading
    ``chord + first + (turn - rate) t + rate t^2`` at ``t`` in ``[0, 1]`` of the way
    along a curve ``length`` px long; None when the ends coincide or no spiral joins them.
    """
    distance, chord, first, last = chord_turn(start, leaving, end, arriving)
    if distance < 1e-9:
        return None
    found, rate, length = _euler_spiral_kernels.spiral_rate(first, last, distance)
    if not found:
        return None
    return first, last - first, rate, length, chord


def headings_within_bend(
    start: np.ndarray,
    leaving: np.ndarray,
    end: np.ndarray,
    arriving: np.ndarray,
    min_radius: float,
    slack: float,
    step: float = TILT_STEP,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The two ends' headings, each turned by at most ``slack`` (radians), nearest the
    given ones whose Euler spiral bends nowhere tighter than ``min_radius`` (px); None
    where the given headings have no spiral (:func:`.paths.gap_curve` then draws its
    cubic) or no such pair turns by :data:`LARGE_TURN` or more.

    The spiral shares a turn between its ends as their headings ask, and its curvature
    changes linearly along it: where the two headings disagree (one read on a bend that
    turns at the cut, one on the straight before it) it crowds the turn at one end,
    tighter than a cable bends. Both readings cannot then be the cable's own: of the
    headings within their uncertainty, the pair turned least from the readings (least
    summed square of the two tilts, tried on a grid of ``step``) whose spiral a cable
    could take is kept. Headings whose spiral already bends no tighter are returned as
    they are.
    """
    limit = 1.0 / float(min_radius)
    if spiral_shape(start, leaving, end, arriving) is None:
        return None
    for first, last in _tilts(float(slack), float(step)):
        turned_leaving = rotated(leaving, first)
        turned_arriving = rotated(arriving, last)
        if not is_large_turn(start, turned_leaving, end, turned_arriving):
            continue
        shape = spiral_shape(start, turned_leaving, end, turned_arriving)
        if shape is not None and max_curvature(shape) <= limit:
            return turned_leaving, turned_arriving
    return None


@functools.lru_cache(maxsize=8)
def _tilts(slack: float, step: float) -> tuple[tuple[float, float], ...]:
    """Pairs of tilts (radians) on a grid of ``step`` up to ``slack`` each, in order of
    their summed square (the untilted pair first). Kept: every bridge asks for the same
    grid, ~1,000 pairs sorted."""
    count = int(np.floor(slack / step + 1e-9))
    grid = step * np.arange(-count, count + 1)
    pairs = [(float(first), float(last)) for first in grid for last in grid]
    return tuple(sorted(pairs, key=lambda pair: (pair[0] ** 2 + pair[1] ** 2, abs(pair[0]), pair)))


def max_curvature(shape: tuple[float, float, float, float, float]) -> float:
    """The largest curvature (1/px) along the spiral of ``shape`` (at one of its ends:
    the curvature changes linearly along it)."""
    _, turn, rate, length, _ = shape
    return max(abs(turn - rate), abs(turn + rate)) / length


def _wrapped(angle: float) -> float:
    """``angle`` in ``[-pi, pi)``."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi

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
"""

from __future__ import annotations

import numpy as np

LARGE_TURN = 0.5 * np.pi
"""Gaps whose ends' headings turn by at least this (radians) about the line between them
take the spiral; gentler ones keep the cubic (:func:`.paths.gap_curve`), which follows
them as closely."""
_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(32)
_NODES = 0.5 * (_NODES + 1.0)  # Gauss-Legendre on [0, 1]
_WEIGHTS = 0.5 * _WEIGHTS
_SCAN = np.linspace(-2.0 * np.pi, 2.0 * np.pi, 97)
"""Offsets of ``A`` (radians) about the first guess scanned for solutions."""
_REFINE_STEPS = 12
"""Steps refining each solution bracketed (Newton's converge in 4-6)."""


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
    # Each step's heading at its middle (exact for a constant-curvature step, within
    # 1e-4 px a step here), then the small closing error spread along the curve.
    along = np.linspace(0.0, 1.0, count)
    middle = 0.5 * (along[1:] + along[:-1])
    heading = chord + first + (turn - rate) * middle + rate * middle**2
    steps = (length / (count - 1)) * np.column_stack([np.cos(heading), np.sin(heading)])
    points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    start = np.asarray(start, np.float64)
    points += start
    points += np.outer(along, np.asarray(end, np.float64) - points[-1])
    return points


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
    turn = last - first
    guess = 3.0 * (first + last)  # exact for symmetric ends (0: the circular arc)
    rates = guess + _SCAN
    sines = _integral(np.sin, first, turn, rates)
    changes = np.flatnonzero(np.signbit(sines[:-1]) != np.signbit(sines[1:]))
    if not len(changes):
        return None
    rates = _roots(first, turn, rates[changes], rates[changes + 1], sines[changes] < 0)
    cosines = _integral(np.cos, first, turn, rates)
    ahead = cosines > 1e-9  # else the spiral would end on the chord behind the start
    if not ahead.any():
        return None
    rates, lengths = rates[ahead], distance / cosines[ahead]
    energies = (turn**2 + rates**2 / 3.0) / lengths
    best = int(np.argmin(energies))
    rate, length = float(rates[best]), float(lengths[best])
    return first, turn, rate, length, chord


def max_curvature(shape: tuple[float, float, float, float, float]) -> float:
    """The largest curvature (1/px) along the spiral of ``shape`` (at one of its ends:
    the curvature changes linearly along it)."""
    _, turn, rate, length, _ = shape
    return max(abs(turn - rate), abs(turn + rate)) / length


def _integral(function, first: float, turn: float, rates: np.ndarray) -> np.ndarray:
    """``integral_0^1 function(first + (turn - rate) t + rate t^2) dt`` per rate."""
    return function(_headings(first, turn, np.asarray(rates, np.float64))) @ _WEIGHTS


def _headings(first: float, turn: float, rates: np.ndarray) -> np.ndarray:
    """The heading at each quadrature node (columns) per rate (rows)."""
    rates = rates[:, None]
    return first + (turn - rates) * _NODES + rates * _NODES**2


def _roots(
    first: float, turn: float, low: np.ndarray, high: np.ndarray, low_negative: np.ndarray
) -> np.ndarray:
    """The rates in ``[low, high]`` (one per bracket) where the spiral ends on the chord:
    Newton's steps kept inside each bracket (a bisection where one would leave it), all
    brackets at once."""
    low, high = low.astype(np.float64), high.astype(np.float64)
    rate = 0.5 * (low + high)
    for _ in range(_REFINE_STEPS):
        headings = _headings(first, turn, rate)
        value = np.sin(headings) @ _WEIGHTS
        slope = (np.cos(headings) * (_NODES**2 - _NODES)) @ _WEIGHTS
        keeps_sign = (value < 0) == low_negative
        low = np.where(keeps_sign, rate, low)
        high = np.where(keeps_sign, high, rate)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = rate - value / slope
        inside = np.isfinite(newton) & (newton > low) & (newton < high)
        rate = np.where(inside, newton, 0.5 * (low + high))
    return rate


def _wrapped(angle: float) -> float:
    """``angle`` in ``[-pi, pi)``."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi

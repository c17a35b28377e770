"""Compiled root search of :mod:`service.perception.euler_spiral`: the rate of the Euler
spiral that ends on the chord and bends least (``euler_spiral.spiral_shape``).

The spiral's heading, measured from the chord, is ``first + (turn - rate) t + rate t^2``
for ``t`` in ``[0, 1]``; it ends on the chord where ``integral sin(heading) dt = 0``. The
integrals are Gauss-Legendre sums over :data:`NODES`, taken one rate at a time (the
NumPy version took them for all rates at once as matrix products: the sums' order, and
so their last bits, differ). With the same rule for the root (:func:`_root`: the step
nearest it), the plain version (``tests/perception/references/euler_spiral.py``) and the
kernels agree within 1e-10 px, their samples bit for bit for the same shape.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_LEGENDRE_NODES, _LEGENDRE_WEIGHTS = np.polynomial.legendre.leggauss(32)
NODES = 0.5 * (_LEGENDRE_NODES + 1.0)
"""Gauss-Legendre nodes on ``[0, 1]``."""
WEIGHTS = 0.5 * _LEGENDRE_WEIGHTS
"""Their weights."""
_NODES_SQUARED = NODES**2
_SLOPE_FACTORS = NODES**2 - NODES
"""The heading's derivative by the rate at each node (``t^2 - t``)."""
SCAN = np.linspace(-2.0 * np.pi, 2.0 * np.pi, 97)
"""Offsets of the rate (radians) about the first guess scanned for solutions."""
REFINE_STEPS = 12
"""Steps refining each solution bracketed (Newton's converge in 4-6)."""
MIN_ALONG_CHORD = 1e-9
"""Below this ``integral cos(heading) dt`` the spiral would end on the chord behind its
start (or at infinity): no solution."""


@njit(cache=True, nogil=True, inline="always")
def _heading(first, turn, rate, k):
    """The spiral's heading from the chord at node ``k``: ``first + (turn - rate) t +
    rate t^2`` (one place for the integrals and the root's Newton steps)."""
    return first + (turn - rate) * NODES[k] + rate * _NODES_SQUARED[k]


@njit(cache=True, nogil=True)
def _sine_integral(first, turn, rate):
    """``integral_0^1 sin(heading) dt``: where it is zero the spiral ends on the chord.
    (Kept apart from the cosine's: the scan takes the sine alone at every rate, the
    cosine once per root.)"""
    total = 0.0
    for k in range(NODES.shape[0]):
        total += np.sin(_heading(first, turn, rate, k)) * WEIGHTS[k]
    return total


@njit(cache=True, nogil=True)
def _cosine_integral(first, turn, rate):
    """``integral_0^1 cos(heading) dt``: the chord's length per px of spiral."""
    total = 0.0
    for k in range(NODES.shape[0]):
        total += np.cos(_heading(first, turn, rate, k)) * WEIGHTS[k]
    return total


@njit(cache=True, nogil=True)
def _root(first, turn, low, high, low_negative):
    """The rate in ``[low, high]`` where the spiral ends on the chord: Newton's steps kept
    inside the bracket (a bisection where one would leave it).

    Returns the step's rate whose integral was nearest zero: once Newton's steps have
    converged, the next one lands on the end of the bracket just moved there (the root
    itself), and the bisection that follows would walk away from it (the NumPy version
    returned such a point, up to 1e-3 rad from the root, at about a fifth of large turns).
    """
    rate = 0.5 * (low + high)
    best_rate = rate
    best_value = np.inf
    for _ in range(REFINE_STEPS):
        value = 0.0
        slope = 0.0
        for k in range(NODES.shape[0]):
            heading = _heading(first, turn, rate, k)
            value += np.sin(heading) * WEIGHTS[k]
            slope += np.cos(heading) * _SLOPE_FACTORS[k] * WEIGHTS[k]
        if abs(value) < best_value:
            best_rate, best_value = rate, abs(value)
        if value == 0.0:
            break
        if (value < 0) == low_negative:
            low = rate
        else:
            high = rate
        inside = False
        newton = 0.0
        if slope != 0.0:
            newton = rate - value / slope
            inside = np.isfinite(newton) and newton > low and newton < high
        rate = newton if inside else 0.5 * (low + high)
    return best_rate


@njit(cache=True, nogil=True)
def spiral_rate(first, last, distance):
    """The Euler spiral's rate and length between ends whose headings are ``first`` and
    ``last`` (radians from the chord, each within a half turn of it) ``distance`` px
    apart: of the rates whose spiral ends on the chord ahead of the start, the one
    bending least (elastic energy ``(turn^2 + rate^2 / 3) / length``).

    Returns
    -------
    found, rate, length : bool, float, float
        ``found`` False (and zeros) when no spiral joins the ends.
    """
    turn = last - first
    guess = 3.0 * (first + last)  # exact for symmetric ends (0: the circular arc)
    best_energy = np.inf
    best_rate = 0.0
    best_length = 0.0
    found = False
    previous_rate = guess + SCAN[0]
    previous = _sine_integral(first, turn, previous_rate)
    for i in range(1, SCAN.shape[0]):
        rate = guess + SCAN[i]
        value = _sine_integral(first, turn, rate)
        if np.signbit(previous) != np.signbit(value):
            root = _root(first, turn, previous_rate, rate, previous < 0)
            along = _cosine_integral(first, turn, root)
            if along > MIN_ALONG_CHORD:
                length = distance / along
                energy = (turn * turn + root * root / 3.0) / length
                # The first of equal energies, as NumPy's argmin.
                if energy < best_energy or not found:
                    best_energy, best_rate, best_length = energy, root, length
                    found = True
        previous_rate, previous = rate, value
    return found, best_rate, best_length


@njit(cache=True, nogil=True)
def spiral_samples(first, turn, rate, length, chord, start_x, start_y, end_x, end_y, count):
    """``count`` samples of the spiral from ``(start_x, start_y)`` to ``(end_x, end_y)``:
    ``euler_spiral.euler_spiral``'s, bit for bit (the same operations in NumPy's order).

    Each step's heading is taken at its middle (exact for a constant-curvature step,
    within 1e-4 px a step here); the small closing error is spread along the curve.
    """
    steps = count - 1
    spacing = 1.0 / steps  # np.linspace(0, 1, count)
    along = np.empty(count, np.float64)
    for i in range(count):
        along[i] = i * spacing + 0.0
    along[steps] = 1.0
    step_length = length / steps
    base = chord + first
    points = np.empty((count, 2), np.float64)
    x = 0.0
    y = 0.0
    points[0, 0] = 0.0
    points[0, 1] = 0.0
    for i in range(steps):
        middle = 0.5 * (along[i + 1] + along[i])
        heading = (base + (turn - rate) * middle) + rate * (middle * middle)
        x += step_length * np.cos(heading)
        y += step_length * np.sin(heading)
        points[i + 1, 0] = x
        points[i + 1, 1] = y
    for i in range(count):
        points[i, 0] += start_x
        points[i, 1] += start_y
    closing_x = end_x - points[steps, 0]
    closing_y = end_y - points[steps, 1]
    for i in range(count):
        points[i, 0] += along[i] * closing_x
        points[i, 1] += along[i] * closing_y
    return points

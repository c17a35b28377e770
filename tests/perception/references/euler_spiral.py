"""Plain :func:`service.perception.euler_spiral.spiral_shape` and ``euler_spiral``: the
NumPy code ``_euler_spiral_kernels`` replaced (all rates and brackets at once, as matrix
products), with the one change the kernel makes: each bracket's root is the Newton step
whose integral was nearest zero (``converged=False``: the last step, as before, which once
converged could be bisected away from the root)."""

import numpy as np

from service.perception.euler_spiral import chord_turn

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(32)
_NODES = 0.5 * (_NODES + 1.0)
_WEIGHTS = 0.5 * _WEIGHTS
_SCAN = np.linspace(-2.0 * np.pi, 2.0 * np.pi, 97)
_REFINE_STEPS = 12


def spiral_shape(start, leaving, end, arriving, converged=True):
    distance, chord, first, last = chord_turn(start, leaving, end, arriving)
    if distance < 1e-9:
        return None
    turn = last - first
    guess = 3.0 * (first + last)
    rates = guess + _SCAN
    sines = _integral(np.sin, first, turn, rates)
    changes = np.flatnonzero(np.signbit(sines[:-1]) != np.signbit(sines[1:]))
    if not len(changes):
        return None
    rates = _roots(first, turn, rates[changes], rates[changes + 1], sines[changes] < 0, converged)
    cosines = _integral(np.cos, first, turn, rates)
    ahead = cosines > 1e-9
    if not ahead.any():
        return None
    rates, lengths = rates[ahead], distance / cosines[ahead]
    energies = (turn**2 + rates**2 / 3.0) / lengths
    best = int(np.argmin(energies))
    return first, turn, float(rates[best]), float(lengths[best]), chord


def euler_spiral(start, leaving, end, arriving, step=1.0, converged=True):
    shape = spiral_shape(start, leaving, end, arriving, converged)
    if shape is None:
        return None
    return spiral_samples(shape, start, end, step)


def spiral_samples(shape, start, end, step=1.0):
    first, turn, rate, length, chord = shape
    count = max(2, int(np.ceil(length / step)) + 1)
    along = np.linspace(0.0, 1.0, count)
    middle = 0.5 * (along[1:] + along[:-1])
    heading = chord + first + (turn - rate) * middle + rate * middle**2
    steps = (length / (count - 1)) * np.column_stack([np.cos(heading), np.sin(heading)])
    points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    points += np.asarray(start, np.float64)
    points += np.outer(along, np.asarray(end, np.float64) - points[-1])
    return points


def _integral(function, first, turn, rates):
    return function(_headings(first, turn, np.asarray(rates, np.float64))) @ _WEIGHTS


def _headings(first, turn, rates):
    rates = rates[:, None]
    return first + (turn - rates) * _NODES + rates * _NODES**2


def _roots(first, turn, low, high, low_negative, converged):
    low, high = low.astype(np.float64), high.astype(np.float64)
    rate = 0.5 * (low + high)
    best_rate, best_value = rate.copy(), np.full(len(rate), np.inf)
    for _ in range(_REFINE_STEPS):
        headings = _headings(first, turn, rate)
        value = np.sin(headings) @ _WEIGHTS
        slope = (np.cos(headings) * (_NODES**2 - _NODES)) @ _WEIGHTS
        nearer = np.abs(value) < best_value
        best_rate = np.where(nearer, rate, best_rate)
        best_value = np.where(nearer, np.abs(value), best_value)
        keeps_sign = (value < 0) == low_negative
        low = np.where(keeps_sign, rate, low)
        high = np.where(keeps_sign, high, rate)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = rate - value / slope
        inside = np.isfinite(newton) & (newton > low) & (newton < high)
        rate = np.where(inside, newton, 0.5 * (low + high))
    return best_rate if converged else rate

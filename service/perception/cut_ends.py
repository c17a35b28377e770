"""Where a gap's bridge leaves the cable: the cut, traced along the mask from the end's fit.

A gap's bridge starts where each end's fit begins (:func:`.bridge_ends.bridge_from_the_fits`):
the fit leaves out the cut's hook, so that point lies on the cable, but one or two radii
before the cut. On a straight cable that costs little; on a tight bend (a loop or a
doubled-back cable turning under an object) the cable turns by 15-60 degrees over that
stretch, which is seen, and the bridge, drawn from there with the fit's direction,
makes that turn as well as the hidden one: across a half turn and more the curve falls
inside the true bend by more than a radius.

So the stretch between where the fit begins and the cut is traced on the mask
(:func:`middle_line`): step by step along the cable, each step put half the cable's
width in from its borders (from the one at the cable's own distance where a touching
strand widens the section), until the section narrows (an object's border has begun to
cut the cable) or the middle line leaves the mask: there the cable passes out of sight
(:func:`end_at_the_cut`). The bridge runs along that traced stretch and from its end,
along the direction a short quadratic fit of the traced middle line gives there, across
the gap (:func:`bridges_from_the_cuts`).
"""

from __future__ import annotations

import numpy as np

from service.perception.geometry import end_fit, polyline_length, rotated, unit
from service.perception.paths import gap_curve

TRACE_STEP_PX = 1.0
"""The step (px) along the cable between two traced middle points."""
SECTION_STEP_PX = 0.25
"""The step (px) at which the mask is read across the cable."""
CUT_NARROWING_PX = 2.0
"""A section narrower than the cable by more than this (px: a pixel's rounding at either
border) has been cut on a side: its middle is no longer the cable's."""
WIDTH_AGREES = 0.35
"""A cross-section is the cable's own when its width is within this share of the
cable's full width: both borders are the cable's, and its middle is the cable's."""
FIT_RADII = 3.0
"""The direction at a cut is fitted over the traced middle line's last this many radii."""
REACH_PAST_SKIP_RADII = 2.0
"""How far (radii) past the tip the fit left out a cut may lie: the skeleton's tip stops
about a radius short of a cut, and a slanted cut's far corner a width further."""


def _border_distance(
    mask: np.ndarray, x: float, y: float, dx: float, dy: float, steps: list[float], reach: float
) -> float:
    """Distance (px) from ``(x, y)`` along ``(dx, dy)`` to the first of the sample
    ``steps`` (px, increasing, up to ``reach``) off ``mask``, or ``reach`` when none is."""
    height, width = mask.shape
    for step in steps:
        # Python's round, as NumPy's rint, rounds halves to even.
        column, row = round(x + step * dx), round(y + step * dy)
        if not (0 <= column < width and 0 <= row < height and mask[row, column]):
            return step - 0.5 * SECTION_STEP_PX
    return reach


def _on_mask(mask: np.ndarray, x: float, y: float) -> bool:
    column, row = round(x), round(y)
    return 0 <= column < mask.shape[1] and 0 <= row < mask.shape[0] and bool(mask[row, column])


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


def middle_line(
    mask: np.ndarray,
    start: np.ndarray,
    heading: np.ndarray,
    curvature: float,
    half_width: float,
    limit: float,
) -> tuple[np.ndarray, bool]:
    """The cable's middle line traced on ``mask`` from ``start`` along ``heading``, at
    most ``limit`` px, and whether it stopped at a cut.

    Each step goes :data:`TRACE_STEP_PX` along the heading, which turns as the end's
    fit bends (``curvature``, signed, 1/px), and is then put half the cable's width
    (``half_width``) in from its borders read across it (:func:`_recentred`). The trace
    stops at a cut where the section across it is narrower than the cable (an object's
    border has begun to cut it) or the middle point leaves the mask.

    Returns
    -------
    points : ndarray
        ``(K, 2)`` traced points from ``start`` (``K >= 1``).
    cut : bool
        Whether the trace stopped at a cut before ``limit``.
    """
    # Plain floats, step by step (a trace is a few dozen steps, each a few samples).
    x, y = (float(value) for value in np.asarray(start, np.float64))
    hx, hy = (float(value) for value in unit(np.asarray(heading, np.float64)))
    points = [(x, y)]
    if not _on_mask(mask, x, y):
        return np.array(points), False
    reach = 2.5 * half_width + 2.0
    steps = np.arange(SECTION_STEP_PX, reach + 1e-9, SECTION_STEP_PX).tolist()
    cos, sin = float(np.cos(curvature * TRACE_STEP_PX)), float(np.sin(curvature * TRACE_STEP_PX))
    for _ in range(int(limit / TRACE_STEP_PX)):
        x, y = x + TRACE_STEP_PX * hx, y + TRACE_STEP_PX * hy
        nx, ny = -hy, hx
        if _on_mask(mask, x, y):
            plus = _border_distance(mask, x, y, nx, ny, steps, reach)
            minus = _border_distance(mask, x, y, -nx, -ny, steps, reach)
            if plus + minus < 2.0 * half_width - CUT_NARROWING_PX:
                # The cut begins here, on one side or both: past it, what is left of
                # the section is no longer centred on the cable.
                return np.array(points), True
            shift = min(max(_recentred(plus, minus, half_width), -TRACE_STEP_PX), TRACE_STEP_PX)
            x, y = x + shift * nx, y + shift * ny
        if not _on_mask(mask, x, y):
            return np.array(points), True
        points.append((x, y))
        hx, hy = cos * hx - sin * hy, sin * hx + cos * hy
    return np.array(points), False


def end_at_the_cut(
    mask: np.ndarray, end, half_width: float, limit: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Where the cable ``end`` (a :class:`.merging.ChainEnd`, where its bridge would
    start) passes out of sight, and its direction there.

    The middle line is traced from the end to the cut (:func:`middle_line`, at most
    ``limit`` px) and back into the piece over :data:`FIT_RADII` radii; the direction at the
    cut is a quadratic's (:func:`.geometry.end_fit`) over the traced line's last
    :data:`FIT_RADII` radii: centred on the cable, not on the skeleton's hooked tip, and
    short enough to follow a tight bend. Where less than half that is traced behind the
    end, the end's own fit bends on to the cut instead.

    Returns
    -------
    (traced, position, direction) or None
        The traced stretch from the end to the cut, the cut (the fit's end, or the
        traced stretch's), its outward direction;
        None where no cut lies ahead within ``limit``, or the end is off the mask.
    """
    position = np.asarray(end.position, np.float64)
    ahead, cut = middle_line(mask, position, end.direction, end.curvature, half_width, limit)
    if not cut or len(ahead) < 2:
        return None
    span = FIT_RADII * half_width
    behind, _ = middle_line(mask, position, -end.direction, -end.curvature, half_width, span)
    if polyline_length(behind) < 0.5 * span:
        # Too little of the cable traced to fit its direction: the end's fit bends on.
        return ahead, ahead[-1], rotated(end.direction, end.curvature * polyline_length(ahead))
    line = np.concatenate([behind[::-1], ahead[1:]])
    # The fit's own end: the traced points carry a pixel's rounding from step to step.
    position, direction, _ = end_fit(line, False, span)
    return ahead, position, direction


def bridges_from_the_cuts(
    ends: list,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    mask: np.ndarray,
    radius: float,
    given: frozenset[int],
    shape: str = "smooth",
    turns: frozenset[tuple[int, int]] = frozenset(),
) -> dict[tuple[int, int], np.ndarray]:
    """Bridges of the gaps (joins of two ends in no junction, with no curve of their
    own in ``given``) drawn from the cuts: from each bridging end (``ends``, where the
    fit begins) along the cable traced to where it passes out of sight
    (:func:`end_at_the_cut`, within the tip the fit left out and
    :data:`REACH_PAST_SKIP_RADII` radii past it; only ends whose fit left a tip out),
    across the gap by :func:`.paths.gap_curve` of ``shape`` between the two cuts, and on
    to the other end's bridging point (the seen stretches drawn as curves from each
    bridging point to its cut). An end with no cut traced keeps its own
    start. The joins in ``turns`` (each as the turn pass keyed it) are bridged so too,
    though their ends are in ``given``, where both ends reach a cut.

    Returns
    -------
    dict
        ``(i, j) -> (M, 2)`` curve from end ``i``'s bridging point to end ``j``'s, for
        the joins where at least one end was traced.
    """
    bridges = {}
    for i, j, _ in joins:
        if junction_of_end[i] >= 0 or junction_of_end[j] >= 0:
            continue
        turn = (i, j) in turns or (j, i) in turns
        if (i in given or j in given) and not turn:
            continue
        traced, cuts = [], []
        for k in (i, j):
            end = ends[k]
            half_width = (end.width or radius) + 0.5
            limit = end.skip + REACH_PAST_SKIP_RADII * half_width + 2.0
            # Only an end whose fit left out its tip starts its bridge behind the cut.
            found = end_at_the_cut(mask, end, half_width, limit) if end.skip > 0 else None
            traced.append(found is not None)
            cuts.append((end.position, end.direction) if found is None else found[1:])
        if not any(traced) or (turn and not all(traced)):
            continue
        (a, leaving), (b, arriving) = (
            (np.asarray(point, np.float64), heading) for point, heading in cuts
        )
        across = gap_curve(a, leaving, b, -arriving, shape=shape)
        # The seen stretches drawn as the cable bends between the bridge's start and its
        # cut (the traced points carry a pixel's rounding from step to step).
        start_a, start_b = (np.asarray(ends[k].position, np.float64) for k in (i, j))
        seen_a = gap_curve(start_a, ends[i].direction, a, leaving, shape=shape)
        seen_b = gap_curve(b, -arriving, start_b, -ends[j].direction, shape=shape)
        curve = np.concatenate([seen_a[:-1], across, seen_b[1:]])
        if (j, i) in turns:
            bridges[j, i] = curve[::-1]  # the key the turn's own curve has
        else:
            bridges[i, j] = curve
    return bridges

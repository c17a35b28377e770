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
(:func:`end_at_the_cut`); past where a slanted cut has begun to narrow the section, on
along the one border that is still the cable's, where the image shows which that is (the
ground beyond it, the object beyond the other), to where the middle passes out of sight
(:func:`along_the_wedge`). The bridge runs along that traced stretch and from its end,
along the direction a short quadratic fit of the traced middle line gives there, across
the gap (:func:`bridges_from_the_cuts`). Across a large turn that curve is the Euler
spiral, whose curvature changes linearly along it: where the two cuts' readings
disagree it crowds the turn at one end, tighter than a cable bends, and the readings
are then turned, within their uncertainty, as little as a cable's shape takes
(:func:`.euler_spiral.headings_within_bend`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from schemas import GapCurve
from service.perception import _shared_kernels
from service.perception.appearance import ground_beside, unlike_ground
from service.perception.bridge_ends import past_a_stub
from service.perception.cut_corners import between_the_corners
from service.perception.euler_spiral import headings_within_bend, is_large_turn
from service.perception.geometry import (
    arc_lengths,
    end_fit,
    median,
    on_mask,
    polyline_length,
    rotated,
    unit,
)
from service.perception.paths import gap_curve
from service.perception.turn_joins import (
    DIRECTION_SLACK,
    HIDDEN_BEND_RADII,
    turns_round_in_one_arc,
)

TRACE_STEP_PX = 1.0
"""The step (px) along the cable between two traced middle points."""
SECTION_STEP_PX = 0.25
"""The step (px) at which the mask is read across the cable."""
CUT_NARROWING_PX = 2.0
"""A section narrower than the cable by more than this (px: a pixel's rounding at either
border) has been cut on a side: its middle is no longer the cable's."""
SECTION_ROUNDING_PX = 1.0
"""How much narrower (px) than the cable a full section may read: each border's
rounding to the pixel grid."""
WIDTH_AGREES = 0.35
"""A cross-section is the cable's own when its width is within this share of the
cable's full width: both borders are the cable's, and its middle is the cable's."""
FIT_RADII = 3.0
"""The direction at a cut is fitted over the traced middle line's last this many radii."""
CARRY_STEP_PX = 0.5
"""The step (px) of the middle line carried on across a cut (:func:`carried_to_the_border`)."""
CARRY_RADII = 1.7
"""How far (half widths) at most the middle line is carried on past the narrowing: far
enough for the lines beside it (half a half width out) to leave the mask across a cut
about 50 degrees from square (1.5 half widths times tan 50 degrees is 1.8)."""
FULL_SECTIONS = 5
"""The last traced sections (a step, a pixel, apart) whose median width is the cable's own
where a wedge is followed: enough to outvote one section's dip from the borders' rounding."""
BEYOND_BORDER_PX = 2.0
"""How far (px) beyond a border its outside is read in the image: the 3x3 patch read
(:func:`.appearance.unlike_ground`) then lies 1-3 px out, clear of the border's pixel
rounding."""
REACH_PAST_SKIP_RADII = 2.0
"""How far (radii) past the tip the fit left out a cut may lie: the skeleton's tip stops
about a radius short of a cut, and a slanted cut's far corner a width further."""


def _border_distance(
    mask: np.ndarray, x: float, y: float, dx: float, dy: float, steps: np.ndarray, reach: float
) -> float:
    """Distance (px) from ``(x, y)`` along ``(dx, dy)`` to the first of the sample
    ``steps`` (px, increasing, up to ``reach``) off ``mask``, or ``reach`` when none is.

    Each sample's pixel is rounded half to even (Python's ``round``, NumPy's ``rint``);
    compiled (:func:`._shared_kernels.border_distance`): a gap's cut reading samples
    thousands of sections a frame."""
    return float(
        _shared_kernels.border_distance(
            mask.view(np.uint8), x, y, dx, dy, steps, reach, 0.5 * SECTION_STEP_PX, False
        )
    )


def _far_border(
    mask: np.ndarray, x: float, y: float, dx: float, dy: float, steps: np.ndarray, reach: float
) -> float | None:
    """Distance (px) from ``(x, y)`` along ``(dx, dy)`` to the first of the sample
    ``steps`` off ``mask`` past the first on it (the mask's border on that side, past a
    first sample that rounds off the pixel ``(x, y)`` lies on), ``reach`` when it runs
    on, or None where no sample is on the mask (compiled:
    :func:`._shared_kernels.border_distance` past the first sample on the mask)."""
    found = float(
        _shared_kernels.border_distance(
            mask.view(np.uint8), x, y, dx, dy, steps, reach, 0.5 * SECTION_STEP_PX, True
        )
    )
    return None if np.isnan(found) else found


def _heading(line: np.ndarray, half_width: float, added=()) -> tuple[float, float]:
    """The direction at the end of ``line`` carried on by the points ``added`` (read as
    one line, without joining them): the chord over its last half width (``half_width``
    px). A single step's, moved by up to a pixel across as each point is put on the
    middle, would swing by 45 degrees; a fit's, extrapolated over the step, swings with
    the rounding of its last points."""
    back = max(len(line) + len(added) - 1 - round(half_width / TRACE_STEP_PX), 0)
    last = added[-1] if len(added) else line[-1]
    behind = line[back] if back < len(line) else added[back - len(line)]
    hx, hy = unit(np.asarray(last) - np.asarray(behind))
    return float(hx), float(hy)


def along_the_wedge(
    mask: np.ndarray,
    points: np.ndarray,
    half_width: float,
    limit: float,
    image: np.ndarray | None = None,
) -> np.ndarray:
    """The cable's middle line carried on from the traced ``points`` (``(K, 2)``, the
    last on the cable's last full section) into the wedge a slanted cut leaves, half the
    cable's width (``half_width``, the full sections' own) in from the one border that is
    still the cable's, at most ``limit`` px.

    Where an object's border crosses the cable at a slant, one border of the cable ends
    where the object's meets it and the other runs on, a width times the slant's tangent
    further: the visible end is a wedge. Past the first border's end the section's
    middle is no longer the cable's (it leans into the wedge, towards its tip), but the
    border that runs on is still the cable's own, and the cable's middle lies half its
    width in from it: where the cable bends into the hidden stretch, that border bends
    with it, and is the only part of the image that shows the bend (the middle line of
    the narrowed sections runs straight on into the wedge's tip, and a fit over it
    leaves 15-50 degrees off where a doubled-back cable turns under the object). So
    each step goes :data:`TRACE_STEP_PX` along the line's heading (:func:`_heading`),
    and is put half a width in from the border read at the cable's own distance (within
    :data:`SECTION_ROUNDING_PX`, a pixel's rounding, of it): from both while both are
    (a section the cut has not narrowed); from one alone once the other reads shorter
    by more than that rounding (two borders short alike are their rounding, or a cut
    across both, and tell neither side), and from that side on. It stops where the
    middle leaves the mask (the cable passes out of sight), where the border followed
    is no longer at the cable's distance (the wedge's tip), or where the line has
    turned further than the tightest bend a cable takes
    (:data:`.turn_joins.HIDDEN_BEND_RADII` ``[0]`` half widths) would over the steps
    taken, and a pixel's rounding over the chord its heading is read on: the border
    followed is then the object's, meeting the cable at its corner.

    From the mask alone the two borders of a wedge cannot be told apart: an object's
    edge crossing at 30-45 degrees reads at the cable's distance from a middle half a
    width in as well as the cable's own border does. The BGR ``image`` tells them apart
    where the object is not of the background's colour: beyond the cable's own border
    lies the ground seen beside the cable's full sections, beyond the object's edge the
    object. So a border is followed alone only where the image says so: beyond the other
    border, read :data:`BEYOND_BORDER_PX` out, something unlike the ground beside the
    cable (:func:`.appearance.unlike_ground`), beyond the followed one the ground; the
    line stops where the followed border's outside no longer reads as the ground. Where
    the image does not decide (no image, an object of the ground's colour, a patch
    touching another cable), nothing is followed: no points are added.

    Returns
    -------
    ndarray
        ``(M, 2)`` the points added past ``points[-1]`` (``M >= 0``).
    """
    if len(points) < 2 or image is None:
        return np.zeros((0, 2))  # without the image nothing tells the borders apart
    x, y = (float(value) for value in points[-1])
    hx, hy = _heading(points, half_width)
    start = (hx, hy)
    reach = 2.5 * half_width + 2.0
    steps = np.arange(SECTION_STEP_PX, reach + 1e-9, SECTION_STEP_PX)
    # The cable's own half width, from its last full sections (the one given may lie
    # a pixel over it): each border is followed at the distance the cable's own shows.
    widths, sections = [], []
    ax, ay = (float(value) for value in unit(points[-1] - points[-min(FULL_SECTIONS, len(points))]))
    for px, py in points[-FULL_SECTIONS:]:
        plus = _border_distance(mask, px, py, -ay, ax, steps, reach)
        minus = _border_distance(mask, px, py, ay, -ax, steps, reach)
        widths.append(plus + minus)
        sections.append((px, py, plus, minus))
    half_width = 0.5 * float(median(np.array(widths)))
    # What lies just beyond the cable's borders along its full sections: the ground
    # (each border where the widths above found it).
    beside = []
    for px, py, plus, minus in sections:
        for sign, out in ((1.0, plus), (-1.0, minus)):
            beside.append(
                (
                    px - sign * ay * (out + BEYOND_BORDER_PX),
                    py + sign * ax * (out + BEYOND_BORDER_PX),
                )
            )
    ground = ground_beside(image, mask, np.array(beside))
    if ground is None:
        return np.zeros((0, 2))
    added = []
    side = 0  # +1 / -1 once the line follows one border alone
    for _ in range(int(limit / TRACE_STEP_PX)):
        nx_, ny_ = x + TRACE_STEP_PX * hx, y + TRACE_STEP_PX * hy
        nx, ny = -hy, hx
        if not on_mask(mask, nx_, ny_):
            break  # the middle has passed out of sight: the cut
        plus = _far_border(mask, nx_, ny_, nx, ny, steps, reach)
        minus = _far_border(mask, nx_, ny_, -nx, -ny, steps, reach)
        plus_own = (
            plus is not None and plus < reach and abs(plus - half_width) <= SECTION_ROUNDING_PX
        )
        minus_own = (
            minus is not None and minus < reach and abs(minus - half_width) <= SECTION_ROUNDING_PX
        )
        # A side is taken for the cable's alone where the other reads shorter by more
        # than a border's rounding: two sections short alike are the borders' rounding
        # or a cut across both, which tells neither side.
        apart = plus is not None and minus is not None and abs(plus - minus) > SECTION_ROUNDING_PX
        if side == 0 and plus_own and minus_own and not apart:
            shift = 0.5 * (plus - minus)
        elif plus_own and (side > 0 or (side == 0 and apart and plus > minus)):
            if not _told_by_the_image(image, mask, ground, (nx_, ny_), (nx, ny), plus, minus, side):
                break
            side, shift = 1, plus - half_width
        elif minus_own and (side < 0 or (side == 0 and apart and minus > plus)):
            if not _told_by_the_image(
                image, mask, ground, (nx_, ny_), (-nx, -ny), minus, plus, side
            ):
                break
            side, shift = -1, half_width - minus
        else:
            break
        shift = min(max(shift, -TRACE_STEP_PX), TRACE_STEP_PX)
        x, y = nx_ + shift * nx, ny_ + shift * ny
        hx, hy = _heading(points, half_width, [*added, (x, y)])
        # The border followed bends no tighter than a cable: turned further from where
        # the wedge began than the tightest bend turns over the steps taken (and a
        # pixel's rounding over the chord the heading is read on), it is the object's.
        turned = abs(np.arctan2(hx * start[1] - hy * start[0], hx * start[0] + hy * start[1]))
        bend = (len(added) + 1) * TRACE_STEP_PX / (HIDDEN_BEND_RADII[0] * half_width)
        if turned > bend + np.arctan(1.0 / half_width):
            break
        added.append((x, y))
    if side == 0:
        return np.zeros((0, 2))  # no border followed alone: the image told nothing
    return np.array(added).reshape(-1, 2)


def _told_by_the_image(
    image: np.ndarray,
    mask: np.ndarray,
    ground: tuple[np.ndarray, float],
    at: tuple[float, float],
    normal: tuple[float, float],
    followed: float,
    other: float | None,
    side: int,
) -> bool:
    """Whether the image says the border ``followed`` px from ``at`` along ``normal``
    is the cable's own: beyond it (:data:`BEYOND_BORDER_PX` out) lies the ``ground``
    seen beside the cable; and, where no side is followed yet (``side`` 0), beyond the
    other border (``other`` px the other way; None: the middle's own pixel) lies
    something unlike it: the object whose edge that is. A patch that cannot be read
    (on another cable, off the picture) tells nothing."""
    x, y = at
    dx, dy = normal
    out = followed + BEYOND_BORDER_PX
    if unlike_ground(image, mask, np.array([x + out * dx, y + out * dy]), ground) is not False:
        return False
    if side != 0:
        return True
    out = (other or 0.0) + BEYOND_BORDER_PX
    return unlike_ground(image, mask, np.array([x - out * dx, y - out * dy]), ground) is True


def middle_line(
    mask: np.ndarray,
    start: np.ndarray,
    heading: np.ndarray,
    curvature: float,
    half_width: float,
    limit: float,
    first_narrowing: bool = False,
) -> tuple[np.ndarray, bool, np.ndarray]:
    """The cable's middle line traced on ``mask`` from ``start`` along ``heading``, at
    most ``limit`` px, and whether it stopped at a cut.

    Each step goes :data:`TRACE_STEP_PX` along the heading, which turns as the end's
    fit bends (``curvature``, signed, 1/px), and is then put half the cable's width
    (``half_width``) in from its borders read across it (where the section is the
    cable's width, from both; where wider, from the border at the cable's own distance). The trace
    stops at a cut where the section across it is narrower than the cable (an object's
    border has begun to cut it) and the next one is too (a cut narrows on, never less;
    one narrow section is its borders' pixel staircase, read at a slant), or the middle point
    leaves the mask. With ``first_narrowing``, at the first narrowed section: the
    reading the turn pass's tests of a cut's shape were measured on
    (:func:`end_at_the_cut`).

    Returns
    -------
    points : ndarray
        ``(K, 2)`` traced points from ``start`` (``K >= 1``).
    cut : bool
        Whether the trace stopped at a cut before ``limit``.
    shortfall : ndarray
        ``(K,)`` how much (px) each point's section is narrower than the cable (0 at
        ``start``, and where the section is wider).
    """
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
    # The start itself (a fit's, up to a couple of pixels off the middle) is put on the
    # middle at once where its section is the cable's: else the first steps, each moved
    # by at most a step, lean across the cable and tilt a short fit through them. Then
    # step by step: compiled (:func:`._shared_kernels.middle_line`, the same operations
    # in the same order): a gap's cut reading traces dozens of sections per end.
    return _shared_kernels.middle_line(
        mask.view(np.uint8),
        x,
        y,
        hx,
        hy,
        cos,
        sin,
        float(half_width),
        int(limit / TRACE_STEP_PX),
        steps,
        float(reach),
        0.5 * SECTION_STEP_PX,
        TRACE_STEP_PX,
        CUT_NARROWING_PX,
        WIDTH_AGREES,
        bool(first_narrowing),
    )


def carried_to_the_border(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    curvature: float,
    half_width: float,
    to_the_border: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The middle line carried on from where the section began to narrow
    (``position``, heading along ``direction``, bending with ``curvature``, 1/px)
    towards where the object's border crosses it, as far as the mask still holds the
    cable on both sides of it, and its direction there.

    An object's border crosses a cable at a slant: the section begins to narrow where
    the border meets the near side, but the cable's middle passes out of sight half the
    slant further on. Past the narrowing the section's middle is no longer the cable's,
    so the line is carried on as it ran (bending no tighter than the tightest bend a
    cable takes, :data:`.turn_joins.HIDDEN_BEND_RADII` ``[0]`` half widths), with two
    lines beside it, half a half width to either side, until the first of them leaves
    the mask: up to there the cable is seen on both sides of the carried middle, so a
    heading a few degrees off cannot have carried it off the cable. Further on the
    carried line is the heading's extrapolation alone: its error grows with the
    distance (a direction read over a few traced points on a tight bend is 10-35
    degrees off), and the side line that leaves last is the one the wedge a slanted
    cut leaves runs on along, more so the more the heading leans into it. So the
    bridge starts a quarter width short of where a straight border crosses the
    middle (halfway between where the two side lines leave), on the cable. At most
    :data:`CARRY_RADII` half widths, and never past where the middle itself leaves
    the mask.

    With ``to_the_border``, carried on to that halfway point itself (a side line not
    yet out at :data:`CARRY_RADII` half widths read there): where the turn pass reads
    the cut's shape (:mod:`.traced_cuts`), the border itself, not the cable's start.
    """
    x, y = (float(value) for value in np.asarray(position, np.float64))
    hx, hy = (float(value) for value in unit(np.asarray(direction, np.float64)))
    bound = 1.0 / (HIDDEN_BEND_RADII[0] * half_width)
    turn = min(max(float(curvature), -bound), bound) * CARRY_STEP_PX
    cos, sin = float(np.cos(turn)), float(np.sin(turn))
    side = 0.5 * half_width
    steps = int(CARRY_RADII * half_width / CARRY_STEP_PX)
    path = [(x, y, hx, hy)]
    exits = [steps, steps]  # where each side line leaves the mask (steps)
    if not on_mask(mask, x, y):
        return np.array([x, y]), np.array([hx, hy])
    for step in range(1, steps + 1):
        x, y = x + CARRY_STEP_PX * hx, y + CARRY_STEP_PX * hy
        hx, hy = cos * hx - sin * hy, sin * hx + cos * hy
        if not on_mask(mask, x, y):
            break
        path.append((x, y, hx, hy))
        for k, sign in enumerate((1.0, -1.0)):
            if exits[k] == steps and not on_mask(mask, x - sign * side * hy, y + sign * side * hx):
                exits[k] = step
        if not to_the_border and min(exits) < steps:
            break
    # Where the first side line leaves (the cable seen on both sides up to there), or
    # between where the two leave; never past the middle's own exit.
    at = round(0.5 * (exits[0] + exits[1])) if to_the_border else min(exits)
    x, y, hx, hy = path[min(at, len(path) - 1)]
    return np.array([x, y]), np.array([hx, hy])


def _carried(
    mask: np.ndarray,
    position: np.ndarray,
    direction: np.ndarray,
    curvature: float,
    half_width: float,
    to_the_border: bool,
    image: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The cut ahead of the last full section (``position``, on the cable's middle) where
    a bridge starts, and its direction: the middle line carried on along ``direction``
    (:func:`carried_to_the_border`, which gives the direction there), the point put
    halfway between the two corners where the cable's borders meet the object's edge
    where the BGR ``image`` shows them (:func:`.cut_corners.between_the_corners`: the
    object not of the ground's colour).

    The carried point leaves the middle by the carry's length times the sine of the
    direction's error (on doubled_back 440000-480000, 1296 carried cuts: the carry's
    drift across against that product, correlation 0.97): on a tight bend into a hidden
    turn, where the fit lags the bend by 15-40 degrees, by up to a quarter width (the
    side line then leaves through the cable's own border). The corners are where the
    image shows them, whatever the direction. Looked for within the carry's reach
    (:data:`CARRY_RADII` half widths) past the near one a width's slant further, from a
    section a half width behind. Not for the turn pass's reads of the border itself
    (``to_the_border``: its tests were measured on the carried line's halfway point).
    """
    carried, heading = carried_to_the_border(
        mask, position, direction, curvature, half_width, to_the_border
    )
    if to_the_border:
        return carried, heading
    reach = (1.0 + 2.0 * CARRY_RADII) * half_width
    steps = np.arange(SECTION_STEP_PX, 2.5 * half_width + 2.0 + 1e-9, SECTION_STEP_PX)
    middle = between_the_corners(
        mask,
        position,
        direction,
        half_width,
        reach,
        steps,
        SECTION_ROUNDING_PX,
        image,
        BEYOND_BORDER_PX,
    )
    return (carried if middle is None else middle), heading


def end_at_the_cut(
    mask: np.ndarray,
    end,
    half_width: float,
    limit: float,
    carry: bool = True,
    to_the_border: bool = False,
    first_narrowing: bool = False,
    image: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Where the cable ``end`` (a :class:`.merging.ChainEnd`, where its bridge would
    start) passes out of sight, and its direction there.

    The middle line is traced from the end to the cut (:func:`middle_line`, at most
    ``limit`` px) and back into the piece over :data:`FIT_RADII` radii; the direction at the
    cut is a quadratic's (:func:`.geometry.end_fit`) over the traced line's last
    :data:`FIT_RADII` radii: centred on the cable, not on the skeleton's hooked tip, and
    short enough to follow a tight bend, fitted on the sections the cut has not begun to
    narrow (those before the run of narrowed sections the trace ends on), and on past
    them into a slanted cut's wedge along the border still the cable's
    (:func:`along_the_wedge`). Where less than
    half that is traced behind the end, the end's own fit bends
    on to the cut instead. With ``carry``, the middle line is then carried on towards
    where the cut's border crosses it (:func:`carried_to_the_border`, to the border
    itself with ``to_the_border``), the point put, with the BGR ``image``, halfway
    between the corners where the cable's borders meet the object's edge
    (:func:`_carried`). With ``first_narrowing``, the traces stop at the first narrowed
    section and the direction is fitted before it, as before the
    borders' rounding was told from a cut (:func:`middle_line`): the reading the turn
    pass's tests of a cut's shape were measured on (:mod:`.traced_cuts`).

    Returns
    -------
    (traced, position, direction) or None
        The traced stretch from the end to the cut, the cut (the fit's end, or the
        traced stretch's, carried on to the border), its outward direction;
        None where no cut lies ahead within ``limit``, or the end is off the mask.
    """
    position = np.asarray(end.position, np.float64)
    ahead, cut, shortfall = middle_line(
        mask, position, end.direction, end.curvature, half_width, limit, first_narrowing
    )
    if not cut or len(ahead) < 2:
        return None
    span = FIT_RADII * half_width
    behind, _, seen_shortfall = middle_line(
        mask, position, -end.direction, -end.curvature, half_width, span, first_narrowing
    )
    if polyline_length(behind) < 0.5 * span:
        # Too little of the cable traced to fit its direction: the end's fit bends on.
        position = ahead[-1]
        direction = rotated(end.direction, end.curvature * polyline_length(ahead))
        if carry:
            position, direction = _carried(
                mask, position, direction, end.curvature, half_width, to_the_border, image
            )
        return ahead, position, direction
    # The points from where a slanted cut begins to narrow the section (by more than
    # the borders' rounding) lean towards what it leaves: a short fit through them
    # tilts by 15-25 degrees. The direction is fitted on the cable's full sections.
    # Against the sections read behind the end (the cable's own, which the half width
    # given may miss by a pixel).
    own = float(median(seen_shortfall[1:])) if len(seen_shortfall) > 1 else 0.0
    # The cut's narrowing runs on to where the trace stopped; a narrower section
    # before a full one is the border's rounding (:func:`middle_line`).
    kept = np.flatnonzero(shortfall <= own + SECTION_ROUNDING_PX)
    full = max(int(kept[-1]) + 1, 2)
    if first_narrowing:
        narrowed = np.flatnonzero(shortfall > own + SECTION_ROUNDING_PX)
        full = max(int(narrowed[0]) if len(narrowed) else len(ahead), 2)
    line = np.concatenate([behind[::-1], ahead[1:full]])
    if carry and not first_narrowing and image is not None:
        # Past the last full section, along the border of a slanted cut's wedge that the
        # image shows is still the cable's (:func:`along_the_wedge`).
        line = np.concatenate([line, along_the_wedge(mask, line, half_width, span, image)])
    # The fit's own end: the traced points carry a pixel's rounding from step to step.
    position, direction, curvature = end_fit(line, False, span)
    if carry:
        position, direction = _carried(
            mask, position, direction, curvature, half_width, to_the_border, image
        )
    return ahead, position, direction


def middle_of(points: np.ndarray) -> np.ndarray:
    """The point halfway along the polyline ``points`` (``(N, 2)``, ``N >= 1``)."""
    points = np.asarray(points, np.float64)
    along = arc_lengths(points)
    if len(points) < 2 or along[-1] <= 0.0:
        return points[0].copy()
    half = 0.5 * along[-1]
    k = min(int(np.searchsorted(along, half, side="right")), len(points) - 1)
    share = (half - along[k - 1]) / max(along[k] - along[k - 1], 1e-12)
    return points[k - 1] + share * (points[k] - points[k - 1])


def short_piece_cut(
    mask: np.ndarray, points: np.ndarray, end, half_width: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the cable through a short piece (``points``, bridged along its partners'
    line: :func:`.bridge_ends.ends_through_short_pieces`) passes out of sight at
    ``end``, and its direction there.

    Thinning bends a short piece's tips toward the cut's corners, often a radius off the
    cable's middle, and the partners' line is a chord of the bend the piece may lie on;
    its middle joint lies on the middle line. So the cut is found as for a fitted end
    (:func:`end_at_the_cut`) from the piece's middle, heading along the partners' line:
    the middle line traced on to the cut, at most half the piece and
    :data:`REACH_PAST_SKIP_RADII` radii past its tip, and its direction read there.

    Returns
    -------
    (position, direction) or None
        None where no cut lies ahead within reach (a tip that is the cable's own, a
        middle off the mask).
    """
    middle = type(end)(end.piece, end.at_start, middle_of(points), end.direction)
    limit = 0.5 * polyline_length(points) + REACH_PAST_SKIP_RADII * half_width + 2.0
    # Not carried on across a slant (:func:`carried_to_the_border`): its direction is
    # read over a few radii of a piece that often starts at a crossing, too unsteady to
    # carry a radius or more.
    found = end_at_the_cut(mask, middle, half_width, limit, carry=False)
    return None if found is None else found[1:]


def unfitted_end_cut(
    mask: np.ndarray, points: np.ndarray, end, half_width: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where the cable through a piece too short for its end's fit (``points``: fewer
    joints past the tip the fit leaves out than the fit needs, so the end is left at the
    tip with the chord through the cut's hook) passes out of sight at ``end``, and its
    direction there.

    Thinning bends the tip into the cut's corner, up to a half width off the cable's
    middle: traced from there, the section is already narrowed and no cut is found
    ahead, and the chord's direction is 20-45 degrees off. The piece's middle joint lies
    on the middle line, and the joints either side of it give the cable's direction
    there (a tip's bend does not reach it): the cut is read as a short piece's
    (:func:`short_piece_cut`) from there, heading along that direction.
    """
    points = np.asarray(points, np.float64)
    outward = points[::-1] if end.at_start else points  # ends at this end's tip
    if len(outward) < 3:
        return None
    along = arc_lengths(outward)
    k = min(max(int(np.searchsorted(along, 0.5 * along[-1])), 1), len(outward) - 2)
    chord = outward[k + 1] - outward[k - 1]
    if not np.hypot(*chord) > 0.0:
        return None
    heading = type(end)(end.piece, end.at_start, end.position, unit(chord))
    return short_piece_cut(mask, points, heading, half_width)


STUB_BACK_RADII = 1.5
"""A stub's cut is traced from this many half widths back from its front: inside the
stub, clear of the crossing (whose section a trace would read as the cable's) and of the
cut's own narrowing."""


def stub_cut(
    mask: np.ndarray, end, front: np.ndarray, half_width: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where a strand seen on past a crossing as a stub passes out of sight, and its
    direction there: ``end`` is the strand's end in the crossing's junction, ``front``
    where the foreground along its direction stops past the junction
    (:func:`.crossing_stubs.ends_past_crossings`).

    The front lies on the end's line, which a direction a few degrees off (a fit bent by
    the crossing) carries a few px off the middle over the stub's 20-40 px. The middle
    line is traced from inside the stub on to the cut (:func:`end_at_the_cut`, not
    carried across a slant), which puts the cut on the cable's middle. The stub is
    straight (what :mod:`.crossing_stubs` reads it as) and too short for a fit of its
    own: its direction is the chord from the end, on the cable's middle line where the
    strand enters the crossing, to that cut. None where no cut is traced from inside
    the stub: the front is then where the end's line left the cable's side (a bending
    strand), not where it is cut."""
    front = np.asarray(front, np.float64)
    start = replace(
        end,
        position=front - STUB_BACK_RADII * half_width * end.direction,
        skip=0.0,
        curvature=0.0,
    )
    limit = (STUB_BACK_RADII + REACH_PAST_SKIP_RADII) * half_width + 2.0
    found = end_at_the_cut(mask, start, half_width, limit, carry=False)
    if found is None:
        return None
    chord = found[1] - np.asarray(end.position, np.float64)
    if not np.hypot(*chord) > 0.0:
        return None
    return found[1], unit(chord)


FORK_ENDS = 3
"""The most ends a junction thinning forks in a cut's wedge holds: the strand's and a
sliver running into each corner. A crossing's holds four, its strands' pieces on either
side: a short piece there is a stretch of the other strand, narrowed by a cut, not a sliver."""
SLIVER_SHARE = 1.0 - WIDTH_AGREES
"""A short piece narrower than this share of the strand it is joined to is no section of
that cable (:data:`WIDTH_AGREES`): a sliver of the cut's corner."""


def _strand_of_sliver(k: int, short, ends: list, through: dict[int, int]) -> int | None:
    """For the bridging end ``k`` of a short piece (``short``: its points and half width,
    px), the end of the strand it is a sliver of, or None.

    A thick cable cut at a slant leaves a wedge that thinning forks: the strand's
    skeleton ends at the fork, and a sliver runs on into each of the cut's corners,
    a half width and more off the cable's middle. The sliver whose far end the junction
    pairing joins to the strand carries the gap's join; its own middle is the corner's,
    not the cable's. So where the piece is narrower than :data:`SLIVER_SHARE` of the
    strand's half width, the strand's end (``through[k ^ 1]``: the piece's other end's
    partner in its junction, a fork of at most :data:`FORK_ENDS` ends) is where the cut is
    traced from."""
    partner = through.get(k ^ 1)
    if partner is None or not short[1] or not ends[partner].width:
        return None
    return partner if short[1] < SLIVER_SHARE * ends[partner].width else None


def read_together(
    a: np.ndarray, leaving: np.ndarray, b: np.ndarray, arriving: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The directions at a doubled-back cable's two cuts, read as the pair they are.

    Two cuts whose outward directions both head the same way (``leaving`` at ``a``,
    ``arriving`` at ``b``; their dot product positive) are the two strands of one cable
    going into an object side by side, to turn round out of sight. Each direction is a
    short fit of its own strand's traced middle (:func:`end_at_the_cut`), which lags a bend
    the cable begins at the cut (10-30 degrees on the turns missed: the fit spans the
    strand's straight or outward-swinging stretch, the cable turns in under the object) and
    leans into a slanted cut's wedge. On the turns missed that error opens the pair: the
    readings swing apart from each other by 30-50 degrees more than the cable does, and the
    hidden curve bulges round outside the turn. So where the readings open away from each
    other (``arriving - leaving`` points from ``a`` to ``b``), both cuts take their common
    direction, the mean of the two: a strand's error the other's reading does not share is
    halved, and the pair's shared lean (the whole turn tilted) is kept. Readings that close
    in on each other (the cable's turn begun before the cuts) or head apart (a gap's two
    ends, the cable running on through the object) are left as they are.

    Parameters
    ----------
    a, b : ndarray of float
        ``(2,)``, the two cut points (x, y).
    leaving, arriving : ndarray of float
        ``(2,)``, unit directions read at ``a`` and at ``b``, each pointing out of its
        strand into the gap.

    Returns
    -------
    (leaving, arriving)
        The two directions, outward at ``a`` and ``b``.
    """
    leaving = np.asarray(leaving, np.float64)
    arriving = np.asarray(arriving, np.float64)
    same_way = float(np.dot(leaving, arriving)) > 0.0
    opening = float(np.dot(arriving - leaving, np.asarray(b) - np.asarray(a))) > 0.0
    if not (same_way and opening):
        return leaving, arriving
    common = unit(leaving + arriving)
    return common, common.copy()


def bridges_from_the_cuts(
    ends: list,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    mask: np.ndarray,
    radius: float,
    given: frozenset[int],
    shape: str = "smooth",
    turns: frozenset[tuple[int, int]] = frozenset(),
    short_pieces: dict[int, tuple[np.ndarray, float]] | None = None,
    unfitted: dict[int, np.ndarray] | None = None,
    image: np.ndarray | None = None,
    stub_fronts: dict | None = None,
) -> dict[tuple[int, int], np.ndarray]:
    """Bridges of the gaps (joins of two ends in no junction, with no curve of their
    own in ``given``) drawn from the cuts: from each bridging end (``ends``, where the
    fit begins) along the cable traced to where it passes out of sight
    (:func:`end_at_the_cut`, within the tip the fit left out and
    :data:`REACH_PAST_SKIP_RADII` radii past it; only ends whose fit left a tip out),
    across the gap by :func:`.paths.gap_curve` of ``shape`` between the two cuts (where
    that is the Euler spiral of a large turn bending tighter than
    :data:`.turn_joins.HIDDEN_BEND_RADII` ``[0]`` of the cable's half width, from the
    nearest headings within :data:`.turn_joins.DIRECTION_SLACK` of the cuts' whose spiral
    does not, :func:`.euler_spiral.headings_within_bend`; two cuts heading the same way,
    a doubled-back cable's strands, read together first, :func:`read_together`, unless
    both pieces run back to one crossing: a loop's turn), and on
    to the other end's bridging point (the seen stretches drawn as curves from each
    bridging point to its cut). An end with no cut traced keeps its own
    start. The joins in ``turns`` (each as the turn pass keyed it) are bridged so too,
    though their ends are in ``given``, where both ends reach a cut, unless the cuts
    leave the strands no room across them to turn round in one arc
    (:func:`.turn_joins.turns_round_in_one_arc`; cuts heading towards each other, the
    strands already bending into the turn, only where closer than its width): those
    keep the turn's own curve, a bulb's. An end in
    ``short_pieces`` (end index -> its short piece's points and half width, px: a piece
    bridged along its partners' line) starts at the cut traced from its piece's middle
    (:func:`short_piece_cut`), with no seen stretch drawn: its piece ends at its tip; or,
    a sliver of a slanted cut's corner joined through the fork to its strand, at the cut
    traced from the strand's end (:func:`_strand_of_sliver`). An end in ``unfitted`` (end
    index -> its piece's points: a piece too short for the end's fit, the end left at its
    tip) whose own trace finds no cut starts at the cut read from its piece's middle
    (:func:`unfitted_end_cut`), its piece ending at its tip as a short piece's.
    With the BGR ``image``, an end's trace may follow a slanted cut's wedge along the
    border the image shows to be the cable's (:func:`along_the_wedge`).
    A join from an end in a crossing's junction (``stub_fronts``: end index -> the end
    moved to its stub's front, :func:`.crossing_stubs.ends_past_crossings`: the strand
    runs on past the crossing as a stub to where it passes out of sight) to an end in no
    junction is a gap too (:func:`.bridge_ends.past_a_stub`): that end's cut is read at
    the stub's front (:func:`stub_cut`), the seen stretch the straight stub.
    A cable whose half width is under :data:`CUT_NARROWING_PX` (a sliver of a short
    piece, a thin cable of a photograph) is not traced: the narrowing that marks a cut
    would be half its section and more, each border's pixel rounding alone reads as one,
    and a direction fitted over its three radii of traced middle (4-6 px) is rounded by
    10-20 degrees (on ariadne simple 00028 a short piece read 1 px wide, traced, turned
    its bridge 21 degrees off its partners' line and 4 px off the cable).

    Returns
    -------
    dict
        ``(i, j) -> (M, 2)`` curve from end ``i``'s bridging point to end ``j``'s, for
        the joins where at least one end was traced.
    """
    bridges = {}
    # Each end joined through a fork's junction (at most three ends: a strand and the
    # slivers of a cut's wedge; a crossing holds four), to its partner there.
    junctions, ends_at = np.unique(
        [junction for junction in junction_of_end if junction >= 0], return_counts=True
    )
    fork = {
        int(junction)
        for junction, count in zip(junctions, ends_at, strict=True)
        if count <= FORK_ENDS
    }
    through = {}
    for i, j, _ in joins if short_pieces else ():  # only a short piece is a sliver
        if junction_of_end[i] in fork and junction_of_end[j] in fork:
            through[i], through[j] = j, i
    fronts = stub_fronts or {}
    for i, j, _ in joins:
        stubbed = past_a_stub(i, j, junction_of_end, frozenset(fronts))
        if not stubbed and (junction_of_end[i] >= 0 or junction_of_end[j] >= 0):
            continue
        turn = (i, j) in turns or (j, i) in turns
        if (i in given or j in given) and not turn:
            continue
        traced, cuts, seen = [], [], []
        for k in (i, j):
            end = ends[k]
            if stubbed and junction_of_end[k] >= 0:
                # The strand runs on straight past the crossing, as a stub, to its cut
                # (:func:`stub_cut`); the seen stretch is the stub, straight. No cut traced
                # there: the front is where the end's line left the cable's side, no cut.
                cut = stub_cut(mask, end, fronts[k].position, (end.width or radius) + 0.5)
                traced.append(cut is not None)
                cuts.append((end.position, end.direction) if cut is None else cut)
                seen.append(False)
                continue
            short = short_pieces.get(k) if short_pieces else None
            strand = _strand_of_sliver(k, short, ends, through) if short is not None else None
            if strand is not None:
                # A sliver in the cut's corner, joined through the fork thinning makes
                # there to the strand it cuts off: the cable passes out of sight where
                # the strand's middle line, traced on across the fork, reaches the cut.
                # Traced as far as the sliver reaches and past it as for any end; not
                # carried on across the slant (the wedge's fork is no straight border).
                # No cut found from the strand: the sliver's middle, the corner's, is no
                # better a start than its tip, which the end keeps.
                half_width = (ends[strand].width or radius) + 0.5
                reach = float(
                    np.hypot(*(np.asarray(short[0], np.float64) - ends[strand].position).T).max()
                )
                limit = ends[strand].skip + reach + REACH_PAST_SKIP_RADII * half_width + 2.0
                found = end_at_the_cut(mask, ends[strand], half_width, limit, carry=False)
                short = None
                if found is not None:
                    traced.append(True)
                    cuts.append(found[1:])
                    seen.append(False)
                    continue
            if short is not None:
                half_width = (short[1] or radius) + 0.5
                found = (
                    short_piece_cut(mask, short[0], end, half_width)
                    if half_width >= CUT_NARROWING_PX
                    else None
                )
                traced.append(found is not None)
                cuts.append((end.position, end.direction) if found is None else found)
                # The piece ends at its tip: the bridge leaves from there to the cut.
                seen.append(False)
                continue
            half_width = (end.width or radius) + 0.5
            limit = end.skip + REACH_PAST_SKIP_RADII * half_width + 2.0
            # Only an end whose fit left out its tip starts its bridge behind the cut.
            traceable = end.skip > 0 and half_width >= CUT_NARROWING_PX
            found = end_at_the_cut(mask, end, half_width, limit, image=image) if traceable else None
            if found is None and traceable and unfitted and k in unfitted:
                # The end is the tip in the cut's corner: the cut is read from the middle.
                cut = unfitted_end_cut(mask, unfitted[k], end, half_width)
                if cut is not None:
                    traced.append(True)
                    cuts.append(cut)
                    seen.append(False)
                    continue
            traced.append(found is not None)
            cuts.append((end.position, end.direction) if found is None else found[1:])
            seen.append(True)
        # A stub with no cut traced is no reading of where the cable passes out of sight.
        stub_missed = stubbed and not traced[0 if junction_of_end[i] >= 0 else 1]
        if not any(traced) or (turn and not all(traced)) or stub_missed:
            continue
        (a, leaving), (b, arriving) = (
            (np.asarray(point, np.float64), heading) for point, heading in cuts
        )
        # The two strands of a doubled-back cable turning round under the object, read
        # together (:func:`read_together`); not a loop's turn, whose strands cross behind
        # their cuts (both pieces run back to one crossing): past a half turn its hidden
        # arc's two ends swing apart as the loop's circle does.
        loop = junction_of_end[i ^ 1] >= 0 and junction_of_end[i ^ 1] == junction_of_end[j ^ 1]
        # Cuts heading towards each other: the strands already bend into the turn
        # where they pass out of sight (the cable has begun turning in view), not
        # strands lying side by side, whose spacing across says how they turn round;
        # only cuts closer than one arc's width say so then.
        converging = float(np.dot(np.subtract(arriving, leaving), b - a)) < 0.0
        cable = 0.5 * ((ends[i].width or radius) + (ends[j].width or radius))
        close = float(np.hypot(*(b - a))) < 2.0 * HIDDEN_BEND_RADII[0] * cable
        if not (loop and int(junction_of_end[i ^ 1]) not in fork):
            leaving, arriving = read_together(a, leaving, b, arriving)
        if (
            turn
            and (close or not converging)
            and not turns_round_in_one_arc(a, leaving, b, arriving, cable)
        ):
            # The cuts say the strands lie too close across to turn round in one arc
            # (staggered cuts of strands side by side): the cable swung out into a
            # bulb, which the turn's own curve follows and a spiral between the cuts
            # cuts across.
            continue
        if GapCurve(shape) is GapCurve.smooth and is_large_turn(a, leaving, b, -arriving):
            # The spiral across a large turn bends as a cable does (no tighter than its
            # tightest bend), its headings turned from the readings as little as that takes.
            within = headings_within_bend(
                a, leaving, b, -arriving, HIDDEN_BEND_RADII[0] * cable, DIRECTION_SLACK
            )
            if within is not None:
                leaving, arriving = within[0], -within[1]
        across = gap_curve(a, leaving, b, -arriving, shape=shape)
        # The seen stretches drawn as the cable bends between the bridge's start and its
        # cut (the traced points carry a pixel's rounding from step to step).
        start_a, start_b = (np.asarray(ends[k].position, np.float64) for k in (i, j))
        seen_a = (
            gap_curve(start_a, ends[i].direction, a, leaving, shape=shape)
            if seen[0]
            else np.array([start_a, a])
        )
        seen_b = (
            gap_curve(b, -arriving, start_b, -ends[j].direction, shape=shape)
            if seen[1]
            else np.array([b, start_b])
        )
        curve = np.concatenate([seen_a[:-1], across, seen_b[1:]])
        if (j, i) in turns:
            bridges[j, i] = curve[::-1]  # the key the turn's own curve has
        else:
            bridges[i, j] = curve
    return bridges

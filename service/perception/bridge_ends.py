"""Where merging's bridges start: the chain ends a gap's curve is drawn between.

The joins are chosen from the ends as their fits extrapolate them to the tips
(:func:`.merging.chain_ends`); the curves across gaps are drawn from ends that say
better where the cable is at the gap: where each end's fit begins
(:func:`bridge_from_the_fits`), along the line through a short piece joined on both
sides (:func:`ends_through_short_pieces`), or, for a short piece joined at one end, as
its longer partner's bend goes on (:func:`ends_of_short_pieces_from_partners`). Ends are
:class:`.merging.ChainEnd` values (changed with :func:`dataclasses.replace`); the joins
and their costs are never changed here.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.perception import _bridge_ends_kernels
from service.perception._bridge_ends_kernels import MOVED, UNDECIDED
from service.perception.geometry import (
    arc_lengths,
    fit_at,
    fit_where_skipped,
    on_mask,
    polyline_length,
)

# An end put along a line through a short piece carries no fit of its own.
_UNFITTED = {"curvature": 0.0, "skip": 0.0, "width": 0.0}


def _moved(end, position: np.ndarray, direction: np.ndarray):
    """``replace(end, position=position, direction=direction)``: the same frozen end
    (all its other fields kept), made without ``dataclasses.replace``'s look at every
    field, for the several crossing and gap ends of every frame."""
    moved = object.__new__(type(end))
    moved.__dict__.update(end.__dict__, position=position, direction=direction)
    return moved


def partners(count: int, joins: list[tuple[int, int, float]]) -> np.ndarray:
    """The end each of ``count`` ends is joined to, or -1."""
    partner = np.full(count, -1)
    for i, j, _ in joins:
        partner[i], partner[j] = j, i
    return partner


def bridge_from_the_fits(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    span: float,
    junction_of_end: list[int],
    distance: np.ndarray | None = None,
    nominal_skip: float | None = None,
    curve_given: frozenset[int] = frozenset(),
    stubs: frozenset[int] = frozenset(),
) -> tuple[list, np.ndarray]:
    """Ends to bridge gaps from: where each end's fit begins, not extrapolated to the tip.

    An end's position and direction are its fit's extrapolation over the tip it left
    out (:attr:`ChainEnd.skip`, a cut end's hook); across a gap on a bend that
    extrapolation turns the bridge off the cable. A gap's bridge (ends in no junction)
    starts instead where the fitted stretch begins, with the fit's own tangent there,
    and the piece's joints before that are left out of the path (not for pieces shorter
    than the fit's ``span``: :func:`ends_through_short_pieces`); where the fit misses
    the piece there by more than :data:`FIT_MISS_PX` (the piece bends within the span),
    on the piece (:func:`start_on_the_piece`). With ``distance`` (the
    mask's distance transform) a crossing's bridge starts clear of the other strand
    (:func:`ends_clear_of_crossing`). A piece too short to fit beyond a tip narrower
    than ``nominal_skip`` says (a cut's hook) starts its bridge past it
    (:func:`_beyond_hooks`), unless the end is in ``curve_given``: its bridge is a curve
    found elsewhere (a turn out of sight, :mod:`.turn_joins`), which starts where that
    curve does. A join from an end in ``stubs`` (in a crossing's junction, its strand
    running on as a stub to where it passes out of sight:
    :func:`.crossing_stubs.ends_past_crossings`) to an end in no junction is a gap as
    well (:func:`past_a_stub`): its free end starts where its fit begins, where that
    lies on the cable (``distance`` above 0; the end keeps its own reading otherwise,
    as the gap's end it was before). Returns the
    ends and the arc lengths to trim per end (for :func:`.paths.assemble_paths`).
    """
    adjusted = list(ends)
    trims = np.zeros(len(ends))
    hooks = np.zeros(len(ends))
    for i, j, _ in joins:
        stubbed = past_a_stub(i, j, junction_of_end, stubs)
        if not stubbed and (junction_of_end[i] >= 0 or junction_of_end[j] >= 0):
            if distance is not None and junction_of_end[i] == junction_of_end[j]:
                for k in (i, j):
                    clear = ends_clear_of_crossing(
                        pieces[ends[k].piece], ends[k], ends[k ^ 1].skip, span, distance
                    )
                    if clear is not None:
                        adjusted[k], trims[k] = clear
            continue
        for k in (i, j):
            end = ends[k]
            if end.skip <= 0 or junction_of_end[k] >= 0:
                continue
            # Pieces shorter than the fit's span are crossed along their partners' line.
            length = polyline_length(pieces[end.piece])
            if length < span or length < 2.0 * end.skip + 1.0:
                # Too short to fit beyond the skipped tip (fit_where_skipped's own
                # bound): where that tip is narrow, a cut's hook, the bridge starts past it.
                if nominal_skip is not None and end.skip > nominal_skip and k not in curve_given:
                    hooks[k] = end.skip
                continue
            points = pieces[end.piece]
            fit_span = span_holding_joints(points, end.at_start, span, end.skip, ends[k ^ 1].skip)
            inner = fit_where_skipped(points, end.at_start, fit_span, end.skip)
            if inner is not None:
                # A quadratic over a piece that bends within its span (a strand hooking
                # into a hidden turn, or a widened fit reaching further in) spreads the
                # bend over the whole stretch and may miss the piece where it begins:
                # there the bridge starts on the piece (the skeleton lies on the cable's
                # middle), and its cut is traced from there, not from beside the cable,
                # along the piece's own segment there (a longer chord is tilted by the
                # bend the fit missed: :func:`segment_direction`), or along the fit's
                # own direction where that segment runs into a cut's wedge
                # (:func:`outer_joint_at_full_width`): there the piece is the hook's.
                backwards = points if end.at_start else points[::-1]
                inner = start_on_the_piece(
                    backwards, end.skip, span, *inner, distance=distance, width=end.width
                )
            if inner is not None and stubbed and not _on_the_cable(distance, inner[0]):
                # A fit whose start lies off the cable runs beside it (a short piece
                # round a turn, :mod:`.end_readings`): the end keeps its own reading.
                inner = None
            if inner is not None:
                adjusted[k] = _moved(end, inner[0], inner[1])
                trims[k] = end.skip
    for piece in np.flatnonzero(hooks.reshape(-1, 2).any(axis=1)).tolist():
        pair = slice(2 * piece, 2 * piece + 2)
        pair_ends = ends[pair]
        widths = np.array([end.width for end in pair_ends])
        # Narrow tips, joined or not: a line through one is no line of the cable.
        narrow = np.array([end.skip if end.skip > nominal_skip else 0.0 for end in pair_ends])
        beyond = _beyond_hooks(pieces[piece], hooks[pair], trims[pair], widths, narrow)
        for k, position, trim in beyond:
            adjusted[2 * piece + k] = replace(adjusted[2 * piece + k], position=position)
            trims[2 * piece + k] = trim
    return adjusted, trims


def _on_the_cable(distance: np.ndarray | None, point: np.ndarray) -> bool:
    """Whether ``point`` (x, y) lies on the mask whose ``distance`` transform is given
    (the pixel nearest it; True where no transform is given, False outside the picture)."""
    # A distance transform is nonzero exactly on the mask.
    return distance is None or on_mask(distance, float(point[0]), float(point[1]))


def past_a_stub(i: int, j: int, junction_of_end: list[int], stubs: frozenset[int]) -> bool:
    """Whether the join of ends ``i`` and ``j`` is a gap from a crossing's stub: one end
    in a junction and in ``stubs`` (its strand seen on past the crossing to where it
    passes out of sight), the other in no junction."""
    crossing = [k for k in (i, j) if junction_of_end[k] >= 0]
    return len(crossing) == 1 and crossing[0] in stubs


# The end fit is a quadratic: it needs this many joints (``_geometry_kernels.end_fit``).
FIT_JOINTS = 4


def span_holding_joints(
    points: np.ndarray, at_start: bool, span: float, skip: float, far_skip: float
) -> float:
    """The arc length an end's fit must span, past its skipped tip, to hold
    :data:`FIT_JOINTS` joints.

    Joints lie a segment's length apart, so whether ``span`` holds four of them past
    ``skip`` depends on where the first one falls: one joint short, the fit fails and the
    end is left at its tip with the chord through the hook it was to skip, tens of
    degrees off a slanted cut. The span is widened to the fourth joint past the skip, as
    long as that stays clear of the other end's skipped tip (``far_skip``); otherwise
    ``span`` is returned unchanged. (Reaching further in, the widened fit may span a
    bend: :func:`bridge_from_the_fits` then starts on the piece where the fit misses it,
    :func:`start_on_the_piece`.)

    Parameters
    ----------
    points : ndarray
        ``(N, 2)`` joints of the piece.
    at_start : bool
        The end at ``points[0]`` or at ``points[-1]``.
    span, skip, far_skip : float
        The fit's usual span, the arc length it leaves out at this end, and that left
        out at the other end.

    Returns
    -------
    float
        ``span``, or the wider span that reaches the fourth joint past ``skip``.
    """
    along = arc_lengths(points[::-1] if not at_start else points)
    past = along[along >= skip]
    if len(past) < FIT_JOINTS:
        return span
    needed = float(past[FIT_JOINTS - 1]) - skip
    if needed <= span or skip + needed > float(along[-1]) - far_skip:
        return span
    # A hair more than the fourth joint's arc length: the fit takes the joints whose arc
    # length is at most skip + span, summed in its own order.
    return needed + 1e-6


def _beyond_hooks(
    points: np.ndarray,
    hooks: np.ndarray,
    trims: np.ndarray,
    widths: np.ndarray,
    narrow: np.ndarray,
):
    """Where a piece too short to fit beyond its cut's hook starts its bridges.

    An end's fit leaves out the tip where the cut narrows the cable (``hooks``, arc
    lengths at the piece's start and end, 0 for none); there thinning bends the
    skeleton toward the cut's far corner, up to a half width off the cable. A piece too
    short to fit beyond that has no extrapolation to trust either: its bridge starts
    at its first joint past the hook instead, on the cable's middle, and the hook's
    joints are left out of the path. The other end's bridge may already start further
    in (``trims``, a crossing's); at least two joints are kept between them (the
    hook's inner joints are given back, the longer hook's first, or the hook is kept
    whole). The tip is taken back onto the line of the two joints past its hook, which
    must lie past the other end's narrow tip too (``narrow``, arc lengths as
    ``hooks``, of either end whether joined or not), and it must lie where a hook puts
    it: off that line by no more than its piece's half width (``widths``, per end;
    :func:`_hooked_off`). A tip further off is no hook but the cable bending (a tight
    loop, a bend at the cut): that end is left as it is. Yields (0 for the start or 1
    for the end, position, arc length to trim) for each end trimmed past its hook.
    """
    along = arc_lengths(points)
    cut = np.maximum(hooks, trims)
    first = int(np.searchsorted(along, cut[0])) if cut[0] > 0 else 0
    last = len(points) - 1
    if cut[1] > 0:
        last = int(np.searchsorted(along, along[-1] - cut[1], side="right")) - 1
    floor = first if hooks[0] <= 0 else 0  # how far each hook may give back
    ceiling = last if hooks[1] <= 0 else len(points) - 1
    while last - first < 1 and (first > floor or last < ceiling):
        if first > floor and (last == ceiling or hooks[0] >= hooks[1]):
            first -= 1
        else:
            last += 1
    if last - first < 1:
        return
    # Trims just short of the kept joints' arc lengths, so that they stay. A narrow tip
    # ends at the first joint of full width (that joint is past it), and arc lengths
    # summed in another order differ in the last bits: compared with the same slack.
    past = narrow - 1e-6
    start_past = hooks[0] > 0 and first > 0 and along[-1] - along[first + 1] >= past[1]
    if start_past and _hooked_off(points[first], points[first + 1], points[0], widths[0]):
        tip = _along_beyond(points[first], points[first + 1], points[0])
        yield 0, tip, float(along[first]) - 1e-6
    end_past = hooks[1] > 0 and last < len(points) - 1 and along[last - 1] >= past[0]
    if end_past and _hooked_off(points[last], points[last - 1], points[-1], widths[1]):
        tip = _along_beyond(points[last], points[last - 1], points[-1])
        yield 1, tip, float(along[-1] - along[last]) - 1e-6


def _hooked_off(outer: np.ndarray, inner: np.ndarray, tip: np.ndarray, half_width: float) -> bool:
    """Whether ``tip`` lies where a cut's hook puts it beyond the line from ``inner``
    through ``outer``: ahead of ``outer`` and off the line by no more than ``half_width``
    (thinning bends the tip at most to the cut's corner). A tip further off is the cable
    itself bending (the line cuts inside the bend), and one behind the line's start is
    no continuation of it (a line through the other end's hook). A piece of unknown
    width (0) sets no bound: any tip ahead counts."""
    step = np.asarray(outer, np.float64) - np.asarray(inner, np.float64)
    length = float(np.hypot(*step))
    if length < half_width or length < 1e-9:
        return False  # two joints closer than a half width give the line no direction
    step = step / length
    offset = np.asarray(tip, np.float64) - np.asarray(outer, np.float64)
    ahead = float(offset @ step)
    off = abs(float(step[0] * offset[1] - step[1] * offset[0]))
    # The joints lie on whole pixels: each may be half a pixel off the line, which
    # tilts it by up to one pixel over its length, carried ahead to the tip.
    return ahead > 0.0 and (half_width <= 0 or off <= half_width + 0.5 + ahead / length)


def _along_beyond(outer: np.ndarray, inner: np.ndarray, tip: np.ndarray) -> np.ndarray:
    """The cut's tip taken back onto the line from ``inner`` through ``outer`` (the
    piece beyond its hook): the hook bends the skeleton sideways, toward the cut's far
    corner, but how far the cable reaches along the piece is still where its tip is."""
    outer, inner = np.asarray(outer, np.float64), np.asarray(inner, np.float64)
    step = outer - inner
    length = float(np.hypot(*step))
    if length < 1e-9:
        return outer
    step = step / length
    return outer + max(0.0, float((np.asarray(tip, np.float64) - outer) @ step)) * step


# A joint is where another strand widens the mask when the distance to the border
# there exceeds its piece's typical half width by more than the distance transform's
# pixel steps along one straight cable.
WIDENED_MARGIN_PX = 1.0

# An end joint is narrow (part of a cut end) below this fraction of the full half width.
FULL_WIDTH_FRACTION = 0.8

# Where a crossing's bridge starts, the piece's own line lies on its strand to within
# the skeleton's pixel steps; a fit that passes further from it than one such step is
# bent by the stretch beyond (a bend behind the crossing), not describing the cable there.
FIT_MISS_PX = 1.0


def ends_clear_of_crossing(
    points: np.ndarray, end, far_skip: float, span: float, distance: np.ndarray
):
    """Where a crossing's bridge should start from one of its ends: clear of the other
    strand, or None to keep ``end`` as it is.

    Near a crossing the skeleton follows the middle of both strands together, so the
    piece's last joints bend toward the other strand, and an end fitted through them,
    extrapolated to the tip, points off its own strand: the bridge drawn from it swings
    out of the cable. The bridge starts instead where the piece is its own width again
    (past the tip joints where the mask is wider than the piece by more than
    ``WIDENED_MARGIN_PX``), at least past the tip its fit skipped, with the tangent of a
    fit of the stretch beyond (over a span short enough for a tight loop's bend, as
    ``_geometry_kernels.bend_aware_fit`` does, and short of the arc length ``far_skip``
    the other end's fit left out, a cut end's narrow hook); the piece's joints before it
    are left out; where that fit misses the piece's own line at the start, the bridge
    starts on the piece (:func:`start_on_the_piece`). Pieces shorter than ``span`` keep
    their end unless its fit misses the piece (:func:`short_piece_clear_of_crossing`);
    pieces of unknown width, or too short to fit beyond the widened tip, are left as
    they are. Returns the end and the arc length to trim.
    """
    # The piece from the end's tip inwards; the loop is compiled
    # (_bridge_ends_kernels.clear_of_crossing).
    backwards = np.ascontiguousarray(points if end.at_start else points[::-1], np.float64)
    # NumPy compares a float32 distance transform with a float in float32.
    narrow_at_most = end.width + WIDENED_MARGIN_PX
    if distance.dtype == np.float32:
        narrow_at_most = float(np.float32(narrow_at_most))
    arguments = (
        backwards,
        bool(end.at_start),
        distance,
        float(end.width),
        float(narrow_at_most),
        float(end.skip),
        float(far_skip),
        float(span),
    )
    outcome, skip, *fit = _bridge_ends_kernels.clear_of_crossing(*arguments, _OWN_TURNS)
    if outcome == UNDECIDED:
        outcome, skip, *fit = _bridge_ends_kernels.clear_of_crossing(*arguments, _turns(backwards))
    if outcome != MOVED:
        if end.width > 0 and polyline_length(points) < span:
            return short_piece_clear_of_crossing(points, backwards, end, span, distance)
        return None
    # Evaluated here, as geometry.fit_where_skipped does: Python's ``skip**2`` is the C
    # library's pow, now and then an ulp off the ``skip * skip`` compiled code takes.
    inner = fit_at(*fit, skip)
    if inner is None:
        return None
    position, direction = start_on_the_piece(backwards, skip, span, *inner)
    return _moved(end, position, direction), skip


def short_piece_clear_of_crossing(
    points: np.ndarray, backwards: np.ndarray, end, span: float, distance: np.ndarray
):
    """:func:`ends_clear_of_crossing` for a piece shorter than the fit's ``span``: its
    end's fit (over the whole piece, as :func:`.merging.chain_ends` fitted it) stays
    unless it misses the piece where the bridge starts, past the widened tip and the tip
    the fit skipped; then the bridge starts on the piece (:func:`start_on_the_piece`).
    A short piece's fit runs into whatever bends its far end (a hook at the picture's
    edge, a cut), and a quadratic over a few joints turns that into an end several px
    off its strand. Returns the end and the arc length to trim, or None to keep it."""
    skip = max(float(end.skip), widened_tip_length(backwards, distance, end.width))
    if skip <= 0 or polyline_length(points) < 2.0 * skip + 1.0:
        return None
    inner = fit_where_skipped(points, end.at_start, span, skip)
    if inner is None:
        return None
    position, direction = start_on_the_piece(backwards, skip, span, *inner)
    if position is inner[0]:
        return None
    return _moved(end, position, direction), skip


def widened_tip_length(backwards: np.ndarray, distance: np.ndarray, width: float) -> float:
    """Arc length from the tip of ``backwards`` (a piece from its tip inwards) to its
    first joint where the mask (``distance``, its distance transform) is no wider than
    the piece's half ``width`` plus ``WIDENED_MARGIN_PX``: the stretch another strand
    widens."""
    rows = np.clip(np.rint(backwards[:, 1]).astype(int), 0, distance.shape[0] - 1)
    cols = np.clip(np.rint(backwards[:, 0]).astype(int), 0, distance.shape[1] - 1)
    narrow = np.flatnonzero(distance[rows, cols] <= width + WIDENED_MARGIN_PX)
    last = int(narrow[0]) if narrow.size else len(backwards) - 1
    return polyline_length(backwards[: last + 1])


def start_on_the_piece(
    backwards: np.ndarray,
    skip: float,
    span: float,
    position: np.ndarray,
    direction: np.ndarray,
    distance: np.ndarray | None = None,
    width: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Where a bridge starts and which way it leaves: the fit's ``position`` and
    ``direction`` at arc length ``skip`` of the piece ``backwards`` (from its tip
    inwards), or the piece's own point there when the fit misses it.

    A quadratic in arc length over a stretch that runs straight out of the crossing and
    bends further in spreads the bend over the whole stretch: at the crossing it lands
    several px off the strand, pointing 20-30 degrees off it, and the bridge leaves the
    cable. Past the widened tip the piece's own line is on its strand (to within
    ``FIT_MISS_PX``); where the fit is further from it than that, the bridge starts on the
    piece, along the chord to its last joint within half the fit's ``span`` (halved as
    ``_geometry_kernels.bend_aware_fit`` halves it on a bend; a chord is tilted from the
    tangent at its start by half the turning along it), or, given the distance
    transform ``distance`` and the piece's half ``width`` (a gap's end) and where the
    segment there runs out to the cable's full width (:func:`outer_joint_at_full_width`,
    read only where the fit misses), along the piece's segment the start lies on
    (:func:`segment_direction`: the fit missed the piece because it bends within the
    span, and the chord over half of it is tilted by half that bend); where that segment
    runs out to a narrow joint instead (a cut's wedge: thinning hooked the tip into the
    cut's corner, and the fit missed the piece for the hook, not for a bend), along the
    fit's own direction: the fit leaves the hooked tip out, and the piece's own lines
    there, its segment and the chord from it, are the hook's (on the moved starts of
    doubled_back 460000-470000 and occluded 470000 at a narrow tip, the fit's direction
    read 1.5 and 6.1 degrees off the cable's on average, the chord 6.2 and 14.9, the
    segment 12.3 and 17.2; BENCHMARKS, ``dbk19``). Returns the position and the outward
    unit direction.
    """
    arcs = arc_lengths(backwards)
    # The one point as points_along finds it (np.interp per coordinate), without its
    # arrays: called for every crossing end of a frame.
    on_piece = np.array(
        [np.interp(skip, arcs, backwards[:, 0]), np.interp(skip, arcs, backwards[:, 1])]
    )
    if float(np.hypot(*(position - on_piece))) <= FIT_MISS_PX:
        return position, direction
    if distance is not None and width > 0.0:
        if outer_joint_at_full_width(backwards, skip, distance, width, arcs):
            along = segment_direction(backwards, arcs, skip)
            return (on_piece, along) if along is not None else (position, direction)
        # Out to a narrow joint (a cut's wedge) the fit missed the piece where thinning
        # hooked the tip into the cut's corner, not where the cable bends: the fit,
        # which leaves that tip out, still runs along the cable, and the piece's own
        # lines there (its segment, the chord from it) are the hook's.
        return on_piece, direction
    # Without the width (a crossing's end: ends_clear_of_crossing), along the chord over
    # half the span.
    beyond = np.flatnonzero((arcs > skip) & (arcs <= skip + 0.5 * span))
    if not beyond.size:
        return position, direction
    chord = on_piece - backwards[beyond[-1]]
    length = float(np.hypot(*chord))
    if length < 1e-9:
        return position, direction
    return on_piece, chord / length


def segment_direction(backwards: np.ndarray, arcs: np.ndarray, arc: float) -> np.ndarray | None:
    """The outward unit direction of the piece's segment on which arc length ``arc``
    lies: the piece's own direction there.

    A piece is a chain of straight segments whose joints lie on the cable's middle line
    (to within the pixel they are rounded to), so between two joints the segment is the
    finest direction the piece gives. A chord from a point on it to a joint further in
    also spans the turns at the joints between: on a cable of even curvature it is tilted
    from the tangent at its start by half the turning along it, some 15-35 degrees over
    half a 40 px fit span on a strand hooking into a hidden turn, against a few degrees
    for the segment itself (its joints' rounding, half a pixel over a segment's length,
    and half the turning along the segment at most).

    Parameters
    ----------
    backwards : ndarray
        ``(N, 2)`` joints of the piece from its tip inwards.
    arcs : ndarray
        ``(N,)`` arc length of each joint from the tip (:func:`.geometry.arc_lengths`).
    arc : float
        Arc length from the tip, above 0, where the direction is wanted.

    Returns
    -------
    ndarray or None
        The unit direction from the segment's inner joint to its outer one (toward the
        tip), or None past the last joint or on a segment of no length.
    """
    inner = int(np.searchsorted(arcs, arc, side="right"))
    if inner < 1 or inner >= len(backwards):
        return None
    step = backwards[inner - 1] - backwards[inner]
    length = float(np.hypot(*step))
    if length < 1e-9:
        return None
    return step / length


def outer_joint_at_full_width(
    backwards: np.ndarray,
    arc: float,
    distance: np.ndarray | None,
    width: float,
    arcs: np.ndarray | None = None,
) -> bool:
    """Whether the piece's segment on which arc length ``arc`` lies (``backwards``: the
    piece from its tip inwards) runs out to a joint where the mask is the cable's full
    width: at least :data:`FULL_WIDTH_FRACTION` of the piece's half ``width``, the
    distance transform ``distance`` read at the joint's pixel.

    Where an occluder cuts a cable at a slant, thinning runs the piece's tip into the
    cut's narrow corner (:func:`.merging.chain_ends`: its fit leaves that stretch out):
    a segment out to such a joint is pulled 1-2 px off the middle and 15-30 degrees off
    the cable, the cut's direction rather than the cable's. Out to a joint at full
    width it lies on the middle. False where the width or the transform is unknown.
    ``arcs``: the joints' arc lengths from the tip, where the caller has them
    (:func:`.geometry.arc_lengths`).
    """
    if distance is None or width <= 0.0:
        return False
    arcs = arc_lengths(backwards) if arcs is None else arcs
    inner = int(np.searchsorted(arcs, arc, side="right"))
    if inner < 1 or inner >= len(backwards):
        return False
    col = min(max(int(np.rint(backwards[inner - 1, 0])), 0), distance.shape[1] - 1)
    row = min(max(int(np.rint(backwards[inner - 1, 1])), 0), distance.shape[0] - 1)
    return float(distance[row, col]) >= FULL_WIDTH_FRACTION * width


# The kernel computes the turns itself (see _turns).
_OWN_TURNS = np.empty(0, np.float64)


def _turns(backwards: np.ndarray) -> np.ndarray:
    """The signed turn at each inner joint of a polyline, from the step before it to the
    step after, by NumPy's arctan2: the kernel's own (the C library's) is an ulp off now
    and then, and decides a span's halving alike unless the turning lies within a hair of
    the limit."""
    steps = np.diff(backwards, axis=0)
    return np.arctan2(
        steps[:-1, 0] * steps[1:, 1] - steps[:-1, 1] * steps[1:, 0],
        steps[:-1, 0] * steps[1:, 0] + steps[:-1, 1] * steps[1:, 1],
    )


def ends_through_short_pieces(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    shorter_than: float,
    junction_of_end: list[int] | None = None,
    turns: frozenset[tuple[int, int]] = frozenset(),
) -> list:
    """Ends for bridging, with short pieces taken along the line between their partners.

    A piece shorter than the end-fit span (say a stretch of cable seen between two
    occluders, cut at a slant at both ends) shows where the cable is, but its own end
    directions are poor: thinning bends both of its ends toward the cuts' corners.
    When it is joined at both ends, the cable runs through it from one partner end to
    the other, so both of its ends point along the line between those two ends, unless
    the piece itself runs clearly across that line: the cable bends there (a loop
    closing under an object, a bend beyond a crossing), and the line between the
    partners would cut the bend short. The piece's own chord (from its first joint to
    its last) is off the cable's direction by at most what its end joints being up to a
    half width off the centre line makes of it, ``atan(2 width / chord)``; turned from
    the partners' line by more, the cable runs through the piece halfway between the
    two.

    With ``junction_of_end``, an end of such a piece whose join is a gap while its
    other end's join runs through a crossing takes the middle of three readings of
    its direction (:func:`_middle_direction`): the line above, and the circles that
    leave each partner along its direction and pass through the end
    (:func:`_arriving_on_circle`). A short piece between a crossing and an object
    often sits where a loop bends into its hidden stretch; there the line between the
    partners is a chord of the bend, 20-30 degrees off the cable at the cut, while the
    two circles follow the bend. On a straight cable all three agree; one reading
    thrown off (a partner's direction tilted by a crossing or a slanted cut) is
    outvoted. The piece's own end fit is no reading: thinning bends its ends. The
    joins themselves, and their costs, are left as they were.

    A piece joined across gaps at both ends (a stretch seen between two objects, or
    between where two strands part and an object), one of them one of ``turns`` (the
    joins the turn pass made, keyed either way round: the cable turns round out of sight
    there, a doubled-back cable's bulb), keeps its own ends: the cable does not run from
    one partner to the other through it, but leaves it into a turn and comes back beside
    it, so the line between the partners, or the circle through the partner across the
    gap and both tips (one of them the other strand's end, across the turn), is no
    reading of its direction (doubled_back 410014: 75 degrees off). A piece joined
    through a crossing at its other end keeps the middle of three readings above, which
    follows a loop's bend into its hidden stretch and outvotes one reading thrown off.
    Needs ``junction_of_end``.
    """
    partner = partners(len(ends), joins)
    adjusted = list(ends)
    for piece, points in enumerate(pieces):
        before, after = partner[2 * piece], partner[2 * piece + 1]
        if before < 0 or after < 0 or polyline_length(points) >= shorter_than:
            continue
        if (
            junction_of_end is not None
            and _gaps_on_both_sides(2 * piece, 2 * piece + 1, partner, junction_of_end)
            and any(
                (own, partner[own]) in turns or (partner[own], own) in turns
                for own in (2 * piece, 2 * piece + 1)
            )
        ):
            continue
        axis = ends[after].position - ends[before].position
        length = float(np.hypot(*axis))
        if length < 1e-9:
            continue
        axis = axis / length
        start, end = ends[2 * piece], ends[2 * piece + 1]
        axis = _chord_across(points, axis, start.width)
        directions = [-axis, axis]
        if junction_of_end is not None:
            for side in (0, 1):
                own, other = 2 * piece + side, 2 * piece + 1 - side
                if _gaps_on_both_sides(own, other, partner, junction_of_end):
                    directions[side] = _through_both_tips(
                        ends[partner[own]].position, ends[own].position, ends[other].position
                    )
                elif _gap_beside_crossing(own, other, partner, junction_of_end):
                    readings = (
                        _arriving_on_circle(ends[partner[other]], ends[own].position),
                        -_arriving_on_circle(ends[partner[own]], ends[own].position),
                    )
                    directions[side] = _middle_direction(directions[side], readings)
        adjusted[2 * piece] = replace(start, direction=directions[0], **_UNFITTED)
        adjusted[2 * piece + 1] = replace(end, direction=directions[1], **_UNFITTED)
    return adjusted


def _gap_beside_crossing(own: int, other: int, partner: np.ndarray, junction_of_end) -> bool:
    """Whether end ``own`` is joined across a gap (neither end in a junction) while its
    piece's ``other`` end is joined through a crossing (both ends in one junction)."""
    across, through = partner[own], partner[other]
    return (
        junction_of_end[own] < 0
        and junction_of_end[across] < 0
        and junction_of_end[other] >= 0
        and junction_of_end[other] == junction_of_end[through]
    )


def _gaps_on_both_sides(own: int, other: int, partner: np.ndarray, junction_of_end) -> bool:
    """Whether both ends of a piece, ``own`` and ``other``, are joined across gaps (no
    end of either join in a junction): a stretch of cable seen between two objects."""
    return all(junction_of_end[k] < 0 for k in (own, other, partner[own], partner[other]))


def _through_both_tips(near: np.ndarray, tip: np.ndarray, other_tip: np.ndarray) -> np.ndarray:
    """The outward direction at ``tip`` of the circle through a short piece's two tips
    (``tip``, ``other_tip``) and its partner's end ``near`` across the gap at ``tip``
    (the line through them when the three are in line), pointing on toward ``near``."""
    chord_near, chord_other = near - tip, other_tip - tip
    cross = float(chord_near[0] * chord_other[1] - chord_near[1] * chord_other[0])
    along = near - other_tip
    if abs(cross) < 1e-9:
        length = float(np.hypot(*along))
        return along / length if length > 1e-9 else along
    # The centre relative to ``tip`` (two chords' perpendicular bisectors meet there).
    squared_near, squared_other = chord_near @ chord_near, chord_other @ chord_other
    centre = np.array(
        [
            chord_other[1] * squared_near - chord_near[1] * squared_other,
            chord_near[0] * squared_other - chord_other[0] * squared_near,
        ]
    ) / (2.0 * cross)
    tangent = np.array([-centre[1], centre[0]]) / float(np.hypot(*centre))
    return tangent if tangent @ along >= 0 else -tangent


def _arriving_on_circle(leaving, position: np.ndarray) -> np.ndarray:
    """The direction in which a circle that leaves end ``leaving`` along its direction
    passes through ``position``: the leaving direction reflected in the chord between
    the two (the leaving direction itself for a point on the end)."""
    chord = np.asarray(position, np.float64) - leaving.position
    length = float(np.hypot(*chord))
    if length < 1e-9:
        return leaving.direction
    chord = chord / length
    return 2.0 * float(leaving.direction @ chord) * chord - leaving.direction


def _middle_direction(reference: np.ndarray, readings) -> np.ndarray:
    """The middle, by angle, of ``reference`` and the unit directions ``readings``
    (two): with three readings of one direction, the middle one is the one that the
    other two do not both contradict, so one reading far off is outvoted."""
    turns = sorted(
        float(np.arctan2(reference[0] * r[1] - reference[1] * r[0], reference @ r))
        for r in (reference, *readings)
    )
    turn = turns[1]
    cos, sin = np.cos(turn), np.sin(turn)
    return np.array(
        [cos * reference[0] - sin * reference[1], sin * reference[0] + cos * reference[1]]
    )


def _chord_across(points: np.ndarray, axis: np.ndarray, half_width: float) -> np.ndarray:
    """The direction of a short piece joined on both sides: ``axis`` (unit, the line
    between its partners), or halfway between it and the piece's own chord where that
    turns from ``axis`` by more than its uncertainty (a piece of unknown ``half_width``
    keeps ``axis``, and so does one of two joints: both are its end joints, placed by
    the cuts)."""
    chord = points[-1] - points[0]
    length = float(np.hypot(*chord))
    if half_width <= 0 or len(points) < 3 or length < 1e-9:
        return axis
    chord = chord / length
    off = float(np.arccos(np.clip(chord @ axis, -1.0, 1.0)))
    if off <= np.arctan2(2.0 * half_width, length):
        return axis
    middle = chord + axis
    norm = float(np.hypot(*middle))
    return axis if norm < 1e-9 else middle / norm


def ends_of_short_pieces_from_partners(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    shorter_than: float,
    junction_of_end: list[int],
) -> list:
    """Ends for bridging, with a short piece joined at one end only arriving as its
    partner's bend goes on.

    A piece shorter than the end-fit span seen beside an occluder (between it and the
    picture's edge, or a free tip) has too little cable to fit a direction: thinning
    bends it toward the cuts' corners, 10-30 degrees off. Its partner across the gap,
    a longer piece, has a good end. The bridge then arrives at the short piece as a
    circle leaving the partner's end along its direction would: along the partner's
    direction reflected in the chord between the two ends. Only gaps (ends in no
    junction); the joins themselves are left as they were.
    """
    partner = partners(len(ends), joins)
    adjusted = list(ends)
    for i, j, _ in joins:
        if junction_of_end[i] >= 0 or junction_of_end[j] >= 0:
            continue
        short = [polyline_length(pieces[ends[k].piece]) < shorter_than for k in (i, j)]
        if short[0] == short[1]:
            continue
        near, far = (i, j) if short[0] else (j, i)
        if partner[near ^ 1] >= 0:  # joined at both ends: ends_through_short_pieces
            continue
        if float(np.hypot(*(ends[near].position - ends[far].position))) < 1e-9:
            continue
        arriving = _arriving_on_circle(ends[far], ends[near].position)
        adjusted[near] = replace(ends[near], direction=-arriving)
    return adjusted


def free_ends_beside_crossings(
    pieces: list[np.ndarray],
    ends: list,
    joins: list[tuple[int, int, float]],
    shorter_than: float,
    junction_of_end: list[int],
) -> list:
    """Ends for choosing joins across gaps, with a short piece's free end read through
    its crossing.

    A piece shorter than the end-fit span between a crossing and an occluder has too
    little cable for its own fit: thinning at the cut bends it 15-40 degrees off, and
    the join under the occluder is missed or goes wrong. When its other end is already
    joined through the crossing, the cable runs on from that partner: the free end
    takes the middle (:func:`_middle_direction`) of its own fit, the line from the
    partner's end to it, and the circle leaving the partner along its direction
    through it (:func:`_arriving_on_circle`). On a straight cable all three agree; one
    thrown off is outvoted.
    """
    partner = partners(len(ends), joins)
    adjusted = list(ends)
    for piece, points in enumerate(pieces):
        if polyline_length(points) >= shorter_than:
            continue
        for side in (0, 1):
            own, other = 2 * piece + side, 2 * piece + 1 - side
            through = partner[other]
            if partner[own] >= 0 or through < 0 or junction_of_end[own] >= 0:
                continue
            if junction_of_end[other] < 0 or junction_of_end[other] != junction_of_end[through]:
                continue
            line = ends[own].position - ends[through].position
            length = float(np.hypot(*line))
            if length < 1e-9:
                continue
            readings = (line / length, _arriving_on_circle(ends[through], ends[own].position))
            direction = _middle_direction(ends[own].direction, readings)
            adjusted[own] = replace(ends[own], direction=direction)
    return adjusted


def unfitted_pieces(
    pieces: list[np.ndarray],
    bridging_ends: list,
    ends: list,
    joins: list[tuple[int, int, float]],
    junction_of_end: list[int],
    stubs: dict | frozenset,
) -> dict[int, np.ndarray]:
    """Per bridging end left at its tip for want of joints to fit, its piece's points.

    An end whose fit left a tip out (a cut's hook) is bridged from where the fit
    begins (:func:`bridge_from_the_fits`); on a piece with fewer than
    :data:`FIT_JOINTS` joints past that tip no fit is made there, and no
    later stage moves the end (a short piece joined at both ends is taken along its
    partners' line instead, unless one of its joins is a turn: then it keeps its own
    ends, and is read here too): it stays at the tip, in the cut's corner, heading along
    the chord through the hook. The ends of gaps' joins are read: neither end in a
    junction, or one an end in ``stubs`` (:func:`past_a_stub`), whose other end is read.
    """
    unfitted = {}
    # Only the ends of gaps' joins (neither end in a junction, or one a stub's) are read.
    junction = junction_of_end
    gaps = sorted(
        k
        for i, j, _ in joins
        if max(junction[i], junction[j]) < 0 or past_a_stub(i, j, junction, stubs)
        for k in (i, j)
        if junction[k] < 0
    )
    for k in gaps:
        end = bridging_ends[k]
        if end is not ends[k] or end.skip <= 0:
            continue
        points = pieces[end.piece]
        along = arc_lengths(points[::-1] if end.at_start else points)
        if np.count_nonzero(along[-1] - along > end.skip) < FIT_JOINTS:
            unfitted[k] = points
    return unfitted

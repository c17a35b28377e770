"""What the image says about a gap between two chain ends: can something hide a cable there?

Merging (:mod:`.merging`) and the turn joins (:mod:`.turn_joins`) bridge a gap over open
background, where nothing the image shows lies over it, only on this evidence: two ends
cut square and alike within :data:`CUT_GAP_RADII` of curve (an object of the background's
own colour hides a cable without showing itself), and never over more than
:data:`OPEN_GAP_RADII` of background unless something is seen over it. Lengths are in
:func:`cable_radius`. Pure functions of the chain ends, the mask and the ends' colours.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.perception.appearance import (
    GAP_END_CLEAR_RADII,
    EndColours,
    background_beside,
    cut_or_lopsided,
    cut_square,
    ends_alike,
    gap_hidden_beside,
    out_of_view,
    reads_own_tip,
    unlike_background,
)
from service.perception.geometry import polyline_length
from service.perception.turn_joins import PIXEL_ROUNDING, WHOLE_TUBE_OUT_OF_VIEW

# A gap over open background whose curve is up to this many of the cable's radii long
# may be joined, by the mutual rule or as a turn (:mod:`.turn_joins`), when both ends
# are cut and alike (:func:`cut_ends_alike`): an object of the background's own colour
# hides a cable without showing itself. The occluders hide at most 15 radii; 2
# more at each end stand for the ends' fits stopping short of the object's border and
# the curve running wider than the hidden stretch (as in OPEN_GAP_RADII).
CUT_GAP_RADII = 19.0
# Or, measured on the curve's open stretch alone (:func:`open_length`: off the
# foreground and under nothing the image shows), up to this many: the longest run of
# cable an occluder of the (15 radii long, up to 8 wide) hides, along its
# diagonal. The curve from two ends' fits starts on the pieces' own tips, and an object
# seen over part of the gap explains that part: two objects side by side, one of the
# background's colour, or a turn whose curve starts where the ends' fits begin.
OPEN_HIDDEN_RADII = 17.0
# An end near the picture's edge leaves the picture when it points out of it by at least
# this sine (15 degrees off the edge's own line).
BORDER_OUT_SINE = 0.26
# How many of a turn's two ends must be cut square when nothing the image shows lies
# over it (:func:`.gap_evidence.cut_ends_alike`): one, since an object's border crosses
# the two side-by-side strands at different slants, and at its corner or along a
# strand's bend into the turn the cut is not straight across.
TURN_CUT_ENDS = 1


def cut_ends_alike(
    a,
    b,
    i: int,
    j: int,
    curve: np.ndarray,
    mask: np.ndarray,
    colours: EndColours | None,
    radius: float,
    cut_needed: int = 2,
    image: np.ndarray | None = None,
) -> bool:
    """Whether the free ends ``a`` (end ``i``) and ``b`` (end ``j``, both
    :class:`.merging.ChainEnd`), joined by ``curve`` at most :data:`CUT_GAP_RADII` long
    (in :func:`cable_radius`: a thick cable's hidden stretch is longer in pixels), or
    whose open stretch (:func:`open_length`, read on ``image`` when given) is at most
    :data:`OPEN_HIDDEN_RADII`, are
    both cut (the foreground stops
    right ahead of each, :func:`.appearance.cut_square`) and look like one cable's
    (:func:`.appearance.ends_alike`: both of a known, agreeing colour and of one width).
    The length is the curve's, not the ends' distance: a turn under an object hides a
    cable's whole bend between two ends that lie side by side.

    Two pieces of one cable hidden by an object of the background's own colour show no
    object over the gap, but they face each other (each the other's clearly cheapest
    partner), are cut where the object's border crosses them, and agree in colour and
    width. A cable's end inside a blob of the foreground (a piece of a pattern
    segmented with the cables) is not cut; two cables of different colour or width are
    not one.

    ``cut_needed`` (1 or 2) is how many of the two ends must be cut square. A turn
    under an object (:mod:`.turn_joins`) asks one, the other end being no cable's own
    tip (:func:`.appearance.cut_or_lopsided`): the two strands lie side by side under
    one object, whose border crosses them at different slants, and where it cuts a
    strand at its corner or along the strand's bend into the turn, the front is
    lopsided, not straight across.
    """
    if not alike_and_short_enough_to_hide(a, b, i, j, curve, mask, colours, radius, image):
        return False
    square = [cut_square(mask, end.position, end.direction, end.width, end.skip) for end in (a, b)]
    if all(square):
        return True
    if cut_needed > 1 or not any(square):
        return False
    other = b if square[0] else a
    return cut_or_lopsided(mask, other.position, other.direction, other.width, other.skip)


def alike_and_short_enough_to_hide(
    a,
    b,
    i: int,
    j: int,
    curve: np.ndarray,
    mask: np.ndarray,
    colours: EndColours | None,
    radius: float,
    image: np.ndarray | None = None,
) -> bool:
    """:func:`cut_ends_alike` but for the cuts: the ends ``a`` (end ``i``) and ``b`` (end
    ``j``) look like one cable's (:func:`.appearance.ends_alike`), and ``curve`` is no
    longer than an object of the background's own colour hides (:data:`CUT_GAP_RADII`
    radii, or :data:`OPEN_HIDDEN_RADII` of it on open background, :func:`open_length`)."""
    if colours is None:
        return False
    if not ends_alike(colours, i, j, (a.width, b.width)):
        return False
    cable = cable_radius(radius, a.width, b.width)
    # The open stretch reads the image along the curve: only for ends alike, and only
    # where the curve is too long for its whole length to count.
    return not (
        polyline_length(curve) > CUT_GAP_RADII * cable
        and open_length(curve, mask, image, (a, b), radius) > OPEN_HIDDEN_RADII * cable
    )


# No bridge runs over more than this many radii of open background, however cheap its
# geometry: an object of the background's own colour shows nothing, but the issue's
# occluders hide at most 15 radii of a cable; crossing one at a slant (a rectangle 15
# radii long and up to 8 wide: a diagonal of 17) with each piece's skeleton stopping up
# to 2 radii short of the object's border (thinning rounds a cut end) leaves 21, and 4
# more radii (2 to each side) stand for the ends' fits. A longer gap is bridged only
# where the image shows something lying over it (:func:`.appearance.gap_hidden`) or
# along the foreground (a doubled-back cable's touching strands).
OPEN_GAP_RADII = 25.0


# Two cables' own tips are joined over open background only on far stronger geometry
# than other ends: a join costing at most this share of the looser limit (half the
# threshold, merging.MUTUAL_COST_FACTOR being 1.5), the cable running straight on.
TIP_STRAIGHT_SHARE = 1.0 / 3.0
# One cable's own tip and an end that shows no cut are joined over open background only
# as the greedy rule joins them, at most this share of the looser limit (the threshold
# itself): dearer joins are the mutual rule's, made for a cable bending out of sight
# under an object, which would have cut at least one of the two ends.
ONE_TIP_SHARE = 2.0 / 3.0


def tips_stay_ends(ends, pairs, costs, limit, mask, hidden) -> np.ndarray:
    """Which candidate joins (``pairs`` of indices into ``ends``, :class:`.merging.ChainEnd`,
    at ``costs``) may be made: all but those, at most ``limit`` dear (dearer ones are
    never made), that join two cables' own tips (:func:`.appearance.own_tip_both_ways`, fronts
    read on ``mask``) across a gap that ``hidden(i, j)`` finds nothing in the image
    lying over.

    The foreground stops right ahead of such an end and rounds off as a cable's end
    does: an object lying over the cable, even one of the background's own colour,
    would have cut it straight, concave or at a slant. Two cables of one colour whose
    tips lie close are two cables, unless the cable runs straight on between them (a
    join at most :data:`TIP_STRAIGHT_SHARE` of ``limit`` dear: a stretch the segmentation
    lost, as across a highlight). Both ends must read so, or, for a join dearer than
    :data:`ONE_TIP_SHARE` of ``limit`` (the mutual rule's, for a bend under an object),
    one, the other showing no cut either (not :func:`.appearance.cut_or_lopsided`): a
    cut across a strand bending into a turn under an object can read round on one of
    them, but an object hiding a stretch of cable cuts at least one of its two ends."""
    keep = np.ones(len(costs), bool)
    tips: dict[int, bool] = {}

    def is_tip(index: int) -> bool:
        if index not in tips:
            end = ends[index]
            tips[index] = reads_own_tip(mask, end.position, end.direction, end.width, end.skip)
        return tips[index]

    for row in np.flatnonzero((costs > TIP_STRAIGHT_SHARE * limit) & (costs <= limit)).tolist():
        i, j = pairs[row].tolist()
        if is_tip(i) and is_tip(j):
            keep[row] = hidden(i, j)
        elif (is_tip(i) or is_tip(j)) and costs[row] > ONE_TIP_SHARE * limit:
            other = ends[j if is_tip(i) else i]
            if not cut_or_lopsided(mask, other.position, other.direction, other.width, other.skip):
                keep[row] = hidden(i, j)
    return keep


def own_tips_rule(ends, mask, hidden):
    """:func:`tips_stay_ends` for these ``ends`` and ``mask``: a callable ``(pairs, costs,
    limit)`` -> which may be made; None without the image's evidence (``hidden``)."""
    if hidden is None:
        return None
    return lambda pairs, costs, limit: tips_stay_ends(ends, pairs, costs, limit, mask, hidden)


def open_gap_limit(radius, first_width, second_width):
    """The longest open gap (px) a join may bridge: :data:`OPEN_GAP_RADII` of the larger
    of the picture's typical radius and the two pieces' own half widths (a thick cable's
    hidden stretch is longer in pixels). Scalars or arrays of widths."""
    return OPEN_GAP_RADII * cable_radius(radius, first_width, second_width)


def cable_radius(radius, first_width, second_width):
    """The radius a gap between two pieces is measured in: the larger of the picture's
    typical ``radius`` and the pieces' mean half width (a thick cable's hidden stretch
    is longer in pixels, a thin one's no shorter than the picture's typical cable's).
    Scalars or arrays of widths."""
    return np.maximum(radius, 0.5 * (first_width + second_width))


def beyond_hiding(ends, pairs, distances, radius) -> np.ndarray:
    """Which candidate joins' ends lie further apart than :func:`open_gap_limit`."""
    if not len(distances):
        return np.zeros(0, bool)
    widths = np.array([end.width for end in ends], np.float64)
    return distances > open_gap_limit(radius, widths[pairs[:, 0]], widths[pairs[:, 1]])


def open_gap_too_long(curve, mask, limit, hidden) -> bool:
    """Whether a gap's ``curve`` ((x, y) samples about 1 px apart) runs over more than
    ``limit`` px of background (off ``mask``, inside the picture) and ``hidden()`` (the
    image's evidence, called only then) finds nothing lying over it. A bridge along the
    foreground (a doubled-back cable's touching strands, another cable) is not open."""
    inside, seen = _samples_on_mask(curve, mask)
    steps = np.hypot(*np.diff(curve, axis=0).T)
    off = (inside & ~seen)[1:]
    return float(steps[off].sum()) > limit and not hidden()


def open_length(curve, mask, image, ends, radius) -> float:
    """How much of a gap's ``curve`` ((x, y) samples about 1 px apart) a cable along it
    would have to be hidden by something of the background's own colour: the px of it
    off the foreground ``mask`` (or outside the picture), less, with ``image``, those where
    the image shows something over the curve (unlike the open background beside the
    two ``ends``' cables, :func:`.appearance.unlike_background`).

    The curve from two ends' fits runs first over the pieces' own tips, on the
    foreground; and an object seen over part of a gap explains that part, however long.
    What is left is what an object of the background's colour must hide."""
    curve = np.asarray(curve, np.float64)
    if len(curve) < 2:
        return 0.0
    inside, seen = _samples_on_mask(curve, mask)
    # Outside the picture nothing is seen over the curve either: open.
    open_ground = ~seen
    judged = inside & ~seen
    if image is not None and judged.any():
        open_ground[judged] = ~unlike_background(image, mask, curve[judged], ends, radius)
    steps = np.hypot(*np.diff(curve, axis=0).T)
    # A step counts as open when the sample it reaches is.
    return float(steps[open_ground[1:]].sum())


def _samples_on_mask(curve: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per (x, y) sample of ``curve``: whether its pixel is inside the picture, and
    whether it is on ``mask`` (False outside the picture)."""
    height, width = mask.shape
    cols = np.rint(curve[:, 0]).astype(np.int64)
    rows = np.rint(curve[:, 1]).astype(np.int64)
    inside = (cols >= 0) & (rows >= 0) & (cols < width) & (rows < height)
    seen = np.zeros(len(curve), bool)
    seen[inside] = mask[rows[inside], cols[inside]]
    return inside, seen


def points_out_of_picture(
    positions: np.ndarray, directions: np.ndarray, shape: tuple[int, ...], margin: float
) -> np.ndarray:
    """Per end, whether it is a cable leaving the picture: within ``margin`` px of an
    edge of a picture of ``shape`` (height, width, ...) and pointing out of it by at
    least :data:`BORDER_OUT_SINE` (or of no direction).

    By the edge, an end running along it or back into the picture (a stub left beyond
    an object by the edge, a cable lying along the edge) is an end like any other.

    Parameters
    ----------
    positions, directions : ndarray, shape (N, 2)
        The ends' (x, y) and outward directions (unit, or zero for none).
    """
    height, width = shape[:2]
    x, y = positions[:, 0], positions[:, 1]
    outwards = np.column_stack(
        [
            np.where(x < margin, -directions[:, 0], -np.inf),
            np.where(y < margin, -directions[:, 1], -np.inf),
            np.where(x > width - 1 - margin, directions[:, 0], -np.inf),
            np.where(y > height - 1 - margin, directions[:, 1], -np.inf),
        ]
    )
    return outwards.max(axis=1) >= BORDER_OUT_SINE * np.hypot(*directions.T)


def turn_evidence(image, mask, ends, colours, radius, partings=()) -> tuple:
    """The tests of the image's evidence that something hides a cable along a curve
    from end ``i`` to end ``j`` (callables ``(i, j, curve) -> bool``), strongest first,
    for the turns under objects (:func:`.turn_joins.turn_joins`): an object shows over
    the curve (:func:`.appearance.gap_hidden`); both ends are cut square and alike
    (:func:`cut_ends_alike`); one end cut square and the other lopsided, as where an
    object's corner or rim cuts a strand bending into the turn (:data:`TURN_CUT_ENDS`);
    the ends are the far ends of the two strands parting at one end of a stretch where
    they touch (``partings``, pairs of ends, :attr:`.touching.TouchingSplit.partings`)
    and the curve no longer than an object of the background's own colour hides
    (:data:`CUT_GAP_RADII`). Which of them a turn is bridged along the curve for:
    :data:`TURN_EVIDENCE_ALONG_CURVE`.

    Two strands touching all along a stretch are a cable doubled back on itself (or
    two cables laid together, whose other ends the merging step joins first, at less
    cost than a turn's: the turns' rivals). Where both strands stop past the stretch's
    end within a bulb's reach of each other, alike, the cable turned round there out of
    sight; an object of the background's own colour, cutting the strands along a round
    rim or as they bend into the bulb, leaves neither cut straight across.
    """
    # What depends on the ends alone is read once, not once per curve tried: the
    # background beside a pair (the turn pass tries up to eight curves per pair, and a
    # frame crowded with cables leaves a dozen pairs within reach of every end), and
    # whether an end is cut square. Most pairs in such a frame are two cables' own round
    # tips, which no curve's evidence can join: the cut tests refuse them before reading
    # the image along the curve, with the answer cut_ends_alike itself would give.
    backgrounds: dict[tuple[int, int], tuple | None] = {}
    square: dict[int, bool] = {}

    def hidden(i: int, j: int, curve: np.ndarray) -> bool:
        pair = (ends[i], ends[j])
        if (i, j) not in backgrounds:
            backgrounds[i, j] = background_beside(image, mask, pair, radius)
        return gap_hidden_beside(image, mask, curve, pair, radius, backgrounds[i, j])

    def cut_square_at(index: int) -> bool:
        if index not in square:
            end = ends[index]
            square[index] = bool(cut_square(mask, end.position, end.direction, end.width, end.skip))
        return square[index]

    def cut_alike(cut_needed: int):
        def passes(i: int, j: int, curve: np.ndarray) -> bool:
            cuts = [cut_square_at(i), cut_square_at(j)]
            if not any(cuts) or (cut_needed > 1 and not all(cuts)):
                return False  # cut_ends_alike says no on these ends, whatever the curve
            return cut_ends_alike(
                ends[i], ends[j], i, j, curve, mask, colours, radius, cut_needed, image
            )

        return passes

    return (
        hidden,
        cut_alike(2),
        cut_alike(TURN_CUT_ENDS),
        lambda i, j, curve: (
            ((i, j) in partings or (j, i) in partings)
            and strands_turn_out_of_sight(ends[i], ends[j], curve, mask, radius)
        ),
    )


def turn_out_of_view(image, mask, ends, radius) -> Callable[..., int]:
    """How much of a cable turning from end ``i`` to end ``j`` along a curve would be
    out of view all the way (:func:`.appearance.out_of_view`), as a callable ``(i, j,
    curve)`` for the turns under objects (:func:`.turn_joins.turn_joins`'
    ``out_of_view``): :data:`.turn_joins.WHOLE_TUBE_OUT_OF_VIEW` its whole tube, 1 its
    middle alone, 0 neither. The background beside a pair of ends is read once for all
    the curves tried between them, whichever way each is read.

    The cable is a tube, not a line (``whole_tube``): where an object the image shows
    hides the turn, the whole of it lies under the object (else it would show), and a
    turn's curve whose tube reaches out past the object's outline onto open background,
    though its middle keeps under it, is less likely the hidden turn. So the tube's two
    borders are read too, at the two ends' mean half width less a pixel's rounding
    (:data:`.turn_joins.PIXEL_ROUNDING`), as :func:`.turn_joins.turn_joins` measures
    the cable. Called with ``whole_tube=False``, the middle alone (1 at most; for a bridge from
    the traced cuts, which starts on the object's very edge: its tube there straddles
    the edge whatever the hidden shape, and reads the cut, not the turn); with
    ``clear_of_rims=True``, the curve's samples within
    :data:`.appearance.GAP_END_CLEAR_RADII` of either end left out, as
    :func:`.appearance.gap_hidden` leaves out the cut's rim (in the pair's own radius,
    :func:`cable_radius`)."""
    backgrounds: dict[tuple[int, int], tuple | None] = {}

    def hidden(
        i: int, j: int, curve: np.ndarray, whole_tube: bool = True, clear_of_rims: bool = False
    ) -> int:
        pair = (ends[i], ends[j])
        if clear_of_rims:
            curve = np.asarray(curve, np.float64)
            # The rim is the cable's own: its width, not the picture's typical one.
            clear = GAP_END_CLEAR_RADII * cable_radius(radius, ends[i].width, ends[j].width)
            curve = curve[
                (np.hypot(*(curve - ends[i].position).T) > clear)
                & (np.hypot(*(curve - ends[j].position).T) > clear)
            ]
        if (i, j) not in backgrounds:
            backgrounds[i, j] = background_beside(image, mask, pair, radius)
        if backgrounds[i, j] is None:
            return 0
        if not out_of_view(image, mask, curve, pair, radius, backgrounds[i, j]):
            return 0
        if not whole_tube:
            return 1
        half_width = (0.5 * (ends[i].width + ends[j].width) or radius) - PIXEL_ROUNDING
        tube = out_of_view(image, mask, curve, pair, radius, backgrounds[i, j], half_width)
        return WHOLE_TUBE_OUT_OF_VIEW if tube else 1

    return hidden


def turn_hiding_extent(image, mask, ends, radius) -> Callable[..., tuple[float, float] | None]:
    """How far the object seen over a turn from end ``i`` to end ``j`` reaches on a line
    through the cuts, as a callable ``(i, j, origin, axis) -> (behind, ahead) or None``
    for the turns under objects (:func:`.turn_joins.turn_joins`' ``hiding_extent``): the
    distances (px) from ``origin`` to where the object's pixels stop, its outline, back
    against ``axis`` (unit) and on along it.

    On the line, each point off the foreground is the object's when it looks unlike the
    open background beside the two ends' cables (:func:`.appearance.unlike_background`,
    as :func:`turn_out_of_view` reads the object) and the ground's otherwise; points on
    the foreground (a cable) say neither. Ahead, the object's pixels stop at the first
    ground point past the first object point (the strands' tips may lie between the
    origin and the object's rim); behind, at the first point from the origin that is not
    the object's (a strand, or the ground between the strands where they pass under the
    object's rim). The picture's edge stops both (nothing says how far the object goes
    on). None where no object point lies ahead, or no background beside the ends can be
    read."""

    def line(i: int, j: int, origin: np.ndarray, heading: np.ndarray):
        height, width = mask.shape
        along = np.arange(0.0, float(np.hypot(height, width)), 1.0)
        points = np.asarray(origin, np.float64) + np.outer(along, heading)
        inside = (
            (points[:, 0] >= 0)
            & (points[:, 1] >= 0)
            & (points[:, 0] <= width - 1)
            & (points[:, 1] <= height - 1)
        )
        stop = int(np.argmin(inside)) if not inside.all() else len(inside)
        points = points[:stop]
        cols, rows = np.rint(points).astype(np.int64).T
        off = ~mask[rows, cols]
        unlike = np.zeros(stop, bool)
        unlike[off] = unlike_background(image, mask, points[off], (ends[i], ends[j]), radius)
        return off & unlike, off & ~unlike, stop

    def extent(i: int, j: int, origin: np.ndarray, axis: np.ndarray):
        axis = np.asarray(axis, np.float64)
        seen, ground, stop = line(i, j, origin, axis)
        first = np.flatnonzero(seen)
        if not len(first):
            return None
        beyond = np.flatnonzero(ground[first[0] :])
        ahead = float(first[0] + beyond[0]) if len(beyond) else float(stop)
        seen_behind, _, stop_behind = line(i, j, origin, -axis)
        not_seen = np.flatnonzero(~seen_behind)
        behind = float(not_seen[0]) if len(not_seen) else float(stop_behind)
        return behind, ahead

    return extent


def cut_bridge_gives_way(
    pair: tuple[int, int],
    curve: np.ndarray,
    turn_bridges: dict[tuple[int, int], np.ndarray],
    wide_turns: frozenset,
    hidden_all_along: Callable[..., int],
    depth_bounded: dict | None = None,
) -> bool:
    """Whether the bridge from the traced cuts of a turn under an object (``pair``, one
    of ``wide_turns``, the turn pass's curve ``turn_bridges[pair]`` found out of view all
    the way) gives way to the turn's own curve, which the evidence placed under the
    object all the way.

    It does where it would put the cable where the image shows open background: a cut
    misread (a fork in the skeleton at the object's edge, a wedge a slanted border
    leaves) turns the bridge out past the object, where a cable would be seen. Shown is
    the bridge's middle anywhere, or, where the turn's curve keeps the cable's whole tube
    under the object, the bridge's tube clear of the cuts' rims: right at a cut the
    bridge starts on the object's very edge and its tube straddles the edge whatever the
    turn's shape (it reads the cut), but past the rim a cable whose side reaches out
    onto open background would be seen there.

    It does also where the object bounds the turn's depth (the cuts lie on its near rim,
    :func:`.turn_joins._by_depth`) and both readings favour the turn's curve: its apex
    lies nearer the middle of the object's depth than the bridge's
    (``depth_bounded[pair]``, :func:`.turn_joins._apex_off_the_middle`: the measure the
    curve was chosen by, of every curve the object hides whole), and it keeps the whole
    tube under the object where the bridge's tube reaches out somewhere, be it only at
    a cut's rim. Each alone is weak: the middle is read along the ends' directions,
    which may cross the object at a slant and overstate its depth, and at a cut the
    bridge's tube straddles the object's edge whatever the turn. A bridge the object
    hides whole is kept whatever its depth: traced from the cuts, it follows the cable
    closely where the cuts are read right. ``hidden_all_along`` is
    :func:`turn_out_of_view`'s callable."""
    if pair not in wide_turns or pair not in turn_bridges:
        return False
    i, j = pair
    turn = turn_bridges[pair]
    # Each curve read once: 0 its middle shows, 1 its middle alone hidden, else the tube.
    turn_hidden = hidden_all_along(i, j, turn)
    if not turn_hidden:
        return False
    if not hidden_all_along(i, j, curve, whole_tube=False):
        return True
    if turn_hidden != WHOLE_TUBE_OUT_OF_VIEW:
        return False
    off_the_middle = (depth_bounded or {}).get(pair)
    if (
        off_the_middle is not None
        and off_the_middle(turn) < off_the_middle(curve)
        and hidden_all_along(i, j, curve) != WHOLE_TUBE_OUT_OF_VIEW
    ):
        return True
    return hidden_all_along(i, j, curve, clear_of_rims=True) != WHOLE_TUBE_OUT_OF_VIEW


def strands_turn_out_of_sight(a, b, curve: np.ndarray, mask: np.ndarray, radius: float) -> bool:
    """Whether the cable may have turned round out of sight along ``curve`` from end
    ``a`` to end ``b`` (:class:`.merging.ChainEnd`), two strands parting from a stretch
    where they touch (:func:`turn_evidence`): the curve is no longer than an object of
    the background's own colour hides (:data:`CUT_GAP_RADII`), it leaves the foreground
    through the first strand's tip and comes back onto it through the second's (within
    a cable's width of the ends), and in between it stays off it: a cable seen nowhere
    along the turn, not one drawn back over the strands it turns round between."""
    if polyline_length(curve) > CUT_GAP_RADII * cable_radius(radius, a.width, b.width):
        return False
    _, seen = _samples_on_mask(curve, mask)
    off = np.flatnonzero(~seen)
    if not len(off) or seen[off[0] : off[-1] + 1].any():
        return False
    # Out of sight through the strands' tips: within a cable's width of where the
    # ends' fits put them, not out through a strand's side.
    return bool(
        np.hypot(*(curve[off[0]] - a.position)) <= 2.0 * a.width
        and np.hypot(*(curve[off[-1]] - b.position)) <= 2.0 * b.width
    )


# Per test of :func:`turn_evidence`, whether a turn it finds is bridged along its curve
# (:func:`.turn_joins.turn_joins`' ``along_curve``): an object seen over it; a bulb
# between two strands parting from a touching stretch, which a gap's bridge would cut
# across. The cuts say only that the gap is short enough to hide.
TURN_EVIDENCE_ALONG_CURVE = (True, False, False, True)

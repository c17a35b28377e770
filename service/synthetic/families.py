"""Named scene families: each a distribution over scenes with exact ground truth.

:func:`make_family_scene` draws scene ``seed`` of a family. Every family stresses one
thing a detector must handle (see :data:`FAMILIES` for what each draws and its ranges)
and keeps the rest like :func:`~service.synthetic.make_scene`: shaded cables with a
highlight, sensor noise, 1280x720 by default, cables that may run off the picture, and
the same ground truth (each cable's whole centreline with its hidden stretches, radius,
colour and depth; every crossing with the cable on top; the visible-cable mask and the
per-cable labels), plus :attr:`~service.synthetic.SyntheticScene.features`, the designed
structures and the values they were drawn with.

What a family promises stays recoverable by a careful human from the image (and, for the
geometry, from the true mask alone):

- strands that touch (a hairpin, cables side by side) are drawn as two shaded tubes, so
  a crease shows between them, and the stretch they share is twice a cable's width; the
  two strands never cross while they touch, so which strand continues where follows from
  their order across the stretch. With the true mask alone the crease is gone but the
  width and the order remain.
- a hidden stretch always has visible cable on both sides (3 radii at the least), so it
  can be inferred; a cable that leaves the picture under an occluder is never drawn.
- crossings are at least 10 degrees (shallow_crossings) or 30 degrees (every other
  family), and each cable runs straight through a shallow crossing.

Seeds: scene ``seed`` of family ``F`` comes from ``numpy.random.default_rng([seed, k])``
with ``k`` a fixed number per family, so families do not share scenes; ``baseline`` is
``make_scene(width, height, 1 + seed % 3, seed=seed, occluders=2)`` exactly.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from service.synthetic.backdrops import cast_shadows, draw_backdrop
from service.synthetic.curves import SAMPLE_SPACING, _clip_to_box_with_offset, _Curve
from service.synthetic.family_occluders import (
    OccluderStyle,
    draw_family_occluder,
    place_family_occluders,
)
from service.synthetic.layout import (
    MIN_CROSSING_ANGLE,
    _crossings_if_well_placed,
    _Exemption,
    _public_crossing,
)
from service.synthetic.render import _PALETTE_BGR, _compose_bands, _draw_cable, _pick_colours
from service.synthetic.scene import _cables_truth, make_scene
from service.synthetic.scene_types import Occluder, SceneFeature, SyntheticScene
from service.synthetic.shapes import (
    arc_insert,
    designed_centreline,
    hairpin_insert,
    loop_insert,
    straight_insert,
    turn_insert,
)

__all__ = ["FAMILIES", "FAMILY_NAMES", "Family", "make_family_scene"]

MIN_SHALLOW_ANGLE = math.radians(10.0)
MAX_SHALLOW_ANGLE = math.radians(30.0)
_CABLE_ATTEMPTS = 150
_SCENE_ATTEMPTS = 20

# Cable colours on white paper (BGR): dark ones (black, dark blue, dark red, dark green,
# brown, dark grey, violet) and bright or colourful ones (red, orange, yellow, light
# blue, green); no white or light grey, which would vanish into the paper.
_PAPER_PALETTE = (
    (32, 30, 30),
    (110, 45, 20),
    (35, 30, 140),
    (45, 95, 35),
    (30, 60, 100),
    (75, 75, 78),
    (120, 40, 90),
    (45, 45, 215),
    (35, 130, 240),
    (50, 215, 225),
    (210, 160, 90),
    (70, 195, 70),
)
_ANY_PALETTE = _PALETTE_BGR + _PAPER_PALETTE[:7]
_PALETTES = {"dark": _PALETTE_BGR, "paper": _PAPER_PALETTE, "any": _ANY_PALETTE}


class _Unplaceable(Exception):
    """This draw of a scene broke a layout rule it cannot repair; draw again."""


@dataclass(frozen=True)
class _Spec:
    """What a family draws (see :data:`FAMILIES`)."""

    cables: tuple[int, int]
    radius_range: tuple[float, float] = (4.0, 9.0)
    loop_probability: float = 0.5
    loop_radii: tuple[float, float] = (5.0, 7.0)
    loops_per_cable: tuple[int, int] = (0, 0)  # designed loops on every cable
    feature: str | None = None  # "hairpin", "shallow_crossing" or "side_by_side"
    occluders: tuple[int, int] = (0, 1)
    occluder_style: OccluderStyle = field(default_factory=OccluderStyle)
    backdrops: tuple[str, ...] = ("dark-textured", "dark-textured", "dark-plain")
    palette: str = "dark"
    same_colour: float = 0.0  # probability that every cable has one colour
    pair_same_colour: float = 0.0  # probability that the designed pair has one colour


@dataclass(frozen=True)
class Family:
    """A named distribution over scenes.

    Attributes
    ----------
    name : str
    summary : str
        What it draws, with the parameter ranges.
    make : callable
        ``make(seed, width, height) -> SyntheticScene``.
    """

    name: str
    summary: str
    make: Callable[[int, int, int], SyntheticScene]


def _family(name: str, summary: str, spec: _Spec) -> Family:
    key = zlib.crc32(name.encode())

    def make(seed: int, width: int, height: int) -> SyntheticScene:
        return _build(np.random.default_rng([seed, key]), width, height, spec, name)

    return Family(name, summary, make)


def _baseline(seed: int, width: int, height: int) -> SyntheticScene:
    return make_scene(width, height, 1 + seed % 3, seed=seed, occluders=2)


_ANY_OCCLUDERS = OccluderStyle()
FAMILIES: dict[str, Family] = {
    family.name: family
    for family in (
        Family(
            "baseline",
            "make_scene as dlo eval --synthetic has always scored it: 1-3 cables (1 + seed mod "
            "3), radius 4-9 px, half with a loop of 5-7 radii, 2 occluders of the background's "
            "colour hiding 20-80 px, dark textured background",
            _baseline,
        ),
        _family(
            "loops",
            "1-3 cables, each with 1-2 loops that cross themselves, loop (bend) radius 3-6 "
            "cable radii, crossing at 45-100 degrees; 0-1 occluder",
            _Spec(cables=(1, 3), loops_per_cable=(1, 2), loop_radii=(3.0, 6.0)),
        ),
        _family(
            "doubled_back",
            "1-3 cables; one doubles back on itself: its two strands run side by side for 6-25 "
            "radii, touching (40 %) or 0.3-1 radius apart, turning round through a bend of 2-4 "
            "radii; 0-1 occluder",
            _Spec(cables=(1, 3), feature="hairpin", loop_probability=0.3),
        ),
        _family(
            "shallow_crossings",
            "2-4 cables; two of them cross at 10-30 degrees, both straight through the "
            "crossing, of one colour in half of the scenes; other crossings >= 30 degrees; "
            "0-1 occluder",
            _Spec(
                cables=(2, 4),
                feature="shallow_crossing",
                loop_probability=0.3,
                pair_same_colour=0.5,
            ),
        ),
        _family(
            "side_by_side",
            "2-4 cables; two of them lie side by side for 10-40 radii along a gentle curve, "
            "touching (40 %) or 0.3-1 radius apart, then part at 20-50 degrees; of one colour "
            "in half of the scenes; 0-1 occluder",
            _Spec(
                cables=(2, 4),
                feature="side_by_side",
                loop_probability=0.3,
                pair_same_colour=0.5,
            ),
        ),
        _family(
            "many",
            "4-10 cables of radius 3-6 px, 30 % with a loop; 0-2 occluders",
            _Spec(cables=(4, 10), radius_range=(3.0, 6.0), loop_probability=0.3, occluders=(0, 2)),
        ),
        _family(
            "occluded",
            "1-3 cables, 2-4 occluders each hiding 3-15 radii: rectangles or discs, half on "
            "the cable's sharpest bends, half coloured like the background (a patch of it) and "
            "half objects of another colour",
            _Spec(cables=(1, 3), occluders=(2, 4)),
        ),
        _family(
            "edge",
            "2-4 cables running off the picture; 1-3 occluders hiding 3-15 radii near where a "
            "cable leaves the picture, 3.5-10 radii of it left visible beyond, sticking out of "
            "the picture where they reach it",
            _Spec(
                cables=(2, 4),
                occluders=(1, 3),
                occluder_style=OccluderStyle(on_bend=0.0, at_edge=1.0),
            ),
        ),
        _family(
            "bright",
            "2-6 cables of radius 3-7 px, dark (black, dark blue, brown...) and bright or "
            "colourful ones (red, orange, yellow, light blue) on white paper under uneven light, "
            "with soft shadows, the table (dark metal or light wood) along 1-2 sides in half of "
            "the scenes; 0-2 occluders",
            _Spec(
                cables=(2, 6),
                radius_range=(3.0, 7.0),
                loop_probability=0.3,
                occluders=(0, 2),
                backdrops=("paper",),
                palette="paper",
            ),
        ),
        _family(
            "textured",
            "2-5 cables of any colour on a busy painting (hundreds of thin strokes and "
            "splashes of many colours); 0-2 occluders",
            _Spec(
                cables=(2, 5),
                loop_probability=0.3,
                occluders=(0, 2),
                backdrops=("painted",),
                palette="any",
            ),
        ),
        _family(
            "same_colour",
            "3-6 cables all of one colour, 40 % with a loop, dark background; 0-2 occluders",
            _Spec(cables=(3, 6), loop_probability=0.4, occluders=(0, 2), same_colour=1.0),
        ),
    )
}
FAMILY_NAMES = tuple(FAMILIES)  # as service.evaluation.conventions.FAMILY_NAMES


def make_family_scene(
    family: str, seed: int, width: int = 1280, height: int = 720
) -> SyntheticScene:
    """Draw scene ``seed`` of a named family (see :data:`FAMILIES`).

    Raises
    ------
    ValueError
        Unknown family, a negative seed, or an image smaller than 320x240.
    RuntimeError
        The family's layout cannot be drawn in an image this small.
    """
    if family not in FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; expected one of {', '.join(FAMILIES)}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if width < 320 or height < 240:
        raise ValueError(f"scene families need an image of 320x240 or more, got {width}x{height}")
    return FAMILIES[family].make(int(seed), width, height)


# --------------------------------------------------------------------------- building


def _build(rng, width, height, spec, name):
    for _ in range(_SCENE_ATTEMPTS):
        try:
            return _build_once(rng, width, height, spec)
        except _Unplaceable:
            continue
    raise RuntimeError(f"could not draw a {name!r} scene in a {width}x{height} image")


class _Layout:
    """Cables placed so far, and the picture they must fit."""

    def __init__(self, width, height):
        self.width, self.height = width, height
        self.box = (0.0, 0.0, width - 1.0, height - 1.0)
        # Cables are grown around a point in the middle, so most of each stays in view.
        self.anchor_low = np.array([0.2 * (width - 1.0), 0.2 * (height - 1.0)])
        self.anchor_high = np.array([0.8 * (width - 1.0), 0.8 * (height - 1.0)])
        self.diagonal = math.hypot(width, height)
        self.curves: list[_Curve] = []
        self.crossings: list = []
        self.features: list[SceneFeature] = []

    def propose(self, rng, radius, inserts, attempt, place=None):
        """A cable with these designed stretches, all of them in the picture, or None.

        ``place(points, anchor_index)`` moves the centreline into place; by default its
        anchor goes to a random point in the middle of the picture.
        """
        shrink = 1.0 - 0.5 * attempt / _CABLE_ATTEMPTS
        length = rng.uniform(0.6, 1.2) * self.diagonal * shrink
        length = max(length, 1.6 * sum(insert.length for insert in inserts))
        designed = designed_centreline(rng, radius, length, self.diagonal, inserts)
        if designed is None:
            return None
        points, anchor_index, spans = designed
        if place is None:
            points = points + rng.uniform(self.anchor_low, self.anchor_high)
        else:
            points = place(points, anchor_index)
        sample_spans = [
            (round(low / SAMPLE_SPACING), round(high / SAMPLE_SPACING)) for low, high in spans
        ]
        return self.clip(points, anchor_index, sample_spans, radius)

    def clip(self, points, anchor_index, sample_spans, radius):
        """The cable cut at the picture's border, and its designed stretches' arc ranges;
        None if one of them (given as sample index ranges) would be cut, or it is short."""
        clipped = _clip_to_box_with_offset(points, anchor_index, self.box)
        if clipped is None:
            return None
        points, offset = clipped
        sample_spans = [(low + offset, high + offset) for low, high in sample_spans]
        if any(low < 1 or high > len(points) - 2 for low, high in sample_spans):
            return None  # a designed stretch would run out of the picture
        curve = _Curve.from_points(points, radius)
        short_side = min(self.width, self.height) - 1.0
        if curve.length < max(0.25 * short_side, 8.0 * radius):
            return None
        return curve, [
            (float(curve.arc[low]), float(curve.arc[high])) for low, high in sample_spans
        ]

    def check(self, curves, min_angle=MIN_CROSSING_ANGLE, exempt=()):
        """Place cables together, each checked against those before it; all or none."""
        placed, crossings = list(self.curves), list(self.crossings)
        for curve, angle, exemptions in zip(curves, min_angle, exempt, strict=True):
            found = _crossings_if_well_placed(
                curve, len(placed), placed, crossings, min_angle=angle, exempt=exemptions
            )
            if found is None:
                return False
            placed.append(curve)
            crossings.extend(found)
        self.curves, self.crossings = placed, crossings
        return True


def _build_once(rng, width, height, spec):
    backdrop = draw_backdrop(
        rng, width, height, spec.backdrops[int(rng.integers(len(spec.backdrops)))]
    )
    n_cables = int(rng.integers(spec.cables[0], spec.cables[1] + 1))
    layout = _Layout(width, height)
    if spec.feature is not None:
        _FEATURES[spec.feature](rng, layout, spec)
    while len(layout.curves) < n_cables:
        _place_random_cable(rng, layout, spec)
    n_cables = len(layout.curves)

    palette = _PALETTES[spec.palette]
    if rng.random() < spec.same_colour:
        colours = _one_colour(rng, n_cables, palette)
    else:
        colours = _pick_colours(rng, n_cables, palette)
        if (
            spec.feature in ("shallow_crossing", "side_by_side")
            and rng.random() < spec.pair_same_colour
        ):
            colours[1] = _one_colour(rng, 1, [colours[0]])[0]
    depths = rng.permutation(n_cables)
    n_occluders = int(rng.integers(spec.occluders[0], spec.occluders[1] + 1))
    occluders = []
    if n_occluders:
        occluders = place_family_occluders(
            rng, n_occluders, layout.curves, layout.crossings, width, height, spec.occluder_style
        )
        if occluders is None:
            raise _Unplaceable

    if backdrop.bright:
        cast_shadows(rng, backdrop.base, layout.curves)
    labels = np.zeros((height, width), dtype=np.uint16)
    paints = []
    for index in np.argsort(depths):
        loop_splits = [
            (crossing.first_arc + crossing.second_arc) / 2.0
            for crossing in layout.crossings
            if crossing.first == crossing.second == index
        ]
        paints += _draw_cable(labels, layout.curves[index], colours[index], index + 1, loop_splits)
    for occluder in occluders:
        paints.append(draw_family_occluder(rng, labels, occluder, backdrop.base))
    noise_sigma = rng.uniform(2.0, 5.0)
    base = backdrop.base

    def background(top, bottom):
        return base[top:bottom].copy()

    image = _compose_bands(rng, background, (height, width), paints, noise_sigma)
    polygons = [occluder.polygon for occluder in occluders]
    cables = _cables_truth(layout.curves, colours, depths, polygons)
    features = list(layout.features)
    for occluder in occluders:
        cable = cables[occluder.target]
        hidden = occluder.polygon.contains(cable.centreline)
        arc = layout.curves[occluder.target].arc[hidden]
        features.append(
            SceneFeature(
                "occluder",
                (occluder.target,),
                {
                    "hidden_length": float(arc.max() - arc.min()),
                    "on_bend": float(occluder.placement == "bend"),
                    "at_edge": float(occluder.placement == "edge"),
                    "like_background": float(occluder.like_background),
                },
            )
        )
    return SyntheticScene(
        image=image,
        mask=labels > 0,
        labels=labels,
        cables=cables,
        crossings=[_public_crossing(crossing, depths) for crossing in layout.crossings],
        occluders=[
            Occluder(polygon=occluder.polygon.vertices, like_background=occluder.like_background)
            for occluder in occluders
        ],
        features=tuple(features),
        backdrop=backdrop.kind,
    )


def _one_colour(rng, n_cables, palette):
    base = np.array(palette[int(rng.integers(len(palette)))])
    return [
        tuple(int(c) for c in np.clip(base + rng.integers(-4, 5, 3), 0, 255))
        for _ in range(n_cables)
    ]


# --------------------------------------------------------------------------- cables


def _place_random_cable(rng, layout, spec):
    index = len(layout.curves)
    for attempt in range(_CABLE_ATTEMPTS):
        radius = float(rng.uniform(*spec.radius_range))
        low, high = spec.loops_per_cable
        if high > 0:
            inserts = [
                loop_insert(rng, radius, spec.loop_radii)
                for _ in range(rng.integers(low, high + 1))
            ]
        elif rng.random() < spec.loop_probability:
            inserts = [loop_insert(rng, radius, spec.loop_radii)]
        else:
            inserts = []
        proposal = layout.propose(rng, radius, inserts, attempt)
        if proposal is None:
            continue
        curve, _ = proposal
        if layout.check([curve], [MIN_CROSSING_ANGLE], [()]):
            for insert in inserts:
                layout.features.append(SceneFeature("loop", (index,), dict(insert.values)))
            return
    raise _Unplaceable


def _place_hairpin(rng, layout, spec):
    """One cable doubled back on itself (see :func:`hairpin_insert`)."""
    index = len(layout.curves)
    for attempt in range(_CABLE_ATTEMPTS):
        radius = float(rng.uniform(*spec.radius_range))
        gap = 0.0 if rng.random() < 0.4 else rng.uniform(0.3, 1.0) * radius
        insert = hairpin_insert(rng, radius, gap)
        proposal = layout.propose(rng, radius, [insert], attempt)
        if proposal is None:
            continue
        curve, [(low, high)] = proposal
        # The strands part at ``part_angle`` each: closeness is allowed until they are
        # the usual 5 radii apart.
        margin = 2.5 * radius / math.sin(math.radians(insert.values["part_angle"]))
        exemption = _Exemption(index, (low - margin, high + margin), (low - margin, high + margin))
        if layout.check([curve], [MIN_CROSSING_ANGLE], [(exemption,)]):
            lead, parallel = insert.lengths[0], insert.lengths[1]
            strands = {
                "strand_start": low + lead,
                "strand_end": low + lead + parallel,
                "return_start": high - lead - parallel,
                "return_end": high - lead,
            }
            values = dict(insert.values) | strands
            layout.features.append(SceneFeature("hairpin", (index,), values))
            return
    raise _Unplaceable


def _place_shallow_crossing(rng, layout, spec):
    """Two cables crossing at 10-30 degrees, each straight where they overlap."""
    first = len(layout.curves)
    for attempt in range(_CABLE_ATTEMPTS):
        radii = [float(r) for r in rng.uniform(*spec.radius_range, 2)]
        angle = rng.uniform(MIN_SHALLOW_ANGLE, MAX_SHALLOW_ANGLE)
        # Straight for as long as the two stay within a few radii of each other.
        reach = 2.5 * sum(radii) / math.sin(angle) + 2.0 * sum(radii)
        proposal = layout.propose(rng, radii[0], [straight_insert(2.0 * reach)], attempt)
        if proposal is None:
            continue
        curve_a, [(low, high)] = proposal
        middle = int(np.searchsorted(curve_a.arc, (low + high) / 2.0))
        crossing_point = curve_a.points[middle]
        direction = curve_a.points[middle + 1] - curve_a.points[middle - 1]
        heading = math.atan2(direction[1], direction[0]) + rng.choice([-1.0, 1.0]) * angle

        def place(points, anchor_index, heading=heading, crossing_point=crossing_point):
            step = points[anchor_index + 1] - points[anchor_index - 1]
            turn = heading - math.atan2(step[1], step[0])
            rotation = np.array(
                [[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]
            )
            return points @ rotation.T + crossing_point

        proposal = layout.propose(rng, radii[1], [straight_insert(2.0 * reach)], attempt, place)
        if proposal is None:
            continue
        curve_b, _ = proposal
        shallow = angle - math.radians(0.1)
        if layout.check([curve_a, curve_b], [MIN_CROSSING_ANGLE, shallow], [(), ()]):
            x, y = (float(v) for v in crossing_point)
            values = {"angle": math.degrees(angle), "x": x, "y": y}
            layout.features.append(SceneFeature("shallow_crossing", (first, first + 1), values))
            return
    raise _Unplaceable


def _place_side_by_side(rng, layout, spec):
    """Two cables lying side by side along a gentle curve, then parting."""
    first = len(layout.curves)
    low_radius, high_radius = spec.radius_range
    for attempt in range(_CABLE_ATTEMPTS):
        radius_a = float(rng.uniform(low_radius, high_radius))
        radius_b = float(np.clip(radius_a * rng.uniform(0.75, 1.33), low_radius, high_radius))
        gap = 0.0 if rng.random() < 0.4 else rng.uniform(0.3, 1.0) * min(radius_a, radius_b)
        along = rng.uniform(10.0, 40.0) * max(radius_a, radius_b)
        curvature = rng.uniform(-1.0, 1.0) / (12.0 * max(radius_a, radius_b))
        proposal = layout.propose(rng, radius_a, [arc_insert(along, curvature)], attempt)
        if proposal is None:
            continue
        curve_a, [(low, high)] = proposal
        side = rng.choice([-1.0, 1.0])
        partner = _partner_alongside(rng, layout, curve_a, (low, high), radius_b, side, gap)
        if partner is None:
            continue
        curve_b, (b_low, b_high), part_margin = partner
        part_margin += 2.5 * (radius_a + radius_b)
        exemption = _Exemption(
            first,
            (b_low - part_margin, b_high + part_margin),
            (low - part_margin, high + part_margin),
        )
        if layout.check([curve_a, curve_b], [MIN_CROSSING_ANGLE] * 2, [(), (exemption,)]):
            values = {
                "gap": gap,
                "length": along,
                "start": low,
                "end": high,
                "partner_start": b_low,
                "partner_end": b_high,
            }
            layout.features.append(SceneFeature("side_by_side", (first, first + 1), values))
            return
    raise _Unplaceable


def _partner_alongside(rng, layout, curve, span, radius, side, gap):
    """A cable beside ``curve``'s stretch ``span``, ``gap`` px from it, turning away at both
    ends; with its stretch's arc range and the arc it takes to part (or None)."""
    inside = np.flatnonzero((curve.arc >= span[0]) & (curve.arc <= span[1]))
    tangents = np.gradient(curve.points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = np.column_stack([-tangents[:, 1], tangents[:, 0]])
    distance = curve.radius + radius + gap
    middle = curve.points[inside] + side * distance * normals[inside]
    part_angle = rng.uniform(math.radians(20.0), math.radians(50.0))
    part_radius = rng.uniform(4.0, 8.0) * radius
    ends = []
    for end, sign in ((-1, 1.0), (0, -1.0)):
        heading = math.atan2(tangents[inside[end], 1], tangents[inside[end], 0])
        if sign < 0:
            heading += math.pi
        length = rng.uniform(0.2, 0.6) * layout.diagonal
        grown = designed_centreline(
            rng,
            radius,
            length,
            layout.diagonal,
            [turn_insert(part_radius, sign * side * part_angle)],
            at_start=True,
            heading=heading,
        )
        ends.append(middle[end] + grown[0][1:])
    points = np.vstack([ends[1][::-1], middle, ends[0]])
    first_middle = len(ends[1])
    anchor_index = first_middle + len(middle) // 2
    span_b = (first_middle, first_middle + len(middle) - 1)
    clipped = layout.clip(points, anchor_index, [span_b], radius)
    if clipped is None:
        return None
    curve_b, [span_b] = clipped
    return (
        curve_b,
        span_b,
        part_radius * part_angle + 2.5 * (curve.radius + radius) / math.sin(part_angle),
    )


_FEATURES = {
    "hairpin": _place_hairpin,
    "shallow_crossing": _place_shallow_crossing,
    "side_by_side": _place_side_by_side,
}

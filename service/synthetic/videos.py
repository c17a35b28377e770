"""Generated videos of moving cables with the exact position of every material point.

:func:`make_video` draws video ``seed`` of a kind (:data:`VIDEO_KINDS`): cables that drift,
turn, bend with waves travelling along them, are crossed by occluders sliding over them,
cross each other and part again, and leave the picture and come back. Each frame comes
with the truth a tracker is judged by: every cable's whole centreline sampled at fixed
*material* positions (sample ``j`` is always the point ``j * SAMPLE_SPACING`` px of cable
from the same end, whatever the cable does), which samples are in the picture and which
are under an occluder.

A cable is a curve of fixed length whose shape is its curvature along the arc: a smooth
random profile plus travelling waves; its middle (the anchor) is placed and turned by the
motion, and the rest follows by integrating the curvature, so the cable never stretches.
Frames are drawn on demand (:meth:`SyntheticVideo.frames`): the same seed always gives the
same video, frame by frame. Every frame obeys the layout rules of the still scenes where
they matter for tracking: crossings at 30 degrees or more, no cable crossing itself, no two
cables running side by side. Videos are 640x480 at 30 frames per second by default.

Seeds follow the test bed's convention (:mod:`service.evaluation.conventions`): 0-99999 to
tune on, 100000 and up held out.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from service.synthetic.backdrops import draw_backdrop
from service.synthetic.curves import (
    SAMPLE_SPACING,
    _Curve,
    _intersections,
    _smooth_random_curvature,
    _true_runs,
)
from service.synthetic.occluders import _draw_occluder, _Rect
from service.synthetic.render import _compose_bands, _draw_cable, _pick_colours
from service.synthetic.scene_types import Occluder

VIDEO_KINDS = ("drift", "rotation", "bends", "occluders", "crossings", "enter_leave")
"""The kinds of generated video, each stressing one kind of motion (see :func:`make_video`)."""

_KIND_KEYS = {kind: 9100 + number for number, kind in enumerate(VIDEO_KINDS)}
_ATTEMPTS = 60
_RESTARTS = 6
_CHECK_EVERY = 2  # frames between layout checks (motion is smooth: a few px per frame)
# Close stretches between two cables (in clearances: 1.5 times their summed radii + 3 px):
# this long as a crossing forms or parts, plus what a crossing at this angle explains.
_BRIEF_CONTACT = 3.0
_MIN_VIDEO_CROSSING_ANGLE = math.radians(20.0)


@dataclass(frozen=True, eq=False)
class CableTruth:
    """One cable in one frame.

    Attributes
    ----------
    points : ndarray, shape (K, 2)
        The whole centreline, in or out of the picture: sample ``j`` is the material point
        ``j * spacing`` px from the cable's first end, in every frame.
    in_picture : ndarray, shape (K,), bool
        Samples inside the picture.
    hidden : ndarray, shape (K,), bool
        Samples under an occluder (not counting other cables at crossings).
    radius : float
    colour : tuple of int
        Base BGR colour.
    spacing : float
        Material arc between samples, px.
    """

    points: np.ndarray
    in_picture: np.ndarray
    hidden: np.ndarray
    radius: float
    colour: tuple[int, int, int]
    spacing: float = SAMPLE_SPACING

    @property
    def visible(self) -> np.ndarray:
        """Samples in the picture and not under an occluder."""
        return self.in_picture & ~self.hidden

    @property
    def visible_length(self) -> float:
        """Length of the cable in view (px): in the picture and not under an occluder."""
        return float(np.count_nonzero(self.visible[1:] & self.visible[:-1])) * self.spacing


@dataclass(frozen=True, eq=False)
class VideoFrame:
    """One frame of a :class:`SyntheticVideo` with its truth.

    Attributes
    ----------
    index : int
    timestamp_s : float
    image : ndarray, shape (H, W, 3), uint8
        BGR.
    mask : ndarray, shape (H, W), bool
        Visible cable pixels.
    cables : list of CableTruth
        In the video's cable order (a cable keeps its index through the video).
    occluders : list of Occluder
    """

    index: int
    timestamp_s: float
    image: np.ndarray
    mask: np.ndarray
    cables: list[CableTruth]
    occluders: list[Occluder]


@dataclass(frozen=True, eq=False)
class _Wave:
    """A sine of curvature travelling along the cable (px of arc per frame)."""

    amplitude: float
    wavelength: float
    speed: float
    phase: float


@dataclass(frozen=True, eq=False)
class _Path:
    """Where a point goes over time: a start, a drift, a Lissajous sway and an excursion.

    The excursion moves the point by ``excursion`` (px, a vector) along an ease-in-out
    ramp: out between frames ``out_frames[0]`` and ``[1]``, back between ``back_frames``
    (None: it stays out). An excursion that starts out (``starts_out``) comes in instead.
    """

    start: np.ndarray
    drift: np.ndarray = field(default_factory=lambda: np.zeros(2))
    sway: np.ndarray = field(default_factory=lambda: np.zeros(2))
    sway_period: np.ndarray = field(default_factory=lambda: np.ones(2))
    sway_phase: np.ndarray = field(default_factory=lambda: np.zeros(2))
    excursion: np.ndarray = field(default_factory=lambda: np.zeros(2))
    out_frames: tuple[float, float] = (0.0, 0.0)
    back_frames: tuple[float, float] | None = None

    def at(self, frame: float) -> np.ndarray:
        sway = self.sway * (np.sin(2.0 * math.pi * frame / self.sway_period + self.sway_phase))
        sway -= self.sway * np.sin(self.sway_phase)  # start at ``start``
        ramp = _ease(frame, *self.out_frames)
        if self.back_frames is not None:
            ramp -= _ease(frame, *self.back_frames)
        return self.start + self.drift * frame + sway + self.excursion * ramp


@dataclass(frozen=True, eq=False)
class _CableMotion:
    """A cable of fixed length: its curvature profile, waves, turning and path."""

    radius: float
    colour: tuple[int, int, int]
    curvature: np.ndarray  # per sample step, 1/px
    max_curvature: float
    anchor: int  # sample index placed by the path
    heading: float  # at the anchor, at frame 0
    turn_rate: float  # rad per frame
    turn_sway: float  # rad amplitude of a slow sway of the heading
    turn_period: float
    path: _Path
    waves: tuple[_Wave, ...] = ()

    @property
    def samples(self) -> int:
        return len(self.curvature) + 1

    def centreline(self, frame: float) -> np.ndarray:
        """The ``(K, 2)`` material samples at a frame."""
        curvature = self.curvature
        if self.waves:
            mid_arc = (np.arange(len(curvature)) + 0.5) * SAMPLE_SPACING
            curvature = curvature.copy()
            for wave in self.waves:
                curvature += wave.amplitude * np.sin(
                    2.0 * math.pi * (mid_arc - wave.speed * frame) / wave.wavelength + wave.phase
                )
            np.clip(curvature, -self.max_curvature, self.max_curvature, out=curvature)
        # Each step follows the heading at its middle, exact for circular arcs.
        turning = (np.cumsum(curvature) - curvature / 2.0) * SAMPLE_SPACING
        anchor_step = min(self.anchor, len(curvature) - 1)
        heading = (
            self.heading
            + self.turn_rate * frame
            + self.turn_sway * math.sin(2.0 * math.pi * frame / self.turn_period)
        )
        turning += heading - turning[anchor_step]
        steps = SAMPLE_SPACING * np.column_stack([np.cos(turning), np.sin(turning)])
        points = np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
        return points - points[self.anchor] + self.path.at(frame)


@dataclass(frozen=True, eq=False)
class _OccluderMotion:
    """A rectangle sliding across the picture at constant velocity."""

    start: np.ndarray
    velocity: np.ndarray
    angle: float
    spin: float  # rad per frame
    half_length: float
    half_width: float
    texture_seed: int

    def rect(self, frame: float) -> _Rect:
        return _Rect(
            centre=self.start + self.velocity * frame,
            angle=self.angle + self.spin * frame,
            half_length=self.half_length,
            half_width=self.half_width,
        )


@dataclass(frozen=True, eq=False)
class SyntheticVideo:
    """A generated video: its motions and how to draw any of its frames.

    Attributes
    ----------
    kind : str
        One of :data:`VIDEO_KINDS`.
    seed : int
    width, height : int
    fps : float
    n_frames : int
    radii : tuple of float
        The cables' radii, in cable order.
    lengths : tuple of float
        The cables' lengths, px.
    """

    kind: str
    seed: int
    width: int
    height: int
    fps: float
    n_frames: int
    radii: tuple[float, ...]
    lengths: tuple[float, ...]
    _cables: tuple[_CableMotion, ...]
    _occluders: tuple[_OccluderMotion, ...]
    _background: np.ndarray
    _background_level: float
    _noise_sigma: float

    @property
    def n_cables(self) -> int:
        return len(self._cables)

    def centrelines(self, index: int) -> list[np.ndarray]:
        """Every cable's material samples at frame ``index`` (no drawing)."""
        return [cable.centreline(index) for cable in self._cables]

    def frame(self, index: int) -> VideoFrame:
        """Draw frame ``index`` (0 to ``n_frames - 1``) with its truth."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} is outside 0..{self.n_frames - 1}")
        height, width = self.height, self.width
        labels = np.zeros((height, width), dtype=np.uint16)
        paints = []
        lines = self.centrelines(index)
        # Drawn bottom first: the cable order is the drawing order (later on top).
        for number, (cable, points) in enumerate(zip(self._cables, lines, strict=True)):
            curve = _Curve.from_points(points, cable.radius)
            paints += _draw_cable(labels, curve, cable.colour, number + 1, [])
        rects = [occluder.rect(index) for occluder in self._occluders]
        shown = []
        for occluder, rect in zip(self._occluders, rects, strict=True):
            if _rect_in_picture(rect, width, height):
                texture = np.random.default_rng(occluder.texture_seed)
                paints.append(_draw_occluder(texture, labels, rect, self._background_level))
                shown.append(rect)
        noise = np.random.default_rng([self.seed, _KIND_KEYS[self.kind], 1, index])

        def background(top, bottom):
            return self._background[top:bottom].copy()

        image = _compose_bands(noise, background, (height, width), paints, self._noise_sigma)
        cables = []
        for cable, points in zip(self._cables, lines, strict=True):
            in_picture = (
                (points[:, 0] >= -0.5)
                & (points[:, 0] <= width - 0.5)
                & (points[:, 1] >= -0.5)
                & (points[:, 1] <= height - 0.5)
            )
            hidden = np.zeros(len(points), dtype=bool)
            for rect in rects:
                hidden |= rect.contains(points)
            cables.append(CableTruth(points, in_picture, hidden, cable.radius, cable.colour))
        return VideoFrame(
            index=index,
            timestamp_s=index / self.fps,
            image=image,
            mask=labels > 0,
            cables=cables,
            occluders=[Occluder(polygon=rect.corners()) for rect in shown],
        )

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[VideoFrame]:
        """Frames ``start`` to ``stop - 1`` (default: to the end), drawn one at a time."""
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        for index in range(start, stop):
            yield self.frame(index)


def make_video(
    seed: int,
    kind: str | None = None,
    *,
    n_frames: int = 300,
    width: int = 640,
    height: int = 480,
    fps: float = 30.0,
    n_cables: int | None = None,
) -> SyntheticVideo:
    """Generate video ``seed`` of a kind: the motions are drawn now, the frames on demand.

    Parameters
    ----------
    seed : int
        Non-negative; the same seed (and arguments) gives the same video.
    kind : str, optional
        One of :data:`VIDEO_KINDS`; by default ``VIDEO_KINDS[seed % 6]``.

        ``drift``
            Cables sway across the picture (up to about 4 px per frame).
        ``rotation``
            Cables turn about their middles (0.15-0.6 degrees per frame).
        ``bends``
            Waves of curvature travel along the cables (1-3 px per frame).
        ``occluders``
            One to three background-coloured boxes slide over the cables.
        ``crossings``
            Two or three cables drift across each other (1-2.2 px per frame): crossings
            form and dissolve.
        ``enter_leave``
            A cable leaves the picture and comes back 0.5-2.5 s later; with two or more
            cables, another one comes in from outside.

        Every kind also sways and turns its cables a little.
    n_frames : int
        Frames in the video (default 300, 10 s at 30 fps).
    width, height : int
        Picture size, at least 320x240.
    fps : float
        Frame rate; the motions are per frame, so this only sets the timestamps.
    n_cables : int, optional
        1 to 3; by default ``1 + (seed // 6) % 3`` (``2 + (seed // 6) % 2`` for
        ``crossings``), so that every kind comes with every count.

    Returns
    -------
    SyntheticVideo

    Raises
    ------
    ValueError
        An argument is out of range.
    RuntimeError
        No motion obeying the layout rules was found (not seen at the default size).
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    kind = VIDEO_KINDS[seed % len(VIDEO_KINDS)] if kind is None else kind
    if kind not in VIDEO_KINDS:
        raise ValueError(f"unknown video kind {kind!r}; expected one of {', '.join(VIDEO_KINDS)}")
    if width < 320 or height < 240:
        raise ValueError(f"videos need a picture of 320x240 or more, got {width}x{height}")
    if not isinstance(n_frames, int) or n_frames < 1:
        raise ValueError(f"n_frames must be a positive integer, got {n_frames!r}")
    if not (isinstance(fps, int | float) and math.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive number, got {fps!r}")
    if n_cables is None:
        # Each kind comes with every count in turn (kind = seed % 6, count by seed // 6).
        turn = seed // len(VIDEO_KINDS)
        n_cables = 2 + turn % 2 if kind == "crossings" else 1 + turn % 3
    if not isinstance(n_cables, int) or not 1 <= n_cables <= 3:
        raise ValueError(f"n_cables must be 1, 2 or 3, got {n_cables!r}")
    rng = np.random.default_rng([int(seed), _KIND_KEYS[kind]])
    backdrop = draw_backdrop(rng, width, height, str(rng.choice(["dark-textured", "dark-plain"])))
    colours = _pick_colours(rng, n_cables)
    checked = range(0, n_frames, _CHECK_EVERY)
    for _ in range(_RESTARTS):
        placed = _place_cables(rng, kind, n_cables, colours, width, height, n_frames, checked)
        if placed is not None:
            break
    else:
        raise RuntimeError(f"could not draw a {kind!r} video of {n_cables} cable(s), seed {seed}")
    cables = tuple(placed)
    occluders = _occluder_motions(rng, kind, cables, width, height, n_frames)
    return SyntheticVideo(
        kind=kind,
        seed=int(seed),
        width=width,
        height=height,
        fps=float(fps),
        n_frames=n_frames,
        radii=tuple(cable.radius for cable in cables),
        lengths=tuple((cable.samples - 1) * SAMPLE_SPACING for cable in cables),
        _cables=cables,
        _occluders=occluders,
        _background=backdrop.base,
        _background_level=float(backdrop.base.mean()),
        _noise_sigma=float(rng.uniform(2.0, 4.0)),
    )


# --------------------------------------------------------------------------- motions


def _place_cables(rng, kind, n_cables, colours, width, height, n_frames, checked):
    """Cable motions drawn one at a time, each redrawn until it obeys the layout rules
    against the ones before; None when one cannot be placed (start again)."""
    placed: list[_CableMotion] = []
    placed_curves: list[list[_Curve]] = []  # per placed cable, its curve at each checked frame
    for number in range(n_cables):
        for attempt in range(_ATTEMPTS):
            # Shorter cables fit more easily; shrink them if the first tries keep failing.
            shrink = 1.0 - 0.4 * attempt / _ATTEMPTS
            cable = _cable_motion(
                rng, kind, number, colours[number], width, height, n_frames, shrink
            )
            curves = _curves_if_clear(cable, placed_curves, checked)
            if curves is not None:
                placed.append(cable)
                placed_curves.append(curves)
                break
        else:
            return None
    return placed


def _cable_motion(rng, kind, number, colour, width, height, n_frames, shrink=1.0):
    diagonal = math.hypot(width, height)
    radius = float(rng.uniform(3.5, 7.0))
    length = float(rng.uniform(0.4, 0.75) * diagonal * shrink)
    n_steps = max(2, math.ceil(length / SAMPLE_SPACING))
    # Bending tighter than 4 radii would pinch the drawn tube into a kink.
    max_curvature = 1.0 / (4.0 * radius)
    curvature = _smooth_random_curvature(rng, n_steps, diagonal, 0.7 * max_curvature)
    centre = np.array([width, height], dtype=float) / 2.0
    spread = np.array([width, height], dtype=float) * 0.22
    start = centre + rng.uniform(-1.0, 1.0, 2) * spread
    # A little sway and turning in every kind.
    path = _Path(
        start=start,
        sway=rng.uniform(3.0, 12.0, 2),
        sway_period=rng.uniform(90.0, 300.0, 2),
        sway_phase=rng.uniform(0.0, 2.0 * math.pi, 2),
    )
    turn_rate = math.radians(rng.uniform(-0.05, 0.05))
    waves: tuple[_Wave, ...] = ()
    if kind == "drift":
        path = _replace(
            path,
            sway=rng.uniform(40.0, 110.0, 2),
            sway_period=rng.uniform(150.0, 360.0, 2),
        )
    elif kind == "rotation":
        turn_rate = math.radians(rng.uniform(0.15, 0.6)) * rng.choice([-1.0, 1.0])
    elif kind == "bends":
        waves = tuple(
            _Wave(
                amplitude=float(rng.uniform(0.25, 0.45) * max_curvature),
                wavelength=float(rng.uniform(120.0, 300.0)),
                speed=float(rng.uniform(1.0, 3.0) * rng.choice([-1.0, 1.0])),
                phase=float(rng.uniform(0.0, 2.0 * math.pi)),
            )
            for _ in range(int(rng.integers(1, 3)))
        )
    elif kind == "crossings" and number > 0:
        # Drift across the first cable (1-2.2 px per frame): crossings form and part.
        heading = rng.uniform(0.0, 2.0 * math.pi)
        velocity = rng.uniform(1.0, 2.2) * np.array([math.cos(heading), math.sin(heading)])
        path = _replace(path, start=centre - velocity * n_frames / 2.0, drift=velocity)
    elif kind == "enter_leave":
        path = _excursion(rng, path, number, n_frames, width, height, length)
    return _CableMotion(
        radius=radius,
        colour=colour,
        curvature=curvature,
        max_curvature=max_curvature,
        anchor=n_steps // 2,
        heading=float(rng.uniform(0.0, 2.0 * math.pi)),
        turn_rate=turn_rate,
        turn_sway=math.radians(rng.uniform(0.0, 6.0)),
        turn_period=float(rng.uniform(120.0, 400.0)),
        path=path,
        waves=waves,
    )


def _excursion(rng, path, number, n_frames, width, height, length):
    """Cable 0 leaves the picture and comes back; cable 1 comes in from outside."""
    side = int(rng.integers(4))
    direction = np.array([(-1.0, 0.0), (1.0, 0.0), (0.0, -1.0), (0.0, 1.0)][side])
    # Far enough that the whole cable (half its length either side of its middle) is out.
    to_border = (path.start[0], width - path.start[0], path.start[1], height - path.start[1])[side]
    distance = to_border + 0.5 * length + 40.0
    seconds = n_frames / 30.0
    if number == 0:
        leave = rng.uniform(0.1, 0.3) * n_frames
        travel = rng.uniform(45.0, 75.0)
        dwell = rng.uniform(0.5, min(2.5, 0.25 * seconds)) * 30.0
        out = (leave, leave + travel)
        back = (out[1] + dwell, out[1] + dwell + travel)
        return _replace(path, excursion=direction * distance, out_frames=out, back_frames=back)
    if number == 1:
        arrive = rng.uniform(0.05, 0.4) * n_frames
        travel = rng.uniform(45.0, 75.0)
        start = path.start + direction * distance
        return _replace(
            path, start=start, excursion=-direction * distance, out_frames=(arrive, arrive + travel)
        )
    return path


def _occluder_motions(rng, kind, cables, width, height, n_frames):
    """Boxes coloured like the background sliding across the picture over the cables."""
    count = int(rng.integers(1, 4)) if kind == "occluders" else 0
    motions = []
    for number in range(count):
        target = cables[int(rng.integers(len(cables)))]
        points = target.centreline(n_frames / 2.0)
        inside = (
            (points[:, 0] > 40)
            & (points[:, 0] < width - 40)
            & (points[:, 1] > 40)
            & (points[:, 1] < height - 40)
        )
        aim = points[int(rng.choice(np.flatnonzero(inside)))] if inside.any() else points[0]
        speed = rng.uniform(1.0, 3.0)
        heading = rng.uniform(0.0, 2.0 * math.pi)
        velocity = speed * np.array([math.cos(heading), math.sin(heading)])
        motions.append(
            _OccluderMotion(
                start=aim - velocity * n_frames / 2.0,
                velocity=velocity,
                angle=float(rng.uniform(0.0, math.pi)),
                spin=math.radians(rng.uniform(-0.3, 0.3)),
                half_length=float(rng.uniform(20.0, 60.0)),
                half_width=float(rng.uniform(12.0, 30.0)),
                texture_seed=int(rng.integers(2**31)) + number,
            )
        )
    return tuple(motions)


# --------------------------------------------------------------------------- layout rules


def _curves_if_clear(cable, placed_curves, frames):
    """The cable's curve at each of ``frames``, or None if a layout rule breaks in one.

    Rules: the cable never crosses itself, and runs close to a cable already placed only
    briefly: where it crosses it, or for a moment as a crossing forms or parts.
    """
    curves = []
    for position, frame in enumerate(frames):
        curve = _Curve.from_points(cable.centreline(frame), cable.radius)
        if _intersections(curve, curve, same=True):
            return None
        for others in placed_curves:
            other = others[position]
            hits = _intersections(curve, other, same=False)
            if not _apart_but_at_crossings(curve, other, hits):
                return None
        curves.append(curve)
    return curves


def _apart_but_at_crossings(curve, other, hits):
    """Two cables run close together only briefly: where they cross (at a clear angle, so
    the stretch is short), or for a moment as a crossing forms or parts."""
    clearance = 1.5 * (curve.radius + other.radius) + 3.0
    distance = other.tree.query(curve.points[::4], distance_upper_bound=clearance)[0]
    close = distance < clearance
    arc = curve.arc[::4]
    crossing_arcs = np.array([hit[2] for hit in hits])
    angles = np.array([hit[4] for hit in hits])
    for start, stop in zip(*_true_runs(close), strict=True):
        low, high = arc[start] - 2.0, arc[stop - 1] + 2.0
        inside = (crossing_arcs >= low) & (crossing_arcs <= high)
        allowed = _BRIEF_CONTACT * clearance
        if np.any(inside):
            angle = max(float(angles[inside].min()), _MIN_VIDEO_CROSSING_ANGLE)
            allowed += 2.0 * clearance / math.sin(angle)
        if arc[stop - 1] - arc[start] > allowed:
            return False
    return True


# --------------------------------------------------------------------------- helpers


def _ease(frame, begin, end):
    """0 before ``begin``, 1 after ``end``, smooth (zero speed at both ends) between."""
    if end <= begin:
        return 0.0 if frame < begin else 1.0
    x = min(max((frame - begin) / (end - begin), 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def _replace(path, **changes):
    values = {name: getattr(path, name) for name in path.__dataclass_fields__}
    values.update(changes)
    return _Path(**values)


def _rect_in_picture(rect, width, height):
    corners = rect.corners()
    low, high = corners.min(axis=0), corners.max(axis=0)
    return high[0] >= 0 and high[1] >= 0 and low[0] <= width - 1 and low[1] <= height - 1


def write_video(video: SyntheticVideo, path, *, frames: int | None = None, fourcc: str = "mp4v"):
    """Write the video's frames to a video file (OpenCV, ``mp4v`` by default).

    ``frames``: only the first this many. Returns the path. Raises ``OSError`` when
    OpenCV cannot create the file.
    """
    import cv2

    count = video.n_frames if frames is None else min(frames, video.n_frames)
    writer = cv2.VideoWriter(
        str(path), cv2.VideoWriter_fourcc(*fourcc), video.fps, (video.width, video.height)
    )
    if not writer.isOpened():
        raise OSError(f"cannot write {path}: OpenCV cannot create the video")
    try:
        for frame in video.frames(0, count):
            writer.write(frame.image)
    finally:
        writer.release()
    return path

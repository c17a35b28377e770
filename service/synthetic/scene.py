""":func:`make_scene`: the original generator, kept bit for bit (every seed reproduces).

It draws smooth, shaded cables (some with a loop that crosses itself) on a dark,
low-saturation background, optionally hides short stretches of them under
background-like occluders, and adds sensor noise. The scene families of
:mod:`service.synthetic.families` build on the same parts.
"""

from __future__ import annotations

import math
import numbers
from typing import Literal

import numpy as np

from service.synthetic.layout import _place_cables, _public_crossing
from service.synthetic.occluders import _draw_occluder, _hidden_samples, _place_occluders
from service.synthetic.render import _compose, _draw_background, _draw_cable, _Paint, _pick_colours
from service.synthetic.scene_types import (
    Occluder,
    SyntheticCable,
    SyntheticScene,
)

MIN_IMAGE_SIDE = 64
MAX_CABLES = 10
MIN_CABLE_RADIUS = 1.0


def make_scene(
    width: int = 1280,
    height: int = 720,
    n_cables: int = 3,
    *,
    seed: int | None = 0,
    radius_range: tuple[float, float] = (4.0, 9.0),
    loops: bool = True,
    occluders: int = 0,
    background: Literal["textured", "plain"] = "textured",
    noise_sigma: float = 4.0,
    margin: float | None = None,
) -> SyntheticScene:
    """Draw a random cable scene and return it with its exact ground truth.

    Parameters
    ----------
    width, height : int
        Image size in px, each at least 64.
    n_cables : int
        Number of cables, 0 to 10.
    seed : int or None
        Seed for :func:`numpy.random.default_rng`; the same seed gives the same scene.
    radius_range : (float, float)
        Cable radii (half widths, px) are drawn uniformly from ``[low, high]``;
        ``1 <= low <= high``.
    loops : bool
        Let about half of the cables make a loop that crosses itself at a clear angle.
    occluders : int
        Number of rotated rectangles laid across cables, each hiding a 20-80 px stretch
        well inside one cable (never over a crossing or near a cable end). Needs at least
        one cable.
    background : {"textured", "plain"}
        Dark, low-saturation background: smoothed noise with a faint wood grain or grid,
        or a uniform grey with a slight gradient.
    noise_sigma : float
        Standard deviation of the Gaussian sensor noise added last (grey levels).
    margin : float or None
        None lets cables run off the image; their centrelines are then cut at the image
        border. A number keeps every cable wholly inside, at least ``margin`` px from each
        border, so both of its ends are visible.

    Returns
    -------
    SyntheticScene

    Raises
    ------
    ValueError
        If an argument is out of range.
    RuntimeError
        If the cables or occluders cannot be placed under the layout rules (too many or
        too wide cables for the image).

    Notes
    -----
    Layout rules, so that the ground truth is unambiguous: cables curve no tighter than
    4 radii and loops have a radius of at least 5 cable radii, so loop holes stay open;
    crossings are at least 30 degrees; two cables (or two parts of one) come within
    2.5 times their summed radii only briefly, at a crossing; cable ends keep 3 radii
    away from other cables. A self-crossing loop is drawn with its later part (larger
    arc length) on top.
    """
    _validate_arguments(
        width, height, n_cables, seed, radius_range, occluders, background, noise_sigma, margin
    )
    rng = np.random.default_rng(seed)

    grey, tint, background_level = _draw_background(rng, width, height, background)
    curves, raw_crossings = _place_cables(rng, width, height, n_cables, radius_range, loops, margin)
    colours = _pick_colours(rng, n_cables)
    depths = rng.permutation(n_cables)
    rects = _place_occluders(rng, occluders, curves, raw_crossings, width, height)

    # Cables and occluders are painted as lists of pixels and their colours, and only
    # laid over the background band by band in _compose: a whole float canvas and its
    # noise would take 24 bytes a pixel, 200 MB at 3840x2160.
    labels = np.zeros((height, width), dtype=np.uint16)
    paints: list[_Paint] = []
    for index in np.argsort(depths):
        loop_splits = [
            (crossing.first_arc + crossing.second_arc) / 2.0
            for crossing in raw_crossings
            if crossing.first == crossing.second == index
        ]
        paints += _draw_cable(labels, curves[index], colours[index], index + 1, loop_splits)
    for rect in rects:
        paints.append(_draw_occluder(rng, labels, rect, background_level))
    image = _compose(rng, grey, tint, paints, noise_sigma)
    del grey  # 4 bytes a pixel: free it before the mask is made

    cables = _cables_truth(curves, colours, depths, rects)
    crossings = [_public_crossing(crossing, depths) for crossing in raw_crossings]
    return SyntheticScene(
        image=image,
        mask=labels > 0,
        labels=labels,
        cables=cables,
        crossings=crossings,
        occluders=[Occluder(polygon=rect.corners()) for rect in rects],
        backdrop=f"dark-{background}",
    )


def _cables_truth(curves, colours, depths, occluders):
    """The ground truth of the cables: ``occluders`` are shapes with ``contains(points)``."""
    return [
        SyntheticCable(
            centreline=curve.points,
            radius=curve.radius,
            colour=colours[index],
            hidden=_hidden_samples(curve.points, occluders),
            depth=int(depths[index]),
        )
        for index, curve in enumerate(curves)
    ]


# --------------------------------------------------------------------------- validation


def _validate_arguments(
    width, height, n_cables, seed, radius_range, occluders, background, noise_sigma, margin
) -> None:
    for name, value in (("width", width), ("height", height)):
        if not _is_int(value) or value < MIN_IMAGE_SIDE:
            raise ValueError(f"{name} must be an integer >= {MIN_IMAGE_SIDE}, got {value!r}")
    if not _is_int(n_cables) or not 0 <= n_cables <= MAX_CABLES:
        raise ValueError(f"n_cables must be an integer from 0 to {MAX_CABLES}, got {n_cables!r}")
    if seed is not None and (not _is_int(seed) or seed < 0):
        raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
    try:
        low, high = (float(value) for value in radius_range)
    except (TypeError, ValueError):
        raise ValueError(
            f"radius_range must be two numbers (low, high), got {radius_range!r}"
        ) from None
    if not (math.isfinite(low) and math.isfinite(high) and MIN_CABLE_RADIUS <= low <= high):
        raise ValueError(
            f"radius_range must be sorted (low <= high) with low >= {MIN_CABLE_RADIUS} px, "
            f"got {radius_range!r}"
        )
    if not _is_int(occluders) or occluders < 0:
        raise ValueError(f"occluders must be a non-negative integer, got {occluders!r}")
    if occluders > 0 and n_cables == 0:
        raise ValueError("occluders are laid across cables, so they need n_cables >= 1")
    if background not in ("textured", "plain"):
        raise ValueError(f"background must be 'textured' or 'plain', got {background!r}")
    if not _is_real(noise_sigma) or not 0 <= noise_sigma < math.inf:
        raise ValueError(f"noise_sigma must be a finite number >= 0, got {noise_sigma!r}")
    if margin is not None:
        if not _is_real(margin) or not 0 <= margin < math.inf:
            raise ValueError(f"margin must be None or a finite number >= 0, got {margin!r}")
        if min(width, height) - 2 * margin < 32:
            raise ValueError(
                f"margin {margin!r} leaves less than 32 px between the borders of a "
                f"{width}x{height} image"
            )


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


def _is_real(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)

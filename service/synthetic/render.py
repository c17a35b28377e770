"""Drawing: backgrounds, shaded cables, sensor noise, and the composed image."""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import pairwise
from statistics import NormalDist

import cv2
import numpy as np
from scipy.spatial import cKDTree

# Saturated colours plus white and light grey, all with value >= 185 so that either
# colourfulness or brightness separates every cable from the dark grey background.
_PALETTE_BGR = (
    (45, 45, 215),  # red
    (35, 130, 240),  # orange
    (50, 215, 225),  # yellow
    (70, 195, 70),  # green
    (185, 175, 40),  # teal
    (225, 120, 40),  # blue
    (200, 80, 150),  # violet
    (170, 105, 240),  # pink
    (235, 235, 232),  # white
    (205, 203, 200),  # light grey
)

# Light from the upper left and above the table; y points down in the image.
_LIGHT = np.array([-0.35, -0.45, 0.82]) / np.linalg.norm([-0.35, -0.45, 0.82])
_HALF_VECTOR = (_LIGHT + np.array([0.0, 0.0, 1.0])) / np.linalg.norm(
    _LIGHT + np.array([0.0, 0.0, 1.0])
)

# Sensor noise is looked up from random bytes: 256 equally likely levels of a unit normal
# distribution (tails cut at about 2.9 sigma), several times faster than drawing normals.
_NOISE_LEVELS = np.array(
    [NormalDist().inv_cdf((level + 0.5) / 256) for level in range(256)], dtype=np.float32
)
_NOISE_LEVELS /= _NOISE_LEVELS.std()

# Pixels per band when the image is composed (_compose): about 3 MB of float32 BGR.
_BAND_PIXELS = 1 << 18


@dataclass(frozen=True, eq=False)
class _Paint:
    """Pixels to set, ``image[rows, cols] = bgr``, over what lies below."""

    rows: np.ndarray
    cols: np.ndarray
    bgr: np.ndarray  # shape (N, 3), float32


def _draw_background(rng, width, height, kind):
    """A dark, low-saturation background: grey levels and a BGR tint, and the mean level.

    Returns
    -------
    grey : ndarray, shape (H, W), float32
    tint : ndarray, shape (3,), float32
        The background's BGR values are ``grey[:, :, None] * tint``.
    level : float
    """
    direction = rng.uniform(0.0, 2.0 * math.pi)
    if kind == "plain":
        level = rng.uniform(45.0, 70.0)
        x = np.arange(width, dtype=np.float32)[None, :]
        y = np.arange(height, dtype=np.float32)[:, None]
        grey = x * np.float32(math.cos(direction)) + y * np.float32(math.sin(direction))
        slope = rng.uniform(4.0, 10.0) * 2.0 / math.hypot(width, height)
        # level + slope * along, in place: no whole-image temporaries.
        grey *= np.float32(slope)
        grey += np.float32(level)
    else:
        level = rng.uniform(40.0, 70.0)
        # The texture has no detail finer than a few pixels, so it is made at half size
        # and enlarged: a quarter of the work, which matters at 4K.
        small_width, small_height = -(-width // 2), -(-height // 2)
        grey = np.float32(level) + 7.0 * _smooth_noise(
            rng, small_width, small_height, max(small_width, small_height) / 6
        )
        grey += 3.0 * _smooth_noise(rng, small_width, small_height, 12.0)
        with_grid = rng.random() >= 0.6
        if not with_grid:
            # Wood-like grain: stripes across ``direction``, warped by slow noise.
            period = rng.uniform(10.0, 28.0) / 2.0
            x = np.arange(small_width, dtype=np.float32)[None, :]
            y = np.arange(small_height, dtype=np.float32)[:, None]
            along = x * np.float32(math.cos(direction)) + y * np.float32(math.sin(direction))
            warp = (2.0 * math.pi * 0.8) * _smooth_noise(rng, small_width, small_height, 80.0)
            phase = along * np.float32(2.0 * math.pi / period) + warp
            grey += 3.0 * np.sin(phase) + 1.5 * np.sin(2.7 * phase + 1.3 * warp)
        grey = cv2.resize(grey, (width, height), interpolation=cv2.INTER_LINEAR)
        if with_grid:
            # A faint cutting-mat grid, drawn at full size to keep its lines crisp.
            spacing = rng.uniform(40.0, 90.0)
            column_on_line = np.mod(np.arange(width), spacing) < 1.5
            row_on_line = np.mod(np.arange(height), spacing) < 1.5
            on_line = column_on_line[None, :] | row_on_line[:, None]
            # Adding the line strength only where on_line is the same as adding
            # ``strength * on_line`` everywhere, without a whole-image float temporary.
            np.add(grey, np.float32(rng.uniform(4.0, 7.0)), out=grey, where=on_line)
    tint = (1.0 + rng.uniform(-0.04, 0.04, 3)).astype(np.float32)
    return np.ascontiguousarray(grey, dtype=np.float32), tint, float(level)


def _compose(rng, grey, tint, paints, noise_sigma):
    """The uint8 BGR image: background ``grey * tint``, paints in order, sensor noise."""

    def background(top, bottom):
        return grey[top:bottom, :, None] * tint[None, None, :]

    return _compose_bands(rng, background, grey.shape, paints, noise_sigma)


def _compose_bands(rng, background, shape, paints, noise_sigma):
    """The uint8 BGR image: background, paints in order, sensor noise, rounded.

    ``background(top, bottom)`` gives the float32 BGR rows ``top:bottom`` (a new array).
    Made in bands of rows, so that only one band is ever held in float32; every pixel
    goes through the same float32 operations in the same order as if the whole image
    were made at once, and the noise bytes are drawn in the same order.
    """
    height, width = shape
    image = np.empty((height, width, 3), dtype=np.uint8)
    # A multiple of 4 rows makes every band's noise a whole number of the 4-byte words
    # rng.bytes draws, so the bands together draw exactly the bytes of one big call.
    band_rows = max(4, _BAND_PIXELS // width // 4 * 4)
    noise_levels = _NOISE_LEVELS * np.float32(noise_sigma)
    for top in range(0, height, band_rows):
        bottom = min(top + band_rows, height)
        band = background(top, bottom)
        for paint in paints:
            inside = (paint.rows >= top) & (paint.rows < bottom)
            band[paint.rows[inside] - top, paint.cols[inside]] = paint.bgr[inside]
        if noise_sigma > 0:
            band += _gaussian_noise(rng, band.shape, noise_levels)
        band += 0.5  # so that truncating to uint8 rounds to nearest
        image[top:bottom] = np.clip(band, 0.0, 255.0, out=band).astype(np.uint8)
    return image


def _gaussian_noise(rng, shape, noise_levels):
    """Zero-mean float32 noise: ``noise_levels`` (scaled ``_NOISE_LEVELS``) looked up."""
    random_bytes = np.frombuffer(rng.bytes(math.prod(shape)), dtype=np.uint8).reshape(shape)
    return cv2.LUT(random_bytes, noise_levels)


def _smooth_noise(rng, width, height, feature_size):
    """Unit-variance-ish noise with blobs about ``feature_size`` px across, float32."""
    small_width = max(2, round(width / feature_size) + 1)
    small_height = max(2, round(height / feature_size) + 1)
    small = rng.standard_normal((small_height, small_width), dtype=np.float32)
    return cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)


def _pick_colours(rng, n_cables, palette=_PALETTE_BGR):
    """Distinct palette colours (repeating after ``len(palette)``), each jittered a little."""
    order = rng.permutation(len(palette))
    colours = []
    for index in range(n_cables):
        base = np.array(palette[order[index % len(order)]])
        jittered = np.clip(base + rng.integers(-10, 11, 3), 0, 255)
        colours.append(tuple(int(channel) for channel in jittered))
    return colours


def _draw_cable(labels, curve, colour, label, loop_splits):
    """Label the pixels of a tube of ``curve.radius`` around the centreline; shade them.

    Returns the shaded pixels as one paint per layer, to lay on the background in order.
    A cable that crosses itself is drawn in layers split half-way round each loop, later
    layers on top, so the later part lies over the earlier one at the crossing. Each layer
    is measured against its stretch plus a little overlap, but paints only the pixels whose
    nearest centreline point is its own, so the layers join without a seam.
    """
    radius = curve.radius
    overlap = radius + 2.0
    colour = np.array(colour, dtype=np.float32)
    bounds = [-math.inf, *sorted(loop_splits), math.inf]
    paints = []
    for low, high in pairwise(bounds):
        if len(bounds) == 2:
            points, arc, tree = curve.points, curve.arc, curve.tree
        else:
            first = max(int(np.searchsorted(curve.arc, low - overlap)) - 1, 0)
            last = min(
                int(np.searchsorted(curve.arc, high + overlap, side="right")) + 1, len(curve.arc)
            )
            points, arc = curve.points[first:last], curve.arc[first:last]
            tree = cKDTree(points)
        rows, cols = _band_pixels(points, radius, labels.shape)
        centres = np.column_stack([cols, rows]).astype(float)
        distance, foot, foot_arc = _nearest_on_polyline(points, arc, tree, centres, radius + 1.5)
        keep = (distance <= radius) & (foot_arc >= low) & (foot_arc <= high)
        rows, cols = rows[keep], cols[keep]
        paints.append(_Paint(rows, cols, _shade(colour, (centres[keep] - foot[keep]) / radius)))
        labels[rows, cols] = label
    return paints


def _band_pixels(points, radius, shape):
    """Row and column indices of a band around the polyline, wider than the tube."""
    height, width = shape
    reach = radius + 3.0
    x0 = max(math.floor(points[:, 0].min() - reach), 0)
    y0 = max(math.floor(points[:, 1].min() - reach), 0)
    x1 = min(math.ceil(points[:, 0].max() + reach), width - 1)
    y1 = min(math.ceil(points[:, 1].max() + reach), height - 1)
    if x0 > x1 or y0 > y1:
        return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    band = np.zeros((y1 - y0 + 1, x1 - x0 + 1), dtype=np.uint8)
    # Every 4th sample (2 px chords) strays from the curve by far less than the band margin.
    outline = points[::4] if (len(points) - 1) % 4 == 0 else np.vstack([points[::4], points[-1:]])
    fixed_point = np.rint((outline - [x0, y0]) * 8.0).astype(np.int32)  # shift=3: 1/8 px
    thickness = 2 * math.ceil(radius) + 3
    cv2.polylines(band, [fixed_point.reshape(-1, 1, 2)], False, 255, thickness, cv2.LINE_8, 3)
    rows, cols = np.nonzero(band)
    return rows + y0, cols + x0


def _nearest_on_polyline(points, arc, tree, queries, max_distance):
    """Distance, nearest point and its arc length on the polyline, for each query point.

    Queries further than ``max_distance`` from every sample get an infinite distance.
    """
    n_queries = len(queries)
    distance = np.full(n_queries, np.inf)
    foot = np.zeros((n_queries, 2))
    foot_arc = np.full(n_queries, np.nan)
    _, nearest = tree.query(queries, distance_upper_bound=max_distance, workers=-1)
    found = nearest < len(points)
    if not np.any(found):
        return distance, foot, foot_arc
    query, nearest = queries[found], nearest[found]
    best = np.full(len(query), np.inf)
    best_foot = np.zeros_like(query)
    best_arc = np.zeros(len(query))
    # The nearest point of the polyline lies on a segment next to the nearest sample.
    for segment in (np.clip(nearest - 1, 0, len(points) - 2), np.clip(nearest, 0, len(points) - 2)):
        start = points[segment]
        step = points[segment + 1] - start
        step_squared = np.maximum(np.einsum("ij,ij->i", step, step), 1e-18)
        t = np.clip(np.einsum("ij,ij->i", query - start, step) / step_squared, 0.0, 1.0)
        candidate = start + t[:, None] * step
        candidate_distance = np.linalg.norm(query - candidate, axis=1)
        better = candidate_distance < best
        best = np.where(better, candidate_distance, best)
        best_foot[better] = candidate[better]
        best_arc[better] = arc[segment[better]] + t[better] * np.sqrt(step_squared[better])
    distance[found], foot[found], foot_arc[found] = best, best_foot, best_arc
    return distance, foot, foot_arc


def _shade(colour, outward):
    """BGR values of a lit cylinder (or hemispherical end) from the in-plane normal.

    ``outward`` is the pixel's offset from the centreline in radii, which is the in-plane
    part of the surface normal; the rest points at the camera.
    """
    facing = np.sqrt(np.clip(1.0 - np.einsum("ij,ij->i", outward, outward), 0.0, 1.0))
    normals = np.column_stack([outward, facing])
    diffuse = np.clip(normals @ _LIGHT, 0.0, 1.0)
    highlight = 0.45 * np.clip(normals @ _HALF_VECTOR, 0.0, 1.0) ** 24
    # The shadowed edge keeps 62% of the colour, still well clear of the dark background.
    brightness = 0.62 + 0.38 * diffuse
    shaded = colour[None, :] * (brightness * (1.0 - highlight))[:, None]
    return (shaded + 255.0 * highlight[:, None]).astype(np.float32)

"""Images made from a detection: instance labels and a visual overlay."""

from __future__ import annotations

import cv2
import numpy as np

from schemas import Detection

# Distinct, colour-blind-friendly BGR colours (Okabe-Ito), then a few more.
PALETTE = (
    (0, 159, 230),
    (233, 180, 86),
    (115, 158, 0),
    (66, 228, 240),
    (178, 114, 0),
    (0, 94, 213),
    (167, 121, 204),
    (255, 255, 255),
    (120, 120, 255),
    (255, 120, 120),
)


def chain_colour(chain_id: int) -> tuple[int, int, int]:
    """The overlay colour of a chain."""
    return PALETTE[chain_id % len(PALETTE)]


def _pixel_polyline(points) -> np.ndarray:
    return np.rint(np.asarray(points, dtype=np.float64)).astype(np.int32).reshape(-1, 1, 2)


# Near a crossing of two cables whose colours differ by at least this much (Lab chroma
# distance), each mask pixel goes to the cable whose colour it has.
COLOUR_SPLIT_MIN_DISTANCE = 10.0
# How far from a crossing (in radii of the strand on top) colour decides.
COLOUR_SPLIT_RADII = 2.5


def render_labels(
    detection: Detection, mask: np.ndarray, image: np.ndarray | None = None
) -> np.ndarray:
    """Instance label image: every mask pixel labelled with the chain it belongs to.

    Parameters
    ----------
    detection : Detection
    mask : ndarray of bool
        ``(H, W)`` foreground mask the detection was made from.
    image : ndarray, optional
        The ``(H, W, 3)`` BGR image. With it, mask pixels near a crossing of two
        differently coloured cables go to the cable whose colour they have (see
        :func:`split_crossings_by_colour`).

    Returns
    -------
    ndarray
        ``(H, W)`` ``uint16``: 0 background, chain ``i`` as ``i + 1``. A mask pixel goes
        to the nearest chain, except near a crossing, where the pixels under the
        strand on top go to that strand; inferred (hidden) segments are drawn as tubes
        of the chain's radius where the mask has no cable.

    Examples
    --------
    >>> import numpy as np
    >>> from schemas import Chain, Detection
    >>> mask = np.zeros((20, 40), bool)
    >>> mask[8:13, 2:38] = True
    >>> chain = Chain(id=0, points=[(2, 10), (12, 10), (22, 10), (32, 10), (37, 10)],
    ...               radius=2.5, inferred=[False] * 4)
    >>> labels = render_labels(Detection(width=40, height=20, segment_length=10,
    ...                                  chains=[chain]), mask)
    >>> int(labels.max()), int((labels == 1).sum()) == int(mask.sum())
    (1, True)
    """
    height, width = detection.height, detection.width
    mask = np.asarray(mask) > 0
    if mask.shape != (height, width):
        raise ValueError(f"mask is {mask.shape[::-1]} but the detection is {(width, height)}")
    labels = np.zeros((height, width), np.uint16)
    if not detection.chains:
        return labels
    seeds = np.zeros((height, width), np.uint16)
    for chain in detection.chains:
        cv2.polylines(seeds, [_pixel_polyline(chain.points)], False, chain.id + 1, 1)
    if mask.any():
        _, nearest = cv2.distanceTransformWithLabels(
            (seeds == 0).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
        )
        lookup = np.zeros(int(nearest.max()) + 1, np.uint16)
        seed_pixels = seeds > 0
        lookup[nearest[seed_pixels]] = seeds[seed_pixels]
        labels = np.where(mask, lookup[nearest], 0).astype(np.uint16)
    for crossing in detection.crossings:
        over = detection.chain(crossing.over)
        reach = int(np.ceil(3.0 * max(over.radius, 1.0) / detection.segment_length)) + 1
        first = max(0, crossing.over_segment - reach)
        last = min(len(over.points) - 1, crossing.over_segment + reach + 1)
        tube = np.zeros((height, width), np.uint8)
        thickness = max(1, round(2 * over.radius))
        cv2.polylines(tube, [_pixel_polyline(over.points[first : last + 1])], False, 1, thickness)
        labels[(tube > 0) & mask] = over.id + 1
    if image is not None and detection.crossings:
        split_crossings_by_colour(labels, detection, mask, image)
    hidden = np.zeros((height, width), np.uint16)
    for chain in detection.chains:
        thickness = max(1, round(2 * chain.radius))
        for k, inferred in enumerate(chain.inferred):
            if not inferred:
                continue
            (x0, y0), (x1, y1) = chain.points[k], chain.points[k + 1]
            col = min(max(round((x0 + x1) / 2), 0), width - 1)
            row = min(max(round((y0 + y1) / 2), 0), height - 1)
            if mask[row, col]:
                # Covered by the strand on top: already labelled as that strand.
                continue
            segment = _pixel_polyline(chain.points[k : k + 2])
            cv2.polylines(hidden, [segment], False, chain.id + 1, thickness)
    free = (labels == 0) & (hidden > 0) & ~mask
    labels[free] = hidden[free]
    return labels


def split_crossings_by_colour(
    labels: np.ndarray, detection: Detection, mask: np.ndarray, image: np.ndarray
) -> None:
    """Relabel, in place, the mask pixels near crossings of differently coloured cables.

    The tube of the strand on top is drawn with the chain's typical radius, so where
    the top cable is a little wider its rim goes to the strand underneath. When the
    two cables' colours differ clearly, colour is the better witness: within
    :data:`COLOUR_SPLIT_RADII` radii of the crossing, each pixel labelled with either
    strand goes to the one whose colour (Lab chroma, which shading changes least) is
    nearer. A cable's colour is the median over its centreline pixels away from every
    crossing. Crossings of a chain with itself, and of cables of similar colour, keep
    the geometric labels.
    """
    height, width = mask.shape
    if image.ndim != 3 or image.shape[2] < 3:
        return  # no colour to go by
    if image.shape[:2] != (height, width):
        raise ValueError(f"image is {image.shape[:2]} but the mask is {mask.shape}")
    chroma = cv2.cvtColor(image[:, :, :3], cv2.COLOR_BGR2LAB)[:, :, 1:].astype(np.float32) - 128.0
    near_crossing = np.zeros((height, width), np.uint8)
    for crossing in detection.crossings:
        reach = round(4.0 * max(detection.chain(crossing.over).radius, 1.0))
        cv2.circle(near_crossing, (round(crossing.x), round(crossing.y)), reach, 1, -1)
    colours = {}
    for chain in detection.chains:
        line = np.zeros((height, width), np.uint8)
        cv2.polylines(line, [_pixel_polyline(chain.points)], False, 1, 1)
        own = (line > 0) & mask & (near_crossing == 0)
        if np.count_nonzero(own) >= 10:
            colours[chain.id] = np.median(chroma[own], axis=0)
    for crossing in detection.crossings:
        over, under = crossing.over, crossing.under
        if over == under or over not in colours or under not in colours:
            continue
        if np.linalg.norm(colours[over] - colours[under]) < COLOUR_SPLIT_MIN_DISTANCE:
            continue
        disc = np.zeros((height, width), np.uint8)
        reach = round(COLOUR_SPLIT_RADII * detection.chain(over).radius + 2.0)
        cv2.circle(disc, (round(crossing.x), round(crossing.y)), reach, 1, -1)
        selected = (disc > 0) & mask & ((labels == over + 1) | (labels == under + 1))
        pixels = chroma[selected]
        to_over = np.linalg.norm(pixels - colours[over], axis=1)
        to_under = np.linalg.norm(pixels - colours[under], axis=1)
        labels[selected] = np.where(to_over <= to_under, over + 1, under + 1)


def render_overlay(image: np.ndarray, detection: Detection) -> np.ndarray:
    """The detection drawn on the image.

    Seen segments are solid lines with a dot at each joint; inferred segments are
    thin white-edged dashes in the chain's colour; crossings are rings in the colour
    of the strand on top.

    Parameters
    ----------
    image : ndarray
        ``(H, W, 3)`` BGR or ``(H, W)`` gray ``uint8``.
    detection : Detection

    Returns
    -------
    ndarray
        ``(H, W, 3)`` ``uint8`` BGR.

    Examples
    --------
    >>> import numpy as np
    >>> from schemas import Chain, Detection
    >>> image = np.zeros((40, 60, 3), np.uint8)
    >>> chain = Chain(id=0, points=[(5, 20), (15, 20), (25, 20)], radius=3,
    ...               inferred=[False, True])
    >>> overlay = render_overlay(image, Detection(width=60, height=40, segment_length=10,
    ...                                           chains=[chain]))
    >>> overlay.shape, overlay.dtype.name, bool(overlay[20, 10].any())
    ((40, 60, 3), 'uint8', True)
    """
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image[:, :, :3].copy()
    # Dim the photograph so the drawing stands out on bright cables.
    canvas = cv2.addWeighted(canvas, 0.55, np.zeros_like(canvas), 0.45, 0)
    scale = max(1, round(max(canvas.shape[:2]) / 900))
    shift = 4
    factor = 1 << shift

    def fixed(point):
        return (round(point[0] * factor), round(point[1] * factor))

    for chain in detection.chains:
        colour = chain_colour(chain.id)
        for k, inferred in enumerate(chain.inferred):
            a, b = chain.points[k], chain.points[k + 1]
            if inferred:
                mid = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
                cv2.line(
                    canvas, fixed(a), fixed(mid), (255, 255, 255), 3 * scale, cv2.LINE_AA, shift
                )
                cv2.line(canvas, fixed(a), fixed(mid), colour, 1 * scale, cv2.LINE_AA, shift)
            else:
                cv2.line(canvas, fixed(a), fixed(b), colour, 2 * scale, cv2.LINE_AA, shift)
        for point in chain.points:
            cv2.circle(canvas, fixed(point), 2 * scale * factor, colour, -1, cv2.LINE_AA, shift)
        # The id beside the first joint in the picture (a track's may lie outside it).
        start = next(
            (
                p
                for p in chain.points
                if 0 <= p[0] < canvas.shape[1] and 0 <= p[1] < canvas.shape[0]
            ),
            chain.points[0],
        )
        cv2.putText(
            canvas,
            str(chain.id),
            (int(start[0]) + 6, int(start[1]) - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.6 * scale,
            colour,
            2 * scale,
            cv2.LINE_AA,
        )
    for crossing in detection.crossings:
        colour = chain_colour(crossing.over)
        centre = fixed((crossing.x, crossing.y))
        cv2.circle(canvas, centre, 7 * scale * factor, colour, 2 * scale, cv2.LINE_AA, shift)
    return canvas

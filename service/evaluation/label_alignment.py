"""Where the labels, a mask and the photograph put a cable's borders, across the cable.

A mask's foreground DICE against hand-drawn labels mixes two errors: the mask's border
off the photographed cable, and the labels' border off it. Near the border the two cannot
be told apart pixel by pixel; across the cable they can. At points along every labelled
cable (away from other cables, crossings and the picture's edge) this module samples the
labels, the mask and the image's CIELAB colours along the cable's normal, and finds on
each side of the cable

- the **labels' border** and the **mask's border**: where each falls to one half;
- the **photograph's border**: where the colour is as near the surface beside the cable
  (the median colour 9-12 px out on that side) as the cable's own colour (the sample
  farthest from the surfaces near the labels' centre) — the half-way point of the edge
  profile, where a blurred edge crosses, whatever the blur.

Along one normal each of the three is an interval; the **1-D DICE** of two intervals
(twice their overlap over their summed lengths) is the foreground DICE that the cable's
body would score if every normal were like this one. ``image~truth`` is then what a mask
that follows the photograph exactly scores against the labels: the ceiling the labels'
own placement sets, crossings, ends and phantoms aside.

``python -m service.evaluation.label_alignment DATASET [...]`` prints, per subset, the
widths, the labels' offset from the photograph, the 1-D DICE of the three pairs, and how
far the mask and the labels reach beyond the photograph's border by the direction the
border faces (a shadow cast by a lamp lies on the side away from it). The mask is the
one the pipeline uses end to end (``dlo eval``'s foreground DICE); ``--mask-from-labels``
scores the true mask instead (a check: its mask~truth is 1).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from skimage.morphology import skeletonize

from service.perception.cable_segmentation import cielab_from_lab8

REACH = 12.0
"""The profile runs this far (px) either way from the labelled centre line."""
STEP = 0.5
"""Profile samples this far apart (px)."""
SURFACE_FROM = 9.0
"""The surface beside the cable is the median colour from this far out (px) to
:data:`REACH`: beyond a labelled cable of up to 12 px offset by up to 3 px."""
CABLE_SEARCH = 3.0
"""The cable's colour is looked for within this far (px) of the labels' centre."""
SPACING = 3
"""Every third pixel of a labelled centre line is a sample point."""
TANGENT_RADIUS = 5.0
"""The centre line's direction: the principal axis of its pixels within this radius."""
CLEARANCE = 16.0
"""Sample points lie at least this far (px) from any other cable's label..."""
IGNORE_CLEARANCE = 12.0
"""... and this far from pixels the labels leave out (crossings)."""


@dataclass(frozen=True)
class NormalSamples:
    """Borders along the normals of labelled cables (:func:`normal_samples`).

    Positions are px along the normal from the labelled centre line, the normal pointing
    to the right (x component > 0; straight down where it is vertical). Each ``(N, 2)``
    array holds the border on the negative and the positive side; NaN where it was not
    found.

    Attributes
    ----------
    points : ndarray
        ``(N, 2)`` x, y of the sample points.
    normals : ndarray
        ``(N, 2)`` unit normals.
    truth, mask, image : ndarray
        ``(N, 2)``: the labels', the mask's and the photograph's borders.
    """

    points: np.ndarray
    normals: np.ndarray
    truth: np.ndarray
    mask: np.ndarray
    image: np.ndarray


def centre_line_points(instance: np.ndarray, spacing: int = SPACING):
    """Points along a labelled cable's centre line with their unit tangents.

    Returns ``(points, tangents)``, each ``(N, 2)`` as x, y; points whose neighbourhood
    holds too few centre-line pixels for a direction (under six) are left out.
    """
    ys, xs = np.nonzero(skeletonize(instance))
    pixels = np.stack([xs, ys], axis=1).astype(np.float64)
    points, tangents = [], []
    for x, y in pixels[::spacing]:
        near = pixels[np.hypot(pixels[:, 0] - x, pixels[:, 1] - y) <= TANGENT_RADIUS]
        if len(near) < 6:
            continue
        centred = near - near.mean(axis=0)
        _, vectors = np.linalg.eigh(centred.T @ centred)
        points.append((x, y))
        tangents.append(vectors[:, 1])
    return np.reshape(points, (-1, 2)), np.reshape(tangents, (-1, 2))


def run_borders(profile: np.ndarray, start: int) -> tuple[float, float]:
    """Where a profile, at least one half at ``start``, falls under one half each way.

    Returns the two crossings in samples, interpolated linearly; NaN on a side where
    the run reaches the profile's end, both NaN when ``profile[start] < 0.5``.
    """
    n = profile.size
    if profile[start] < 0.5:
        return np.nan, np.nan
    right = start
    while right + 1 < n and profile[right + 1] >= 0.5:
        right += 1
    left = start
    while left > 0 and profile[left - 1] >= 0.5:
        left -= 1
    high = (
        right + (profile[right] - 0.5) / (profile[right] - profile[right + 1])
        if right + 1 < n
        else np.nan
    )
    low = left - (profile[left] - 0.5) / (profile[left] - profile[left - 1]) if left > 0 else np.nan
    return low, high


def half_way_borders(colours: np.ndarray, offsets: np.ndarray, centre: float):
    """The photograph's borders of the cable in one profile of colours.

    Parameters
    ----------
    colours : ndarray
        ``(M, 3)`` CIELAB along the normal.
    offsets : ndarray
        ``(M,)`` their positions (px), increasing.
    centre : float
        Where the labels put the cable's centre (px).

    Returns
    -------
    (float, float)
        Positions (px) where the colour is as near the surface on that side as the
        cable's colour; NaN where it does not get there.
    """
    surfaces = [
        np.median(colours[offsets <= -SURFACE_FROM], axis=0),
        np.median(colours[offsets >= SURFACE_FROM], axis=0),
    ]
    search = np.flatnonzero(np.abs(offsets - centre) <= CABLE_SEARCH)
    if search.size == 0:
        return np.nan, np.nan
    far = np.linalg.norm(colours[search] - (surfaces[0] + surfaces[1]) / 2, axis=1)
    core = search[np.argmax(far)]
    cable = colours[core]
    borders = []
    for surface, direction in zip(surfaces, (-1, 1), strict=True):
        # > 0 where the colour is nearer the cable than this side's surface.
        lead = np.linalg.norm(colours - surface, axis=1) - np.linalg.norm(colours - cable, axis=1)
        index = core
        while 0 < index < offsets.size - 1 and lead[index] >= 0:
            index += direction
        if lead[index] >= 0:
            borders.append(np.nan)
            continue
        inside = index - direction
        fraction = lead[inside] / (lead[inside] - lead[index])
        borders.append(offsets[inside] + direction * fraction * STEP)
    return borders[0], borders[1]


def normal_samples(
    image_bgr: np.ndarray,
    labels: np.ndarray,
    mask: np.ndarray,
    ignore: np.ndarray | None = None,
) -> NormalSamples:
    """Sample the labels, a mask and the photograph across every labelled cable.

    Parameters
    ----------
    image_bgr : ndarray
        ``(H, W, 3)`` BGR ``uint8``.
    labels : ndarray
        ``(H, W)`` integer instance labels, 0 the background.
    mask : ndarray of bool
        ``(H, W)`` the mask to judge.
    ignore : ndarray of bool, optional
        Pixels the labels leave out (where cables overlap); they count as every cable's.
    """
    if image_bgr.shape[:2] != labels.shape or labels.shape != mask.shape:
        raise ValueError("image, labels and mask must be of one size")
    height, width = labels.shape
    lab = cielab_from_lab8(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2Lab))
    ignore = np.zeros(labels.shape, bool) if ignore is None else ignore
    near_ignored = cv2.distanceTransform((~ignore).view(np.uint8), cv2.DIST_L2, 3)
    offsets = np.arange(-REACH, REACH + STEP / 2, STEP)
    collected = {key: [] for key in ("points", "normals", "truth", "mask", "image")}
    for label in np.unique(labels[(labels > 0) & ~ignore]):
        own = (labels == label) | ignore
        others = (labels > 0) & ~own
        clearance = cv2.distanceTransform((~others).view(np.uint8), cv2.DIST_L2, 3)
        points, tangents = centre_line_points(own)
        if points.size == 0:
            continue
        cols, rows = points[:, 0].astype(int), points[:, 1].astype(int)
        keep = (clearance[rows, cols] >= CLEARANCE) & (near_ignored[rows, cols] >= IGNORE_CLEARANCE)
        normals = np.stack([-tangents[:, 1], tangents[:, 0]], axis=1)
        normals[normals[:, 0] < 0] *= -1
        normals[(normals[:, 0] == 0) & (normals[:, 1] < 0)] *= -1
        # Three parallel normals a pixel apart along the cable, averaged.
        xs = points[:, 0, None, None] + offsets[None, :, None] * normals[:, 0, None, None]
        ys = points[:, 1, None, None] + offsets[None, :, None] * normals[:, 1, None, None]
        shifts = np.array([-1.0, 0.0, 1.0])[None, None, :]
        xs = xs + shifts * tangents[:, 0, None, None]
        ys = ys + shifts * tangents[:, 1, None, None]
        keep &= (xs.min(axis=(1, 2)) >= 0) & (xs.max(axis=(1, 2)) <= width - 1)
        keep &= (ys.min(axis=(1, 2)) >= 0) & (ys.max(axis=(1, 2)) <= height - 1)
        if not keep.any():
            continue
        xs, ys = xs[keep], ys[keep]

        def profile(values, xs=xs, ys=ys):
            return map_coordinates(values, [ys, xs], order=1).mean(axis=2)

        truth = profile(own.astype(np.float32))
        ours = profile(mask.astype(np.float32))
        colours = np.stack([profile(lab[..., channel]) for channel in range(3)], axis=2)
        centre_index = offsets.size // 2
        for k in range(truth.shape[0]):
            truth_borders = run_borders(truth[k], centre_index)
            if np.isnan(truth_borders).any():
                continue
            truth_borders = offsets[0] + STEP * np.array(truth_borders)
            centre = truth_borders.mean()
            inside = np.flatnonzero((ours[k] >= 0.5) & (np.abs(offsets - centre) <= CABLE_SEARCH))
            mask_borders = (np.nan, np.nan)
            if inside.size:
                start = inside[np.argmin(np.abs(offsets[inside] - centre))]
                mask_borders = offsets[0] + STEP * np.array(run_borders(ours[k], start))
            collected["points"].append(points[keep][k])
            collected["normals"].append(normals[keep][k])
            collected["truth"].append(truth_borders)
            collected["mask"].append(mask_borders)
            collected["image"].append(half_way_borders(colours[k], offsets, centre))
    return NormalSamples(**{key: np.reshape(value, (-1, 2)) for key, value in collected.items()})


def interval_dice(one: np.ndarray, two: np.ndarray) -> np.ndarray:
    """1-D DICE of intervals ``(N, 2)`` against ``(N, 2)``: twice the overlap over the sum."""
    overlap = np.clip(np.minimum(one[:, 1], two[:, 1]) - np.maximum(one[:, 0], two[:, 0]), 0, None)
    return 2.0 * overlap / ((one[:, 1] - one[:, 0]) + (two[:, 1] - two[:, 0]))


def facing_angles(samples: NormalSamples) -> np.ndarray:
    """``(N, 2)``: the direction (degrees, 0 = +x, 90 = down the picture) each border faces."""
    right = np.degrees(np.arctan2(samples.normals[:, 1], samples.normals[:, 0]))
    return np.stack([(right + 180.0) % 360.0, right % 360.0], axis=1)


def beyond_image(borders: np.ndarray, image: np.ndarray) -> np.ndarray:
    """``(N, 2)``: how far (px) borders reach out beyond the photograph's, per side."""
    return np.stack([image[:, 0] - borders[:, 0], borders[:, 1] - image[:, 1]], axis=1)


def summarize(samples: NormalSamples) -> dict[str, float]:
    """The figures the command prints, over the samples where all borders were found."""
    whole = ~(np.isnan(samples.mask).any(axis=1) | np.isnan(samples.image).any(axis=1))
    truth, mask, image = samples.truth[whole], samples.mask[whole], samples.image[whole]
    summary = {"samples": float(whole.sum())}
    if not whole.any():
        return summary
    offset = image.mean(axis=1) - truth.mean(axis=1)
    summary |= {
        "width truth": float(np.median(truth[:, 1] - truth[:, 0])),
        "width mask": float(np.median(mask[:, 1] - mask[:, 0])),
        "width image": float(np.median(image[:, 1] - image[:, 0])),
        "offset p10": float(np.percentile(offset, 10)),
        "offset median": float(np.median(offset)),
        "offset p90": float(np.percentile(offset, 90)),
        "mask~truth": float(interval_dice(mask, truth).mean()),
        "image~truth": float(interval_dice(image, truth).mean()),
        "mask~image": float(interval_dice(mask, image).mean()),
    }
    facing = facing_angles(samples)[whole].ravel()
    bins = np.round(facing / 45.0).astype(int) % 8
    mask_beyond = beyond_image(mask, image).ravel()
    truth_beyond = beyond_image(truth, image).ravel()
    for index in range(8):
        pick = bins == index
        if pick.any():
            summary[f"mask beyond {45 * index}"] = float(mask_beyond[pick].mean())
            summary[f"truth beyond {45 * index}"] = float(truth_beyond[pick].mean())
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Print the alignment table of one or more data sets (see the module docstring)."""
    from service.evaluation import dataset
    from service.imageio import read_image

    parser = argparse.ArgumentParser(prog="python -m service.evaluation.label_alignment")
    parser.add_argument("datasets", nargs="+")
    parser.add_argument("--mask-from-labels", action="store_true")
    args = parser.parse_args(argv)
    for root in args.datasets:
        items, _ = dataset.find_labelled_images(root)
        for subset in sorted({item.subset for item in items}):
            parts = []
            for item in (item for item in items if item.subset == subset):
                truth = dataset.read_labels(item.labels)
                image = read_image(item.image)
                true_mask = item.mask and dataset.read_mask(item.mask)
                _, result, _ = dataset.evaluate_image(
                    image,
                    truth,
                    mask_from_labels=args.mask_from_labels,
                    truth_mask=true_mask,
                    judge_crossings=False,
                )
                parts.append(
                    normal_samples(image, truth, result.mask, dataset.ignored_pixels(truth))
                )
            merged = NormalSamples(
                *(
                    np.concatenate([getattr(p, f.name) for p in parts])
                    for f in fields(NormalSamples)
                )
            )
            summary = summarize(merged)
            print(f"{root} {subset}")
            for key, value in summary.items():
                print(f"  {key:18s} {value:8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

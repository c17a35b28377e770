"""The ground truth a synthetic scene comes with (public dataclasses).

Coordinates are pixels as ``[x, y]`` with pixel centres at integer positions (the OpenCV
convention): ``image[row, col]`` is centred on ``x = col, y = row``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class SyntheticCable:
    """Ground truth for one cable.

    Attributes
    ----------
    centreline : ndarray, shape (N, 2), float64
        ``[x, y]`` samples at most 1 px apart along the whole in-image cable, hidden
        stretches included, from one end to the other.
    radius : float
        Half the cable width in px.
    colour : tuple of int
        Base BGR colour (the drawn cable is shaded around it).
    hidden : ndarray, shape (N,), bool
        True for centreline samples covered by an occluder. Being under another cable at a
        crossing does not count as hidden.
    depth : int
        Drawing order: cables are drawn in increasing depth, so higher is on top.
    """

    centreline: np.ndarray
    radius: float
    colour: tuple[int, int, int]
    hidden: np.ndarray
    depth: int


@dataclass(frozen=True, eq=False)
class SyntheticCrossing:
    """A place where two centrelines cross, or where a loop crosses its own cable.

    Attributes
    ----------
    x, y : float
        Where the centrelines intersect (px).
    over, under : int
        Indices into :attr:`SyntheticScene.cables` of the cable on top and the one below.
        They are equal for a self-crossing loop, where the part further along the
        centreline (larger arc length) lies on top.
    over_arc, under_arc : float
        Arc length (px from the first centreline sample) of the crossing along the ``over``
        and the ``under`` cable. For a self-crossing ``over_arc > under_arc``.
    """

    x: float
    y: float
    over: int
    under: int
    over_arc: float = math.nan
    under_arc: float = math.nan


@dataclass(frozen=True, eq=False)
class Occluder:
    """An object lying on top of the cables, coloured like the background.

    Attributes
    ----------
    polygon : ndarray, shape (K, 2), float64
        ``[x, y]`` vertices in order. A pixel is covered when its centre lies inside.
    """

    polygon: np.ndarray


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """A synthetic image and its exact ground truth.

    Attributes
    ----------
    image : ndarray, shape (H, W, 3), uint8
        The BGR image.
    mask : ndarray, shape (H, W), bool
        Visible cable pixels: what a perfect segmentation returns.
    labels : ndarray, shape (H, W), uint16
        0 for background, ``i + 1`` where cable ``i`` is visible; at a crossing, the cable on
        top.
    cables : list of SyntheticCable
    crossings : list of SyntheticCrossing
    occluders : list of Occluder
    """

    image: np.ndarray
    mask: np.ndarray
    labels: np.ndarray
    cables: list[SyntheticCable]
    crossings: list[SyntheticCrossing]
    occluders: list[Occluder]

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
    """An object lying on top of the cables.

    Attributes
    ----------
    polygon : ndarray, shape (K, 2), float64
        ``[x, y]`` vertices of a convex polygon, in order. A pixel is covered when its
        centre lies inside. It may reach beyond the picture.
    like_background : bool
        Coloured like the background (always, in :func:`make_scene`), or an object of
        another colour.
    """

    polygon: np.ndarray
    like_background: bool = True


@dataclass(frozen=True, eq=False)
class SceneFeature:
    """A structure a scene family placed on purpose, and the values it was drawn with.

    Attributes
    ----------
    kind : str
        ``"loop"`` (a loop crossing itself; values ``bend_radius`` px and
        ``crossing_angle`` degrees), ``"hairpin"`` (a cable doubled back: ``bend_radius``
        px of its tightest bend, ``gap`` px between the strands' surfaces,
        ``parallel_length`` px, ``part_angle`` degrees, and the arc ranges of the two
        strands that run side by side, ``strand_start``-``strand_end`` and
        ``return_start``-``return_end``), ``"shallow_crossing"`` (``angle`` degrees, at
        ``x``, ``y``), ``"side_by_side"`` (``gap`` px between the two cables' surfaces,
        ``length`` px, along arcs ``start``-``end`` of the first cable and
        ``partner_start``-``partner_end`` of the second) or ``"occluder"``
        (``hidden_length`` px, and 0/1 flags ``on_bend``, ``at_edge``,
        ``like_background``). Arcs are px from the cable's first centreline sample.
    cables : tuple of int
        Indices into :attr:`SyntheticScene.cables` of the cables involved.
    values : dict of str to float
    """

    kind: str
    cables: tuple[int, ...]
    values: dict[str, float]


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
    features : tuple of SceneFeature
        What a scene family placed on purpose (empty for :func:`make_scene`).
    backdrop : str
        The background's kind: ``"dark-textured"``, ``"dark-plain"``, ``"paper"`` or
        ``"painted"``.
    """

    image: np.ndarray
    mask: np.ndarray
    labels: np.ndarray
    cables: list[SyntheticCable]
    crossings: list[SyntheticCrossing]
    occluders: list[Occluder]
    features: tuple[SceneFeature, ...] = ()
    backdrop: str = "dark-textured"

"""End extension: the free ends of each merged chain pushed out to where the cable ends.

Thinning stops about one radius short of a square-cut cable end, and farther short of
a thin cable's tip; a grasp at "the end" should still be on the cable. So each free end
is moved along its direction to where the mask stops, or, when that is farther, toward
the farthest pixel of the cable ahead, and then one radius back inside. A cable that
runs out of the picture does not end there: its chain goes to the edge. The walk along
the direction goes as far as the mask does, not a few radii: thinning can leave a long
straight stretch without skeleton (Zhang-Suen removes a diagonal line two pixels thick,
so a 45-degree tip thins away back to where the cable bends), and a cable's short end
past a crossing loses its piece to spur removal, its chain stopping at the crossing,
where the other cable's strands reach as far into the cone ahead as its own and the
farthest rim's middle lay between them. An extension that stops inside the cable (the
walk leaving a curving cable through its side, or the rim search at its limit) goes on
from its new tip, a few times at most. Extensions lie on the mask, so they are seen
cable, not inferred.
"""

from __future__ import annotations

import numpy as np

from service.perception import _end_extension_kernels
from service.perception.skeleton import as_uint8

# At most this many extensions of a free end, each from where the last one stopped.
END_EXTENSION_ROUNDS = 3
# How far ahead of a free chain end (in radii) and within which angle of its direction
# the cable's farthest pixel is looked for.
TIP_SEARCH_RADII = 5.0
TIP_SEARCH_COS = float(np.cos(np.radians(35.0)))
# The pixels this close (px) to the farthest distance ahead make the cable's far rim.
FAR_RIM_PX = 2.0


def extend_end(
    points: np.ndarray, at_start: bool, mask: np.ndarray, radius: float, span: float
) -> np.ndarray:
    """One end of a polyline pushed out to where the cable ends in the mask, less one radius.

    Parameters
    ----------
    points : ndarray
        ``(N, 2)`` polyline, ``[x, y]`` in pixels.
    at_start : bool
        Extend the end at ``points[0]`` (else the one at ``points[-1]``).
    mask : ndarray of bool
        The foreground mask.
    radius : float
        Cable half width in pixels.
    span : float
        Arc length over which the end's direction is fitted.

    Returns
    -------
    ndarray
        ``points`` with one new vertex at that end, or ``points`` itself when the end
        would move by less than a pixel.
    """
    # Compiled (_end_extension_kernels.extended_tip); the plain version is the reference
    # in tests/perception/references/end_extension.py.
    moved, x, y = _end_extension_kernels.extended_tip(
        np.ascontiguousarray(points, np.float64),
        bool(at_start),
        as_uint8(mask),
        float(radius),
        float(span),
        TIP_SEARCH_RADII * radius + 2.0,
        TIP_SEARCH_COS,
        FAR_RIM_PX,
    )
    if not moved:
        return points
    new_tip = np.array([x, y])
    return np.vstack([new_tip, points]) if at_start else np.vstack([points, new_tip])


def extend_ends(
    vertices: np.ndarray, filled: np.ndarray, mask: np.ndarray, radius: float, span: float
) -> tuple[np.ndarray, np.ndarray]:
    """Both ends of a merged path extended, each up to :data:`END_EXTENSION_ROUNDS` times.

    An extension that ends at its search limit still inside the cable (a thin cable
    whose skeleton stopped several widths short of its tip) goes on from its new tip;
    once at the end it adds nothing and the rounds stop.

    Parameters
    ----------
    vertices : ndarray
        ``(N, 2)`` dense polyline of the path.
    filled : ndarray of bool
        ``(N - 1,)`` per-edge flags of edges drawn across gaps.
    mask : ndarray of bool
    radius : float
        Cable half width in pixels.
    span : float
        Arc length over which each end's direction is fitted.

    Returns
    -------
    vertices, filled : ndarray
        The extended polyline and its flags; the new edges are not filled (they lie on
        the mask).
    """
    for at_start in (True, False):
        for _ in range(END_EXTENSION_ROUNDS):
            extended = extend_end(vertices, at_start, mask, radius, span)
            added = len(extended) - len(vertices)
            if added == 0:
                break
            flags = np.zeros(added, bool)
            filled = np.concatenate([flags, filled] if at_start else [filled, flags])
            vertices = extended
    return vertices, filled

"""Plain thinning, branch counts, spur removal and radius estimate (step 2)."""

import cv2
import numpy as np

from service.perception.skeleton import _BRANCH_COUNT

# The 8 neighbours in the order of the branch-count bits: clockwise from east, (row, col).
NEIGHBOUR_OFFSETS = ((0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1))


_ZS_RING = ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1), (-1, -1))


def _ring(image, row, col):
    """The values of P2..P9 round (row, col); outside the image is 0."""
    height, width = image.shape
    return [
        int(0 <= row + dr < height and 0 <= col + dc < width and image[row + dr, col + dc])
        for dr, dc in _ZS_RING
    ]


def _zhang_suen_removes(ring, first):
    north, east, south, west = ring[0], ring[2], ring[4], ring[6]
    steps = sum(1 for k in range(8) if not ring[k] and ring[(k + 1) % 8])
    if not (2 <= sum(ring) <= 6 and steps == 1):
        return False
    if first:
        return not (north and east and south) and not (east and south and west)
    return not (north and east and west) and not (north and south and west)


def _staircase_removes(ring):
    north, east, south, west = ring[0], ring[2], ring[4], ring[6]
    if sum(ring) < 2 or (north and east and south and west):
        return False
    if not ((north and east) or (east and south) or (south and west) or (west and north)):
        return False
    # The set neighbours must be one 8-connected group: label the 3x3 patch.
    patch = np.zeros((3, 3), np.uint8)
    for value, (dr, dc) in zip(ring, _ZS_RING, strict=True):
        patch[1 + dr, 1 + dc] = value
    return cv2.connectedComponents(patch, connectivity=8)[0] - 1 == 1


def thin(mask):
    """Zhang-Suen sub-iterations on the whole image, then the raster staircase pass."""
    image = (np.asarray(mask) != 0).astype(np.uint8)
    rows, cols = np.nonzero(image)
    quiet, first = 0, True
    while quiet < 2:
        rows, cols = np.nonzero(image)
        doomed = [
            (r, c)
            for r, c in zip(rows, cols, strict=True)
            if _zhang_suen_removes(_ring(image, r, c), first)
        ]
        for r, c in doomed:
            image[r, c] = 0
        quiet = 0 if doomed else quiet + 1
        first = not first
    for r, c in zip(*np.nonzero(image), strict=True):
        if image[r, c] and _staircase_removes(_ring(image, r, c)):
            image[r, c] = 0
    return image > 0


def branch_counts(skeleton):
    kernel = np.zeros((3, 3), np.float32)
    for bit, (dr, dc) in enumerate(NEIGHBOUR_OFFSETS):
        kernel[1 + dr, 1 + dc] = 1 << bit
    pattern = cv2.filter2D(
        skeleton.astype(np.uint8), cv2.CV_32F, kernel, borderType=cv2.BORDER_CONSTANT
    ).astype(np.uint8)
    counts = _BRANCH_COUNT[pattern]
    counts[~skeleton] = 0
    return counts


def _next_pixels(skeleton, row, col, visited):
    height, width = skeleton.shape
    found = []
    for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0), (1, 1), (1, -1), (-1, -1), (-1, 1)):
        r, c = row + dr, col + dc
        if 0 <= r < height and 0 <= c < width and skeleton[r, c] and (r, c) not in visited:
            found.append((r, c))
    return found


def remove_spurs(skeleton, spur_length, passes=2):
    skeleton = skeleton.copy()
    for _ in range(passes):
        counts = branch_counts(skeleton)
        removed_any = False
        for row, col in np.argwhere(counts == 1):
            if not skeleton[row, col]:
                continue
            path = [(row, col)]
            visited = {(row, col)}
            length = 0.0
            reached_junction = False
            while length <= spur_length:
                row_c, col_c = path[-1]
                candidates = _next_pixels(skeleton, row_c, col_c, visited)
                if not candidates:
                    break
                nxt = candidates[0]
                if counts[nxt] >= 3 or len(candidates) > 2:
                    reached_junction = True
                    break
                length += 1.0 if (nxt[0] == row_c or nxt[1] == col_c) else 1.4142
                path.append(nxt)
                visited.add(nxt)
                for extra in candidates[1:]:
                    if abs(extra[0] - nxt[0]) <= 1 and abs(extra[1] - nxt[1]) <= 1:
                        visited.add(extra)
            if reached_junction and length < spur_length:
                for r, c in path:
                    skeleton[r, c] = False
                removed_any = True
        if not removed_any:
            break
        skeleton = thin(skeleton)
    return skeleton


def estimate_radius(mask, skeleton):
    if not skeleton.any():
        return 0.0
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    return max(float(np.median(distance[skeleton])) - 0.5, 0.5)

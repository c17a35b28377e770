"""``dlo bench --rings``: how detection time grows with the number of cables in view.

The scene is a grid of small bright rings on a dark background, one per 40x40 px cell
(:func:`rings_image`): 10,000 rings make a legal 16-megapixel image (the service takes up
to 40) with as many chains as a picture can reasonably hold. Every ring is one chain, so
a step whose work grows with the square of the number of chains (merging used to cost
every pair of chain ends) shows at once. Timed like the rest of ``dlo bench``: one thread,
the kernels loaded first, ``detect()`` on the image in memory.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

RING_CELL_PX = 40
"""Each ring sits in a square cell this wide: 10,000 rings make 4000x4000 px."""
RING_RADIUS_PX = 12
RING_WIDTH_PX = 4
RING_JITTER_PX = 3
"""Each ring's centre is moved up to this much from its cell's centre (seeded)."""
DEFAULT_RING_COUNTS = (1_000, 4_000, 10_000)


def rings_image(count: int, seed: int = 0) -> np.ndarray:
    """A BGR image of ``count`` rings in a near-square grid of 40x40 px cells.

    Parameters
    ----------
    count : int
        Number of rings (at least 1).
    seed : int
        Seed of the centres' jitter.

    Returns
    -------
    ndarray
        ``(rows * 40, columns * 40, 3)`` ``uint8``, with ``columns = ceil(sqrt(count))``.

    Examples
    --------
    >>> rings_image(4).shape
    (80, 80, 3)
    """
    import cv2

    if count < 1:
        raise ValueError(f"count must be at least 1, not {count}")
    columns = math.ceil(math.sqrt(count))
    rows = math.ceil(count / columns)
    image = np.full((rows * RING_CELL_PX, columns * RING_CELL_PX, 3), 25, np.uint8)
    jitter = np.random.default_rng(seed).integers(
        -RING_JITTER_PX, RING_JITTER_PX + 1, size=(count, 2)
    )
    for index in range(count):
        row, column = divmod(index, columns)
        centre = (
            column * RING_CELL_PX + RING_CELL_PX // 2 + int(jitter[index, 0]),
            row * RING_CELL_PX + RING_CELL_PX // 2 + int(jitter[index, 1]),
        )
        cv2.circle(image, centre, RING_RADIUS_PX, (200, 200, 200), RING_WIDTH_PX, cv2.LINE_AA)
    return image


def run_rings_bench(counts: Sequence[int], repeats: int, as_json: bool) -> int:
    """Time ``detect`` on :func:`rings_image` of each count; print a table (or JSON).

    Runs in the one-thread child process of ``dlo bench``; returns its exit status.
    """
    import resource
    import sys

    import cv2
    import numba

    from schemas import DetectParams
    from service.console import load_kernels, stderr_console
    from service.perception import detect

    # The brightness path, as when these figures were first measured: the scene is about
    # merging thousands of chains, and `auto` sends a picture this full of bright rings to
    # the slower cable-contrast segmentation.
    params = DetectParams(segmentation="brightness")

    cv2.setNumThreads(1)
    numba.set_num_threads(1)
    load_kernels(stderr_console())
    rows: list[dict[str, Any]] = []
    for count in counts:
        image = rings_image(count)
        walls, totals, merging = [], [], []
        for _ in range(repeats):
            started = time.perf_counter()
            detection = detect(image, params)
            walls.append((time.perf_counter() - started) * 1000.0)
            totals.append(detection.timings_ms.total)
            merging.append(detection.timings_ms.merging)
        height, width = image.shape[:2]
        rows.append(
            {
                "rings": count,
                "width": width,
                "height": height,
                "megapixels": width * height / 1e6,
                "chains": len(detection.chains),
                "merging_ms": float(np.median(merging)),
                "total_ms": float(np.median(totals)),
                "wall_ms": float(np.median(walls)),
                "repeats": repeats,
            }
        )
        del image, detection
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    peak_mb = peak / (1024.0 * 1024.0 if sys.platform == "darwin" else 1024.0)
    if as_json:
        print(json.dumps({"rings": rows, "peak_rss_mb": peak_mb}, indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(
        title=f"rings: one thread, detect() on the image in memory (median of {repeats} run(s))",
        title_justify="left",
    )
    for column in ("rings", "image", "Mpx", "chains", "merging ms", "total ms", "ms per ring"):
        table.add_column(column, justify="right")
    for row in rows:
        table.add_row(
            f"{row['rings']:,}",
            f"{row['width']}x{row['height']}",
            f"{row['megapixels']:.1f}",
            f"{row['chains']:,}",
            f"{row['merging_ms']:.0f}",
            f"{row['total_ms']:.0f}",
            f"{row['total_ms'] / row['rings']:.2f}",
        )
    console = Console(width=160)
    console.print(table)
    console.print(f"peak resident memory: {peak_mb:.0f} MB", highlight=False)
    return 0

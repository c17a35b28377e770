"""Names and seed ranges of the synthetic test bed, importable without the generator.

``dlo eval --help`` shows them, and importing :mod:`service.synthetic` (OpenCV, SciPy) or
the detector would slow every ``dlo`` command's start; ``tests/service/test_synthetic_families.py``
checks that :data:`FAMILY_NAMES` names exactly :data:`service.synthetic.FAMILIES`.
"""

TUNING_SEEDS = (0, 99_999)
"""Seeds to tune on and to look at failures with (inclusive range)."""

HELD_OUT_FIRST_SEED = 100_000
"""Seeds from here up are held out: run them only to report, never to choose a change."""

FAMILY_NAMES = (
    "baseline",
    "loops",
    "doubled_back",
    "shallow_crossings",
    "side_by_side",
    "many",
    "occluded",
    "edge",
    "bright",
    "textured",
    "same_colour",
)
"""The scene families of :data:`service.synthetic.FAMILIES`, in table order."""

"""service.numba_start: a ``dlo`` process loads cached kernels without numba's registries,
and nothing else changes: the same detections, and numba still compiles new code.

Each case runs in a fresh interpreter, as a ``dlo`` process starts (in this one numba
is set up already).
"""

from __future__ import annotations

import pytest

from tests.helpers import python_json

DETECTIONS = """
import hashlib, json, sys
import cv2
import numpy as np
LIGHT = sys.argv[1] == "light"
if LIGHT:
    from service.numba_start import load_cached_kernels_lightly
    replaced = load_cached_kernels_lightly()
    assert load_cached_kernels_lightly() == replaced  # a second call changes nothing
from schemas import DetectParams, SegmentationMethod
from service.perception import detect, warm_up
from service.synthetic import make_scene

warm_up()
# Modules only numba's registry refresh imports (a kernel's environment may import others).
registries = any(
    name in sys.modules for name in ("numba.typed.typeddict", "numba.np.polynomial.polynomial_core")
)
scene = make_scene(480, 320, 3, seed=100003, occluders=2)
light_ground = np.full((120, 200, 3), 205, np.uint8)
cv2.line(light_ground, (10, 30), (190, 95), (60, 40, 150), 7)
contrast = DetectParams(segmentation=SegmentationMethod.contrast)
found = [detect(scene.image), detect(None, mask=scene.mask), detect(light_ground, contrast)]
digests = []
for detection in found:
    fields = detection.model_dump(mode="json")
    fields.pop("timings_ms")
    digests.append(hashlib.sha1(json.dumps(fields, sort_keys=True).encode()).hexdigest())

# New code still compiles, registries and all (np.median lowers through numba.np).
from numba import njit
median = njit(lambda values: np.median(values))(np.array([3.0, 1.0, 2.0]))
print(json.dumps({
    "replaced": LIGHT and replaced,
    "registries_before_detecting": registries,
    "chains": [len(detection.chains) for detection in found],
    "digests": digests,
    "median": float(median),
}))
"""


def run_detections(mode: str) -> dict:
    return python_json(DETECTIONS, mode)


@pytest.fixture(scope="module")
def numbas_own_loading() -> dict:
    return run_detections("numba")


def test_kernels_load_without_the_registries_and_detect_the_same(numbas_own_loading):
    light = run_detections("light")
    assert light["replaced"] is True  # this numba's loader is the one the module knows
    assert light["registries_before_detecting"] is False
    assert numbas_own_loading["registries_before_detecting"] is True
    assert all(light["chains"])  # every case found cables: the comparison means something
    assert light["digests"] == numbas_own_loading["digests"]
    assert light["median"] == numbas_own_loading["median"] == 2.0

"""The kernels compiled ahead of time (service.perception._aot, service.build_kernels).

numba's JIT is the reference: every call a detection or the tracker makes to a kernel is
recorded with numba's kernels and replayed on the compiled module, whose results (and the
arrays a kernel writes into) must be identical, bit for bit. A fresh process that uses the
module detects exactly what numba does without importing numba. A missing, stale or broken
build, and a call with argument types it was not compiled for, go to numba.

The module is built by ``make venv`` / ``make test`` (``python -m service.build_kernels``,
about a minute); the tests that need it skip when it is absent or stale, unless
``DLO_TEST_REQUIRE_AOT`` is set (as ``.ci/run`` does).
"""

from __future__ import annotations

import copy
import json
import os
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from service.perception import _aot
from service.perception._aot import KERNEL_SOURCES
from tests.helpers import python_json

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared" / "datasets"


def fresh_build() -> dict:
    manifest, reason = _aot.read_manifest()
    if manifest is None:
        if os.environ.get("DLO_TEST_REQUIRE_AOT"):
            pytest.fail(f"no ahead-of-time build: {reason}")
        pytest.skip(f"no ahead-of-time build: {reason}")
    return manifest


@pytest.fixture(scope="module")
def compiled() -> dict[str, types.ModuleType]:
    """Stand-ins for every kernel module that the build holds (not installed)."""
    manifest = fresh_build()
    library = _aot._load_library(Path(manifest["library_path"]))
    return {
        stem: _aot._stand_in("service.perception", stem, exports, library)
        for stem, exports in manifest["exports"].items()
    }


def scenes():
    """Inputs that take every path: generated families, masks, the HSV and contrast
    segmentations, and the data sets' first photographs when they are here."""
    import cv2

    from schemas import DetectParams, SegmentationMethod
    from service.synthetic import FAMILY_NAMES, make_family_scene, make_scene

    default = DetectParams()
    for family in FAMILY_NAMES:
        scene = make_family_scene(family, 100_001, width=480, height=320)
        yield scene.image, None, default
    scene = make_scene(480, 320, 3, seed=100_002, occluders=2)
    yield scene.image, None, default
    yield None, scene.mask, default
    yield scene.image, scene.mask, DetectParams(colour_weight=0.5)
    hsv = DetectParams(
        segmentation=SegmentationMethod.hsv, hsv_low=(0, 0, 100), hsv_high=(179, 255, 255)
    )
    yield scene.image, None, hsv
    lines = np.full((200, 260, 3), 205, np.uint8)
    cv2.line(lines, (10, 30), (250, 170), (40, 60, 170), 7)
    cv2.line(lines, (20, 180), (240, 20), (150, 40, 40), 5)
    yield lines, None, DetectParams(segmentation=SegmentationMethod.contrast)
    for pattern in ("mbest/S1/images/*.jpg", "ariadne/*/images/*.jpg"):
        for path in sorted(SHARED.glob(pattern))[:1]:
            yield cv2.imread(str(path)), None, default


def record_calls(monkeypatch: pytest.MonkeyPatch, modules: dict[str, types.ModuleType]):
    """Wrap numba's kernels that the build compiled: each call's arguments (copied
    before the call), result and arguments after it."""
    calls: list[tuple[str, str, tuple, object, tuple]] = []
    for stem, module in modules.items():
        jit = _aot.jit_module(stem)
        for name in vars(module):
            if name.startswith("_"):
                continue
            kernel = getattr(jit, name)

            def recorder(*args, _kernel=kernel, _stem=stem, _name=name):
                before = copy.deepcopy(args)
                result = _kernel(*args)
                calls.append((_stem, _name, before, copy.deepcopy(result), copy.deepcopy(args)))
                return result

            monkeypatch.setattr(jit, name, recorder)
    return calls


def assert_identical(actual, expected, where: str) -> None:
    if isinstance(expected, tuple | list):
        assert type(actual) is type(expected) and len(actual) == len(expected), where
        for a, e in zip(actual, expected, strict=True):
            assert_identical(a, e, where)
    elif isinstance(expected, np.ndarray):
        assert isinstance(actual, np.ndarray), where
        assert actual.dtype == expected.dtype and actual.shape == expected.shape, where
        assert actual.tobytes() == expected.tobytes(), where  # bit for bit, NaNs included
    else:
        assert type(actual) is type(expected), where
        both_nan = isinstance(expected, float) and expected != expected and actual != actual
        assert both_nan or actual == expected, where


def test_every_call_of_a_detection_and_the_tracker_gives_numbas_result(
    compiled, monkeypatch: pytest.MonkeyPatch
):
    from service.perception import Tracker, detect_full
    from service.synthetic import make_video

    calls = record_calls(monkeypatch, compiled)
    for image, mask, params in scenes():
        detect_full(image, params, mask)
    tracker = Tracker()
    for frame in make_video(100_003, "crossings", n_frames=6).frames():
        tracker.update(frame.image, timestamp_s=frame.timestamp_s)
    monkeypatch.undo()
    called = {(stem, name) for stem, name, *_ in calls}
    assert len(called) >= 30, sorted(called)
    fallbacks = dict(_aot.FALLBACKS)
    for stem, name, before, result, after in calls:
        arguments = copy.deepcopy(before)
        assert_identical(getattr(compiled[stem], name)(*arguments), result, f"{stem}.{name}")
        assert_identical(arguments, after, f"{stem}.{name} (arguments written)")
    assert fallbacks == _aot.FALLBACKS, "a call had argument types the build lacks"


DETECT_AND_DUMP = """
import hashlib, json, sys
from service.perception import _aot, detect, warm_up
from service.synthetic import FAMILY_NAMES, make_family_scene
warm_up()
digests = []
for family in FAMILY_NAMES:
    scene = make_family_scene(family, 100_004, width=480, height=320)
    for detection in (detect(scene.image), detect(None, mask=scene.mask)):
        text = detection.model_dump_json(exclude={"timings_ms"})
        digests.append(hashlib.sha1(text.encode()).hexdigest())
from service.perception import compiled_ahead_of_time
print(json.dumps({"status": _aot.status(), "numba": "numba" in sys.modules,
                  "covers": compiled_ahead_of_time() and compiled_ahead_of_time("tracking"),
                  "llvmlite": "llvmlite" in sys.modules, "fallbacks": _aot.FALLBACKS,
                  "digests": digests}))
"""


def run_fresh(kernels: str) -> dict:
    return python_json(DETECT_AND_DUMP, env={**os.environ, "DLO_KERNELS": kernels})


def test_a_fresh_process_detects_as_numba_does_without_importing_numba():
    fresh_build()
    compiled, jit = run_fresh("auto"), run_fresh("jit")
    assert compiled["status"] == "aot" and compiled["covers"]
    assert not compiled["numba"] and not compiled["llvmlite"]
    assert compiled["fallbacks"] == {}
    assert jit["status"] == "jit: DLO_KERNELS=jit" and jit["numba"]
    assert compiled["digests"] == jit["digests"]


def test_arguments_of_other_types_go_to_numba_unconverted(compiled):
    from service.perception import _pruning_kernels as jit_pruning

    chain_lengths = compiled["_pruning_kernels"].chain_lengths
    rng = np.random.default_rng(100_005)
    joints = rng.uniform(0.0, 50.0, (12, 2))
    ends = np.array([5, 12], np.int64)
    label = "_pruning_kernels.chain_lengths"
    before = _aot.FALLBACKS.get(label, 0)
    exact = chain_lengths(joints, ends)
    assert _aot.FALLBACKS.get(label, 0) == before  # the compiled signature
    assert_identical(exact, jit_pruning.chain_lengths(joints, ends), label)
    wide = np.zeros((12, 4))
    wide[:, ::2] = joints
    readonly = joints.copy()
    readonly.flags.writeable = False
    others = [
        (wide[:, ::2], ends),  # every other column: not contiguous
        (np.asfortranarray(joints), ends),
        (readonly, ends),
        (joints, ends.astype(np.int32)),
    ]
    for arguments in others:
        assert_identical(chain_lengths(*arguments), exact, label)
    assert _aot.FALLBACKS[label] == before + len(others)


FALL_BACK_IN_AN_AOT_PROCESS = """
import json, sys
import numpy as np
import service.perception
from service.perception import _aot, _pruning_kernels, _shared_kernels
joints = np.arange(24.0).reshape(12, 2) ** 1.5
ends = np.array([5, 12], np.int64)
compiled = _pruning_kernels.chain_lengths(joints, ends)
before = "numba" in sys.modules
other = _pruning_kernels.chain_lengths(np.asfortranarray(joints), ends)  # numba's kernel
jit = _aot.jit_module("_pruning_kernels")
print(json.dumps({
    "status": _aot.status(), "numba_before": before, "numba_after": "numba" in sys.modules,
    "same": compiled.tobytes() == other.tobytes(), "fallbacks": _aot.FALLBACKS,
    "stand_ins_kept": sys.modules["service.perception._pruning_kernels"] is _pruning_kernels
        and service.perception._pruning_kernels is _pruning_kernels,
    "jit_is_numba": type(jit.chain_lengths).__name__ == "CPUDispatcher",
    "jit_imports_numba_kernels": type(jit.pairwise_sum).__name__ == "CPUDispatcher",
    "ring": _shared_kernels.RING_DR.tolist(),
}))
"""


def test_in_a_process_on_the_build_a_call_it_lacks_loads_numbas_kernels():
    fresh_build()
    result = python_json(FALL_BACK_IN_AN_AOT_PROCESS, env={**os.environ, "DLO_KERNELS": "auto"})
    assert result["status"] == "aot" and not result["numba_before"] and result["numba_after"]
    assert result["same"] and result["fallbacks"] == {"_pruning_kernels.chain_lengths": 1}
    assert result["stand_ins_kept"] and result["jit_is_numba"]
    assert result["jit_imports_numba_kernels"]
    assert result["ring"] == [0, 1, 1, 1, 0, -1, -1, -1]  # a constant, from numba's module


@pytest.fixture
def no_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The manifests are looked for in an empty folder."""
    monkeypatch.setattr(_aot, "manifest_paths", lambda: [tmp_path / _aot.MANIFEST_NAME])
    monkeypatch.setattr(_aot, "_state", {"status": "", "modules": {}, "manifest": None})
    monkeypatch.delenv(_aot.ENVIRONMENT, raising=False)
    return tmp_path / _aot.MANIFEST_NAME


def install_into_a_new_package() -> types.ModuleType:
    package = types.ModuleType("aot_test_package")
    _aot.install(package)
    return package


def test_a_missing_build_leaves_numbas_kernels(no_build: Path):
    package = install_into_a_new_package()
    assert _aot.status().startswith("jit: not built")
    assert not _aot.active() and not _aot.covers("detection")
    assert not [name for name in sys.modules if name.startswith("aot_test_package.")]
    assert not hasattr(package, "_merging_kernels")


def test_a_build_from_other_kernel_sources_is_stale(no_build: Path, tmp_path: Path, monkeypatch):
    no_build.write_text(json.dumps({"key": _aot.source_key(), "library": "none.so"}))
    assert _aot.read_manifest()[0] is not None
    edited = []
    for path in KERNEL_SOURCES:
        copy_path = tmp_path / path.name
        copy_path.write_bytes(path.read_bytes() + (b"# an edit\n" if not edited else b""))
        edited.append(copy_path)
    monkeypatch.setattr(_aot, "KERNEL_SOURCES", tuple(edited))
    install_into_a_new_package()
    assert _aot.status().startswith("jit: stale")
    assert not _aot.active()


def test_a_build_that_does_not_load_leaves_numbas_kernels(no_build: Path, tmp_path: Path):
    broken = tmp_path / f"broken{_aot.library_suffix()}"
    broken.write_bytes(b"not a shared object")
    no_build.write_text(
        json.dumps({"key": _aot.source_key(), "library": broken.name, "exports": {}})
    )
    package = install_into_a_new_package()
    assert _aot.status().startswith("jit: the compiled module did not load")
    assert not _aot.active()
    assert not [name for name in vars(package) if name.endswith("_kernels")]


def test_dlo_kernels_jit_turns_the_build_off(no_build: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv(_aot.ENVIRONMENT, "jit")
    install_into_a_new_package()
    assert _aot.status() == "jit: DLO_KERNELS=jit"

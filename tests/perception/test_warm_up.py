"""warm_up and kernels_cached: every kernel loaded before the first image, and the stamp.

What warm_up guarantees is checked, not how long it takes (speed lives in ``dlo bench``):
after it every kernel a step calls has machine code for the argument types the
pipeline uses, so that a detection compiles nothing; and kernels_cached turns true.
"""

import ast
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from numba.core.dispatcher import Dispatcher

import service.perception
from service.perception import _aot, _kernel_cache, kernels_cached, warm_up
from service.perception.tracking_warm_up import warm_up_tracking

PACKAGE = Path(service.perception.__file__).parent
KERNEL_FILES = sorted(PACKAGE.glob("_*_kernels.py"))
STEP_FILES = sorted(set(PACKAGE.glob("*.py")) - set(KERNEL_FILES))
ROOT = PACKAGE.parents[1]


def kernel_module(path: Path):
    return __import__(f"service.perception.{path.stem}", fromlist=["_"])


def dispatchers(path: Path) -> dict[str, Dispatcher]:
    module = kernel_module(path)
    return {
        name: value
        for name, value in vars(module).items()
        if isinstance(value, Dispatcher) and value.__module__ == module.__name__
    }


def kernels_the_steps_call() -> set[tuple[str, str]]:
    return _aot.kernels_the_steps_call()


def test_the_kernel_files_are_found_and_the_cache_key_covers_them_all():
    assert len(KERNEL_FILES) >= 9
    assert tuple(KERNEL_FILES) == _kernel_cache.KERNEL_SOURCES


@pytest.mark.parametrize("path", KERNEL_FILES, ids=lambda path: path.stem)
def test_kernel_modules_import_only_numpy_numba_and_other_kernel_modules(path):
    allowed = re.compile(r"(__future__|numpy|numba|service\.perception\._\w+_kernels)$")
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            assert all(allowed.match(alias.name) for alias in node.names), path.name
        elif isinstance(node, ast.ImportFrom):
            assert allowed.match(node.module or ""), f"{path.name} imports {node.module}"


def test_every_kernel_is_called_by_a_step_or_by_another_kernel():
    sources = "\n".join(path.read_text() for path in [*KERNEL_FILES, *STEP_FILES])
    called = kernels_the_steps_call()
    for path in KERNEL_FILES:
        for name in dispatchers(path):
            calls = len(re.findall(rf"\b{name}\(", sources)) - 1  # less its own def
            assert calls > 0 or (path.stem, name) in called, f"{path.stem}.{name} is never called"


def test_warm_up_compiles_every_kernel_the_steps_call():
    called = kernels_the_steps_call()
    assert len(called) >= 20
    warm_up()
    warm_up_tracking()  # the tracker's set (service.console.KERNEL_SETS)
    for module_name, name in sorted(called):
        kernel = getattr(kernel_module(PACKAGE / f"{module_name}.py"), name)
        assert isinstance(kernel, Dispatcher), f"{module_name}.{name} is not a kernel"
        assert kernel.signatures, f"warm_up left {module_name}.{name} uncompiled"


FRESH_PROCESS = """
import json
import cv2
import numpy as np
from numba.core.dispatcher import Dispatcher
from schemas import DetectParams, SegmentationMethod
from service.perception import _kernel_cache, detect, kernels_cached, warm_up
from service.synthetic import make_scene

def signatures():
    counts = {}
    for path in _kernel_cache.KERNEL_SOURCES:
        module = __import__(f"service.perception.{path.stem}", fromlist=["_"])
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher):
                counts[f"{path.stem}.{name}"] = len(value.signatures)
    return counts

kernels_cached()
loaded_by_the_check = [name for name, count in signatures().items() if count]
warm_up()
before = signatures()
scene = make_scene(480, 320, 3, seed=7, occluders=2)
detect(scene.image)
detect(None, mask=scene.mask)
detect(scene.image, mask=scene.mask)
hsv = DetectParams(
    segmentation=SegmentationMethod.hsv, hsv_low=(0, 0, 100), hsv_high=(179, 255, 255)
)
detect(scene.image, hsv)
red_on_grey = np.full((100, 160, 3), 200, np.uint8)
cv2.line(red_on_grey, (10, 50), (150, 50), (40, 40, 210), 9)
detect(red_on_grey)
after = signatures()
print(json.dumps({
    "loaded_by_the_check": loaded_by_the_check,
    "compiled_by_a_detection": [name for name in after if after[name] != before[name]],
    "cached": kernels_cached(),
}))
"""


def test_in_a_fresh_process_a_detection_after_warm_up_compiles_nothing():
    # A fresh interpreter: no kernel is loaded until warm_up, as on a user's first run.
    result = subprocess.run(
        [sys.executable, "-c", FRESH_PROCESS],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["loaded_by_the_check"] == []  # kernels_cached loads no kernel
    # Images, masks, both, the HSV and the colourfulness paths: nothing new to compile.
    assert report["compiled_by_a_detection"] == []
    assert report["cached"] is True


@pytest.fixture
def own_stamp(tmp_path, monkeypatch):
    """The stamp in a temporary directory, keyed on copies of the kernel sources."""
    copies = []
    for path in _kernel_cache.KERNEL_SOURCES:
        copies.append(tmp_path / path.name)
        shutil.copy2(path, copies[-1])
    monkeypatch.setattr(_kernel_cache, "KERNEL_SOURCES", tuple(copies))
    monkeypatch.setattr(
        _kernel_cache,
        "stamp_path",
        lambda group=_kernel_cache.DETECTION: tmp_path / "stamp" / f"kernels-{group}",
    )
    return tmp_path


def test_kernels_cached_turns_true_after_warm_up(own_stamp):
    assert not kernels_cached()
    warm_up()
    assert kernels_cached()
    stamp = json.loads((own_stamp / "stamp" / "kernels-detection").read_text())
    assert stamp["key"] == _kernel_cache.kernels_key()


def test_kernels_cached_turns_false_when_a_kernel_source_changes(own_stamp):
    warm_up()
    assert kernels_cached()
    source = own_stamp / "_merging_kernels.py"
    source.write_text(source.read_text() + "\n# an edit\n")
    assert not kernels_cached()
    warm_up()  # compiles the edited kernels (here: loads the real ones) and stamps again
    assert kernels_cached()


def test_kernels_cached_turns_false_when_numbas_cache_is_gone(own_stamp):
    warm_up()
    stamp_file = own_stamp / "stamp" / "kernels-detection"
    stamp = json.loads(stamp_file.read_text())
    empty = own_stamp / "empty-cache"
    empty.mkdir()
    stamp_file.write_text(json.dumps({**stamp, "numba_cache": str(empty)}))
    assert not kernels_cached()
    stamp_file.write_text("not json")
    assert not kernels_cached()


def test_a_kernel_file_the_detector_never_loads_needs_no_index_nor_its_warm_up(
    own_stamp, monkeypatch
):
    """Kernels with a warm-up of their own (a tracker's, say): a one-image ``dlo detect``
    neither loads them nor takes their missing machine code for a first run."""
    others = own_stamp / "_elsewhere_kernels.py"
    others.write_text("from numba import njit\n")
    monkeypatch.setattr(_kernel_cache, "KERNEL_SOURCES", (*_kernel_cache.KERNEL_SOURCES, others))
    warm_up()
    assert kernels_cached()  # the detector's group, though _elsewhere has no index
    stamp = json.loads((own_stamp / "stamp" / "kernels-detection").read_text())
    assert "_elsewhere_kernels" not in stamp["files"]
    assert {path.stem for path in KERNEL_FILES} <= set(stamp["files"])
    assert not kernels_cached("elsewhere")  # its warm-up has not run
    assert _kernel_cache.write_stamp(stamp["numba_cache"], group="elsewhere")
    assert kernels_cached("elsewhere") and kernels_cached()
    others.write_text("from numba import njit\n# an edit\n")
    assert not kernels_cached() and not kernels_cached("elsewhere")


def test_an_unwritable_stamp_is_no_error(tmp_path, monkeypatch):
    blocker = tmp_path / "a file"
    blocker.write_text("")
    monkeypatch.setattr(_kernel_cache, "stamp_path", lambda group="detection": blocker / group)
    assert _kernel_cache.write_stamp(str(tmp_path)) is False
    warm_up()
    assert not kernels_cached()


@pytest.mark.parametrize("path", KERNEL_FILES, ids=lambda path: path.stem)
def test_no_kernel_needs_blas_or_lapack(path: Path):
    """`dlo` tells numba not to probe for BLAS (service.numba_start.skip_numba_blas_probe):
    that holds only while no kernel multiplies matrices or calls np.linalg."""
    for node in ast.walk(ast.parse(path.read_text())):
        assert not (isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult)), path
        if isinstance(node, ast.Attribute):
            assert node.attr not in {"linalg", "dot", "matmul", "vdot", "inner", "outer"}, (
                f"{path.name}:{node.lineno} uses np.{node.attr}"
            )


def test_a_dlo_process_loads_the_kernels_without_scipy():
    """With the probe skipped, warm-up and a detection never import scipy.linalg."""
    script = (
        "import sys\n"
        "from service.numba_start import skip_numba_blas_probe\n"
        "skip_numba_blas_probe()\n"
        "import numpy as np\n"
        "from service.perception import detect, warm_up\n"
        "warm_up()\n"
        "image = np.zeros((120, 160, 3), np.uint8)\n"
        "image[50:60, 10:150] = 255\n"
        "assert len(detect(image).chains) == 1\n"
        "print('scipy.linalg' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, check=True
    )
    assert result.stdout.strip() == "False"

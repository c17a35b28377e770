"""Kernels compiled ahead of time: the same kernel functions, loaded without numba.

A process that only detects a few images spends most of its start importing numba and
loading the JIT-compiled kernels from numba's cache (about 0.6 s of a one-image ``dlo
detect``). ``python -m service.build_kernels`` (run by ``make venv``, the Dockerfile and a
``dlo`` front end's first run) compiles every kernel the warm-ups call, with the argument
types they call it with, into one extension module by ``numba.pycc``: the machine code of
the very same ``_<step>_kernels.py`` functions, which imports in about a millisecond and
needs no numba at run time.

When this package is imported, :func:`install` looks for that module. If it is there and
built from these kernel sources (a hash of their text recorded at build time), this Python
and this numba, each kernel module (``service.perception._merging_kernels`` ...) is
replaced by a stand-in whose kernels call the compiled module: the step modules, which
call ``_merging_kernels.join_cost(...)``, run the compiled code without a change.
Otherwise, or with ``DLO_KERNELS=jit`` in the environment, nothing is replaced and numba
compiles (or loads) the kernels as before: the JIT is the fallback and the reference.

Each stand-in kernel checks its arguments against the types the module was compiled for,
exactly as numba would type them (the dtype, the number of dimensions, C/F/any layout,
writeable and aligned for an array; Python or NumPy ``float``/``int``/``bool`` for a
scalar). A call that does not match is not converted: it goes to the numba-compiled kernel
(numba imported then, once), as does any kernel or attribute the module does not hold.
Such calls are counted in :data:`FALLBACKS`, so that tests can check that a detection makes
none.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import json
import os
import platform
import sys
import threading
import types
from importlib.machinery import EXTENSION_SUFFIXES, ExtensionFileLoader
from pathlib import Path
from typing import Any

import numpy as np

PACKAGE_DIR = Path(__file__).resolve().parent
KERNEL_SOURCES = tuple(sorted(PACKAGE_DIR.glob("_*_kernels.py")))
"""The kernel files, whose text the compiled module must match (and numba's cache too)."""
ENVIRONMENT = "DLO_KERNELS"
"""``jit`` in the environment: never use the compiled module (numba's JIT, as before it)."""
MODULE_NAME = "dlo_kernels_aot"
"""The extension module's own name (its ``PyInit_`` function)."""
MANIFEST_NAME = "dlo-kernels-aot.json"
FORMAT = 2
"""The manifest's layout (2: with the kernel modules' constants); a manifest of another layout
is stale."""

FALLBACKS: dict[str, int] = {}
"""``"module.kernel"`` -> how many calls went to numba because the compiled module had no
code for their argument types (or for the kernel), in this process."""

_state: dict[str, Any] = {"status": "not installed", "modules": {}, "manifest": None}
_jit_lock = threading.RLock()
_jit_modules: dict[str, types.ModuleType] = {}

# numpy's ndarray.flags.num bits (C_CONTIGUOUS, F_CONTIGUOUS, ALIGNED, WRITEABLE).
_C, _F, _ALIGNED, _WRITEABLE = 0x1, 0x2, 0x100, 0x400


def cpu_description() -> str:
    """The CPU's model name and feature flags (the first processor's), or the machine."""
    found = []
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as cpuinfo:
            for line in cpuinfo:
                if line.startswith(("model name", "flags", "Features")):
                    found.append(line.partition(":")[2].strip())
                elif not line.strip() and found:
                    break
    except OSError:
        pass
    return "|".join(found) or platform.processor() or platform.machine()


def numba_version_text() -> str:
    """numba's version file as text, found without importing numba ("" when absent)."""
    try:
        spec = importlib.util.find_spec("numba")
    except (ImportError, ValueError):
        return ""
    if spec is None or not spec.origin:
        return ""
    try:
        return (Path(spec.origin).parent / "_version.py").read_text(encoding="utf-8")
    except OSError:
        return ""


def source_key() -> str:
    """A hash of what the compiled module must match: the kernel sources' text, this
    Python and NumPy (whose C API the module uses), this numba (its version file) and
    this CPU (model and feature flags: the module is compiled for the CPU it is built on,
    as numba's JIT compiles). Reads about 100 kB; imports nothing."""
    digest = hashlib.sha256()
    for path in KERNEL_SOURCES:
        digest.update(f"{path.name}\0".encode())
        digest.update(path.read_bytes())
        digest.update(b"\0")
    python = f"{sys.implementation.cache_tag}\0{sys.platform}\0numpy {np.__version__}"
    digest.update(f"{FORMAT}\0{python}\0".encode())
    digest.update(cpu_description().encode())
    digest.update(numba_version_text().encode())
    return digest.hexdigest()


def kernels_the_steps_call() -> set[tuple[str, str]]:
    """``(kernel module, kernel)`` for every ``_<step>_kernels.name`` that a module of
    the perception package other than a kernel module reads (read from the sources)."""
    import ast
    import re

    found = set()
    for path in sorted(PACKAGE_DIR.glob("*.py")):
        if path in KERNEL_SOURCES:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and re.fullmatch(r"_\w+_kernels", node.value.id)
            ):
                found.add((node.value.id, node.attr))
    return found


def manifest_paths() -> list[Path]:
    """Where a build's manifest may be, in the order they are read: the package's
    ``__pycache__`` (beside numba's cache of the kernels), then the user's cache."""
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    package = hashlib.sha1(str(PACKAGE_DIR).encode()).hexdigest()[:16]
    return [
        PACKAGE_DIR / "__pycache__" / MANIFEST_NAME,
        user_cache / "dlo-service" / f"{package}-{MANIFEST_NAME}",
    ]


def build_manifest_path() -> Path:
    """Where a build writes: the first of :func:`manifest_paths` that can be written."""
    in_tree = PACKAGE_DIR / "__pycache__"
    if os.access(in_tree, os.W_OK) or (not in_tree.exists() and os.access(PACKAGE_DIR, os.W_OK)):
        return manifest_paths()[0]
    return manifest_paths()[1]


def library_suffix() -> str:
    """The file ending of an extension module for this Python (``.cpython-311-...so``)."""
    return EXTENSION_SUFFIXES[0]


def read_manifest() -> tuple[dict[str, Any] | None, str]:
    """The first manifest built from these sources, or None and why there is none."""
    key = source_key()
    reason = "not built (python -m service.build_kernels)"
    for path in manifest_paths():
        try:
            manifest = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if not isinstance(manifest, dict) or manifest.get("key") != key:
            reason = f"stale: built from other kernel sources, Python, NumPy, numba or CPU ({path})"
            continue
        manifest["library_path"] = str(path.parent / str(manifest.get("library", "")))
        return manifest, ""
    return None, reason


def status() -> str:
    """``"aot"`` when the compiled module is in use, else ``"jit: <why>"``."""
    return str(_state["status"])


def active() -> bool:
    """Do the kernel modules of this process run the compiled module?"""
    return _state["status"] == "aot"


def covers(group: str = "detection") -> bool:
    """Does the compiled module in use hold the kernels of warm-up ``group`` (a name of
    ``service.console.KERNEL_SETS``; the detector's by default)?"""
    manifest = _state["manifest"]
    return active() and manifest is not None and group in manifest.get("groups", [])


def install(package: types.ModuleType) -> str:
    """Replace the kernel modules of ``package`` by stand-ins on the compiled module, when
    it is there, fresh and imports; call before any step module is imported. Returns
    :func:`status`. Any failure leaves numba's kernels in place."""
    if os.environ.get(ENVIRONMENT, "").strip().lower() == "jit":
        _state["status"] = f"jit: {ENVIRONMENT}=jit"
        return status()
    manifest, reason = read_manifest()
    if manifest is None:
        _state["status"] = f"jit: {reason}"
        return status()
    try:
        library = _load_library(Path(manifest["library_path"]))
        # Every kernel module, those without compiled kernels too: numba's kernel modules
        # must never import a stand-in's kernels (see jit_module).
        stand_ins = {
            path.stem: _stand_in(
                package.__name__,
                path.stem,
                manifest["exports"].get(path.stem, {}),
                library,
                manifest.get("constants", {}).get(path.stem, {}),
            )
            for path in KERNEL_SOURCES
        }
    except Exception as error:
        _state["status"] = f"jit: the compiled module did not load ({error})"
        return status()
    for stem, module in stand_ins.items():
        sys.modules[f"{package.__name__}.{stem}"] = module
        setattr(package, stem, module)
    _state.update(status="aot", modules=stand_ins, manifest=manifest)
    return status()


def _load_library(path: Path) -> types.ModuleType:
    name = f"{__package__}.{MODULE_NAME}"
    loader = ExtensionFileLoader(name, str(path))
    spec = importlib.util.spec_from_file_location(name, str(path), loader=loader)
    if spec is None:
        raise ImportError(f"no extension module at {path}")
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def jit_module(stem: str) -> types.ModuleType:
    """The numba kernel module ``stem`` (``"_merging_kernels"``), even while its stand-in
    is installed: imported on first use, with its kernel imports numba's too."""
    package_name = __package__ or "service.perception"
    with _jit_lock:
        if stem in _jit_modules:
            return _jit_modules[stem]
        if not active():
            return importlib.import_module(f"{package_name}.{stem}")
        package = sys.modules[package_name]
        stand_ins: dict[str, types.ModuleType] = _state["modules"]
        # Import the kernel files with their own names free, so that the kernels they
        # import from each other are numba's, then put the stand-ins back.
        for name in stand_ins:
            sys.modules.pop(f"{package_name}.{name}", None)
        try:
            for path in KERNEL_SOURCES:
                _jit_modules[path.stem] = importlib.import_module(f"{package_name}.{path.stem}")
        finally:
            for path in KERNEL_SOURCES:
                full = f"{package_name}.{path.stem}"
                if path.stem in stand_ins:
                    sys.modules[full] = stand_ins[path.stem]
                    setattr(package, path.stem, stand_ins[path.stem])
        return _jit_modules[stem]


def _stand_in(
    package: str,
    stem: str,
    exports: dict[str, list[dict[str, Any]]],
    library: types.ModuleType,
    constants: dict[str, Any] | None = None,
) -> types.ModuleType:
    """A module named like kernel module ``stem`` whose exported kernels call ``library``,
    holding the module's plain numeric ``constants`` as recorded at build time."""
    module = types.ModuleType(f"{package}.{stem}", f"{stem}, compiled ahead of time.")
    module.__file__ = str(PACKAGE_DIR / f"{stem}.py")
    module.__package__ = package

    def __getattr__(name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        value = getattr(jit_module(stem), name)
        if callable(value):
            return _counted(f"{stem}.{name}", value)
        return value

    module.__getattr__ = __getattr__  # type: ignore[method-assign]
    for name, value in (constants or {}).items():
        setattr(module, name, value)
    for name, signatures in exports.items():
        setattr(module, name, _checked_kernel(stem, name, signatures, library))
    return module


def _counted(label: str, kernel: Any) -> Any:
    def call(*args: Any) -> Any:
        FALLBACKS[label] = FALLBACKS.get(label, 0) + 1
        return kernel(*args)

    call.__name__ = label.rpartition(".")[2]
    return call


_SCALARS = {
    "float64": "(type({a}) is float or type({a}) is _np.float64)",
    "int64": "((type({a}) is int and -9223372036854775808 <= {a} <= 9223372036854775807)"
    " or type({a}) is _np.int64)",
    "bool": "(type({a}) is bool or type({a}) is _np.bool_)",
}


def _check(argument: str, spec: dict[str, Any], namespace: dict[str, Any]) -> str:
    """Python source of a test that ``argument`` is what numba would type as ``spec``
    (constants it needs go into ``namespace``)."""
    if spec["kind"] == "array":
        layout = spec["layout"]
        mask = (_C if layout == "C" else _C | _F) | _ALIGNED | _WRITEABLE
        want = {"C": _C, "F": _F, "A": 0}[layout]
        want |= (_ALIGNED if spec["aligned"] else 0) | (_WRITEABLE if spec["mutable"] else 0)
        dtype = f"_dtype{len(namespace)}"
        namespace[dtype] = np.dtype(spec["dtype"])
        return (
            f"(type({argument}) is _np.ndarray and {argument}.ndim == {int(spec['ndim'])}"
            f" and ({argument}.dtype is {dtype} or {argument}.dtype == {dtype})"
            f" and {argument}.flags.num & {mask} == {want})"
        )
    if spec["kind"] == "scalar" and spec["type"] in _SCALARS:
        return _SCALARS[spec["type"]].format(a=argument)
    if spec["kind"] == "scalar":
        return f"type({argument}) is _np.{spec['type']}"
    raise ValueError(f"no check for {spec}")


def _checked_kernel(
    stem: str, name: str, signatures: list[dict[str, Any]], library: types.ModuleType
) -> Any:
    """A function that calls the compiled kernel whose signature its arguments match,
    else numba's kernel."""
    label = f"{stem}.{name}"
    arity = {len(signature["args"]) for signature in signatures}
    if len(arity) != 1:
        raise ValueError(f"{label}: signatures of different lengths")
    arguments = [f"a{index}" for index in range(arity.pop())]
    namespace: dict[str, Any] = {"_np": np, "_fallback": _fallback(stem, name)}
    lines = [f"def {name}({', '.join(arguments)}):"]
    for index, signature in enumerate(signatures):
        namespace[f"_compiled{index}"] = getattr(library, signature["symbol"])
        tests = " and ".join(
            _check(argument, spec, namespace)
            for argument, spec in zip(arguments, signature["args"], strict=True)
        )
        lines.append(f"    if {tests or 'True'}:")
        lines.append(f"        return _compiled{index}({', '.join(arguments)})")
    lines.append(f"    return _fallback({', '.join(arguments)})")
    exec(compile("\n".join(lines), f"<compiled kernel {label}>", "exec"), namespace)
    kernel = namespace[name]
    kernel.__qualname__ = name
    kernel.__module__ = f"{__package__}.{stem}"
    kernel.compiled_signatures = [signature["text"] for signature in signatures]
    return kernel


def _fallback(stem: str, name: str) -> Any:
    label = f"{stem}.{name}"

    def call(*args: Any) -> Any:
        FALLBACKS[label] = FALLBACKS.get(label, 0) + 1
        return getattr(jit_module(stem), name)(*args)

    return call

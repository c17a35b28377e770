"""Compile the perception kernels ahead of time: ``python -m service.build_kernels``.

Runs every warm-up of :data:`service.console.KERNEL_SETS` with numba's JIT (compiling the
kernels into numba's cache on a machine's first run), takes each kernel's argument types
from what the warm-ups called it with, and compiles those same kernel functions with
``numba.pycc`` into one extension module beside numba's cache (the package's
``__pycache__``, else the user's cache). A manifest records the hash of the kernel sources
it was built from and, per kernel, the compiled signatures; :mod:`service.perception._aot`
reads it when the package is imported. Needs a C and C++ compiler and Python's headers
(gcc, g++ and python3-dev on Debian), at build time only.

The machine code is for this CPU, with the features numba's JIT would use (LLVM's host
CPU name and feature list), and releases the GIL as the kernels' ``nogil=True`` does:
the same code as numba's JIT, which keeps detections bit-identical (pycc's default, the
architecture's generic CPU, made the kernels of a photograph about 25 % slower). The
manifest's key holds the CPU's model and flags, so that another CPU runs numba's kernels.

Only what a step calls is compiled (each ``_<step>_kernels.name`` in the package's other
modules), with the argument types the warm-ups gave it (array, float, int and bool
arguments); kernels that only other kernels call are compiled into their callers. A signature
with other argument types (a tuple, a list, ``None``) stays with numba and is listed in
the manifest under ``kept_jit``; a call with it then goes to numba's kernel.

Exit status 0 when built (or already fresh, unless ``--force``), 1 when the build failed:
the kernels then run on numba's JIT as before.
"""

from __future__ import annotations

import os

# This process compiles with numba: its kernel modules must be numba's, not the stand-ins
# of an earlier build (set before service.perception is imported).
os.environ["DLO_KERNELS"] = "jit"

import argparse
import contextlib
import json
import shutil
import sys
import tempfile
import time
from importlib import import_module
from pathlib import Path
from typing import Any

from service.console import KERNEL_SETS
from service.perception import _aot


def _argument_spec(argument: Any) -> dict[str, Any] | None:
    """How :mod:`service.perception._aot` checks an argument of numba type ``argument``
    (None: a type it does not check, kept on numba)."""
    from numba.core import types
    from numba.np.numpy_support import as_dtype

    if isinstance(argument, types.Array):
        return {
            "kind": "array",
            "dtype": str(as_dtype(argument.dtype)),
            "ndim": argument.ndim,
            "layout": argument.layout,
            "mutable": argument.mutable,
            "aligned": argument.aligned,
        }
    if isinstance(argument, types.Literal):
        return None
    if isinstance(argument, types.Boolean):
        return {"kind": "scalar", "type": "bool"}
    if isinstance(argument, types.Integer | types.Float):
        return {"kind": "scalar", "type": str(argument)}
    return None


def collect() -> tuple[dict[str, dict[str, list[Any]]], list[str]]:
    """After the warm-ups: per kernel module, each kernel a step calls, with the numba
    signatures to compile (those the warm-ups gave it); and the signatures left to numba.
    A kernel that only other kernels call is compiled into its callers."""
    from numba.core.dispatcher import Dispatcher

    exports: dict[str, dict[str, list[Any]]] = {}
    kept: list[str] = []
    for stem, name in sorted(_aot.kernels_the_steps_call()):
        kernel = getattr(sys.modules.get(f"service.perception.{stem}"), name, None)
        if not isinstance(kernel, Dispatcher) or not kernel.signatures:
            kept.append(f"{stem}.{name}: no warm-up calls it")
            continue
        for signature in kernel.nopython_signatures:
            specs = [_argument_spec(argument) for argument in signature.args]
            if all(specs):
                exports.setdefault(stem, {}).setdefault(name, []).append((signature, specs))
            else:
                kept.append(f"{stem}.{name}{signature}")
    return exports, kept


def _flags_releasing_the_gil() -> Any:
    """pycc's compile flags, releasing the GIL as the kernels' ``nogil=True`` does."""
    from numba.core.compiler import Flags

    flags = Flags()
    flags.release_gil = True
    return flags


def _host_features(codegen: Any) -> str:
    """The CPU features numba's JIT compiles for (this CPU's own, as LLVM reads them):
    pycc would take only those of the CPU model's name, which a virtual machine may
    not all have."""
    return codegen._get_host_cpu_features()


def build(force: bool = False, quiet: bool = False) -> Path | None:
    """Build the module unless a fresh one is there; returns its manifest's path."""
    manifest_path = _aot.build_manifest_path()
    key = _aot.source_key()
    if not force:
        existing, _ = _aot.read_manifest()
        if existing is not None:
            with contextlib.suppress(OSError):
                manifest_path.touch()  # newer than the sources, for make
            return manifest_path

    def say(message: str) -> None:
        if not quiet:
            print(message, file=sys.stderr, flush=True)

    started = time.perf_counter()
    for name, target in KERNEL_SETS.items():
        module, _, function = target.partition(":")
        say(f"build_kernels: warm-up {name} (numba's JIT)")
        getattr(import_module(module), function)()
    exports, kept = collect()

    import warnings

    from numba.core.codegen import AOTCPUCodegen
    from numba.core.errors import NumbaPendingDeprecationWarning

    with warnings.catch_warnings():
        # pycc is pending deprecation (since numba 0.57) with no replacement released yet:
        # known, and the JIT stays the fallback should a numba drop it.
        warnings.simplefilter("ignore", NumbaPendingDeprecationWarning)
        import numba.pycc.compiler
        from numba.pycc import CC

    cc = CC(_aot.MODULE_NAME, source_module=__name__)
    cc.target_cpu = "host"
    manifest_exports: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for stem, kernels in exports.items():
        for name, signatures in kernels.items():
            for index, (signature, specs) in enumerate(signatures):
                symbol = f"{stem}__{name}__{index}"
                cc.export(symbol, signature)(
                    getattr(sys.modules[f"service.perception.{stem}"], name).py_func
                )
                manifest_exports.setdefault(stem, {}).setdefault(name, []).append(
                    {"symbol": symbol, "text": str(signature), "args": specs}
                )
    count = sum(
        len(signatures) for kernels in manifest_exports.values() for signatures in kernels.values()
    )
    say(f"build_kernels: compiling {count} kernel signatures ahead of time (about a minute)")
    manifest_path.parent.mkdir(parents=True, exist_ok=True)
    library = f"{manifest_path.stem}-{key[:16]}-{os.getpid()}{_aot.library_suffix()}"
    build_dir = Path(tempfile.mkdtemp(prefix="dlo-kernels-", dir=manifest_path.parent))
    original_flags = numba.pycc.compiler.Flags
    numba.pycc.compiler.Flags = _flags_releasing_the_gil  # type: ignore[assignment,misc]
    original_features = AOTCPUCodegen._customize_tm_features
    AOTCPUCodegen._customize_tm_features = _host_features  # type: ignore[method-assign]
    try:
        cc.output_dir = str(build_dir)
        cc.compile()
        os.replace(build_dir / cc.output_file, manifest_path.parent / library)
    finally:
        numba.pycc.compiler.Flags = original_flags  # type: ignore[misc]
        AOTCPUCodegen._customize_tm_features = original_features  # type: ignore[method-assign]
        shutil.rmtree(build_dir, ignore_errors=True)
    manifest = {
        "key": key,
        "format": _aot.FORMAT,
        "library": library,
        "cpu": _aot.cpu_description(),
        "groups": sorted(KERNEL_SETS),
        "exports": manifest_exports,
        "constants": _kernel_constants(),
        "kept_jit": kept,
        "seconds": round(time.perf_counter() - started, 1),
    }
    partial = manifest_path.with_name(f"{manifest_path.name}.{os.getpid()}.tmp")
    partial.write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    os.replace(partial, manifest_path)
    _remove_older_libraries(manifest_path.parent, library)
    say(f"build_kernels: {manifest_path.parent / library} ({manifest['seconds']} s)")
    return manifest_path


def _kernel_constants() -> dict[str, dict[str, int | float | bool]]:
    """Per kernel module, its plain numeric constants (upper-case module names bound to an
    ``int``, ``float`` or ``bool``): the stand-ins hold them, so that a step module that
    imports one (``from ._merging_kernels import MIN_BEND_RADII``) does not import numba."""
    constants: dict[str, dict[str, int | float | bool]] = {}
    for path in _aot.KERNEL_SOURCES:
        module = import_module(f"service.perception.{path.stem}")
        constants[path.stem] = {
            name: value
            for name, value in vars(module).items()
            if name.isupper() and type(value) in (int, float, bool)
        }
    return constants


def _remove_older_libraries(directory: Path, keep: str) -> None:
    """Delete the libraries of earlier builds (a process that loaded one keeps its copy)."""
    for path in directory.glob(f"{Path(_aot.MANIFEST_NAME).stem}-*{_aot.library_suffix()}"):
        if path.name != keep:
            path.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m service.build_kernels", description=__doc__.splitlines()[0]
    )
    parser.add_argument(
        "--force", action="store_true", help="build even when a fresh build is there"
    )
    parser.add_argument("--quiet", action="store_true", help="say nothing on success")
    arguments = parser.parse_args(argv)
    try:
        build(force=arguments.force, quiet=arguments.quiet)
    except Exception as error:
        print(f"build_kernels: not built, numba's JIT stays in use: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Whether numba's cache on this machine holds the compiled kernels: a stamp file.

numba compiles a kernel (``cache=True``) on its first call in a process unless its cache
holds machine code for this source file, this numba and this CPU. Compiling every kernel
of the perception core takes tens of seconds; loading them from the cache, a fraction of
a second. :func:`service.perception.warm_up` writes a stamp once every kernel is in the
cache; :func:`kernels_cached` compares it with this machine and this source, without
loading any kernel, so that a front end can say before its first detection that this
run is about to compile.

The stamp holds a key (a hash of the kernel source files with their modification times
and sizes, which numba also checks, the numba version, the Python version and the CPU),
the directory numba caches the kernels in and the kernel files whose kernels the warm-up
loaded. It lives in that directory when it is the package's ``__pycache__`` (so that
deleting the cache deletes the stamp), else in the user's cache directory.

Each set of kernels warmed up together has a stamp of its own (``group``): the
detector's (:data:`DETECTION`, written by :func:`service.perception.warm_up`) and any
other that a front end loads only when it needs it (a tracker's, say), so that a
one-image ``dlo detect`` neither loads such kernels nor takes their absence for a first
run. Any kernel file's change clears every stamp (a kernel may call any other file's).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import sys
from pathlib import Path

from service.perception import _aot
from service.perception._aot import KERNEL_SOURCES, PACKAGE_DIR

STAMP_NAME = "dlo-kernels.stamp"
DETECTION = "detection"
"""The group of the detector's kernels, those :func:`service.perception.warm_up` loads."""
# numba's own settings that change the machine code or where it is cached.
_NUMBA_SETTINGS = ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES", "NUMBA_CACHE_DIR", "NUMBA_OPT")


def kernels_key() -> str:
    """A hash of what numba's cached machine code depends on, for this source and machine."""
    digest = hashlib.sha256()
    for path in KERNEL_SOURCES:
        stat = path.stat()
        digest.update(f"{path.name}\0{stat.st_mtime}\0{stat.st_size}\0".encode())
        digest.update(path.read_bytes())
    # Already imported by the kernel modules (this loads no kernel).
    import numba

    parts = [
        numba.__version__,
        sys.implementation.cache_tag or "",
        platform.machine(),
        _aot.cpu_description(),
        *(os.environ.get(name, "") for name in _NUMBA_SETTINGS),
    ]
    digest.update("\0".join(parts).encode())
    return digest.hexdigest()


def stamp_path(group: str = DETECTION) -> Path:
    """Where the stamp of ``group`` is: the package's ``__pycache__`` when writable, else
    the user cache."""
    name = STAMP_NAME if group == DETECTION else f"dlo-kernels-{group}.stamp"
    in_tree = PACKAGE_DIR / "__pycache__"
    if os.access(in_tree, os.W_OK) or (not in_tree.exists() and os.access(PACKAGE_DIR, os.W_OK)):
        return in_tree / name
    user_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    package = hashlib.sha1(str(PACKAGE_DIR).encode()).hexdigest()[:16]
    return user_cache / "dlo-service" / f"{package}-{name}"


def _has_every_index(cache_dir: str, stems: list[str]) -> bool:
    """Does ``cache_dir`` hold a numba index file for every kernel file in ``stems``?"""
    try:
        names = os.listdir(cache_dir)
    except OSError:
        return False
    indexed = {name.partition(".")[0] for name in names if name.endswith(".nbi")}
    return all(stem in indexed for stem in stems)


def loaded_kernel_files() -> list[str]:
    """The kernel files (stems) of which this process holds machine code for a kernel."""
    from numba.core.dispatcher import Dispatcher

    loaded = []
    for path in KERNEL_SOURCES:
        module = sys.modules.get(f"{__package__}.{path.stem}")
        kernels = vars(module).values() if module is not None else ()
        if any(isinstance(kernel, Dispatcher) and kernel.signatures for kernel in kernels):
            loaded.append(path.stem)
    return loaded


def kernels_cached(group: str = DETECTION) -> bool:
    """Are the kernels of this source compiled into numba's cache on this machine?

    True when a previous :func:`service.perception.warm_up` (for another ``group``, the
    warm-up of that group) compiled its kernels from these very source files with this
    numba on this CPU, and numba's cache still holds them: the next warm-up (or first
    detection) loads machine code instead of compiling it. Reads the stamp and the
    kernel source files (well under a millisecond here) and loads no kernel.

    Examples
    --------
    >>> import sys
    >>> from service.perception import kernels_cached, warm_up
    >>> if not kernels_cached():
    ...     print("compiling the detection kernels (once per machine) ...", file=sys.stderr)
    >>> warm_up()

    True, too, when the kernels of ``group`` run compiled ahead of time
    (:mod:`service.perception._aot`): nothing is left to compile or load.
    """
    if _aot.covers(group):
        return True
    try:
        stamp = json.loads(stamp_path(group).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if not isinstance(stamp, dict) or stamp.get("key") != kernels_key():
        return False
    files = stamp.get("files", [path.stem for path in KERNEL_SOURCES])
    if not isinstance(files, list) or not all(isinstance(stem, str) for stem in files):
        return False
    return _has_every_index(str(stamp.get("numba_cache", "")), files)


def write_stamp(numba_cache: str, group: str = DETECTION) -> bool:
    """Record that the kernels of ``group``, all those this process has loaded now, are
    compiled into ``numba_cache`` (numba's directory). Call it at the end of the group's
    warm-up.

    Returns False, and leaves no stamp, when it cannot be written (a read-only install).
    """
    path = stamp_path(group)
    text = json.dumps(
        {"key": kernels_key(), "numba_cache": str(numba_cache), "files": loaded_kernel_files()}
    )
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial.write_text(text, encoding="utf-8")
        os.replace(partial, path)
    except OSError:
        with contextlib.suppress(OSError):
            partial.unlink(missing_ok=True)
        return False
    return True

"""How a ``dlo`` process starts numba: only what loading cached kernels needs.

A one-image ``dlo detect`` spends more time getting numba ready than detecting. Two
things numba does on its first kernel are of no use to a process that only loads machine
code from the cache, and the command line (never the library) leaves them out:

- :func:`skip_numba_blas_probe`: numba looks for a BLAS library by importing all of
  ``scipy.linalg`` (about 0.2 s); the detector's kernels need neither BLAS nor LAPACK.
- :func:`load_cached_kernels_lightly`: before it loads a cached kernel numba imports and
  installs every typing and lowering registry it has (``numba.np.arraymath``,
  ``numba.typed`` ...; about 0.15 s), which only compiling uses. Loading machine code
  needs numba's runtime alone. Should a kernel not be in the cache, numba's own loader
  runs, and compiling installs the registries itself.

Both are checked by tests (tests/service/test_numba_start.py,
tests/perception/test_warm_up.py) against the numba installed: a numba whose internals
differ keeps its own behaviour, only slower to start.
"""

from __future__ import annotations

import sys
from typing import Any


def skip_numba_blas_probe() -> None:
    """Tell numba, in this ``dlo`` process, not to look for a BLAS library.

    The first time numba compiles or loads a kernel it imports its array-maths support,
    which probes for BLAS by importing all of ``scipy.linalg``: about 0.2 s of a one-image
    ``dlo detect``. The detector's kernels use neither BLAS nor LAPACK (a test in
    tests/perception/test_warm_up.py reads their sources to keep it so), so the probe only
    costs time. Only the CLI does this, never the library: a program that imports
    ``service.perception`` may compile numba code of its own that needs BLAS. A numba
    whose internals differ keeps its probe.
    """
    if "numba.np.arraymath" in sys.modules:  # too late: numba has probed already
        return
    try:
        from numba.np import linalg
    except ImportError:
        return

    def no_blas() -> None:
        raise ImportError("BLAS not probed: the dlo kernels need none")

    if hasattr(linalg, "ensure_blas"):
        linalg.ensure_blas = no_blas


def load_cached_kernels_lightly() -> bool:
    """Load kernels from numba's cache without first installing numba's registries.

    numba's loader (``Cache.load_overload``) refreshes the target context before it
    reads the cache: on the first kernel of a process that imports a few hundred
    modules of numba's typing and lowering support (about 0.15 s of a one-image
    ``dlo detect``), none of which loading machine code uses. After this call a cached
    kernel is loaded with numba's runtime (NRT) initialised and nothing else; a kernel
    the cache lacks goes to numba's own loader, and compiling it refreshes the context
    as numba always does. The machine code, and so every result, is the same.

    Returns whether the loader was replaced (False for a numba whose internals differ,
    which keeps its own loader). Calling it again changes nothing.
    """
    try:
        from numba.core.caching import Cache
        from numba.core.runtime import nrt
    except ImportError:
        return False
    numba_loader = Cache.load_overload
    if getattr(numba_loader, "dlo_light", False):
        return True
    if not (hasattr(Cache, "_load_overload") and hasattr(nrt.rtsys, "initialize")):
        return False

    def load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        nrt.rtsys.initialize(target_context)  # loaded kernels allocate through NRT
        try:
            loaded = self._load_overload(sig, target_context)
        except OSError:  # numba's loader knows which of these to tolerate
            loaded = None
        if loaded is None:  # not cached (or stale): numba's loader, then it compiles
            return numba_loader(self, sig, target_context)
        return loaded

    load_overload.dlo_light = True  # type: ignore[attr-defined]
    load_overload.__doc__ = numba_loader.__doc__
    Cache.load_overload = load_overload
    return True

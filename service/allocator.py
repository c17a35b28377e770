"""How a ``dlo`` process asks the C allocator to keep the memory a detection frees.

A detection of a photograph allocates, and frees again, a few megabytes of image-sized
scratch arrays (the distance transform, the skeleton and its copies, the spur walk's
marks, the segmentation's masks). With glibc's default settings the freed memory at the
top of the heap may be handed back to the kernel at the end of every frame (``brk``
down), so that the next frame gets it again as fresh pages, each zeroed by a page fault:
800 to 1,200 faults per mbest photograph in a process where that happens, 2 to 5 ms of a
frame on a busy virtual machine. Whether it happens depends on what the process
allocated before (glibc adapts its thresholds to the blocks it has freed). Raising
glibc's trim and ``mmap`` thresholds keeps that memory in the process in every case, so
later frames reuse it without faults. The results do not change: only where the memory
comes from.

glibc adapts both thresholds by itself, upwards, but only when it frees a block it had
mapped on its own (a block larger than the current ``mmap`` threshold), and setting
either one by hand turns that off for both; so both are set, at the values glibc's
adaptation stops at (32 MiB for ``mmap``, twice that for the trim). A process keeps
at most :data:`TRIM_THRESHOLD_BYTES` of free memory at the heap's top, and blocks
above :data:`MMAP_THRESHOLD_BYTES` (a 4K image's float copies) are still mapped and
unmapped on their own.

Only the command line does this (:func:`service.console.load_kernels`, and the HTTP
service's warm-up), never the library: a program that imports ``service.perception``
keeps its own allocator settings.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

# glibc's mallopt() parameters (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 32 * 1024 * 1024
"""Blocks at least this large are mapped on their own (glibc's adaptive maximum)."""
TRIM_THRESHOLD_BYTES = 2 * MMAP_THRESHOLD_BYTES
"""Free memory at the top of the heap beyond this is handed back to the kernel."""

_kept = False


def keep_freed_memory() -> bool:
    """Set glibc's trim and ``mmap`` thresholds so that freed scratch memory is reused.

    Returns whether the thresholds are set (False where the C library is not glibc, or
    glibc refused: the process keeps its allocator's defaults, only slower per frame).
    Calling it again changes nothing.
    """
    global _kept
    if _kept:
        return True
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    _kept = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)
    )
    return _kept

"""service.allocator: a process that keeps freed memory reuses it without page faults.

Each case runs in a fresh interpreter: the allocator's settings are process-wide.
"""

from __future__ import annotations

import platform

import pytest

from tests.helpers import python_json

# Five 3 MB scratch arrays alive at once, then freed, frame after frame: glibc's
# adaptive thresholds (3 MB mapped on its own, 6 MB kept) hand the 15 MB back at the
# end of each frame and fault it in again on the next, as a detection's scratch images did.
FRAMES = """
import json, resource, sys
import numpy as np
if sys.argv[1] == "keep":
    from service.allocator import keep_freed_memory
    assert keep_freed_memory() and keep_freed_memory()  # a second call changes nothing
faults = []
for frame in range(6):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    scratch = [np.ones(3_000_000, np.uint8) for _ in range(5)]
    del scratch
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(json.dumps(faults))
"""

glibc = pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only"
)


@glibc
def test_freed_scratch_memory_is_reused_without_page_faults():
    default = python_json(FRAMES, "default")
    kept = python_json(FRAMES, "keep")
    # 15 MB is about 3,700 pages: most faulted in again every frame by default, once when kept.
    assert min(default[2:]) > 2000
    assert max(kept[2:]) < 100


def test_keep_freed_memory_is_a_no_op_without_glibc(monkeypatch):
    from service import allocator

    monkeypatch.setattr(allocator, "_kept", False)
    monkeypatch.setattr(allocator.platform, "libc_ver", lambda: ("musl", "1.2"))
    assert allocator.keep_freed_memory() is False

"""Settings shared by the whole test session.

Tests only talk over loopback. A service's embedded zenoh peer listens on
tcp/127.0.0.1:7447 by default, which a `make run` or another test run on the machine may
hold: every service the tests start, in this process and in the `dlo` processes they spawn
(which inherit the environment), listens on a free loopback port instead, and multicast
scouting stays off. A test that relies on a configuration file's endpoints passes
``zenoh_listen=None`` (or drops the variable from a child's environment).

The kernels run on numba's JIT, the reference (``DLO_KERNELS=jit``, unless the environment
says otherwise): the tests of warm-up and numba's cache look at numba's kernels, and a
``dlo`` front end's first run in a test must not compile the kernels ahead of time.
tests/perception/test_aot.py compares the ahead-of-time build with them.
"""

import os

os.environ["DLO_ZENOH_MULTICAST"] = "false"
os.environ["DLO_ZENOH_LISTEN"] = "tcp/127.0.0.1:0"
os.environ.setdefault("DLO_KERNELS", "jit")

import sys
from pathlib import Path

# `from tests.helpers import ...` from any test module (pytest runs with --import-mode=importlib).
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

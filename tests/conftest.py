"""Settings shared by the whole test session.

Tests only talk over loopback: zenoh's multicast scouting (on by default for an
embedded peer) would send discovery packets to the local network, so it is switched
off for every service the tests start, in this process and in the `dlo` processes
they spawn (which inherit the environment).
"""

import os

os.environ["DLO_ZENOH_MULTICAST"] = "false"

import sys
from pathlib import Path

# `from tests.helpers import ...` from any test module (pytest runs with --import-mode=importlib).
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

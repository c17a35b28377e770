"""Settings shared by the whole test session.

Tests only talk over loopback. A service's embedded zenoh peer listens on
tcp/127.0.0.1:7447 by default, which a `make run` or another test run on the machine may
hold: every service the tests start, in this process and in the `dlo` processes they spawn
(which inherit the environment), listens on a free loopback port instead, and multicast
scouting stays off. A test that relies on a configuration file's endpoints passes
``zenoh_listen=None`` (or drops the variable from a child's environment).
"""

import os

os.environ["DLO_ZENOH_MULTICAST"] = "false"
os.environ["DLO_ZENOH_LISTEN"] = "tcp/127.0.0.1:0"

import sys
from pathlib import Path

# `from tests.helpers import ...` from any test module (pytest runs with --import-mode=importlib).
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.insert(0, _ROOT)

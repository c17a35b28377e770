"""Settings shared by the whole test session.

Tests only talk over loopback: zenoh's multicast scouting (on by default for an
embedded peer) would send discovery packets to the local network, so it is switched
off for every service the tests start, in this process and in the `dlo` processes
they spawn (which inherit the environment).
"""

import os

os.environ["DLO_ZENOH_MULTICAST"] = "false"

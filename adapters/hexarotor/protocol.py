"""MAVLink 2 through pymavlink, and the autopilot facts both ends of our link need.

Importing this module selects MAVLink 2 (``MAVLINK20``) before pymavlink's ``mavutil``
loads its dialect. The mode numbers are the autopilots' own:

* ArduCopter's flight modes are plain ``custom_mode`` numbers (ArduPilot, "Flight modes"
  and ``mode.h``: STABILIZE 0, GUIDED 4, LOITER 5, RTL 6, LAND 9).
* PX4 packs a main mode in bits 16-23 and a sub mode in bits 24-31 of ``custom_mode``
  (PX4 ``px4_custom_mode.h``: POSCTL 3, AUTO 4 with its sub modes, OFFBOARD 6).
"""

from __future__ import annotations

import os

# MAVLink 2 must be chosen before mavutil is imported, or it loads the v1 dialect.
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # mavutil was imported earlier, without it
    mavutil.set_dialect(mavutil.current_dialect)
mavlink = mavutil.mavlink

POSITION_YAW_TYPE_MASK = 0x09F8
"""``SET_POSITION_TARGET_LOCAL_NED.type_mask`` using position and yaw only (velocity,
acceleration and yaw rate ignored)."""

ARDUPILOT_MODES = {"STABILIZE": 0, "GUIDED": 4, "LOITER": 5, "LAND": 9}
PX4_MAIN_POSCTL, PX4_MAIN_AUTO, PX4_MAIN_OFFBOARD = 3, 4, 6
PX4_SUB_AUTO_LOITER = 3


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4's ``custom_mode``: main mode in bits 16-23, sub mode in bits 24-31."""
    return (main_mode << 16) | (sub_mode << 24)


def px4_main_mode(custom_mode: int) -> int:
    """The main mode of a PX4 ``custom_mode`` (bits 16-23)."""
    return (custom_mode >> 16) & 0xFF

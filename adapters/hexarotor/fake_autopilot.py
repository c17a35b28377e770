"""What the fake vehicle does toward a ground station, flavour by flavour: ArduCopter or PX4.

Each rule below follows the autopilot's own documentation or source, named beside it, so
that a client written against the real autopilot (MAVSDK, a ground station, our adapter)
meets the same answers. The fake keeps one flavour-neutral *behaviour* per mode (follow
setpoints, hold, take off, land, return); :class:`ArduCopterRules` and :class:`PX4Rules`
map modes, commands and refusals onto it.

Sources (ArduPilot: ardupilot.org/copter/docs and ardupilot.org/dev/docs; ArduCopter's
``GCS_Mavlink.cpp``, ``mode.h``, ``takeoff.cpp``. PX4: docs.px4.io user guide
"Offboard Mode" and "Flight Modes"; PX4's ``Commander.cpp`` and ``px4_custom_mode.h``):

* **Mode numbers.** ArduCopter: ``custom_mode`` is the mode number (STABILIZE 0, GUIDED 4,
  LOITER 5, RTL 6, LAND 9; ``mode.h``). PX4: main mode in bits 16-23, sub mode in bits
  24-31 (POSCTL 3, AUTO 4 with TAKEOFF 2, LOITER 3, RTL 5, LAND 6, OFFBOARD 6;
  ``px4_custom_mode.h``). ``MAV_CMD_DO_SET_MODE`` carries them as param2 (and param3, the
  PX4 sub mode) with ``MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`` in param1.
* **Refusals.** ArduCopter answers a mode, arming or takeoff it refuses with
  ``MAV_RESULT_FAILED`` (``GCS_MAVLINK::_set_mode_common`` and the command handlers); PX4's
  commander answers ``MAV_RESULT_TEMPORARILY_REJECTED``. A command neither knows:
  ``MAV_RESULT_UNSUPPORTED``.
* **Guided / offboard.** ArduCopter GUIDED follows ``SET_POSITION_TARGET_LOCAL_NED``
  position targets and keeps flying to the last one when they stop ("Copter Commands in
  Guided Mode"); on the ground it stays there until ``MAV_CMD_NAV_TAKEOFF`` (which needs
  it armed, landed, and a target above; ``Mode::do_user_takeoff``). PX4 OFFBOARD is
  accepted only while a setpoint stream is present (setpoints at more than 2 Hz, so the
  last one younger than 0.5 s), armed or not, and falls back to Hold when the stream has
  been silent for ``COM_OF_LOSS_T`` (1 s here; the failsafe action is configurable on
  PX4, Hold is modelled); a position setpoint above the ground lifts it off.
* **Take-off, land, return.** ``MAV_CMD_NAV_TAKEOFF``: ArduCopter climbs in GUIDED to
  param7 m above home and then holds there as its guided target; PX4 switches to
  AUTO.TAKEOFF, climbs to param7 (AMSL) or, when NaN, ``MIS_TAKEOFF_ALT`` (2.5 m), then
  holds in AUTO.LOITER. ``MAV_CMD_NAV_LAND`` and ``MAV_CMD_NAV_RETURN_TO_LAUNCH`` switch
  to LAND / RTL (ArduCopter) or AUTO.LAND / AUTO.RTL (PX4); landing descends at
  ``LAND_SPEED`` 0.5 m/s (ArduCopter) or ``MPC_LAND_SPEED`` 0.7 m/s (PX4); the return
  flies home at its altitude (at least ``rtl_altitude_m``; the real defaults, 15 m and
  60 m, are for open fields) and lands.
* **Disarming.** Both disarm on their own after touching down in a landing (ArduCopter
  in LAND at once; PX4 after ``COM_DISARM_LAND`` 2 s) and when armed on the ground for 10
  s without taking off (``DISARM_DELAY`` 10 s; ``COM_DISARM_PRFLT`` 10 s).
* **Arming.** Refused in LAND and RTL (ArduCopter's ``allows_arming``); PX4 refuses in
  AUTO.LAND / AUTO.RTL, and in OFFBOARD without a setpoint stream.
* **Home.** Set where the vehicle arms (PX4 ``Commander::set_home_position`` on arming;
  ArduPilot likewise).
"""

from __future__ import annotations

import math
from typing import ClassVar, Literal

from adapters.hexarotor.protocol import (
    ARDUPILOT_MODES,
    PX4_MAIN_AUTO,
    PX4_MAIN_OFFBOARD,
    PX4_MAIN_POSCTL,
    PX4_SUB_AUTO_LOITER,
    mavlink,
    px4_custom_mode,
    px4_main_mode,
)

Autopilot = Literal["ardupilot", "px4"]
Behaviour = Literal["follow", "hold", "takeoff", "land", "rtl", "manual"]

PX4_SUB_AUTO_TAKEOFF, PX4_SUB_AUTO_RTL, PX4_SUB_AUTO_LAND = 2, 5, 6
ARDUPILOT_RTL = 6

STREAM_FRESH_S = 0.5
"""A setpoint stream is present while its last setpoint is younger than this (> 2 Hz)."""
PREFLIGHT_DISARM_S = 10.0
"""Armed on the ground this long without taking off: disarm (DISARM_DELAY / COM_DISARM_PRFLT)."""


class AutopilotRules:
    """The flavour-specific answers; see :class:`ArduCopterRules` and :class:`PX4Rules`."""

    name: Autopilot
    mav_autopilot: int
    refused: int
    """The ``MAV_RESULT`` of a mode, arming or flight command the autopilot refuses."""
    land_speed_m_s: float
    landed_disarm_s: float
    offboard_loss_s: float | None
    """Silence after which following setpoints ends (None: the last target is kept)."""
    takeoff_needed_on_ground: bool
    """Setpoints do not lift the vehicle off; only NAV_TAKEOFF does."""

    def initial_mode(self) -> int:
        raise NotImplementedError

    def behaviour(self, custom_mode: int) -> Behaviour:
        raise NotImplementedError

    def mode_for(self, behaviour: Behaviour) -> int:
        """The mode the autopilot shows while doing ``behaviour`` on its own."""
        raise NotImplementedError

    def requested_mode(self, param2: float, param3: float) -> int | None:
        """The ``custom_mode`` a DO_SET_MODE asks for, or None when it names no mode."""
        raise NotImplementedError

    def after_takeoff(self) -> int:
        """The mode once a NAV_TAKEOFF has reached its altitude."""
        raise NotImplementedError

    def takeoff_altitude_m(self, param7: float, home_alt_m: float, default_m: float) -> float:
        """Height above home a NAV_TAKEOFF climbs to."""
        raise NotImplementedError

    def may_arm(self, custom_mode: int, stream_fresh: bool) -> bool:
        behaviour = self.behaviour(custom_mode)
        if behaviour in ("land", "rtl"):
            return False
        return not (behaviour == "follow" and self.offboard_loss_s is not None and not stream_fresh)

    def may_enter(self, custom_mode: int, stream_fresh: bool) -> bool:
        """Whether a requested mode is accepted now."""
        if self.behaviour(custom_mode) == "follow" and self.offboard_loss_s is not None:
            return stream_fresh
        return True


class ArduCopterRules(AutopilotRules):
    name: Autopilot = "ardupilot"
    mav_autopilot = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    refused = mavlink.MAV_RESULT_FAILED
    land_speed_m_s = 0.5
    landed_disarm_s = 0.0
    offboard_loss_s = None
    takeoff_needed_on_ground = True

    BEHAVIOURS: ClassVar[dict[int, Behaviour]] = {
        ARDUPILOT_MODES["STABILIZE"]: "manual",
        ARDUPILOT_MODES["GUIDED"]: "follow",
        ARDUPILOT_MODES["LOITER"]: "hold",
        ARDUPILOT_RTL: "rtl",
        ARDUPILOT_MODES["LAND"]: "land",
    }

    def initial_mode(self) -> int:
        return ARDUPILOT_MODES["LOITER"]

    def behaviour(self, custom_mode: int) -> Behaviour:
        return self.BEHAVIOURS.get(custom_mode, "hold")

    def mode_for(self, behaviour: Behaviour) -> int:
        return {
            "hold": ARDUPILOT_MODES["LOITER"],
            "land": ARDUPILOT_MODES["LAND"],
            "rtl": ARDUPILOT_RTL,
            "takeoff": ARDUPILOT_MODES["GUIDED"],
            "follow": ARDUPILOT_MODES["GUIDED"],
        }.get(behaviour, ARDUPILOT_MODES["LOITER"])

    def requested_mode(self, param2: float, param3: float) -> int | None:
        mode = int(param2)
        return mode if mode in self.BEHAVIOURS else None

    def after_takeoff(self) -> int:
        return ARDUPILOT_MODES["GUIDED"]

    def takeoff_altitude_m(self, param7: float, home_alt_m: float, default_m: float) -> float:
        return param7 if math.isfinite(param7) else default_m  # relative to home


class PX4Rules(AutopilotRules):
    name: Autopilot = "px4"
    mav_autopilot = mavlink.MAV_AUTOPILOT_PX4
    refused = mavlink.MAV_RESULT_TEMPORARILY_REJECTED
    land_speed_m_s = 0.7
    landed_disarm_s = 2.0
    offboard_loss_s = 1.0
    takeoff_needed_on_ground = False

    SUB_BEHAVIOURS: ClassVar[dict[int, Behaviour]] = {
        PX4_SUB_AUTO_TAKEOFF: "takeoff",
        PX4_SUB_AUTO_LOITER: "hold",
        PX4_SUB_AUTO_RTL: "rtl",
        PX4_SUB_AUTO_LAND: "land",
    }

    def initial_mode(self) -> int:
        return px4_custom_mode(PX4_MAIN_POSCTL)

    def behaviour(self, custom_mode: int) -> Behaviour:
        main = px4_main_mode(custom_mode)
        if main == PX4_MAIN_OFFBOARD:
            return "follow"
        if main == PX4_MAIN_AUTO:
            return self.SUB_BEHAVIOURS.get((custom_mode >> 24) & 0xFF, "hold")
        return "hold"  # POSCTL with centred sticks holds position

    def mode_for(self, behaviour: Behaviour) -> int:
        sub = {
            "takeoff": PX4_SUB_AUTO_TAKEOFF,
            "land": PX4_SUB_AUTO_LAND,
            "rtl": PX4_SUB_AUTO_RTL,
        }.get(behaviour, PX4_SUB_AUTO_LOITER)
        if behaviour == "follow":
            return px4_custom_mode(PX4_MAIN_OFFBOARD)
        return px4_custom_mode(PX4_MAIN_AUTO, sub)

    def requested_mode(self, param2: float, param3: float) -> int | None:
        main, sub = int(param2), int(param3)
        if main in (PX4_MAIN_POSCTL, PX4_MAIN_OFFBOARD):
            return px4_custom_mode(main)
        if main == PX4_MAIN_AUTO and sub in self.SUB_BEHAVIOURS:
            return px4_custom_mode(main, sub)
        return None

    def after_takeoff(self) -> int:
        return px4_custom_mode(PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER)

    def takeoff_altitude_m(self, param7: float, home_alt_m: float, default_m: float) -> float:
        return param7 - home_alt_m if math.isfinite(param7) else default_m  # AMSL


def rules_for(autopilot: str) -> AutopilotRules:
    """The rules of ``"ardupilot"`` or ``"px4"``."""
    if autopilot == "ardupilot":
        return ArduCopterRules()
    if autopilot == "px4":
        return PX4Rules()
    raise ValueError(f"autopilot must be 'ardupilot' or 'px4', got {autopilot!r}")

"""MAVSDK, an independent MAVLink implementation, flies ``dlo hexa fake-vehicle``.

MAVSDK is PX4's own SDK; its Python package ``mavsdk-grpc`` ships ``mavsdk_server``, the
C++ core, in the wheel. Each test starts ``dlo hexa fake-vehicle`` as a separate process
(real time, as SITL runs for a ground station), lets MAVSDK's server listen for it on a
free loopback UDP port, and runs MAVSDK's standard flows: connect, telemetry (position,
battery, landed state, health), arm, position control in offboard (PX4) or guided
(ArduPilot, after a take-off) to a target 1 m away, and land. Every wait is on a
telemetry event; each has a generous limit only so that a broken vehicle fails the test
instead of hanging it.
"""

from __future__ import annotations

import asyncio
import math
import shutil
import subprocess
import sys
from collections.abc import AsyncIterator, Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from adapters.hexarotor.fake_vehicle import DEFAULT_HOME
from tests.helpers import free_port, free_udp_port

mavsdk = pytest.importorskip("mavsdk_grpc", reason="needs MAVSDK (pip install mavsdk-grpc)")
from mavsdk_grpc import System  # noqa: E402
from mavsdk_grpc.offboard import PositionNedYaw  # noqa: E402
from mavsdk_grpc.telemetry import LandedState  # noqa: E402

EVENT_TIMEOUT_S = 60.0
"""Generous for a loaded 2-core machine; every wait ends as soon as its event comes."""
TARGET = (1.0, 0.0, -1.0)
"""The offboard / guided target, local NED: 1 m north, 1 m up."""
REACHED_M = 0.1


def dlo_command() -> list[str]:
    """How to run ``dlo`` from this environment (the console script beside the interpreter)."""
    script = shutil.which("dlo", path=str(Path(sys.executable).parent))
    if script is None:
        pytest.skip("the dlo console script is not installed (pip install -e .)")
    return [script]


@pytest.fixture
def fake_vehicle() -> Iterator[Callable[[str], int]]:
    """Start ``dlo hexa fake-vehicle --autopilot A`` sending to a free port; returns the port."""
    processes: list[subprocess.Popen] = []

    def start(autopilot: str) -> int:
        port = free_udp_port()
        command = [
            *dlo_command(),
            "hexa",
            "fake-vehicle",
            "--url",
            f"udpout:127.0.0.1:{port}",
            "--autopilot",
            autopilot,
            "--seed",
            "5",
        ]
        processes.append(
            subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        )
        return port

    yield start
    for process in processes:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=10)


async def first(stream: AsyncIterator[Any], condition: Callable[[Any], bool] = bool) -> Any:
    """The first item of a MAVSDK telemetry stream that meets ``condition``."""
    async for item in stream:
        if condition(item):
            return item
    raise AssertionError("the stream ended")


async def event(stream: AsyncIterator[Any], condition: Callable[[Any], bool] = bool) -> Any:
    return await asyncio.wait_for(first(stream, condition), EVENT_TIMEOUT_S)


def near(position: Any, target: tuple[float, float, float]) -> bool:
    here = (position.north_m, position.east_m, position.down_m)
    return math.dist(here, target) <= REACHED_M


async def connect(port: int) -> System:
    drone = System(port=free_port())
    await drone.connect(system_address=f"udpin://127.0.0.1:{port}")
    await event(drone.core.connection_state(), lambda state: state.is_connected)
    return drone


async def check_telemetry(drone: System) -> None:
    """Position (local and global), battery, landed state and health, as a GCS reads them."""
    local = await event(drone.telemetry.position_velocity_ned())
    assert math.dist((local.position.north_m, local.position.east_m), (0, 0)) < 0.05
    position = await event(drone.telemetry.position())
    assert position.latitude_deg == pytest.approx(DEFAULT_HOME[0], abs=1e-5)
    assert position.longitude_deg == pytest.approx(DEFAULT_HOME[1], abs=1e-5)
    assert position.relative_altitude_m == pytest.approx(0.0, abs=0.05)
    battery = await event(drone.telemetry.battery())
    assert 90 < battery.remaining_percent <= 100
    assert 16.0 < battery.voltage_v < 17.0  # 4 cells, nearly full
    landed = await event(drone.telemetry.landed_state())
    assert landed == LandedState.ON_GROUND
    health = await event(drone.telemetry.health(), lambda h: h.is_home_position_ok)
    assert health.is_armable and health.is_global_position_ok and health.is_local_position_ok
    assert health.is_gyrometer_calibration_ok and health.is_accelerometer_calibration_ok
    home = await event(drone.telemetry.home())
    assert home.latitude_deg == pytest.approx(DEFAULT_HOME[0], abs=1e-5)


async def arm(drone: System) -> None:
    await drone.action.arm()
    await event(drone.telemetry.armed())


async def go_to_target(drone: System) -> None:
    await drone.offboard.set_position_ned(PositionNedYaw(*TARGET, 0.0))
    await drone.offboard.start()
    await event(drone.telemetry.position_velocity_ned(), lambda p: near(p.position, TARGET))
    await event(drone.telemetry.landed_state(), lambda state: state == LandedState.IN_AIR)


async def land(drone: System) -> None:
    await drone.action.land()
    await event(drone.telemetry.landed_state(), lambda state: state == LandedState.ON_GROUND)
    await event(drone.telemetry.armed(), lambda armed: not armed)  # it disarms on its own


async def px4_flow(port: int) -> None:
    """MAVSDK's offboard example: arm, stream a setpoint, start offboard, fly, land."""
    drone = await connect(port)
    try:
        await check_telemetry(drone)
        await arm(drone)
        await drone.offboard.set_position_ned(PositionNedYaw(0.0, 0.0, 0.0, 0.0))
        await go_to_target(drone)  # PX4 lifts off for a setpoint above the ground
        await land(drone)
    finally:
        drone._stop_mavsdk_server()


async def ardupilot_flow(port: int) -> None:
    """Arm, take off in GUIDED (ArduCopter's way), guided position control, land."""
    drone = await connect(port)
    try:
        await check_telemetry(drone)
        await arm(drone)
        await drone.action.set_takeoff_altitude(1.0)
        await drone.action.takeoff()
        await event(drone.telemetry.position_velocity_ned(), lambda p: p.position.down_m < -0.9)
        await go_to_target(drone)
        await land(drone)
    finally:
        drone._stop_mavsdk_server()


@pytest.mark.parametrize(("autopilot", "flow"), [("px4", px4_flow), ("ardupilot", ardupilot_flow)])
def test_mavsdk_flies_the_fake_vehicle(fake_vehicle, autopilot, flow) -> None:
    asyncio.run(flow(fake_vehicle(autopilot)))

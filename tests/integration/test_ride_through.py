"""Power-loss ride-through (F11.01/F11.02, issue 42) through the wire.

Modbus TCP served in this process, pymodbus as the master, virtual time moved by the test. The drive runs a
load with inertia at 1500 rpm; the supply goes. With ride-through on, the master reads "running, no fault"
and a bus held at the ride-through level (80 % of 48 V) while the speed falls, with no command of its own,
until the rotor's energy is spent; then undervoltage (0x0A) as before. A short dip is ridden through and
the drive runs back up to its set speed. With it off (as shipped) the same loss trips 0x0A in milliseconds.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
from pymodbus.client import AsyncModbusTcpClient

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import FaultCause, load_profile
from c20sim.wire.registers import Reg
from tests.integration.conftest import Link, modbus_tcp_link
from tests.integration.conftest import read_register as read
from tests.integration.conftest import write_register as write

PROFILE = load_profile("c20-400hr")
UV = PROFILE.fault_code(FaultCause.UNDERVOLTAGE)
RIDE_V = 0.8 * PROFILE.supply.voltage_v  # F11.02 = 80 %


@pytest.fixture
async def link() -> AsyncIterator[Link]:
    async with modbus_tcp_link(PROFILE) as pair:
        yield pair


async def running_loaded(sim: Simulator, client: AsyncModbusTcpClient, ride: int) -> None:
    drive = sim.drive(1)
    drive.set_load_inertia(30 * PROFILE.motor.inertia_kg_m2)
    drive.set_load_torque(0.38)  # 30 % of the rated torque
    await write(client, Reg.WRITE_ENABLE, 1)
    await write(client, "F11.01", ride)
    await write(client, Reg.SPEED_SETPOINT, 1500)
    await write(client, Reg.COMMAND, 1)
    sim.advance(5.0)
    assert await read(client, Reg.MOTOR_SPEED) == 1500


async def test_a_lost_supply_is_ridden_through_on_the_loads_energy_then_trips_uv(link: Link) -> None:
    sim, client = link
    await running_loaded(sim, client, 1)
    sim.drive(1).set_supply_voltage(0.0)
    speeds = []
    while await read(client, Reg.FAULT_CODE) == 0:
        sim.advance(0.05)
        if await read(client, Reg.FAULT_CODE):
            break
        assert await read(client, Reg.STATUS1) == 1 and await read(client, Reg.COMMAND) == 1  # running, as told
        bus = await read(client, Reg.BUS_VOLTAGE) / 10
        assert bus >= PROFILE.supply.undervoltage_v
        speeds.append(await read(client, Reg.MOTOR_SPEED))
        if len(speeds) > 2:
            assert bus == pytest.approx(RIDE_V, abs=0.15)  # held at the ride-through level
        assert len(speeds) < 200
    assert await read(client, Reg.FAULT_CODE) == UV
    assert len(speeds) > 40  # over 2 s of riding through, where without it the bus was gone in ms
    assert speeds == sorted(speeds, reverse=True) and speeds[0] > 1400 and speeds[-1] < 300  # slowing down
    assert "ride-through" in sim.drive(1).telemetry().auto_action


async def test_a_short_dip_is_ridden_through_and_the_drive_runs_back_up(link: Link) -> None:
    sim, client = link
    await running_loaded(sim, client, 1)
    drive = sim.drive(1)
    drive.set_supply_voltage(0.0)
    sim.advance(0.5)
    low = await read(client, Reg.MOTOR_SPEED)
    assert 300 < low < 1450 and await read(client, Reg.STATUS1) == 1
    drive.set_supply_voltage(48.0)
    sim.advance(3.0)
    assert await read(client, Reg.FAULT_CODE) == 0
    assert await read(client, Reg.MOTOR_SPEED) == 1500
    assert "ride-through ended" in drive.telemetry().auto_action


async def test_off_as_shipped_the_loss_trips_uv_in_milliseconds(link: Link) -> None:
    sim, client = link
    await running_loaded(sim, client, 0)
    sim.drive(1).set_supply_voltage(0.0)
    sim.advance(0.05)
    assert await read(client, Reg.FAULT_CODE) == UV

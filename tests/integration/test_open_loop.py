"""Open-loop droop (F00.00 = 2005H = 1, issue 42) through the wire: the speed falls under load by the I R drop.

Modbus TCP served in this process, pymodbus as the master. Closed loop (as shipped) holds 1500 rpm under half
the rated torque; open loop settles below it by the slip whose torque carries the load: a voltage-mode drive's
I R drop over the back-EMF constant, (load torque / kt) x R / kt rad/s (assumed: the sheet names the mode only).
"""

from __future__ import annotations

import math

import pytest

from c20sim.drive.profile import load_profile
from c20sim.wire.registers import Reg
from tests.integration.conftest import modbus_tcp_link

PROFILE = load_profile("c20-400hr")


async def speeds(mode: int) -> tuple[int, int]:
    """3006H unloaded and under half the rated torque, in control mode ``mode``."""
    async with modbus_tcp_link(PROFILE) as (sim, client):
        for register, value in ((Reg.CONTROL_MODE, mode), (Reg.SPEED_SETPOINT, 1500), (Reg.COMMAND, 1)):
            assert not (await client.write_register(register, value, device_id=1)).isError()
        sim.advance(3.0)
        unloaded = (await client.read_holding_registers(Reg.MOTOR_SPEED, count=1, device_id=1)).registers[0]
        sim.drive(1).set_load_torque(0.5 * PROFILE.motor.kt_nm_per_a * PROFILE.motor.rated_current_a)
        sim.advance(3.0)
        loaded = (await client.read_holding_registers(Reg.MOTOR_SPEED, count=1, device_id=1)).registers[0]
        return unloaded, loaded


async def test_closed_loop_holds_the_speed_and_open_loop_droops_by_the_ir_drop() -> None:
    assert await speeds(2) == (1500, 1500)
    unloaded, loaded = await speeds(1)
    m = PROFILE.motor
    slip = 0.5 * m.rated_current_a * m.resistance_ohm / m.kt_nm_per_a * 60 / (2 * math.pi)  # rpm
    assert slip == pytest.approx(94, abs=1)
    assert unloaded - loaded == pytest.approx(slip, abs=2)  # the load's share of the droop
    assert 1480 < unloaded < 1500  # friction and drag droop a little too

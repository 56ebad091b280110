"""Automatic fault reset (F08.28/F08.29) and the restart after power (F01.21/F01.22) through the wire (issue 42).

Modbus TCP served in this process, pymodbus as the master, virtual time moved by the test. The function
codes are written over the bus as a master configures them; the fault code 2102H is polled around each
moment the drive acts by itself, a millisecond either side.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from c20sim.drive.profile import FaultCause, load_profile
from c20sim.drive.terminals import Input
from c20sim.wire.registers import Reg
from tests.integration.conftest import Link, modbus_tcp_link
from tests.integration.conftest import read_register as read
from tests.integration.conftest import write_register as write

PROFILE = load_profile("c20-400hr")
EF = PROFILE.fault_code(FaultCause.EXTERNAL)
UV = PROFILE.fault_code(FaultCause.UNDERVOLTAGE)


@pytest.fixture
async def link() -> AsyncIterator[Link]:
    async with modbus_tcp_link(PROFILE) as pair:
        yield pair


async def test_auto_reset_clears_a_fault_after_its_interval_the_set_number_of_times_then_stops(link: Link) -> None:
    sim, client = link
    await write(client, Reg.WRITE_ENABLE, 1)
    await write(client, "F08.28", 2)  # two trials
    await write(client, "F08.29", 15)  # 1.5 s apart
    for trial in (1, 2, 3):
        await write(client, Reg.VIRTUAL_INPUTS, int(Input.EF))  # an external fault, then gone at once
        sim.advance(0.002)
        assert await read(client, Reg.FAULT_CODE) == EF
        tripped = sim.drive(1).t - 0.001  # the step the EF input tripped on (one step after the write)
        await write(client, Reg.VIRTUAL_INPUTS, 0)
        sim.advance(tripped + 1.5 - 0.002 - sim.now())
        assert await read(client, Reg.FAULT_CODE) == EF  # 1 ms before the interval: still latched
        sim.advance(0.003)
        if trial < 3:
            assert await read(client, Reg.FAULT_CODE) == 0, trial  # cleared with no write of the master's
            assert await read(client, Reg.STATUS1) == 3
            assert f"automatic reset {trial} of 2" in sim.drive(1).telemetry().auto_action
        else:
            assert await read(client, Reg.FAULT_CODE) == EF  # no trials left: it stays
    sim.advance(10.0)
    assert await read(client, Reg.FAULT_CODE) == EF
    await write(client, Reg.COMMAND, 7)  # the master's reset clears it, and the count
    assert await read(client, Reg.FAULT_CODE) == 0
    await write(client, Reg.VIRTUAL_INPUTS, int(Input.EF))
    sim.advance(0.002)
    await write(client, Reg.VIRTUAL_INPUTS, 0)
    sim.advance(1.6)
    assert await read(client, Reg.FAULT_CODE) == 0  # trials again after the manual reset


async def test_an_auto_reset_whose_cause_persists_counts_as_a_trial(link: Link) -> None:
    sim, client = link
    await write(client, Reg.WRITE_ENABLE, 1)
    await write(client, "F08.28", 3)
    await write(client, "F08.29", 10)
    await write(client, Reg.VIRTUAL_INPUTS, int(Input.EF))  # held: every attempt is refused
    sim.advance(3.5)
    assert await read(client, Reg.FAULT_CODE) == EF
    assert sim.drive(1).machine.auto_resets == 3
    await write(client, Reg.VIRTUAL_INPUTS, 0)
    sim.advance(5.0)
    assert await read(client, Reg.FAULT_CODE) == EF  # spent: the master must reset


async def test_off_as_shipped_a_fault_stays(link: Link) -> None:
    sim, client = link
    await write(client, Reg.VIRTUAL_INPUTS, int(Input.EF))
    sim.advance(0.01)
    await write(client, Reg.VIRTUAL_INPUTS, 0)
    sim.advance(60.0)
    assert await read(client, Reg.FAULT_CODE) == EF


async def test_a_run_the_power_ended_is_taken_up_again_after_the_wait(link: Link) -> None:
    sim, client = link
    drive = sim.drive(1)
    await write(client, Reg.WRITE_ENABLE, 1)
    await write(client, "F01.21", 1)
    await write(client, "F01.22", 5)  # 0.5 s after the bus is back
    await write(client, Reg.SPEED_SETPOINT, 1200)
    await write(client, Reg.COMMAND, 1)
    sim.advance(2.0)
    drive.set_supply_voltage(0.0)  # the power goes
    sim.advance(1.0)
    assert await read(client, Reg.FAULT_CODE) == UV
    drive.set_supply_voltage(48.0)  # and comes back: the bus recovers within milliseconds
    sim.advance(0.05)
    back = drive.machine.restart_due
    assert back is not None and await read(client, Reg.FAULT_CODE) == UV
    sim.advance(back * 0.001 - drive.t - 0.002)
    assert await read(client, Reg.FAULT_CODE) == UV  # waiting
    sim.advance(0.004)
    assert await read(client, Reg.FAULT_CODE) == 0
    assert await read(client, Reg.STATUS1) == 1 and await read(client, Reg.COMMAND) == 1
    sim.advance(3.0)
    assert await read(client, Reg.MOTOR_SPEED) == 1200
    assert "restart after power" in drive.telemetry().auto_action


async def test_without_restart_after_power_the_uv_fault_stays(link: Link) -> None:
    sim, client = link
    drive = sim.drive(1)
    await write(client, Reg.SPEED_SETPOINT, 1200)
    await write(client, Reg.COMMAND, 1)
    sim.advance(2.0)
    drive.set_supply_voltage(0.0)
    sim.advance(1.0)
    drive.set_supply_voltage(48.0)
    sim.advance(5.0)
    assert await read(client, Reg.FAULT_CODE) == UV

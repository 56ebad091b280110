"""The simple PLC (2007H = 6, F10 group; issue 42) through the wire: stages in virtual time, flags on 300EH.

Modbus TCP served in this process, pymodbus as the master, virtual time moved by the test. The master writes
a two-stage programme (1200 rpm for 1.0 s, 2400 rpm for 1.5 s), selects source 6 and runs forward: 3006H
follows the stages, 300EH's Y3 (bit 2) pulses 0.5 s at each stage's end and Y4 (bit 3) at the cycle's end,
read a millisecond either side; with F10.00 = 2 the programme cycles, with 0 it stops after one cycle.
"""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest
from pymodbus.client import AsyncModbusTcpClient

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.wire.registers import Reg
from tests.integration.conftest import Link, modbus_tcp_link
from tests.integration.conftest import read_register as read
from tests.integration.conftest import write_register as write

PROFILE = load_profile("c20-400hr")
RUN, Y3, Y4 = 0x1, 0x4, 0x8


@pytest.fixture
async def link() -> AsyncIterator[Link]:
    async with modbus_tcp_link(PROFILE) as pair:
        yield pair


async def programme(sim: Simulator, client: AsyncModbusTcpClient, mode: int) -> float:
    """Two stages and ``mode``; source 6; run forward. Returns the time of the run command's first step."""
    await write(client, Reg.WRITE_ENABLE, 1)
    for code, value in (("F10.00", mode), ("F10.02", 1200), ("F10.03", 10), ("F10.04", 2400), ("F10.05", 15)):
        await write(client, code, value)
    for code in ("F10.07", "F10.09"):  # the shipped stages 2 and 3 off
        await write(client, code, 0)
    await write(client, Reg.SPEED_SOURCE, 6)
    await write(client, Reg.COMMAND, 1)
    return sim.now() + 0.001  # the programme starts on the next step


async def at(sim: Simulator, t: float) -> None:
    sim.advance(t - sim.now())


async def test_the_programme_steps_through_its_stages_with_its_flags_and_cycles(link: Link) -> None:
    sim, client = link
    t0 = await programme(sim, client, 2)
    await at(sim, t0 + 0.9)
    assert await read(client, Reg.MOTOR_SPEED) == 1200 and await read(client, Reg.OUTPUT_TERMINALS) == RUN
    await at(sim, t0 + 0.999)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN  # stage 0 not over yet
    await at(sim, t0 + 1.001)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN | Y3  # stage 0 complete
    assert await read(client, Reg.SET_SPEED) == 2400
    await at(sim, t0 + 1.501)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN  # the pulse is 0.5 s
    await at(sim, t0 + 2.4)
    assert await read(client, Reg.MOTOR_SPEED) == 2400
    await at(sim, t0 + 2.499)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN
    await at(sim, t0 + 2.501)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN | Y3 | Y4  # stage 1 and the cycle complete
    assert await read(client, Reg.SET_SPEED) == 1200  # cycling: stage 0 again
    await at(sim, t0 + 3.4)
    assert await read(client, Reg.MOTOR_SPEED) == 1200
    await at(sim, t0 + 5.001)
    assert await read(client, Reg.OUTPUT_TERMINALS) == RUN | Y3 | Y4  # the second cycle
    assert sim.drive(1).plc.cycles == 2


async def test_mode_0_stops_after_one_cycle(link: Link) -> None:
    sim, client = link
    t0 = await programme(sim, client, 0)
    await at(sim, t0 + 2.501)
    assert await read(client, Reg.OUTPUT_TERMINALS) & (Y3 | Y4) == Y3 | Y4
    assert await read(client, Reg.COMMAND) == 0  # the run ended by the programme: the command dropped
    await at(sim, t0 + 6.0)
    assert await read(client, Reg.STATUS1) == 3 and await read(client, Reg.MOTOR_SPEED) == 0


async def test_mode_1_runs_on_at_the_last_stage(link: Link) -> None:
    sim, client = link
    t0 = await programme(sim, client, 1)
    await at(sim, t0 + 10.0)
    assert await read(client, Reg.MOTOR_SPEED) == 2400 and await read(client, Reg.STATUS1) == 1


async def test_a_stop_sends_the_programme_back_to_its_first_stage(link: Link) -> None:
    sim, client = link
    t0 = await programme(sim, client, 2)
    await at(sim, t0 + 1.5)
    assert await read(client, Reg.SET_SPEED) == 2400
    await write(client, Reg.COMMAND, 5)
    sim.advance(3.0)
    t1 = sim.now() + 0.001
    await write(client, Reg.COMMAND, 1)
    await at(sim, t1 + 0.9)
    assert await read(client, Reg.MOTOR_SPEED) == 1200  # stage 0 again, its full second

"""S-curve ramps (F01.05-F01.07, issue 42) through the wire: speed in the configured time, a smooth jerk.

Modbus TCP served in this process, pymodbus as the master, virtual time moved by the test, 3002H (the ramp
frequency, 0.01 Hz) read every 10 ms. With F01.05 = 1 and 30 % / 30 % segments, a 2.0 s ramp (2003H = 20)
from 0 to 3000 rpm (200.00 Hz) reaches it at 2.0 s as the linear ramp does, but its rate changes by at most
the S curve's jerk per poll, where the linear ramp's jumps at each end.
"""

from __future__ import annotations

import itertools
from collections.abc import AsyncIterator

import pytest
from pymodbus.client import AsyncModbusTcpClient

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.wire.registers import Reg, parse_fcode
from tests.integration.conftest import Link, modbus_tcp_link

PROFILE = load_profile("c20-400hr")
POLL = 0.01
#: the S curve's jerk: a peak rate 1 / (1 - (0.3 + 0.3) / 2) of the linear one, reached in 30 % of 2 s;
#: the linear ramp moves 200.00 Hz in 2 s = 1 Hz (100 counts) per 10 ms poll
PEAK = 100 / 0.7  # counts per poll
JERK = PEAK / (0.3 * 2.0 / POLL)  # counts per poll, per poll


@pytest.fixture
async def link() -> AsyncIterator[Link]:
    async with modbus_tcp_link(PROFILE) as pair:
        yield pair


async def ramp(sim: Simulator, client: AsyncModbusTcpClient, shape: int) -> list[int]:
    """3002H every 10 ms from the run command, for 2.5 s."""
    for register, value in ((Reg.WRITE_ENABLE, 1), (parse_fcode("F01.05"), shape), (Reg.ACCEL_TIME, 20)):
        assert not (await client.write_register(register, value, device_id=1)).isError()
    assert not (await client.write_register(Reg.SPEED_SETPOINT, 3000, device_id=1)).isError()
    assert not (await client.write_register(Reg.COMMAND, 1, device_id=1)).isError()
    out = []
    for _ in range(250):
        sim.advance(POLL)
        out.append((await client.read_holding_registers(Reg.RAMP_FREQUENCY, count=1, device_id=1)).registers[0])
    return out


def second_differences(values: list[int]) -> list[int]:
    rates = [b - a for a, b in itertools.pairwise(values)]
    return [b - a for a, b in itertools.pairwise(rates)]


async def test_an_s_curve_reaches_speed_in_the_ramp_time_with_a_bounded_jerk(link: Link) -> None:
    sim, client = link
    read = await ramp(sim, client, 1)
    reached = read.index(20000)
    assert reached in (199, 200)  # 2.00 s (the poll at 1.99 s or 2.00 s: the S curve lands on its last step)
    assert read[99] == pytest.approx(10000, abs=30)  # half way at half time: the curve is symmetric
    jerk = max(abs(j) for j in second_differences(read))
    assert jerk <= JERK + 2  # 0.01 Hz rounding on each of three reads
    assert max(b - a for a, b in itertools.pairwise(read)) == pytest.approx(PEAK, abs=2)


async def test_the_linear_ramp_takes_as_long_with_a_jerk_at_each_end(link: Link) -> None:
    sim, client = link
    read = await ramp(sim, client, 0)
    assert read.index(20000) in (199, 200)
    assert max(abs(j) for j in second_differences(read)) >= 90  # the rate from 0 to 100 counts in one poll

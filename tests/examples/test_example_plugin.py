"""Examples: testing C20 client code with the ``c20sim`` fixture (installed with c20sim, no conftest needed).

The fixture gives a running drive on RTU over TCP (port 0) with a virtual
clock: nothing moves until the test calls ``c20sim.advance``. Run them with
``pytest tests/examples``.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from c20sim.testing import C20Sim


class Conveyor:
    """The client code under test: a tiny C20 master, as a user would write one."""

    def __init__(self, client: ModbusTcpClient, device: int = 1) -> None:
        self.client = client
        self.device = device

    def start(self, rpm: int) -> None:
        self.client.write_register(0x2001, rpm, device_id=self.device)
        self.client.write_register(0x2000, 1, device_id=self.device)

    def healthy(self) -> bool:
        fault = self.client.read_holding_registers(0x2102, count=1, device_id=self.device)
        return not fault.isError() and fault.registers[0] == 0

    def recover(self) -> None:
        self.client.write_register(0x2000, 7, device_id=self.device)


@pytest.fixture
def conveyor(c20sim: C20Sim) -> Iterator[Conveyor]:
    assert c20sim.host is not None and c20sim.port is not None
    client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=1, retries=0)
    assert client.connect()
    yield Conveyor(client)
    client.close()


def test_start_writes_the_speed_then_runs(conveyor: Conveyor, c20sim: C20Sim) -> None:
    conveyor.start(1200)
    c20sim.assert_written("2001H", 1200)
    c20sim.assert_written("2000H", 1)  # forward run
    c20sim.advance(1.0)
    c20sim.assert_register("motor_speed", 1200)


def test_recovers_after_an_undervoltage_trip(conveyor: Conveyor, c20sim: C20Sim) -> None:
    conveyor.start(1500)
    c20sim.advance(1.0)
    c20sim.set(supply_v=15)  # the 48 V supply sags below the 20 V trip level
    c20sim.advance(0.1)
    assert not conveyor.healthy()
    c20sim.assert_fault(0x0A)
    c20sim.set(supply_v=48)
    c20sim.advance(0.5)
    conveyor.recover()
    assert conveyor.healthy()
    c20sim.assert_register("status1", 3)  # stopped


def test_an_injected_fault(conveyor: Conveyor, c20sim: C20Sim) -> None:
    c20sim.inject_fault(16, persistent=True)  # power module overheat, until cleared
    conveyor.recover()
    assert not conveyor.healthy()  # the reset is refused while the cause persists
    c20sim.clear_fault(reset=False)
    conveyor.recover()
    assert conveyor.healthy()


@pytest.mark.c20sim(drives=(1, 2))
def test_a_dead_drive_on_the_line(c20sim: C20Sim) -> None:
    c20sim.drive(2).link_faults(offline=True)
    client = ModbusTcpClient(c20sim.host or "", port=c20sim.port or 0, framer=FramerType.RTU, timeout=0.2, retries=0)
    assert client.connect()
    assert client.read_holding_registers(0x2103, count=1, device_id=1).registers == [0x20]
    with pytest.raises(ModbusIOException):  # drive 2 never answers
        client.read_holding_registers(0x2103, count=1, device_id=2)
    client.close()
    assert [record.note for record in c20sim.frames(drive=2)] == ["drive offline (injected)"]


async def test_in_an_asyncio_test(c20sim: C20Sim) -> None:
    client = AsyncModbusTcpClient(c20sim.host or "", port=c20sim.port or 0, framer=FramerType.RTU, timeout=1, retries=0)
    assert await client.connect()
    await client.write_register(0x2001, 600, device_id=1)
    await client.write_register(0x2000, 2, device_id=1)  # reverse run
    c20sim.advance(2.0)
    assert c20sim.state().speed_rpm == -600.0
    client.close()

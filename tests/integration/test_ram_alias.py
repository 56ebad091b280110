"""The RAM-only address (function code | 8000H) on the wire, from pymodbus over a pty and RTU over TCP.

A master written for the INVT family writes its cyclic set-points there: the write is answered and acts,
the state file (the EEPROM) is untouched, a read at the alias gets 0x02, a power cycle loses the value,
and the frame log says "RAM only".
"""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.wire.registers import Reg

KEYPAD_SPEED, ALIAS = 0x000A, 0x800A  # F00.10 and its RAM-only address


@pytest.fixture
async def served(tmp_path: Path) -> AsyncIterator[tuple[Simulator, Server, Path]]:
    state = tmp_path / "eeprom.json"
    sim = Simulator(load_profile("c20-400hr"), (1,), clock=VirtualClock(), state=state)
    server = Server(sim, ServeOptions(pty=True, tcp="127.0.0.1:0"))
    await server.start()
    try:
        yield sim, server, state
    finally:
        await server.aclose()


@pytest.mark.parametrize("transport", ["pty", "rtu-over-tcp"])
async def test_a_master_writes_the_ram_only_address(served: tuple[Simulator, Server, Path], transport: str) -> None:
    sim, server, state = served
    client: AsyncModbusSerialClient | AsyncModbusTcpClient
    if transport == "pty":
        assert server.endpoints.pty is not None
        client = AsyncModbusSerialClient(server.endpoints.pty.path, framer=FramerType.RTU, timeout=2.0, retries=0)
    else:
        assert server.endpoints.tcp is not None
        port = server.endpoints.tcp.port
        client = AsyncModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=2.0, retries=0)
    assert await client.connect()
    try:
        default = sim.profile.defaults[KEYPAD_SPEED]
        saved = state.read_bytes()
        assert not (await client.write_register(Reg.WRITE_ENABLE, 1, device_id=1)).isError()
        reply = await client.write_register(ALIAS, 2500, device_id=1)
        assert not reply.isError() and (reply.address, reply.registers) == (ALIAS, [2500])
        assert (await client.read_holding_registers(KEYPAD_SPEED, count=1, device_id=1)).registers == [2500]
        refused = await client.read_holding_registers(ALIAS, count=1, device_id=1)
        assert refused.isError() and refused.exception_code == 0x02
        written = await client.write_registers(0x800B, [30, 40], device_id=1)  # 0x10: F00.11, F00.12 in RAM
        assert not written.isError()
        assert (await client.read_holding_registers(Reg.DECEL_TIME, count=1, device_id=1)).registers == [40]
        assert state.read_bytes() == saved  # nothing reached the EEPROM
        assert json.loads(state.read_text())["parameters"]["F00.10"] == default
        texts = [record.text for record in sim.bus.records]
        assert "write F00.10 (RAM only) = 09C4: 25.00 Hz" in texts
        sim.drive(1).power_cycle()  # switched off and on: RAM-only values are gone
        assert (await client.read_holding_registers(KEYPAD_SPEED, count=1, device_id=1)).registers == [default]
        assert (await client.read_holding_registers(Reg.DECEL_TIME, count=1, device_id=1)).registers == [5]
    finally:
        client.close()

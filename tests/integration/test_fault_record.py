"""The fault record through the wire (issue 42): F07.27-F07.48 after a trip, shifted by the next, kept in EEPROM.

A simulator served in this process on Modbus TCP with a state file, pymodbus's TCP client as the master,
virtual time moved by the test. Two trips with different causes and states (undervoltage while running at
1500 rpm, then an external fault while running at 900 rpm); the record read register by register, as an
alarm screen reads it; then a power cycle of the drive, and a new process's worth of simulator on the same
state file, both still reading it.
"""

from __future__ import annotations

from pathlib import Path

from pymodbus.client import AsyncModbusTcpClient

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.faultrecord import CURRENT_CONTEXT, FAULT_TYPES, PREVIOUS_CONTEXT
from c20sim.drive.profile import FaultCause, load_profile
from c20sim.drive.terminals import Input
from c20sim.serve import ServeOptions, Server
from c20sim.wire.registers import Reg

PROFILE = load_profile("c20-400hr")
UV = PROFILE.fault_code(FaultCause.UNDERVOLTAGE)
EF = PROFILE.fault_code(FaultCause.EXTERNAL)


async def read(client: AsyncModbusTcpClient, addresses: tuple[int, ...]) -> list[int]:
    """One register per request (the 400hr reads one at a time, as its sheet documents)."""
    values = []
    for address in addresses:
        reply = await client.read_holding_registers(address, count=1, device_id=1)
        assert not reply.isError(), (hex(address), reply)
        values.extend(reply.registers)
    return values


async def served(state: Path) -> tuple[Simulator, Server, AsyncModbusTcpClient]:
    sim = Simulator(PROFILE, (1,), clock=VirtualClock(), state=state)
    server = Server(sim, ServeOptions(modbus_tcp="127.0.0.1:0"))
    await server.start()
    assert server.endpoints.modbus_tcp is not None
    client = AsyncModbusTcpClient("127.0.0.1", port=server.endpoints.modbus_tcp.port, timeout=2.0, retries=0)
    assert await client.connect()
    return sim, server, client


async def run_at(sim: Simulator, client: AsyncModbusTcpClient, rpm: int) -> list[int]:
    """Run forward at ``rpm`` until settled; the live 3000H, 3001H, 3003H, 3004H, 3008H, 300CH, 300DH, 300EH."""
    assert not (await client.write_register(Reg.SPEED_SETPOINT, rpm, device_id=1)).isError()
    assert not (await client.write_register(Reg.COMMAND, 1, device_id=1)).isError()
    sim.advance(3.0)
    live = (Reg.OUTPUT_FREQUENCY, Reg.RAMP_FREQUENCY, Reg.OUTPUT_VOLTAGE, Reg.OUTPUT_CURRENT)
    rest = (Reg.BUS_VOLTAGE, Reg.TEMPERATURE, Reg.INPUT_TERMINALS, Reg.OUTPUT_TERMINALS)
    return await read(client, live + rest)


async def test_the_record_holds_the_state_at_the_trip_shifts_on_the_next_and_survives_power(tmp_path: Path) -> None:
    state = tmp_path / "drive.json"
    sim, server, client = await served(state)
    try:
        drive = sim.drive(1)
        assert await read(client, FAULT_TYPES + CURRENT_CONTEXT) == [0] * 14  # a fresh EEPROM: no fault yet
        before_uv = await run_at(sim, client, 1500)
        assert before_uv[0] == 10000 and before_uv[-1] & 1  # 100.00 Hz (4 pole pairs), RUN on
        drive.set_supply_voltage(0.0)  # the supply gone: the bus falls to the UV level while running
        sim.advance(0.5)
        assert await read(client, (Reg.FAULT_CODE,)) == [UV]
        first = await read(client, FAULT_TYPES + CURRENT_CONTEXT)
        assert first[:6] == [UV, 0, 0, 0, 0, 0]
        running, ramp, volts, amps, bus, temp, inputs, outputs = first[6:]
        # The state the trip met: still running at speed, the bus at the UV level (20.0 V), RUN on.
        assert (running, ramp, inputs, outputs) == (before_uv[0], before_uv[1], 0, 1)
        assert amps == before_uv[3] and temp == before_uv[5]
        assert 195 <= bus <= 200 and volts == before_uv[2]  # the output as it was: the bus fell in ms
        # Supply back, reset, run slower; then an external fault (EF on the virtual inputs).
        drive.set_supply_voltage(48.0)
        sim.advance(0.5)
        assert not (await client.write_register(Reg.COMMAND, 7, device_id=1)).isError()
        before_ef = await run_at(sim, client, 900)
        assert not (await client.write_register(Reg.VIRTUAL_INPUTS, int(Input.EF), device_id=1)).isError()
        sim.advance(0.01)
        assert await read(client, (Reg.FAULT_CODE,)) == [EF]
        second = await read(client, FAULT_TYPES + CURRENT_CONTEXT + PREVIOUS_CONTEXT)
        assert second[:6] == [EF, UV, 0, 0, 0, 0]  # shifted down one
        assert second[6:8] == before_ef[:2] == [6000, 6000]  # 60.00 Hz at 900 rpm
        assert second[12] == int(Input.EF) and second[13] == 1  # EF on the inputs, RUN still on
        assert second[14:] == first[6:]  # the first trip's state is now the previous fault's
        # A write is refused: the record is the drive's own.
        refused = await client.write_register(FAULT_TYPES[0], 0, device_id=1)
        assert refused.isError()
        # A restore of the defaults keeps it.
        assert not (await client.write_register(Reg.VIRTUAL_INPUTS, 0, device_id=1)).isError()
        assert not (await client.write_register(Reg.COMMAND, 7, device_id=1)).isError()
        assert not (await client.write_register(Reg.WRITE_ENABLE, 1, device_id=1)).isError()
        assert not (await client.write_register(Reg.RESTORE_DEFAULTS, 1, device_id=1)).isError()
        assert await read(client, FAULT_TYPES + CURRENT_CONTEXT + PREVIOUS_CONTEXT) == second
        # A power cycle: RAM and the fault latch clear, the record stays.
        drive.power_cycle()
        assert await read(client, (Reg.FAULT_CODE,)) == [0]
        assert await read(client, FAULT_TYPES + CURRENT_CONTEXT + PREVIOUS_CONTEXT) == second
    finally:
        client.close()
        await server.aclose()
    # The process gone: a new simulator on the same state file reads the same record.
    sim, server, client = await served(state)
    try:
        assert await read(client, FAULT_TYPES + CURRENT_CONTEXT + PREVIOUS_CONTEXT) == second
    finally:
        client.close()
        await server.aclose()


async def test_the_hour_counters_read_over_the_wire_and_survive_a_new_process(tmp_path: Path) -> None:
    """F07.13 (power-on hours) and F07.14 (running hours), in EEPROM beside the record (issue 42)."""
    state = tmp_path / "drive.json"
    sim, server, client = await served(state)
    try:
        sim.advance(1800.0)  # half an hour stopped
        await run_at(sim, client, 1200)
        sim.advance(2 * 3600.0)  # then two hours running (3 s of it before, in run_at)
        assert await read(client, (0x070D, 0x070E)) == [2, 2]
        refused = await client.write_register(0x070D, 0, device_id=1)
        assert refused.isError() and refused.exception_code == 0x07  # read-only
    finally:
        client.close()
        await server.aclose()
    sim, server, client = await served(state)
    try:
        assert await read(client, (0x070D, 0x070E)) == [2, 2]
    finally:
        client.close()
        await server.aclose()

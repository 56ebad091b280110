"""Save first, apply after: a parameter write whose EEPROM save fails is refused with 0x04 and changes nothing.

``c20sim serve --state`` as a subprocess, a pymodbus master over RTU over
TCP. The state file's directory is moved away under the server (a save can
then not create its temporary file, as with a read-only directory or a full
disk, and root cannot be kept out by permissions). The write must be answered
with exception 0x04, the value must read back unchanged, the file must keep
the old value, and the server says so in one line, with no traceback.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file


def test_a_failed_save_answers_0x04_and_keeps_the_old_value(tmp_path: Path) -> None:
    state_dir = tmp_path / "eeprom"
    state_dir.mkdir()
    state, ready = state_dir / "drive.json", tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--state", str(state)]
    proc = subprocess.Popen(
        [*command, "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        port = int(wait_for_ready_file(ready, proc)["tcp"].rsplit(":", 1)[1])
        client = ModbusTcpClient("127.0.0.1", port=port, framer=FramerType.RTU, timeout=2.0, retries=0)
        assert client.connect()
        try:
            assert not client.write_register(Reg.ACCEL_TIME, 5000, device_id=1).isError()
            moved = tmp_path / "moved"
            state_dir.rename(moved)  # the next save cannot create its temporary file
            refused = client.write_register(Reg.ACCEL_TIME, 1234, device_id=1)
            assert refused.isError() and refused.exception_code == 0x04, refused
            assert client.read_holding_registers(Reg.ACCEL_TIME, count=1, device_id=1).registers == [5000]
        finally:
            client.close()
        stored = json.loads((moved / "drive.json").read_text())["parameters"]["F00.11"]
        assert stored == 5000
    finally:
        proc.terminate()
        _out, err = proc.communicate(timeout=10)
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if "EEPROM save failed" in line]
    assert len(lines) == 1, err
    assert "0x04" in lines[0] and str(state) in lines[0], lines


async def test_a_failed_save_is_refused_and_changes_nothing_through_the_modbus_tcp_gateway(tmp_path: Path) -> None:
    """The same rule through another door: a simulator served in this process on Modbus TCP, pymodbus's TCP
    client, a 0x10 write of two function codes. The save fails: 0x04, and neither value changes, in the drive
    or in the file."""
    state_dir = tmp_path / "eeprom"
    state_dir.mkdir()
    sim = Simulator(load_profile(), (1,), clock=VirtualClock(), state=state_dir / "drive.json")
    server = Server(sim, ServeOptions(modbus_tcp="127.0.0.1:0"))
    await server.start()
    try:
        assert server.endpoints.modbus_tcp is not None
        client = AsyncModbusTcpClient("127.0.0.1", port=server.endpoints.modbus_tcp.port, timeout=2.0, retries=0)
        assert await client.connect()
        try:
            assert not (await client.write_registers(Reg.ACCEL_TIME, [5000, 4000], device_id=1)).isError()
            moved = tmp_path / "moved"
            state_dir.rename(moved)
            refused = await client.write_registers(Reg.ACCEL_TIME, [1234, 2345], device_id=1)
            assert refused.isError() and refused.exception_code == 0x04, refused
            for register, value in ((Reg.ACCEL_TIME, 5000), (Reg.ACCEL_TIME + 1, 4000)):  # one a read, as the sheet
                assert (await client.read_holding_registers(register, count=1, device_id=1)).registers == [value]
        finally:
            client.close()
    finally:
        await server.aclose()
    stored = json.loads((moved / "drive.json").read_text())["parameters"]
    assert (stored["F00.11"], stored["F00.12"]) == (5000, 4000)

"""The pty knows from the device whether any program has it open: two openers, one closes, the other is answered.

``c20sim serve --pty`` as a subprocess (bus timing on, as shipped), masters in this process: pymodbus's and
minimalmodbus's serial clients (pyserial underneath), a raw descriptor as the second program (a ``stty``, a
monitor, ModemManager). No client retries: every request must be answered the first time.
"""

from __future__ import annotations

import os
import subprocess
import sys
import termios
from collections.abc import Iterator
from pathlib import Path

import minimalmodbus
import pytest
from pymodbus.client import ModbusSerialClient

from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file

TRIALS = 20
STOPPED = 3  #: 2100H of a stopped drive


@pytest.fixture
def pty(tmp_path: Path) -> Iterator[str]:
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--pty", "--ready-file", str(ready)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        yield wait_for_ready_file(ready, proc)["pty"]
    finally:
        proc.kill()
        proc.wait()
        assert proc.stderr is not None
        proc.stderr.close()


def pymodbus_master(path: str) -> ModbusSerialClient:
    client = ModbusSerialClient(path, baudrate=19200, timeout=2.0, retries=0)
    assert client.connect()
    return client


def pymodbus_read(client: ModbusSerialClient) -> int:
    result = client.read_holding_registers(Reg.STATUS1, count=1, device_id=1)
    assert not result.isError(), result
    return int(result.registers[0])


def minimal_master(path: str) -> minimalmodbus.Instrument:
    instrument = minimalmodbus.Instrument(path, 1, close_port_after_each_call=False)
    instrument.serial.baudrate = 19200
    instrument.serial.timeout = 2.0
    return instrument


def other_program(path: str) -> int:
    """A second program with the device open (as ``stty`` or a monitor holds it): a descriptor, never read."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    termios.tcgetattr(fd)
    return fd


def test_two_programs_open_the_pty_one_closes_the_other_is_answered_every_time(pty: str) -> None:
    """A monitor opens the device, the master opens it too, the monitor closes: all ten reads answered; then
    a second program opens and closes right after each of 50 reads: all 50 answered."""
    monitor = other_program(pty)
    client = pymodbus_master(pty)
    try:
        os.close(monitor)
        assert [pymodbus_read(client) for _ in range(10)] == [STOPPED] * 10
        answered = 0
        for _ in range(50):
            os.close(other_program(pty))
            answered += pymodbus_read(client) == STOPPED
        assert answered == 50
    finally:
        client.close()


def test_a_pymodbus_master_that_opens_right_after_a_close_is_answered_first_time(pty: str) -> None:
    for trial in range(TRIALS):
        first = pymodbus_master(pty)
        assert pymodbus_read(first) == STOPPED
        first.close()
        second = pymodbus_master(pty)  # 0 ms after the close
        try:
            assert pymodbus_read(second) == STOPPED, f"trial {trial}"
        finally:
            second.close()


def test_a_minimalmodbus_master_that_opens_right_after_a_close_is_answered_first_time(pty: str) -> None:
    for trial in range(TRIALS):
        first = minimal_master(pty)
        assert first.read_register(Reg.STATUS1) == STOPPED
        first.serial.close()
        second = minimal_master(pty)  # 0 ms after the close
        try:
            assert second.read_register(Reg.STATUS1) == STOPPED, f"trial {trial}"
            second.write_register(Reg.SPEED_SETPOINT, 100 + trial)
            assert second.read_register(Reg.SPEED_SETPOINT) == 100 + trial
        finally:
            second.serial.close()

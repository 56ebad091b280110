"""The RAM-only address of a function code (code | 8000H), as the INVT family has it (issue 27).

Through the slave, on the behavioural model with a state file: the write meets the code's rules, acts at
once, is not saved, is lost at power-up; a read there gets 0x02; the frame log and decode say "RAM only".
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from c20sim.core.bus import Bus
from c20sim.core.slave import Slave
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.decode import decode_frame
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    FrameEvent,
    FrameKind,
    ReadRequest,
    ReadResponse,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    encode,
)
from c20sim.wire.registers import Reg, fcode_address

KEYPAD_SPEED = fcode_address(0, 10)  # F00.10, 000AH
ALIAS = KEYPAD_SPEED | 0x8000  # 800AH
ACCEL = fcode_address(0, 11)  # F00.11, mirrored by 2003H


@pytest.fixture
def profile() -> Profile:
    return load_profile("c20-400hr")


def served(profile: Profile, tmp_path: Path) -> tuple[Slave, Drive, Path]:
    state = tmp_path / "eeprom.json"
    drive = Drive(profile, state_path=state)
    slave = Slave(profile, drive)
    assert slave.handle(WriteSingleRequest(1, Reg.WRITE_ENABLE, 1), 0.0) == WriteSingleResponse(1, Reg.WRITE_ENABLE, 1)
    return slave, drive, state


def saved(state: Path) -> dict[str, int]:
    parameters = json.loads(state.read_text())["parameters"]
    assert isinstance(parameters, dict)
    return parameters


@pytest.mark.parametrize("name", ["c20-400hr", "c20-2200hv"])
def test_the_shipped_profiles_have_the_alias(name: str, tmp_path: Path) -> None:
    """Each shipped profile's drive takes every function code at its RAM-only address: in effect, not saved."""
    profile = load_profile(name)
    assert profile.protocol.ram_only_alias is True
    slave, drive, state = served(profile, tmp_path)
    before = state.read_bytes()
    taken = 0
    for spec in profile.registers.parameters():
        if not spec.access.writable or spec.address == profile.password_address:
            continue
        value = spec.minimum if profile.defaults[spec.address] != spec.minimum else spec.minimum + 1
        alias = spec.address | 0x8000
        assert slave.handle(WriteSingleRequest(1, alias, value), 0.1) == WriteSingleResponse(1, alias, value), (
            spec.label
        )
        assert drive.parameters.get(spec.address) == value, spec.label  # in effect
        taken += 1
    assert taken >= 20
    assert state.read_bytes() == before  # nothing saved
    drive.power_cycle()
    for spec in profile.registers.parameters():
        assert drive.parameters.get(spec.address) == profile.defaults[spec.address], spec.label  # the EEPROM's


def test_a_write_at_the_alias_acts_in_ram_and_is_not_saved(profile: Profile, tmp_path: Path) -> None:
    slave, drive, state = served(profile, tmp_path)
    before = state.read_bytes()
    assert slave.handle(WriteSingleRequest(1, ALIAS, 2500), 0.1) == WriteSingleResponse(1, ALIAS, 2500)
    assert slave.handle(ReadRequest(1, KEYPAD_SPEED, 1), 0.2) == ReadResponse(1, (2500,))  # in effect
    assert state.read_bytes() == before  # the state file (the EEPROM) did not change
    assert saved(state)["F00.10"] == profile.defaults[KEYPAD_SPEED]
    # Another code written at its own address is saved; the RAM-only value is not saved with it.
    assert slave.handle(WriteSingleRequest(1, ACCEL, 20), 0.3) == WriteSingleResponse(1, ACCEL, 20)
    assert saved(state)["F00.11"] == 20 and saved(state)["F00.10"] == profile.defaults[KEYPAD_SPEED]
    assert drive.parameters.get(KEYPAD_SPEED) == 2500
    drive.power_cycle()  # lost at power-off; the EEPROM's value is back
    assert drive.parameters.get(KEYPAD_SPEED) == profile.defaults[KEYPAD_SPEED]
    assert drive.parameters.get(ACCEL) == 20
    again = Drive(profile, state_path=state)  # a restart reads the file: no trace of it
    assert again.parameters.get(KEYPAD_SPEED) == profile.defaults[KEYPAD_SPEED]


def test_the_alias_drives_the_model_at_once(profile: Profile) -> None:
    drive = Drive(profile)
    slave = Slave(profile, drive)
    slave.handle(WriteSingleRequest(1, Reg.WRITE_ENABLE, 1), 0.0)
    # F00.03 (maximum speed) at 8003H: AI1 at 10 V then runs at the new maximum.
    assert slave.handle(WriteSingleRequest(1, 0x8003, 1200), 0.0) == WriteSingleResponse(1, 0x8003, 1200)
    assert drive.motion.cfg.max_rpm == 1200.0


def test_a_read_at_the_alias_gets_0x02(profile: Profile, tmp_path: Path) -> None:
    slave, _, _ = served(profile, tmp_path)
    assert slave.handle(ReadRequest(1, ALIAS, 1), 0.0) == ExceptionResponse(1, 0x03, ExceptionCode.ILLEGAL_ADDRESS)


def test_the_alias_meets_the_codes_rules(profile: Profile) -> None:
    drive = Drive(profile)
    slave = Slave(profile, drive)

    def code(request: object) -> ExceptionCode | None:
        response = slave.handle(request, drive.t)  # type: ignore[arg-type]
        return response.code if isinstance(response, ExceptionResponse) else None

    assert code(WriteSingleRequest(1, ALIAS, 100)) is ExceptionCode.OPERATION_FAILED  # 200EH = 0: locked
    slave.handle(WriteSingleRequest(1, Reg.WRITE_ENABLE, 1), 0.0)
    assert code(WriteSingleRequest(1, ALIAS, 40001)) is ExceptionCode.ILLEGAL_VALUE  # F00.10 is 0-40000
    assert code(WriteSingleRequest(1, 0x8032, 1)) is ExceptionCode.ILLEGAL_ADDRESS  # F00.50 is no code
    assert code(WriteSingleRequest(1, Reg.COMMAND | 0x8000, 1)) is ExceptionCode.ILLEGAL_ADDRESS  # A000H: no code
    slave.handle(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 1000), 0.0)
    slave.handle(WriteSingleRequest(1, Reg.COMMAND, 1), 0.0)
    assert drive.running
    assert code(WriteSingleRequest(1, 0x8003, 2000)) is ExceptionCode.NOT_WHILE_RUNNING  # F00.03 is W/R*
    # A 0x10 over two aliases: all or nothing, both in RAM.
    request = WriteMultipleRequest(1, 0x800B, (30, 40), 2, 4)
    assert slave.handle(request, drive.t) == WriteMultipleResponse(1, 0x800B, 2)
    assert (drive.read(0x000B), drive.read(0x000C)) == (30, 40)
    assert slave.handle(ReadRequest(1, Reg.ACCEL_TIME, 1), drive.t) == ReadResponse(1, (30,))  # the mirror too


def test_without_the_quirk_the_alias_is_an_unknown_address(profile: Profile) -> None:
    strict = dataclasses.replace(profile, protocol=dataclasses.replace(profile.protocol, ram_only_alias=False))
    slave = Slave(strict, Drive(strict))
    slave.handle(WriteSingleRequest(1, Reg.WRITE_ENABLE, 1), 0.0)
    response = slave.handle(WriteSingleRequest(1, ALIAS, 100), 0.0)
    assert response == ExceptionResponse(1, 0x06, ExceptionCode.ILLEGAL_ADDRESS)


def test_frame_log_and_decode_say_ram_only(profile: Profile) -> None:
    bus = Bus([Slave(profile, Drive(profile))])
    unlock = encode(WriteSingleRequest(1, Reg.WRITE_ENABLE, 1))
    bus.handle(FrameEvent(FrameKind.FRAME, unlock, 0.0))
    frame = encode(WriteSingleRequest(1, ALIAS, 2500))
    bus.handle(FrameEvent(FrameKind.FRAME, frame, 0.01))
    request, reply = list(bus.records)[-2:]
    assert request.text == "write F00.10 (RAM only) = 09C4: 25.00 Hz"
    assert reply.text == "write F00.10 (RAM only) = 09C4: 25.00 Hz"
    assert decode_frame(frame, profile.registers).text == ("slave 1: write F00.10 (RAM only) = 09C4: 25.00 Hz; CRC ok")
    read = encode(ReadRequest(1, ALIAS, 1))
    assert decode_frame(read, profile.registers).text == "slave 1: read F00.10 (keypad speed setting, RAM only); CRC ok"
    assert decode_frame(read).text == "slave 1: read F00.10 (RAM only); CRC ok"

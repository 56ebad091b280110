"""The slave's access rules: each exception code of the sheet, exactly."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from c20sim.core.bus import Bus
from c20sim.core.slave import Slave
from c20sim.drive.profile import Profile, parse_profile
from c20sim.drive.store import RegisterStoreDrive
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    with_crc,
)
from c20sim.wire.registers import Reg
from tests.conftest import Line

X = ExceptionCode


class RunningDrive(RegisterStoreDrive):
    """A store drive that reports running, to exercise the W/R* lock."""

    @property
    def running(self) -> bool:
        return True


class RefusingDrive(RegisterStoreDrive):
    """A drive that refuses run commands, as the model does off the communication channel."""

    def check_write(self, address: int, value: int) -> None:
        from c20sim.wire.errors import ModbusError

        if address == Reg.COMMAND and value == 1:
            raise ModbusError(ExceptionCode.OPERATION_FAILED, "not the communication channel")


@pytest.fixture
def slave(profile: Profile) -> Slave:
    return Slave(profile, RegisterStoreDrive(profile))


def exc(slave: Slave, request: object) -> ExceptionCode | None:
    response = slave.handle(request, 0.0)  # type: ignore[arg-type]
    return response.code if isinstance(response, ExceptionResponse) else None


def test_reads_and_writes_round_trip(slave: Slave) -> None:
    assert slave.handle(WriteSingleRequest(1, 0x2001, 1500), 0.0) == WriteSingleResponse(1, 0x2001, 1500)
    assert slave.handle(ReadRequest(1, 0x2001, 1), 0.0) == ReadResponse(1, (1500,))


def test_01_unsupported_function(slave: Slave) -> None:
    assert slave.handle(UnsupportedRequest(1, 0x04, b"\x30\x00\x00\x01"), 0.0) == ExceptionResponse(
        1, 0x04, X.ILLEGAL_FUNCTION
    )


@pytest.mark.parametrize("address", [0x0032, 0x200C, 0x2104, 0x3012, 0x1FFF, 0xFFFF])
def test_02_unknown_address(slave: Slave, address: int) -> None:
    assert exc(slave, ReadRequest(1, address, 1)) is X.ILLEGAL_ADDRESS
    assert exc(slave, WriteSingleRequest(1, address, 0)) is X.ILLEGAL_ADDRESS


@pytest.mark.parametrize("count", [0, 2, 125, 0xFFFF])
def test_03_read_count_beyond_the_profile(slave: Slave, count: int) -> None:
    assert exc(slave, ReadRequest(1, 0x2100, count)) is X.ILLEGAL_VALUE


def test_longer_reads_when_the_profile_allows_them(profile: Profile) -> None:
    wide = dataclasses.replace(profile, protocol=dataclasses.replace(profile.protocol, max_read_registers=4))
    slave = Slave(wide, RegisterStoreDrive(wide))
    assert slave.handle(ReadRequest(1, 0x2100, 4), 0.0) == ReadResponse(1, (3, 0x41, 0, 0x20))
    assert exc(slave, ReadRequest(1, 0x2102, 3)) is X.ILLEGAL_ADDRESS  # 2104H is not in the map


@pytest.mark.parametrize(
    ("register", "value"),
    [(0x2000, 0), (0x2000, 9), (0x2001, 3001), (0x2002, 21), (0x2003, 0), (0x2008, 0), (0x2009, 7), (0x200A, 0x200)],
)
def test_03_value_out_of_range(slave: Slave, register: int, value: int) -> None:
    assert exc(slave, WriteSingleRequest(1, register, value)) is X.ILLEGAL_VALUE


def test_03_function_code_range_is_checked_before_write_enable(slave: Slave) -> None:
    # The sheet: writing F00.00 = 5 fails with 0x03 on a drive fresh from power-up (200EH = 0).
    assert exc(slave, WriteSingleRequest(1, 0x0000, 5)) is X.ILLEGAL_VALUE


def test_03_mirror_takes_the_function_codes_range(profile: Profile) -> None:
    # 2005H is 0-3 in the sheet; a model whose F00.00 accepts 0-2 refuses 3 at either address.
    text = (
        Path(profile.path)
        .read_text()
        .replace("max = 3                           # sheet 2005H", "max = 2                           # sheet 2005H")
    )
    narrow = parse_profile(text, "narrow.toml")
    slave = Slave(narrow, RegisterStoreDrive(narrow))
    assert exc(slave, WriteSingleRequest(1, 0x2005, 3)) is X.ILLEGAL_VALUE
    assert exc(slave, WriteSingleRequest(1, 0x2005, 1)) is None


def test_dial_switch_settings_inside_the_sheets_ranges_are_taken(slave: Slave) -> None:
    # Sheet: 2005H "3: dial switch setting (SW1 valid)", 2006H "3: dial switch setting (SW3 valid)",
    # 2007H "5: dial switch setting (SW2, SW3 valid)".
    for register, value in ((0x2005, 3), (0x2006, 3), (0x2007, 5)):
        assert exc(slave, WriteSingleRequest(1, register, value)) is None, f"{register:04X}H = {value}"
        assert slave.handle(ReadRequest(1, register, 1), 0.0) == ReadResponse(1, (value,))
    assert exc(slave, WriteSingleRequest(1, 0x2005, 4)) is X.ILLEGAL_VALUE  # beyond the sheet's 0-3


def test_a_feature_the_model_lacks_is_refused_with_the_profiles_code(profile: Profile) -> None:
    slave = Slave(profile, RegisterStoreDrive(profile))
    assert exc(slave, WriteSingleRequest(1, 0x2007, 6)) is None  # simple PLC: the shipped profiles run it
    assert exc(slave, WriteSingleRequest(1, 0x2006, 4)) is X.ILLEGAL_VALUE  # 2006H = 4: named by no sheet line
    other = dataclasses.replace(
        profile, protocol=dataclasses.replace(profile.protocol, lacking_feature_exception=1, simple_plc=False)
    )
    slave = Slave(other, RegisterStoreDrive(other))
    assert exc(slave, WriteSingleRequest(1, 0x2006, 4)) is X.ILLEGAL_FUNCTION
    assert exc(slave, WriteSingleRequest(1, 0x2007, 6)) is X.ILLEGAL_FUNCTION  # simple_plc = false: refused


def test_04_function_code_write_while_200e_is_0(slave: Slave) -> None:
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2500)) is X.OPERATION_FAILED
    slave.handle(WriteSingleRequest(1, 0x200E, 1), 0.0)
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2500)) is None
    assert slave.handle(ReadRequest(1, 0x000A, 1), 0.0) == ReadResponse(1, (2500,))
    slave.handle(WriteSingleRequest(1, 0x200E, 0), 0.0)
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2600)) is X.OPERATION_FAILED


def test_04_a_drive_refusal_comes_back_as_its_code(profile: Profile) -> None:
    slave = Slave(profile, RefusingDrive(profile))
    assert exc(slave, WriteSingleRequest(1, 0x2000, 1)) is X.OPERATION_FAILED
    assert slave.drive.read(0x2000) == 0


def test_mirrored_register_and_function_code_share_a_value(slave: Slave) -> None:
    # 2003H mirrors F00.11 (acceleration time); a 20xxH write needs no write enable.
    assert exc(slave, WriteSingleRequest(1, 0x2003, 50)) is None
    assert slave.handle(ReadRequest(1, 0x000B, 1), 0.0) == ReadResponse(1, (50,))


def test_05_password(profile: Profile) -> None:
    locked = dataclasses.replace(profile, protocol=dataclasses.replace(profile.protocol, password=1234))
    slave = Slave(locked, RegisterStoreDrive(locked))
    slave.handle(WriteSingleRequest(1, 0x200E, 1), 0.0)
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2500)) is X.PASSWORD_ERROR
    assert exc(slave, WriteSingleRequest(1, 0x0700, 999)) is X.PASSWORD_ERROR  # wrong password
    assert exc(slave, WriteSingleRequest(1, 0x0700, 1234)) is None
    assert slave.handle(ReadRequest(1, 0x0700, 1), 0.0) == ReadResponse(1, (0,))  # write-only
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2500)) is None
    # 20xxH registers never needed it.
    assert exc(slave, WriteSingleRequest(1, 0x0700, 1)) is X.PASSWORD_ERROR
    assert exc(slave, WriteSingleRequest(1, 0x2001, 100)) is None
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2600)) is X.PASSWORD_ERROR


def test_05_password_in_a_refused_0x10_frame_does_not_unlock(profile: Profile) -> None:
    # Password register F00.09, right before F00.10: one frame gives the password and an out-of-range F00.10.
    protocol = dataclasses.replace(profile.protocol, password=1234, password_register="F00.09")
    slave = Slave(dataclasses.replace(profile, protocol=protocol), RegisterStoreDrive(profile))
    slave.handle(WriteSingleRequest(1, 0x200E, 1), 0.0)
    assert exc(slave, WriteMultipleRequest(1, 0x0009, (1234, 50000))) is X.ILLEGAL_VALUE
    assert not slave.unlocked  # all or nothing: the password did not take either
    # The same frame with a good value unlocks and writes in one go.
    assert slave.handle(WriteMultipleRequest(1, 0x0009, (1234, 2500)), 0.0) == WriteMultipleResponse(1, 0x0009, 2)
    assert slave.unlocked
    assert slave.drive.read(0x000A) == 2500


def test_no_password_register_without_a_password(slave: Slave) -> None:
    assert exc(slave, WriteSingleRequest(1, 0x0700, 1234)) is X.ILLEGAL_ADDRESS


@pytest.mark.parametrize("register", [0x2100, 0x2101, 0x2102, 0x2103, 0x3000, 0x3006, 0x300C, 0x3011])
def test_07_write_to_a_read_only_register(slave: Slave, register: int) -> None:
    assert exc(slave, WriteSingleRequest(1, register, 1)) is X.READ_ONLY


@pytest.mark.parametrize("register", [0x2002, 0x2005, 0x2008, 0x2009, 0x200F])
def test_08_w_r_star_locked_while_running(profile: Profile, register: int) -> None:
    slave = Slave(profile, RunningDrive(profile))
    assert exc(slave, WriteSingleRequest(1, register, 1)) is X.NOT_WHILE_RUNNING


@pytest.mark.parametrize("register", [0x2000, 0x2001, 0x2003, 0x2004, 0x2006, 0x2007, 0x200A, 0x200B, 0x200E])
def test_w_r_registers_stay_writable_while_running(profile: Profile, register: int) -> None:
    slave = Slave(profile, RunningDrive(profile))
    assert exc(slave, WriteSingleRequest(1, register, 1)) is None


def test_08_applies_to_w_r_star_function_codes(profile: Profile) -> None:
    slave = Slave(profile, RunningDrive(profile))
    slave.handle(WriteSingleRequest(1, 0x200E, 1), 0.0)
    assert exc(slave, WriteSingleRequest(1, 0x0200, 2)) is X.NOT_WHILE_RUNNING  # F02.00 pole pairs
    assert exc(slave, WriteSingleRequest(1, 0x000A, 2)) is None  # F00.10 is W/R


def test_0x10_write_is_all_or_nothing(slave: Slave) -> None:
    assert slave.handle(WriteMultipleRequest(1, 0x2000, (1, 1500)), 0.0) == WriteMultipleResponse(1, 0x2000, 2)
    assert slave.drive.read(0x2001) == 1500
    # The third register, 2002H pole pairs, is out of range: nothing is written.
    assert exc(slave, WriteMultipleRequest(1, 0x2000, (5, 2000, 99))) is X.ILLEGAL_VALUE
    assert (slave.drive.read(0x2000), slave.drive.read(0x2001)) == (1, 1500)
    # Running past the map (200CH is absent): nothing is written.
    assert exc(slave, WriteMultipleRequest(1, 0x200A, (1, 2, 3))) is X.ILLEGAL_ADDRESS
    assert slave.drive.read(0x200A) == 0


def test_0x10_bad_counts(slave: Slave) -> None:
    # A byte count that is not 2 x N: the sheet's 0x06, "the length of data frame is incorrect".
    assert exc(slave, WriteMultipleRequest(1, 0x2000, (1, 1500), count=3)) is X.FRAME_ERROR
    assert exc(slave, WriteMultipleRequest(1, 0x2000, (1, 1500), byte_count=5)) is X.FRAME_ERROR
    # A register count out of 1-123 with a matching byte count: a value not allowed.
    assert exc(slave, WriteMultipleRequest(1, 0x2000, (), count=0, byte_count=0)) is X.ILLEGAL_VALUE
    assert slave.drive.read(0x2001) == 0  # nothing written


def test_0x10_byte_count_exception_is_the_profiles(profile: Profile) -> None:
    modbus = dataclasses.replace(profile, protocol=dataclasses.replace(profile.protocol, byte_count_exception=3))
    slave = Slave(modbus, RegisterStoreDrive(modbus))
    assert exc(slave, WriteMultipleRequest(1, 0x2000, (1, 1500), count=3)) is X.ILLEGAL_VALUE


def test_restore_defaults(slave: Slave) -> None:
    slave.handle(WriteSingleRequest(1, 0x200E, 1), 0.0)
    slave.handle(WriteSingleRequest(1, 0x000A, 2500), 0.0)
    slave.handle(WriteSingleRequest(1, 0x2003, 77), 0.0)
    assert exc(slave, WriteSingleRequest(1, 0x200F, 1)) is None
    assert slave.handle(ReadRequest(1, 0x000A, 1), 0.0) == ReadResponse(1, (5000,))
    assert slave.handle(ReadRequest(1, 0x2003, 1), 0.0) == ReadResponse(1, (5,))
    assert slave.handle(ReadRequest(1, 0x200F, 1), 0.0) == ReadResponse(1, (0,))


def test_06_bad_crc_gets_frame_error_on_the_wire(profile: Profile) -> None:
    line = Line(Bus([Slave(profile, RegisterStoreDrive(profile))]))
    assert line.hex("01 03 21 00 00 01 8E 37") == "01 83 06 C1 32"
    assert line.hex(with_crc(bytes.fromhex("01 06 20 00 00 01 00"))) == "01 86 06 C2 62"
    assert line.hex("01 03 21 00 00 01 8E 36") == "01 03 02 00 03 F8 45"

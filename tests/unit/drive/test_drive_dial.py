"""The dial switches SW1-SW3: a condition of the drive, acting where 2006H = 3 or 2007H = 5 selects them."""

from __future__ import annotations

import pytest

from c20sim.drive.model import Drive
from c20sim.drive.profile import load_profile
from c20sim.wire.errors import ModbusError
from c20sim.wire.protocol import ExceptionCode
from c20sim.wire.registers import Reg


def fresh() -> Drive:
    profile = load_profile()
    drive = Drive(profile)
    for register, value in ((Reg.RUN_CHANNEL, 3), (Reg.SPEED_SOURCE, 5)):
        drive.write(profile.registers.canonical(register), value)
    return drive


def test_switches_start_off_and_read_back() -> None:
    drive = fresh()
    assert drive.dial_switches == (False, False, False)
    drive.set_dial_switches(True, False, True)
    assert drive.dial_switches == (True, False, True)


@pytest.mark.parametrize(
    ("sw2", "sw3", "source"), [(False, False, 0), (True, False, 1), (False, True, 2), (True, True, 4)]
)
def test_sw2_sw3_select_the_speed_source(sw2: bool, sw3: bool, source: int) -> None:
    drive = fresh()
    drive.set_dial_switches(False, sw2, sw3)
    assert drive.telemetry().speed_source == source


def test_sw2_on_takes_the_speed_from_the_knob() -> None:
    drive = fresh()
    drive.set_ai(1, 5.0)
    assert drive.read(Reg.SET_SPEED) == 750  # both off: the keypad speed, F00.10 = 50.00 Hz at 4 pole pairs
    drive.set_dial_switches(False, True, False)
    assert drive.read(Reg.SET_SPEED) == 1500  # AI1 at 5 V of 10: half of 3000 rpm


def test_sw3_selects_the_run_channel() -> None:
    drive = fresh()
    drive.set_dial_switches(False, False, False)
    assert (drive.read(Reg.STATUS2) >> 5) & 0b11 == 0  # keypad control
    with pytest.raises(ModbusError) as info:
        drive.check_write(Reg.COMMAND, 1)
    assert info.value.code is ExceptionCode.OPERATION_FAILED
    assert drive.keypad(1)  # the keypad's run key is taken
    drive.set_dial_switches(False, False, True)
    assert (drive.read(Reg.STATUS2) >> 5) & 0b11 == 1  # terminal control
    assert not drive.keypad(1)

"""The fault record on the model (issue 42): six fault types newest first, the oldest dropped; a failed save."""

from __future__ import annotations

import json
from pathlib import Path

from c20sim.drive.faultrecord import CURRENT_CONTEXT, FAULT_TYPES, PREVIOUS_CONTEXT, RECORD, has_record
from c20sim.drive.model import Drive
from c20sim.drive.profile import load_profile
from c20sim.wire.registers import Reg, format_fcode


def test_both_profiles_have_the_whole_record_read_only() -> None:
    for name in ("c20-400hr", "c20-2200hv"):
        profile = load_profile(name)
        assert has_record(profile.defaults)
        assert all(not profile.registers[a].access.writable for a in RECORD)


def test_seven_trips_keep_the_last_six_newest_first(tmp_path: Path) -> None:
    drive = Drive(load_profile("c20-400hr"), state_path=tmp_path / "d.json")
    for i, code in enumerate((0x20, 0x21, 0x22, 0x23, 0x24, 0x25, 0x26)):
        drive.advance_to(0.1 * (i + 1))
        drive.force_fault(code)
        drive.keypad(7)  # reset
    assert [drive.read(a) for a in FAULT_TYPES] == [0x26, 0x25, 0x24, 0x23, 0x22, 0x21]
    stored = json.loads((tmp_path / "d.json").read_text())["parameters"]
    assert [stored[format_fcode(a)] for a in FAULT_TYPES] == [0x26, 0x25, 0x24, 0x23, 0x22, 0x21]


def test_a_trip_whose_save_fails_keeps_the_record_in_ram_and_the_drive_going(tmp_path: Path) -> None:
    directory = tmp_path / "eeprom"
    directory.mkdir()
    drive = Drive(load_profile("c20-400hr"), state_path=directory / "d.json")
    directory.rename(tmp_path / "moved")  # the save cannot create its temporary file
    drive.write(Reg.SPEED_SETPOINT, 600)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(2.0)
    drive.force_fault(0x30)
    assert drive.read(Reg.FAULT_CODE) == 0x30 and drive.read(FAULT_TYPES[0]) == 0x30
    assert drive.read(CURRENT_CONTEXT[0]) == 4000  # 40.00 Hz at 600 rpm, 4 pole pairs
    assert drive.read(PREVIOUS_CONTEXT[0]) == 0
    drive.power_cycle()  # RAM-only: gone with the power
    assert drive.read(FAULT_TYPES[0]) == 0

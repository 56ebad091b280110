"""The simulator: drives at the command line's addresses and baud, one state file each."""

from __future__ import annotations

from pathlib import Path

import pytest

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator, parse_addresses, state_path_for
from c20sim.drive.profile import Profile
from c20sim.wire.errors import C20SimError
from c20sim.wire.registers import Reg


@pytest.mark.parametrize(
    ("text", "addresses"), [("1", [1]), ("1,2,5", [1, 2, 5]), ("1-3,7", [1, 2, 3, 7]), (" 9 ", [9])]
)
def test_parse_addresses(text: str, addresses: list[int]) -> None:
    assert parse_addresses(text) == addresses


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty entry"),
        ("1,,2", "empty entry"),
        ("0", "address 0 is outside 1-247"),
        ("1,1", "address 1 is listed twice"),
        ("3-1", "'3-1' runs backwards"),
        ("a", "'a' is not an address"),
    ],
)
def test_parse_addresses_errors(text: str, message: str) -> None:
    with pytest.raises(C20SimError, match=message):
        parse_addresses(text)


def test_drives_sit_at_their_addresses(profile: Profile) -> None:
    sim = Simulator(profile, (3, 7), clock=VirtualClock())
    assert [sim.slaves[a].address for a in (3, 7)] == [3, 7]
    assert sim.drive(7).read(profile.registers.canonical(Reg.ADDRESS)) == 7


def test_baud_from_the_command_line_is_the_drives_setting(profile: Profile) -> None:
    sim = Simulator(profile, (1,), clock=VirtualClock(), baud=9600)
    assert sim.drive(1).read(profile.registers.canonical(Reg.BAUD)) == 3  # F08.01 = 3: 9600
    assert sim.bus.line_baud == 9600
    with pytest.raises(C20SimError, match="baud 9601 is not one the C20 supports"):
        Simulator(profile, (1,), clock=VirtualClock(), baud=9601)


def test_one_state_file_per_drive(tmp_path: Path) -> None:
    state = tmp_path / "eeprom.json"
    assert state_path_for(state, 1, 1) == state
    assert state_path_for(state, 5, 3) == tmp_path / "eeprom.5.json"
    assert state_path_for(None, 5, 3) is None


def test_advance_needs_the_virtual_clock(profile: Profile) -> None:
    from c20sim.core.clock import RealtimeClock

    with pytest.raises(C20SimError, match="only be advanced with the virtual clock"):
        Simulator(profile, (1,), clock=RealtimeClock()).advance(1.0)
    sim = Simulator(profile, (1,), clock=VirtualClock())
    assert sim.advance(2.5) == 2.5
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(C20SimError, match="time does not run backwards"):
            sim.advance(bad)
    assert sim.now() == 2.5

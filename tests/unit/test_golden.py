"""The sheet's command table (docs/protocol.md, corrected frames), byte for byte.

Each row is sent as a master would send it, to the behavioural model built
from the default profile; where a row needs a state (write enable for a
function-code write, the supply switched off, an undervoltage trip), the test
reaches it through the public API: Modbus writes and the injection methods.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pymodbus.framer.rtu import FramerRTU

from c20sim.core.bus import Bus
from c20sim.core.slave import Slave
from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile
from tests.conftest import Line

ECHO = "echo"

# (operation, request, response), in the order of docs/protocol.md.
STATELESS_ROWS = [
    ("forward run", "01 06 20 00 00 01 43 CA", ECHO),
    ("reverse run", "01 06 20 00 00 02 03 CB", ECHO),
    ("stop", "01 06 20 00 00 05 42 09", ECHO),
    ("fault reset", "01 06 20 00 00 07 C3 C8", ECHO),
    ("set speed 3000 rpm", "01 06 20 01 0B B8 D4 88", ECHO),
    ("write 200EH", "01 06 20 0E 00 00 E3 C9", ECHO),
    ("read F00.10", "01 03 00 0A 00 01 A4 08", "01 03 02 13 88 B5 12"),
    ("read status word 2", "01 03 21 01 00 01 DF F6", "01 03 02 00 41 78 74"),
    ("read F00.50 (absent)", "01 03 00 32 00 01 25 C5", "01 83 02 C0 F1"),
    ("write F00.00 = 5", "01 06 00 00 00 05 49 C9", "01 86 03 02 61"),
]


@pytest.fixture
def drive(profile: Profile) -> Drive:
    return Drive(profile)


@pytest.fixture
def line(profile: Profile, drive: Drive) -> Line:
    return Line(Bus([Slave(profile, drive)]))


@pytest.mark.parametrize(
    ("operation", "request_hex", "response_hex"), STATELESS_ROWS, ids=[r[0] for r in STATELESS_ROWS]
)
def test_sheet_row(line: Line, operation: str, request_hex: str, response_hex: str) -> None:
    expected = request_hex if response_hex == ECHO else response_hex
    assert line.hex(request_hex) == expected


def test_write_f00_10_needs_write_enable_as_the_sheet_implies(line: Line) -> None:
    # "Enable function code writable" (200EH = 1), then "write F00.10 = 25.00 Hz".
    assert line.hex("01 06 20 0E 00 01 22 09") == "01 06 20 0E 00 01 22 09"
    assert line.hex("01 06 00 0A 09 C4 AE 0B") == "01 06 00 0A 09 C4 AE 0B"
    assert line.hex("01 03 00 0A 00 01 A4 08") == "01 03 02 09 C4 BF 87"


def test_read_status_word_1_with_the_supply_off(line: Line, drive: Drive) -> None:
    # The sheet's row reads 0005h: drive off, bus voltage not established once the bus capacitor has bled down.
    drive.advance_to(line.t)
    drive.set_supply_voltage(0.0)
    assert line.hex("01 03 21 00 00 01 8E 36", dt=2.0) == "01 03 02 00 05 78 47"


def test_read_fault_code_after_an_undervoltage_trip(line: Line, drive: Drive) -> None:
    # The sheet's row reads 0x0A: undervoltage fault. Run the motor, then sag the supply.
    assert line.hex("01 06 20 01 0B B8 D4 88") == "01 06 20 01 0B B8 D4 88"
    assert line.hex("01 06 20 00 00 01 43 CA") == "01 06 20 00 00 01 43 CA"
    line.send("01 03 21 00 00 01 8E 36", dt=1.0)
    drive.set_supply_voltage(15.0)
    # The spinning motor holds the bus up until it slows below about 1500 rpm (back-EMF 20 V): about 0.5 s.
    assert line.hex("01 03 21 02 00 01 2F F6", dt=1.0) == "01 03 02 00 0A 38 43"
    assert line.hex("01 03 21 00 00 01 8E 36") == "01 03 02 00 04 B9 87"  # status word 1: fault


# --- Every golden frame's CRC, by two implementations that are not the project's crc16.


def _standard_crc_table() -> list[int]:
    """The table of the Modbus over Serial Line spec (V1.02, 6.2.2), from its definition: for each byte value,
    eight shifts right of a 16-bit register, XOR with the polynomial 0xA001 whenever the bit shifted out is 1."""
    table = []
    for byte in range(256):
        register = byte
        for _ in range(8):
            register = (register >> 1) ^ 0xA001 if register & 1 else register >> 1
        table.append(register)
    return table


_TABLE = _standard_crc_table()


def standard_crc(body: bytes) -> bytes:
    """CRC-16/MODBUS as the spec defines it: preset 0xFFFF, table-driven, low byte sent first."""
    register = 0xFFFF
    for byte in body:
        register = (register >> 8) ^ _TABLE[(register ^ byte) & 0xFF]
    return bytes((register & 0xFF, register >> 8))


def pymodbus_crc(body: bytes) -> bytes:
    return FramerRTU.compute_CRC(body).to_bytes(2, "big")  # pymodbus returns it byte-swapped: wire order


#: Every frame written out in this file (requests and replies): eight hex pairs or more in a string.
GOLDEN = sorted(set(re.findall(r'"((?:[0-9A-F]{2} ){3,}[0-9A-F]{2})"', Path(__file__).read_text())))


def test_the_golden_frames_are_all_found() -> None:
    assert len(GOLDEN) >= 20, GOLDEN


def test_the_standard_crc_matches_the_specs_worked_example() -> None:
    # The spec's example (6.2.2, and the sheet's first row): 01 06 20 00 00 01 -> CRC 43 CA, low byte first.
    assert standard_crc(bytes.fromhex("010620000001")) == bytes.fromhex("43CA")
    assert _TABLE[1] == 0xC0C1 and _TABLE[255] == 0x4040  # the spec's table: auchCRCHi/Lo at 1 and 255


@pytest.mark.parametrize("frame", GOLDEN)
def test_a_golden_frames_crc_is_the_standards_and_pymodbuss(frame: str) -> None:
    data = bytes.fromhex(frame)
    assert (standard_crc(data[:-2]), pymodbus_crc(data[:-2])) == (data[-2:], data[-2:]), frame

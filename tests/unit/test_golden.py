"""The sheet's command table (spec/NOTES.md, corrected frames), byte for byte.

Each row is sent as a master would send it, to a drive built from the default
profile; where a row needs a state (write enable for a function-code write,
a fault for the fault-code read), the test reaches it through the public API.
"""

from __future__ import annotations

import pytest

from c20sim.bus import Bus
from c20sim.drive.store import RegisterStoreDrive
from c20sim.profile import Profile
from c20sim.slave import Slave
from tests.conftest import Line

ECHO = "echo"

# (operation, request, response), in the order of NOTES.md.
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
def line(profile: Profile) -> Line:
    return Line(Bus([Slave(profile, RegisterStoreDrive(profile))]))


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

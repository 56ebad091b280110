"""``c20sim exercise write`` never writes a value other than the one typed: for every writable register of every
shipped profile, a value past its range, one that would wrap in 16 bits, and nan/inf are one line and exit 2, and
nothing is sent (the port is never opened). Through the command line, as a user types it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from c20sim.cli import main
from c20sim.drive.profile import load_profile
from c20sim.wire.registers import RegisterSpec

PROFILES = ("c20-400hr", "c20-2200hv")
#: a port that does not exist: a value that got past the checks would end in "cannot open", not in its own line
NOWHERE = "/nonexistent/ttyC20"


def amount(spec: RegisterSpec, raw: int) -> str:
    if spec.hex_display:
        text = f"0x{raw & 0xFFFF:04X}"
    else:
        decimals = max(0, len(f"{spec.scale:g}".partition(".")[2]))
        text = f"{raw * spec.scale:.{decimals}f} {spec.unit}".rstrip()
    name = spec.values.get(raw & 0xFFFF)
    return f"{text} ({name})" if name else text


def typed(spec: RegisterSpec, raw: int) -> str:
    """What a user types for ``raw`` in the register's units."""
    decimals = max(0, len(f"{spec.scale:g}".partition(".")[2]))
    return f"{raw * spec.scale:.{decimals}f}"


def writable(profile: str) -> list[RegisterSpec]:
    return [s for s in load_profile(profile).registers.specs() if s.access.writable]


@pytest.mark.parametrize("profile", PROFILES)
def test_no_writable_register_takes_a_value_it_cannot_hold(profile: str, capsys: pytest.CaptureFixture[str]) -> None:
    specs = writable(profile)
    assert len(specs) == 67  # every W/R and W/R* register and function code of the profile (issue 42 added 27)
    for spec in specs:
        where = f"{spec.label} {spec.name}"
        bounds = f"{amount(spec, spec.minimum)} to {amount(spec, spec.maximum)}"
        cases = [
            (typed(spec, spec.maximum + 1), f"{where}: {typed(spec, spec.maximum + 1)} is outside {bounds}"),
            (typed(spec, 0x10000), f"{where}: {typed(spec, 0x10000)} is outside {bounds}"),  # would wrap to 0
            (
                typed(spec, 0x10000 + spec.minimum),
                f"{where}: {typed(spec, 0x10000 + spec.minimum)} is outside {bounds}",
            ),
            ("-1", f"{where}: -1 is outside {bounds}"),
            (
                "nan",
                f"{where}: nan is not a finite number; give one from {amount(spec, spec.minimum)} to "
                f"{amount(spec, spec.maximum)}",
            ),
            (
                "inf",
                f"{where}: inf is not a finite number; give one from {amount(spec, spec.minimum)} to "
                f"{amount(spec, spec.maximum)}",
            ),
            (
                "-inf",
                f"{where}: -inf is not a finite number; give one from {amount(spec, spec.minimum)} to "
                f"{amount(spec, spec.maximum)}",
            ),
        ]
        if spec.minimum > 0:
            cases.append(
                (typed(spec, spec.minimum - 1), f"{where}: {typed(spec, spec.minimum - 1)} is outside {bounds}")
            )
        if spec.scale < 1:  # between two steps: 2.55 where the register counts 0.1 s
            half = f"{(spec.minimum + 0.5) * spec.scale:.6g}"
            cases.append(
                (
                    half,
                    f"{where}: {half} is not a whole number of its steps of "
                    f"{f'{spec.scale:g} {spec.unit}'.rstrip()}; the nearest is ",
                )
            )
        for text, message in cases:
            assert main(["exercise", NOWHERE, "--profile", profile, "write", spec.label, text]) == 2, (spec.label, text)
            err = capsys.readouterr().err
            assert err.startswith(f"c20sim: {message}") and err.count("\n") == 1, (spec.label, text, err)
            assert "cannot open" not in err


@pytest.mark.parametrize(
    ("words", "message"),
    [
        (
            ["write", "setpoint", "65536"],
            "c20sim: 2001H communication speed setting: 65536 is outside 0 rpm to 3000 rpm\n",
        ),
        (
            ["write", "setpoint", "nan"],
            "c20sim: 2001H communication speed setting: nan is not a finite number; give one from 0 rpm to 3000 rpm\n",
        ),
        (
            ["write", "setpoint", "1500.4"],
            "c20sim: 2001H communication speed setting: 1500.4 is not a whole number "
            "of its steps of 1 rpm; the nearest is 1500 rpm\n",
        ),
        (
            ["write", "accel", "2.55"],
            "c20sim: 2003H acceleration time: 2.55 is not a whole number of its steps of 0.1 s; the nearest is 2.5 s\n",
        ),
        (
            ["write", "command", "9"],
            "c20sim: 2000H communication control command: 9 is outside 1 (forward run) to 8 (jog stop)\n",
        ),
        (
            ["--out", "x.jsonl", "--speeds", "1,2,x"],
            "c20sim: --speeds 1,2,x: 'x' is not a number; give rpm such as 900,1800\n",
        ),
        (
            ["--out", "x.jsonl", "--speeds", "1,nan"],
            "c20sim: --speeds 1,nan: each speed above 0 and at most 3000 rpm (the profile's rated)\n",
        ),
        (["--address", "256", "read", "speed"], "c20sim: --address 256: give the drive's address, 1-247 (2008H)\n"),
        (
            ["--address", "0", "write", "setpoint", "10"],
            "c20sim: --address 0: give the drive's address, 1-247 (2008H)\n",
        ),
    ],
)
def test_each_bad_value_is_one_line_from_the_command_line(words: list[str], message: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "exercise", NOWHERE, *words],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (result.returncode, result.stdout, result.stderr) == (2, "", message)

"""The power-on and running hour counters (F07.13, F07.14; issue 42): whole hours, in EEPROM."""

from __future__ import annotations

import json
from pathlib import Path

from c20sim.drive.counters import F_POWER_ON_HOURS, F_RUNNING_HOURS
from c20sim.drive.model import STEP, Drive
from c20sim.drive.profile import load_profile
from c20sim.wire.registers import Reg, format_fcode

HOUR = 3600.0


def hours(drive: Drive) -> tuple[int, int]:
    return drive.read(F_POWER_ON_HOURS), drive.read(F_RUNNING_HOURS)


def test_the_counters_count_whole_hours_of_power_and_of_running_and_keep_them(tmp_path: Path) -> None:
    state = tmp_path / "d.json"
    drive = Drive(load_profile("c20-400hr"), state_path=state)
    drive.advance_to(2.5 * HOUR)  # stopped: powered, not running
    assert hours(drive) == (2, 0)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)  # runs from 2.5 h
    drive.advance_to(3.5 * HOUR - 2 * STEP)
    assert hours(drive) == (3, 0)
    drive.advance_to(3.5 * HOUR + 2 * STEP)
    assert hours(drive) == (3, 1)  # an hour of running, to the step
    drive.write(Reg.COMMAND, 6)  # a free stop 2 ms after the hour: 2 ms of the next counted
    drive.advance_to(4.0 * HOUR)
    drive.write(Reg.COMMAND, 1)  # running again from 4 h: the second hour 2 ms before 5 h
    drive.advance_to(5.0 * HOUR - 4 * STEP)
    assert hours(drive) == (4, 1)
    drive.advance_to(5.0 * HOUR)
    assert hours(drive) == (5, 2)
    stored = json.loads(state.read_text())["parameters"]
    assert (stored[format_fcode(F_POWER_ON_HOURS)], stored[format_fcode(F_RUNNING_HOURS)]) == (5, 2)
    drive.advance_to(5.6 * HOUR)
    drive.power_cycle()  # the part hours go; the whole ones stay
    assert hours(drive) == (5, 2)
    drive.advance_to(drive.t + 0.9 * HOUR)
    assert hours(drive) == (5, 2)  # 0.6 h before the cycle and 0.9 h after: not an hour since power-up
    drive.advance_to(drive.t + 0.1 * HOUR + STEP)
    assert hours(drive) == (6, 2)
    drive.write(Reg.WRITE_ENABLE, 1)
    drive.write(Reg.RESTORE_DEFAULTS, 1)  # kept, as the fault record
    assert hours(drive) == (6, 2)
    assert hours(Drive(load_profile("c20-400hr"), state_path=state)) == (6, 2)  # a new process on the file


def test_the_counts_are_the_same_whatever_the_polling() -> None:
    def run(poll: float) -> list[tuple[int, int]]:
        """Running 3 h from 0.1 h on: the counts at each quarter hour, polled every ``poll`` seconds."""
        drive = Drive(load_profile("c20-400hr"))
        drive.advance_to(0.1 * HOUR)
        drive.write(Reg.SPEED_SETPOINT, 900)
        drive.write(Reg.COMMAND, 1)
        out = []
        k = round(0.1 * HOUR / poll)
        while k * poll < 3.2 * HOUR:
            k += 1
            drive.advance_to(k * poll)
            if abs(k * poll / (0.25 * HOUR) - round(k * poll / (0.25 * HOUR))) < 1e-9:
                out.append(hours(drive))
        return out

    coarse = run(0.25 * HOUR)[:12]  # 0.25 h to 3.0 h
    assert coarse == run(60.0)[:12] == run(7.2)[:12]
    assert coarse[3] == (1, 0) and coarse[4] == (1, 1) and coarse[-1] == (3, 2)

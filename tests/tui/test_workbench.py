"""Every device fault switch trips its own code, by its cause, on a virtual clock (no screen)."""

from __future__ import annotations

import pytest

from c20sim.clock import VirtualClock
from c20sim.profile import load_profile
from c20sim.registers import Reg
from c20sim.simulator import Simulator
from c20sim.tui.workbench import History, Workbench


def running_bench() -> Workbench:
    bench = Workbench(Simulator(load_profile(), (1,), clock=VirtualClock()))
    drive = bench.drive(1)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)
    bench.advance(1.0)
    assert drive.read(Reg.MOTOR_SPEED) == 1500
    return bench


@pytest.mark.parametrize(
    ("key", "seconds", "code"),
    [
        ("u", 0.5, 0x0A),  # UV
        ("v", 0.5, 0x09),  # OV3: at constant speed
        ("c", 0.5, 0x06),  # OC3: at constant speed
        ("l", 40.0, 0x0B),  # OL1
        ("k", 4.0, 27),  # STALL (assumed code)
        ("o", 31.0, 0x10),  # OH2
        ("h", 0.5, 26),  # HALL (assumed code)
        ("e", 0.1, 0x11),  # EF
        ("1", 0.0, 0x01),  # OUt1, latched
        ("8", 0.0, 0x15),  # EEP, latched
    ],
)
def test_each_device_fault_trips_its_code_and_clears(key: str, seconds: float, code: int) -> None:
    bench = running_bench()
    drive = bench.drive(1)
    bench.toggle_device_fault(1, key)
    assert bench.device_fault_active(1, key)
    bench.advance(max(seconds, 0.001))
    assert drive.read(Reg.FAULT_CODE) == code
    bench.toggle_device_fault(1, "z")
    assert not bench.device_fault_active(1, key)
    bench.advance(60.0)  # the drive cools, the bus settles
    assert bench.keypad(1, "reset") is None
    assert drive.read(Reg.FAULT_CODE) == 0


def test_overheat_takes_about_thirty_seconds() -> None:
    bench = running_bench()
    bench.toggle_device_fault(1, "o")
    bench.advance(25.0)
    assert bench.drive(1).read(Reg.FAULT_CODE) == 0
    bench.advance(6.0)
    assert bench.drive(1).read(Reg.FAULT_CODE) == 0x10


def test_history_keeps_one_minute_at_half_second_steps() -> None:
    bench = running_bench()
    bench.advance(100.0)
    history = bench.history[1]
    assert len(history.speed) == 120
    assert set(history.speed) == {1500.0}
    fresh = History()
    assert fresh.add(bench.telemetry(1))
    assert not fresh.add(bench.telemetry(1))  # the same instant: no second sample

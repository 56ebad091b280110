"""Every device fault switch trips its own code, by its cause, on a virtual clock (no screen)."""

from __future__ import annotations

import pytest

from c20sim import control
from c20sim.control import ControlError
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.drive.terminals import Input
from c20sim.tui.workbench import History, Workbench, condition_range
from c20sim.wire.registers import Reg


def running_bench() -> Workbench:
    bench = Workbench(Simulator(load_profile(), (1,), clock=VirtualClock()))
    drive = bench.sim.drive(1)
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
        ("c", 0.5, 0x06),  # a shock load while running: OC3 (current limiting stretches a heavy ramp instead)
        ("l", 40.0, 0x0C),  # OL2: 18 A is 164 % of the drive's 11 A (INVT curve: about 26 s)
        ("k", 4.0, 27),  # STALL (assumed code)
        ("o", 160.0, 0x10),  # OH2: ambient 150 °C
        ("h", 0.5, 26),  # HALL (assumed code)
        ("e", 0.1, 0x11),  # EF
        ("1", 0.0, 0x01),  # OUt1, latched
        ("8", 0.0, 0x15),  # EEP, latched
    ],
)
def test_each_device_fault_trips_its_code_and_clears(key: str, seconds: float, code: int) -> None:
    bench = running_bench()
    drive = bench.sim.drive(1)
    bench.toggle_device_fault(1, key)
    assert bench.device_fault_active(1, key)
    bench.advance(max(seconds, 0.001))
    assert drive.read(Reg.FAULT_CODE) == code
    bench.toggle_device_fault(1, "z")
    assert not bench.device_fault_active(1, key)
    bench.advance(60.0)  # the drive cools, the bus settles
    assert bench.keypad(1, "reset") is None
    assert drive.read(Reg.FAULT_CODE) == 0


def test_history_keeps_one_minute_at_half_second_steps() -> None:
    bench = running_bench()
    bench.advance(100.0)
    history = bench.history[1]
    assert len(history.speed) == 120
    assert set(history.speed) == {1500.0}
    fresh = History()
    assert fresh.add(bench.telemetry(1))
    assert not fresh.add(bench.telemetry(1))  # the same instant: no second sample


def test_switches_follow_conditions_set_by_the_control_api() -> None:
    """The bench reads the drive: what the API (``dashboard --control``, a scenario) changes shows, and a key undoes it."""
    bench = running_bench()
    sim = bench.sim
    control.set_conditions(sim, 1, {"supply_v": 18})
    assert bench.device_fault_active(1, "u")
    bench.toggle_device_fault(1, "u")  # the cause switched off: the supply is back
    assert bench.telemetry(1).supply_v == sim.profile.supply.voltage_v
    assert not bench.device_fault_active(1, "u")
    control.set_conditions(sim, 1, {"ambient_c": 150, "hall_fault": "stuck0", "terminal_inputs": int(Input.EF)})
    assert [bench.device_fault_active(1, key) for key in "ohe"] == [True, True, True]
    bench.toggle_device_fault(1, "e")
    assert bench.sim.drive(1).telemetry().input_terminals & Input.EF == 0
    key = next(k for k, (code, _) in bench.forced.items() if code == 0x15)
    control.inject_fault(sim, 1, 0x15, persistent=True)
    assert bench.device_fault_active(1, key)
    control.power_cycle(sim, 1)  # clears the latched fault, keeps the conditions
    assert not bench.device_fault_active(1, key)
    assert bench.device_fault_active(1, "o")
    assert bench.conditions(1).ambient_c == 150


def test_conditions_are_checked_as_the_control_api_checks_them() -> None:
    bench = running_bench()
    for setter, value, message in (
        (bench.set_supply, 5000.0, "supply_v: 5000 is outside 0-2000"),
        (bench.set_load, -1.0, "load_torque_nm: -1 is outside 0-1000"),
        (bench.set_ambient, 544.0, "ambient_c: 544 is outside -50-150"),
    ):
        with pytest.raises(ControlError, match=message):
            setter(1, value)
    tel = bench.telemetry(1)
    assert (tel.supply_v, tel.load_torque_nm, tel.ambient_c) == (48.0, 0.0, 25.0)
    assert condition_range("supply_v") == (0.0, 2000.0)
    assert condition_range("ambient_c") == (-50.0, 150.0)


def test_overheat_is_an_ambient_the_control_api_accepts() -> None:
    bench = running_bench()
    bench.toggle_device_fault(1, "o")
    ambient = bench.telemetry(1).ambient_c
    assert ambient == 150.0  # the API's maximum: a scenario can replay it
    control.set_conditions(bench.sim, 1, {"ambient_c": ambient})
    seconds = bench.overheat_seconds()
    assert 155 < seconds < 160  # 240 s * ln(125 / 65)
    how = next(s.how for s in bench.device_switches if s.key == "o")
    assert f"trips in about {seconds:.0f} s" in how
    assert "T/t advances virtual time" in how
    bench.advance(seconds - 3)
    assert bench.sim.drive(1).read(Reg.FAULT_CODE) == 0
    bench.advance(6.0)
    assert bench.sim.drive(1).read(Reg.FAULT_CODE) == 0x10


@pytest.mark.parametrize(("key", "state"), [("jog", "jog forward"), ("jogrev", "jog reverse")])
def test_each_jog_key_releases_its_jog(key: str, state: str) -> None:
    bench = Workbench(Simulator(load_profile(), (1,), clock=VirtualClock()))
    assert bench.cycle_channel(1) == 0  # communication -> keypad
    assert bench.keypad(1, key) is None
    bench.advance(1.0)
    assert bench.sim.drive(1).state.value == state
    assert bench.keypad(1, key) is None  # pressed again: released
    bench.advance(2.0)
    assert bench.sim.drive(1).state.value == "stopped"
    assert bench.sim.drive(1).read(Reg.MOTOR_SPEED) == 0

"""Observing the drive never changes it: the same timeline polled often or rarely gives identical state.

The comparison is exact (registers and the telemetry's floats), at the times
both polling patterns share. The timelines cross ramps, load steps, trips,
resets and long steady stretches that the model skips in closed form.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from c20sim.drive.model import Drive, Telemetry
from c20sim.drive.profile import Profile, load_profile
from c20sim.drive.terminals import Input
from c20sim.wire.registers import FIXED_REGISTERS, Reg

Action = Callable[[Drive], None]


@pytest.fixture(scope="module")
def profile() -> Profile:
    return load_profile("c20-400hr")


def snapshot(drive: Drive, profile: Profile) -> tuple[tuple[int, ...], Telemetry]:
    cells = [profile.registers.canonical(a) for a in FIXED_REGISTERS] + sorted(profile.defaults)
    return tuple(drive.read(c) for c in cells), drive.telemetry()


def simulate(
    profile: Profile, events: dict[int, list[Action]], end_ms: int, poll_ms: int, compare_ms: int
) -> dict[int, tuple[tuple[int, ...], Telemetry]]:
    """Run a timeline (times in ms), polling every ``poll_ms``; snapshots at multiples of ``compare_ms``."""
    drive = Drive(profile)
    times = sorted(set(range(poll_ms, end_ms + 1, poll_ms)) | set(events))
    seen: dict[int, tuple[tuple[int, ...], Telemetry]] = {}
    for ms in times:
        drive.advance_to(ms / 1000)
        for action in events.get(ms, []):
            action(drive)
        drive.read(Reg.MOTOR_SPEED)  # every poll looks
        if ms and ms % compare_ms == 0 and ms % poll_ms == 0:
            seen[ms] = snapshot(drive, profile)
    return seen


def write(register: int, value: int) -> Action:
    return lambda d: d.write(d.profile.registers.canonical(register), value)


def busy_timeline() -> dict[int, list[Action]]:
    return {
        0: [write(Reg.SPEED_SETPOINT, 3000), write(Reg.COMMAND, 1)],
        2250: [lambda d: d.set_load_torque(0.8)],
        4500: [lambda d: d.set_supply_voltage(40.0)],
        6123: [lambda d: d.set_supply_voltage(15.0)],  # undervoltage trip while running
        7500: [lambda d: d.set_supply_voltage(48.0)],
        8000: [write(Reg.COMMAND, 7)],
        8300: [write(Reg.SPEED_SETPOINT, 2000), write(Reg.COMMAND, 2)],
        12700: [lambda d: d.set_load_torque(3.0)],  # stall
        20000: [lambda d: d.set_load_torque(0.0), write(Reg.COMMAND, 7), lambda d: d.set_ambient(40.0)],
        20500: [
            lambda d: d.set_load_inertia(0.01),
            write(Reg.ACCEL_TIME, 20),  # 2 s: a 0.5 s ramp of this inertia trips overcurrent
            write(Reg.SPEED_SETPOINT, 3000),
            write(Reg.COMMAND, 1),
        ],
        30250: [write(0x0B03, 0), write(Reg.DECEL_TIME, 20), write(Reg.COMMAND, 5)],  # stall prevention off: OV2
        31500: [lambda d: d.set_load_inertia(0.0)],
        33000: [write(Reg.COMMAND, 7), write(0x0802, 20), lambda d: d.communicated(33.0)],
        33100: [write(Reg.COMMAND, 3), lambda d: d.communicated(33.1)],
        34400: [lambda d: d.set_terminal_inputs(Input.EF)],
        35000: [lambda d: d.set_terminal_inputs(0), write(Reg.COMMAND, 7)],
        35500: [write(Reg.COMMAND, 4), lambda d: d.communicated(35.5)],  # then silence: timeout at 37.5
    }


def test_polling_every_ms_or_every_second_gives_identical_state(profile: Profile) -> None:
    events = busy_timeline()
    fine = simulate(profile, events, 40_000, 1, 1000)
    coarse = simulate(profile, events, 40_000, 1000, 1000)
    assert fine.keys() == coarse.keys() == set(range(1000, 40_001, 1000))
    for ms in fine:
        assert fine[ms] == coarse[ms], f"differs at {ms / 1000} s"
    statuses = [fine[ms][1].status for ms in sorted(fine)]
    assert {1, 2, 3, 4} <= set(statuses)  # the timeline really ran, tripped and recovered
    codes = {fine[ms][1].fault_code for ms in fine}
    assert {0x0A, 0x1B, 0x08, 0x12} <= codes  # undervoltage, stall, overvoltage, communication


def overload_timeline() -> dict[int, list[Action]]:
    return {
        0: [write(Reg.SPEED_SETPOINT, 1500), write(0x021B, 500), write(Reg.COMMAND, 1)],  # F02.27 = 50.0 %
        3000: [lambda d: d.set_load_torque(1.16), lambda d: d.set_ambient(30.0)],  # 193 % of 5 A: OL1 after ~100 s
        250_000: [write(Reg.COMMAND, 7), lambda d: d.set_load_torque(0.5)],  # cooled below the warning level
        250_500: [write(Reg.COMMAND, 1)],
    }


def test_trips_inside_skipped_stretches_land_on_the_same_step(profile: Profile) -> None:
    events = overload_timeline()
    fine = simulate(profile, events, 400_000, 10, 1000)
    coarse = simulate(profile, events, 400_000, 1000, 1000)
    rare = simulate(profile, events, 400_000, 100_000, 100_000)
    assert fine.keys() == coarse.keys()
    for ms in fine:
        assert fine[ms] == coarse[ms], f"differs at {ms / 1000} s"
    for ms in rare:
        assert rare[ms] == fine[ms], f"differs at {ms / 1000} s"
    assert fine[100_000][1].status == 1
    assert fine[110_000][1].fault_code == 0x0B
    assert fine[400_000][1].status == 1


def physics_timeline() -> dict[int, list[Action]]:
    """Issue 13's physics: stall prevention, the speed loop under load steps, active loads, F08.03, Hall timing."""
    return {
        0: [
            lambda d: d.set_load_inertia(0.003),
            write(Reg.ACCEL_TIME, 30),
            write(Reg.SPEED_SETPOINT, 3000),
            write(Reg.COMMAND, 1),
        ],
        5000: [write(Reg.DECEL_TIME, 5), write(Reg.COMMAND, 5)],  # stretched by stall prevention
        8000: [lambda d: d.set_load_inertia(0.0), write(Reg.SPEED_SETPOINT, 1500), write(Reg.COMMAND, 1)],
        11_000: [lambda d: d.set_load_torque(0.6)],  # the loop dips and recovers
        14_000: [lambda d: d.set_load_torque(0.0), lambda d: d.set_active_load(0.6)],  # lowering: regenerates
        17_000: [lambda d: d.set_active_load(-0.6), write(Reg.SPEED_SETPOINT, 0)],  # held at zero
        20_000: [
            lambda d: d.set_active_load(0.0),
            write(Reg.SPEED_SETPOINT, 100),
            write(0x0802, 10),  # F08.02 = 1 s
            write(0x0803, 2),  # F08.03 = 2: ramp to a stop on a timeout
            lambda d: d.communicated(20.0),
        ],  # silence: stops at 21 s, then the Hall reading times out
        23_000: [write(0x0802, 0), write(Reg.SPEED_SETPOINT, 2000), write(Reg.COMMAND, 1)],
        27_000: [write(Reg.COMMAND, 6)],  # free stop: the output registers read 0 while it coasts
    }


def test_the_new_physics_is_as_deterministic(profile: Profile) -> None:
    events = physics_timeline()
    fine = simulate(profile, events, 32_000, 1, 1000)
    odd = simulate(profile, events, 32_000, 7, 7000)
    coarse = simulate(profile, events, 32_000, 1000, 1000)
    assert fine.keys() == coarse.keys()
    for ms in fine:
        assert fine[ms] == coarse[ms], f"differs at {ms / 1000} s"
    for ms in odd:
        assert odd[ms] == fine[ms], f"differs at {ms / 1000} s"
    states = [fine[ms][1].state for ms in sorted(fine)]
    assert {"forward", "decelerating", "stopped", "coasting"} <= set(states)
    assert fine[16_000][1].current_a < 0.0  # regenerating
    assert fine[22_000][1].state == "stopped" and fine[22_000][1].fault_code == 0
    assert all(fine[ms][1].fault_code == 0 for ms in fine)


def test_writing_the_set_speed_it_holds_changes_nothing(profile: Profile) -> None:
    # A master that writes its set speed every cycle: the drive takes the same value again as a write of
    # nothing, and ends exactly where a drive written once does (a value that changes still acts at once).
    once = {0: [write(Reg.SPEED_SETPOINT, 2500), write(Reg.COMMAND, 1)], 4000: [write(Reg.SPEED_SETPOINT, 1000)]}
    every = {ms: [write(Reg.SPEED_SETPOINT, 2500 if ms < 4000 else 1000)] for ms in range(0, 8000, 10)}
    every[0].append(write(Reg.COMMAND, 1))
    a = simulate(profile, once, 8000, 10, 1000)
    b = simulate(profile, every, 8000, 10, 1000)
    assert a == b
    assert a[3000][1].speed_rpm == 2500 and a[8000][1].speed_rpm == 1000

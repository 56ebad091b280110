"""Stall prevention and current limiting as continuous regulators (issue 42), on the model in virtual time.

A heavy stop with overvoltage stall prevention brakes at the current that holds the bus at the stall level:
3004H read every millisecond moves by at most the regulator's slew (a share of the current limit per step),
where before it alternated between braking and motoring each step (-10.1 A / +0.85 A, bus 52-58 V). The
stop then takes about the time the rotor's energy needs to go into the brake resistor at the stall level.
"""

from __future__ import annotations

import itertools

import pytest

from c20sim.drive.integrator import STALL_SLEW_SHARE
from c20sim.drive.model import STEP, Drive
from c20sim.drive.physics import RPM
from c20sim.drive.profile import Profile, load_profile
from c20sim.drive.statemachine import State
from c20sim.wire.registers import Reg

PROFILES = ("c20-400hr", "c20-2200hv")


def at_3000(profile: Profile, times: float) -> Drive:
    """A drive with ``times`` x the rotor's inertia coupled, run up to 3000 rpm (current limiting on)."""
    drive = Drive(profile)
    drive.set_load_inertia(times * profile.motor.inertia_kg_m2)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    k = 0
    while drive.read(Reg.MOTOR_SPEED) != 3000:
        k += 1
        drive.advance_to(k * STEP)
        assert k < 30_000 and drive.read(Reg.FAULT_CODE) == 0
    return drive


def polls(drive: Drive) -> list[tuple[int, float, State]]:
    """3004H (0.01 A), the bus (V) and the state, read every 1 ms while the drive decelerates."""
    out = []
    k = round(drive.t / STEP)
    while drive.state is State.DECELERATING:
        k += 1
        drive.advance_to(k * STEP)
        out.append((drive.read(Reg.OUTPUT_CURRENT), drive.telemetry().bus_v, drive.state))
        assert len(out) < 60_000
    return out


@pytest.mark.parametrize("name", PROFILES)
def test_a_heavy_stop_moves_3004h_by_at_most_the_regulators_slew_per_ms(name: str) -> None:
    profile = load_profile(name)
    drive = at_3000(profile, 170)
    drive.write(profile.registers.canonical(Reg.DECEL_TIME), 1)  # 0.1 s: far beyond what the bus can take
    drive.write(Reg.COMMAND, 5)
    read = polls(drive)
    assert drive.read(Reg.FAULT_CODE) == 0 and drive.read(Reg.STATUS1) == 6  # stopped, braking at zero
    slew = round(STALL_SLEW_SHARE * profile.protection.current_limit_a * 100)  # 0.01 A per ms
    steps = [abs(b[0] - a[0]) for a, b in itertools.pairwise(read) if b[2] is State.DECELERATING]
    assert max(steps) <= slew + 1  # 3004H rounds to 0.01 A
    stall_v = profile.supply.voltage_v * 1.2  # F11.04 = 120 %
    assert max(bus for _, bus, _ in read) <= stall_v + 1e-6  # held at the level, never above it
    # While the regulator holds the bus at the level, every poll reads it there: no comb between levels.
    held = [bus for _, bus, _ in read[50 : len(read) // 3]]
    assert min(held) == pytest.approx(stall_v, abs=0.01) and max(held) == pytest.approx(stall_v, abs=0.01)


@pytest.mark.parametrize("name", PROFILES)
def test_the_heavy_stop_takes_about_the_energy_over_the_resistors_power(name: str) -> None:
    """The rotor's energy into the brake resistor at the stall level, less what the motor and the inverter
    burn: the stop lasts at most that long (the current limit stretches its slow end, below which the
    regenerated power no longer reaches the resistor's) and not much less."""
    profile = load_profile(name)
    drive = at_3000(profile, 170)
    drive.write(profile.registers.canonical(Reg.DECEL_TIME), 1)
    drive.write(Reg.COMMAND, 5)
    began = drive.t
    polls(drive)
    took = drive.t - began
    stall_v = profile.supply.voltage_v * 1.2
    energy = 0.5 * 171 * profile.motor.inertia_kg_m2 * (3000 * RPM) ** 2
    bound = energy / (stall_v**2 / profile.supply.brake_resistor_ohm)
    assert 0.8 * bound < took < 1.15 * bound


@pytest.mark.parametrize("name", PROFILES)
def test_a_current_limited_start_holds_3004h_at_the_level_without_a_comb(name: str) -> None:
    profile = load_profile(name)
    level = round(profile.protection.drive_rated_current_a * 1.6 * 100)  # F11.06 = 160 %
    drive = Drive(profile)
    drive.set_load_inertia(170 * profile.motor.inertia_kg_m2)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    read = []
    for k in range(20, 2000):  # from 20 ms, past the first steps' rise
        drive.advance_to(k * STEP)
        read.append(drive.read(Reg.OUTPUT_CURRENT))
    assert set(read) == {level}

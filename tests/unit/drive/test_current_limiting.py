"""Current limiting (F11.05/F11.06, issue 27): a heavy start or stop stretches instead of tripping.

The figures come from the profile: the limiting level is 160 % of the drive's rated current (F11.06), the
clamp and the trip are the profile's. With limiting off (F11.05 = 0) the drive trips OC1/OC2 as before.
"""

from __future__ import annotations

import math

import pytest

from c20sim.drive.model import F_CURRENT_LIMIT_LEVEL, F_CURRENT_LIMITING, F_OV_STALL, Drive
from c20sim.drive.physics import RPM
from c20sim.drive.profile import FaultCause, Profile, load_profile
from c20sim.wire.registers import Reg
from tests.unit.drive.test_drive_faults import faulted, first_time

PROFILES = ("c20-400hr", "c20-2200hv")


def level_a(profile: Profile) -> float:
    return profile.protection.drive_rated_current_a * 1.6  # F11.06 = 160.0 %


def start(profile: Profile, inertia: float, *, limiting: int = 1) -> Drive:
    """A forward run to 3000 rpm on the default 0.5 s ramp with ``inertia`` coupled."""
    drive = Drive(profile)
    drive.write(F_CURRENT_LIMITING, limiting)
    drive.set_load_inertia(inertia)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    return drive


def at_speed(d: Drive) -> bool:
    return d.read(Reg.MOTOR_SPEED) == 3000 or faulted(d)


@pytest.mark.parametrize("name", PROFILES)
def test_a_heavy_start_reaches_speed_later_than_the_ramp_and_does_not_trip(name: str) -> None:
    profile = load_profile(name)
    m = profile.motor
    inertia = 30 * m.inertia_kg_m2  # about 30x the rotor: the 0.5 s ramp would ask 2-3x the trip level
    asked = (m.inertia_kg_m2 + inertia) * 3000 * RPM / 0.5 / m.kt_nm_per_a
    assert asked > profile.protection.overcurrent_a
    drive = start(profile, inertia)
    drive.advance_to(0.2)
    assert drive.read(Reg.OUTPUT_CURRENT) == round(level_a(profile) * 100)  # at the level, below the clamp
    ramp, output = drive.read(Reg.RAMP_FREQUENCY), drive.read(Reg.OUTPUT_FREQUENCY)
    assert abs(ramp - output) <= 1  # the ramp advances only as fast as the rotor: within 0.01 Hz of it
    assert ramp < 0.4 * drive.read(Reg.SET_FREQUENCY) / 2  # less than half the way the 0.5 s ramp would be
    reached = first_time(drive, at_speed, 10.0, 0.001)
    assert reached is not None and not faulted(drive)
    # The time the level's torque takes, against friction and the viscous drag at each speed.
    torque = level_a(profile) * m.kt_nm_per_a - m.friction_nm
    b = m.viscous_nm_per_krpm / 1000.0 / RPM  # N m per rad/s
    omega = 3000 * RPM
    expected = (m.inertia_kg_m2 + inertia) / b * math.log(torque / (torque - b * omega))
    assert expected > 0.5
    assert reached == pytest.approx(expected, rel=0.03)


@pytest.mark.parametrize("name", PROFILES)
def test_with_limiting_off_the_same_start_trips_oc1(name: str) -> None:
    profile = load_profile(name)
    drive = start(profile, 30 * profile.motor.inertia_kg_m2, limiting=0)
    assert first_time(drive, faulted, 0.01) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERCURRENT_ACCEL)


def test_the_level_is_f11_06_of_the_drive_rating_and_never_above_the_clamp() -> None:
    profile = load_profile("c20-400hr")
    drive = start(profile, 0.01)
    drive.write(F_CURRENT_LIMIT_LEVEL, 1000)  # 100.0 %: 11 A
    drive.advance_to(0.2)
    assert drive.read(Reg.OUTPUT_CURRENT) == 1100
    drive.write(F_CURRENT_LIMIT_LEVEL, 2000)  # 200.0 % = 22 A, above the 20 A clamp: the clamp
    drive.advance_to(0.4)
    assert drive.read(Reg.OUTPUT_CURRENT) == round(profile.protection.current_limit_a * 100)


def hard_stop(profile: Profile, *, stall: int, limiting: int) -> tuple[Drive, float, float | None]:
    """0.05 kg m^2 at 3000 rpm, then a stop with a 0.1 s decel (2004H = 1): (drive, start of the stop, its end)."""
    drive = start(profile, 0.05)
    reached = first_time(drive, at_speed, 20.0, 0.01)
    assert reached is not None and not faulted(drive)
    drive.write(F_CURRENT_LIMITING, limiting)
    drive.write(F_OV_STALL, stall)
    drive.write(profile.registers.canonical(Reg.DECEL_TIME), 1)
    drive.write(Reg.COMMAND, 5)
    began = drive.t
    end = first_time(drive, lambda d: d.read(Reg.STATUS1) in (4, 6), began + 60.0, 0.001)
    return drive, began, end


def test_a_hard_stop_of_a_heavy_load_stretches_without_a_trip() -> None:
    profile = load_profile("c20-400hr")
    drive, began, end = hard_stop(profile, stall=1, limiting=1)
    assert end is not None and drive.read(Reg.STATUS1) == 6  # braking at zero: no fault
    # The kinetic energy goes into the brake resistor, which takes at most (overvoltage level)^2 / R:
    # the stop takes at least that long, far longer than the 0.1 s asked.
    s = profile.supply
    energy = 0.5 * (profile.motor.inertia_kg_m2 + 0.05) * (3000 * RPM) ** 2
    assert end - began > energy / (s.overvoltage_v**2 / s.brake_resistor_ohm) > 5.0


def test_stall_prevention_off_the_hard_stop_trips_ov2() -> None:
    profile = load_profile("c20-400hr")
    drive, began, end = hard_stop(profile, stall=0, limiting=1)
    assert end is not None and end - began < 0.1
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERVOLTAGE_DECEL)


def test_limiting_off_the_hard_stop_trips_oc2_only_without_stall_prevention() -> None:
    """Stall prevention is a regulator on the braking current from the stop's first step (issue 42): with it
    on, the stop brakes only as hard as the bus can take, so it stretches without tripping even with limiting
    off; with both off the 0.1 s ramp asks far beyond the trip level in its first millisecond: OC2."""
    profile = load_profile("c20-400hr")
    drive, began, end = hard_stop(profile, stall=1, limiting=0)
    assert end is not None and drive.read(Reg.STATUS1) == 6
    assert end - began > 5.0
    drive, began, end = hard_stop(profile, stall=0, limiting=0)
    assert end is not None and end - began <= 0.002
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERCURRENT_DECEL)


def test_a_shock_load_faster_than_the_limit_still_trips_oc3() -> None:
    profile = load_profile("c20-400hr")
    drive = start(profile, 0.0)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.advance_to(2.0)
    # The loop answers one step of the load's deceleration with kp x the speed lost: 2 pi 20 Hz x 1 ms x T / kt.
    shock = 1.25 * profile.protection.overcurrent_a * profile.motor.kt_nm_per_a / (2 * math.pi * 20.0 * 0.001)
    drive.set_load_torque(shock)
    assert first_time(drive, faulted, 2.01) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERCURRENT_CONSTANT)

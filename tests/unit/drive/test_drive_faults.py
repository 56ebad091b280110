"""Faults are causes: each trips with the profile's code, and resets only once its cause is gone."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from c20sim.drive.model import F_CURRENT_LIMITING, F_MOTOR_OVERLOAD_COEFFICIENT, F_OV_STALL, STEP, Drive
from c20sim.drive.profile import FaultCause, Profile, load_profile
from c20sim.drive.terminals import Input, Output
from c20sim.wire.registers import Reg


@pytest.fixture(scope="module")
def profile() -> Profile:
    return load_profile("c20-400hr")


def cell(profile: Profile, register: int) -> int:
    return profile.registers.canonical(register)


def running(profile: Profile, rpm: int = 3000, until: float = 3.0) -> Drive:
    drive = Drive(profile)
    drive.write(Reg.SPEED_SETPOINT, rpm)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(until)
    assert drive.read(Reg.MOTOR_SPEED) == rpm
    return drive


def first_time(drive: Drive, condition: Callable[[Drive], bool], until: float, step: float = STEP) -> float | None:
    """Poll from the drive's time until ``condition`` holds; the time it first did."""
    start, i = drive.t, 0
    while True:
        i += 1
        t = start + i * step
        if t > until + 1e-9:
            return None
        drive.advance_to(t)
        if condition(drive):
            return t


def faulted(drive: Drive) -> bool:
    return drive.read(Reg.STATUS1) == 4


def reset(drive: Drive) -> None:
    drive.write(Reg.COMMAND, 7)
    drive.advance_to(drive.t + 0.01)


def test_supply_drop_while_running_trips_undervoltage(profile: Profile) -> None:
    drive = running(profile)
    drive.set_supply_voltage(15.0)  # below the 20 V trip level
    assert first_time(drive, faulted, 4.0) is not None
    assert drive.read(Reg.FAULT_CODE) == 0x0A
    assert drive.read(Reg.CURRENT_FAULT) == 0x0A
    assert drive.read(Reg.STATUS2) & 0x01 == 0
    assert drive.read(Reg.OUTPUT_TERMINALS) == Output.FAULT
    reset(drive)
    assert faulted(drive)  # the supply is still low
    drive.set_supply_voltage(48.0)
    drive.advance_to(drive.t + 0.1)
    assert faulted(drive)  # latched until reset
    reset(drive)
    assert drive.read(Reg.FAULT_CODE) == 0
    assert drive.read(Reg.STATUS1) == 3  # coasting down from where the trip left it
    drive.advance_to(drive.t + 60.0)
    assert drive.read(Reg.STATUS1) == 3


def test_supply_drop_while_stopped_powers_off(profile: Profile) -> None:
    drive = Drive(profile)
    drive.set_supply_voltage(15.0)
    assert first_time(drive, lambda d: d.read(Reg.STATUS1) == 5, 5.0) is not None
    assert drive.read(Reg.STATUS2) == 0x0040  # bit 0: bus not established
    assert drive.read(Reg.FAULT_CODE) == 0x0A  # as the sheet's example pair reads (status 5, fault 0x0A)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(drive.t + 0.5)
    assert drive.read(Reg.STATUS1) == 5  # no bus, no run
    drive.set_supply_voltage(48.0)
    assert first_time(drive, lambda d: d.read(Reg.STATUS1) == 3, drive.t + 1.0) is not None
    assert drive.read(Reg.STATUS2) == 0x0041
    assert drive.read(Reg.FAULT_CODE) == 0


def test_supply_switched_off_drains_the_bus(profile: Profile) -> None:
    drive = Drive(profile)
    drive.set_supply_voltage(0.0)
    drive.advance_to(120.0)
    assert drive.read(Reg.BUS_VOLTAGE) == 0
    assert drive.read(Reg.STATUS1) == 5
    assert drive.telemetry().steady


def decelerate(profile: Profile, decel_raw: int, *, stall_prevention: bool = True) -> Drive:
    drive = Drive(profile)
    drive.set_load_inertia(0.01)
    drive.write(cell(profile, Reg.ACCEL_TIME), 30)  # 3 s: a heavy load needs a gentle start
    drive.write(F_OV_STALL, int(stall_prevention))
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(10.0)
    assert drive.read(Reg.MOTOR_SPEED) == 3000
    drive.write(cell(profile, Reg.DECEL_TIME), decel_raw)
    drive.write(Reg.COMMAND, 5)
    return drive


def test_fast_deceleration_of_a_heavy_load_trips_overvoltage_with_stall_prevention_off(profile: Profile) -> None:
    drive = decelerate(profile, 20, stall_prevention=False)  # 2 s: 13 A of braking, within the current limit
    assert first_time(drive, faulted, 12.0) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERVOLTAGE_DECEL)
    assert drive.telemetry().bus_v > profile.supply.overvoltage_v


def test_slow_deceleration_of_the_same_load_does_not(profile: Profile) -> None:
    drive = decelerate(profile, 100)  # 10 s
    peak = 0.0

    def stopped(d: Drive) -> bool:
        nonlocal peak
        peak = max(peak, d.telemetry().bus_v)
        return d.read(Reg.STATUS1) in (3, 4)

    assert first_time(drive, stopped, 25.0) is not None
    assert drive.read(Reg.STATUS1) == 3
    assert profile.supply.voltage_v < peak < profile.supply.overvoltage_v  # it regenerated, the chopper held


def trip_time(profile: Profile, amps: float, until: float, coefficient_raw: int = 1000) -> tuple[float, int]:
    """Seconds a budget lasts at 1500 rpm drawing ``amps``, and the fault code.

    Measured from the moment the current has settled, scaled by the share of the budget still left then.
    """
    m = profile.motor
    drive = Drive(profile)
    drive.write(F_MOTOR_OVERLOAD_COEFFICIENT, coefficient_raw)
    drive.write(F_CURRENT_LIMITING, 0)  # off: a start may carry a load beyond the limiting level (160 %)
    drive.write(cell(profile, Reg.ACCEL_TIME), 50)  # loaded from the start: a gentle ramp stays below the limit
    drive.set_load_torque(amps * m.kt_nm_per_a - m.friction_nm - m.viscous_nm_per_krpm * 1.5)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(4.0)
    tel = drive.telemetry()
    assert tel.current_a == pytest.approx(amps, abs=1e-6)
    left = 1.0 - max(tel.motor_overload, tel.drive_overload)
    tripped = first_time(drive, faulted, until, 0.01)
    assert tripped is not None, f"no trip at {amps} A within {until} s"
    return (tripped - 4.0) / left, drive.read(Reg.FAULT_CODE)


@pytest.mark.parametrize(("multiple", "seconds"), [(1.16, 3600.0), (1.5, 720.0), (1.8, 300.0), (2.0, 60.0)])
def test_motor_overload_follows_the_invt_curve(profile: Profile, multiple: float, seconds: float) -> None:
    # F02.27 = 50 %: the motor's 10 A rating protects as 5 A, so the drive (11 A) is not overloaded meanwhile.
    elapsed, code = trip_time(profile, 5.0 * multiple, seconds * 1.1, coefficient_raw=500)
    assert code == profile.fault_code(FaultCause.MOTOR_OVERLOAD)
    assert elapsed == pytest.approx(seconds, rel=0.01)


@pytest.mark.parametrize(("multiple", "seconds"), [(1.5, 60.0), (1.8, 10.0)])
def test_drive_overload_trips_first_on_its_own_curve(profile: Profile, multiple: float, seconds: float) -> None:
    amps = profile.protection.drive_rated_current_a * multiple  # 16.5 A, 19.8 A: the motor would last minutes
    assert amps <= profile.protection.current_limit_a
    elapsed, code = trip_time(profile, amps, seconds * 1.1)
    assert code == profile.fault_code(FaultCause.DRIVE_OVERLOAD)
    assert elapsed == pytest.approx(seconds, rel=0.01)


def test_overload_remembers_heat_between_runs(profile: Profile) -> None:
    m, p = profile.motor, profile.protection
    drive = running(profile, 1500)
    drive.write(F_MOTOR_OVERLOAD_COEFFICIENT, 500)  # protects as 5 A
    load = 10.0 * m.kt_nm_per_a - m.friction_nm - m.viscous_nm_per_krpm * 1.5  # 10 A: 200 %, 60 s
    drive.set_load_torque(load)
    drive.advance_to(drive.t + 30.0)
    half = drive.telemetry().motor_overload
    drive.set_load_torque(0.0)
    drive.advance_to(drive.t + 60.0)
    idle = drive.telemetry().current_a / 5.0
    cooled = half - 60.0 * (1.0 - idle * idle) / p.overload_cooling_s
    assert drive.telemetry().motor_overload == pytest.approx(cooled, abs=0.01)
    drive.set_load_torque(load)
    start = drive.t
    again = first_time(drive, faulted, start + 100.0, 0.01)
    assert again is not None
    assert half == pytest.approx(0.5, abs=0.02)
    assert again - start == pytest.approx((1.0 - cooled) * 60.0, rel=0.02)  # not a fresh 60 s: it remembers


def test_overload_resets_only_after_cooling_down(profile: Profile) -> None:
    drive = running(profile, 1500)
    drive.set_load_torque(15 * profile.motor.kt_nm_per_a)  # 15.5 A: 141 % of the drive, OL2
    assert first_time(drive, faulted, 300.0, 0.5) is not None
    drive.set_load_torque(0.0)
    reset(drive)
    assert faulted(drive)
    drive.advance_to(drive.t + 30.0)
    reset(drive)
    assert faulted(drive)  # 30 s of a 240 s cool-down: still above the 80 % warning level
    drive.advance_to(drive.t + 30.0)
    reset(drive)
    assert drive.read(Reg.STATUS1) == 3


def test_fault_reset_fails_while_the_cause_persists(profile: Profile) -> None:
    drive = running(profile)
    drive.set_terminal_inputs(Input.EF)
    drive.advance_to(drive.t + STEP)
    assert faulted(drive)
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.EXTERNAL)
    reset(drive)
    assert faulted(drive)
    drive.set_terminal_inputs(0)
    reset(drive)
    assert not faulted(drive)
    assert drive.read(Reg.FAULT_CODE) == 0


def test_fault_stops_the_motor_by_coasting(profile: Profile) -> None:
    drive = running(profile)
    drive.force_fault(0x10)
    assert faulted(drive)
    assert not drive.running
    drive.advance_to(drive.t + 0.1)
    assert drive.read(Reg.OUTPUT_CURRENT) == 0
    assert 0 < drive.read(Reg.MOTOR_SPEED) < 3000
    drive.write(Reg.COMMAND, 1)  # a run command does not restart a faulted drive
    drive.advance_to(drive.t + 60.0)
    assert drive.read(Reg.MOTOR_SPEED) == 0
    assert faulted(drive)


def test_forced_persistent_fault_waits_for_release(profile: Profile) -> None:
    drive = Drive(profile)
    drive.force_fault(0x13, persistent=True)
    assert drive.read(Reg.FAULT_CODE) == 0x13
    assert drive.keypad(7) is False
    drive.release_fault()
    assert drive.keypad(7) is True
    drive.advance_to(0.01)
    assert drive.read(Reg.STATUS1) == 3
    with pytest.raises(ValueError):
        drive.force_fault(0)


def test_load_step_beyond_the_trip_level_is_held_at_the_current_limit(profile: Profile) -> None:
    # Overcurrent follows current, not load torque: 6 N m would need 47 A, but the current limit holds it at 20 A
    # and the locked rotor trips, as a jam does.
    # Current limiting off: the current sits at the hardware clamp.
    drive = running(profile)
    drive.write(F_CURRENT_LIMITING, 0)
    drive.set_load_torque(6.0)
    assert first_time(drive, faulted, drive.t + 0.5) is None
    assert drive.read(Reg.OUTPUT_CURRENT) == round(profile.protection.current_limit_a * 100)
    assert first_time(drive, faulted, drive.t + 5.0) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.STALL)
    # On (the default): the ramp holds too, the current stays between the limiting level and the clamp.
    limited = running(profile)
    limited.set_load_torque(6.0)
    assert first_time(limited, faulted, limited.t + 0.5) is None
    level = profile.protection.drive_rated_current_a * 1.6
    assert round(level * 100) <= limited.read(Reg.OUTPUT_CURRENT) <= round(profile.protection.current_limit_a * 100)
    assert first_time(limited, faulted, limited.t + 5.0) is not None
    assert limited.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.STALL)


def test_locked_rotor_trips_stall(profile: Profile) -> None:
    drive = running(profile)
    drive.set_load_torque(3.0)  # more than the current limit can hold, less than the overcurrent trip
    start = drive.t
    tripped = first_time(drive, faulted, 10.0)
    assert tripped is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.STALL)
    assert profile.protection.stall_time_s < tripped - start < profile.protection.stall_time_s + 0.5


def test_overheat_trips_and_resets_when_cool(profile: Profile) -> None:
    drive = running(profile)
    drive.set_ambient(75.0)
    drive.set_load_torque(1.0)
    assert first_time(drive, faulted, 3000.0, 1.0) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.OVERHEAT)
    assert drive.read(Reg.TEMPERATURE) >= 850
    reset(drive)
    assert faulted(drive)
    drive.advance_to(drive.t + 600.0)
    reset(drive)
    assert not faulted(drive)


@pytest.mark.parametrize("kind", ["stuck0", "stuck7", "sequence"])
def test_hall_sensor_faults(profile: Profile, kind: str) -> None:
    drive = Drive(profile)
    drive.set_hall_fault(kind)
    drive.advance_to(1.0)
    if kind == "sequence":
        assert drive.read(Reg.STATUS1) == 3  # an order error shows only at an edge: while turning
    else:
        assert faulted(drive)  # code 0 or 7 is impossible at standstill too
        assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.HALL)
        return
    drive.write(Reg.SPEED_SETPOINT, 1000)
    drive.write(Reg.COMMAND, 1)
    assert first_time(drive, faulted, 2.0) is not None
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.HALL)
    reset(drive)
    assert faulted(drive)
    drive.set_hall_fault(None)
    reset(drive)
    assert not faulted(drive)


def test_communication_timeout(profile: Profile) -> None:
    drive = Drive(profile)
    drive.write(0x0802, 10)  # F08.02 = 1.0 s
    drive.advance_to(5.0)
    assert not faulted(drive)  # not armed before the first request
    drive.communicated(5.0)
    drive.advance_to(6.0)
    drive.communicated(6.0)
    assert first_time(drive, faulted, 10.0) == pytest.approx(7.001)
    assert drive.read(Reg.FAULT_CODE) == profile.fault_code(FaultCause.COMMUNICATION)
    reset(drive)
    assert not faulted(drive)


def test_communication_timeout_off_or_not_under_communication(profile: Profile) -> None:
    drive = Drive(profile)
    drive.communicated(0.0)
    drive.advance_to(100.0)
    assert not faulted(drive)
    drive.write(0x0802, 10)
    drive.write(cell(profile, Reg.RUN_CHANNEL), 1)
    drive.advance_to(200.0)
    assert not faulted(drive)

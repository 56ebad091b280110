"""How the drive model compares with published figures of the INVT Goodrive family, for each shipped profile.

Every "model" figure is measured by running the pure model in virtual time;
the "reference" column says what it is checked against: a published INVT
figure (document named), or `assumed` where only the profile's own constants
give it. Output is a Markdown table per profile, for bench/RESULTS.md.

Run: .venv/bin/python bench/bench_fidelity.py
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

from c20sim.drive.integrator import STALL_SLEW_SHARE
from c20sim.drive.model import (
    F_COMM_ACTION,
    F_COMM_TIMEOUT,
    F_CURRENT_LIMITING,
    F_MOTOR_OVERLOAD_COEFFICIENT,
    F_OV_STALL,
    STEP,
    Drive,
)
from c20sim.drive.physics import HALL_SEQUENCE, RPM
from c20sim.drive.profile import Profile, available_profiles, load_profile
from c20sim.drive.statemachine import State
from c20sim.wire.registers import Reg, fcode_address

Row = tuple[str, str, str]


def cell(profile: Profile, register: int) -> int:
    return profile.registers.canonical(register)


def until(drive: Drive, condition: Callable[[Drive], bool], end: float, step: float = STEP) -> float | None:
    """Poll from the drive's time; the first time ``condition`` holds, or None by ``end``."""
    start, i = drive.t, 0
    while start + i * step <= end:
        i += 1
        drive.advance_to(start + i * step)
        if condition(drive):
            return drive.t
    return None


def run(profile: Profile, rpm: float, *, accel_raw: int = 5, inertia: float = 0.0, t: float = 3.0) -> Drive:
    drive = Drive(profile)
    drive.set_load_inertia(inertia)
    drive.write(cell(profile, Reg.ACCEL_TIME), accel_raw)
    drive.write(Reg.SPEED_SETPOINT, round(rpm))
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(t)
    return drive


def fault_name(drive: Drive) -> str:
    code = drive.read(Reg.FAULT_CODE)
    return drive.profile.fault_name(code).split(":")[0] if code else "no fault"


def stall_prevention(profile: Profile) -> list[Row]:
    rows = []
    nominal = profile.supply.voltage_v
    for stall in (1, 0):
        drive = run(profile, 3000, accel_raw=30, inertia=9 * profile.motor.inertia_kg_m2, t=0.0)
        drive.write(F_OV_STALL, stall)
        drive.advance_to(5.0)
        drive.write(Reg.COMMAND, 5)
        peak = 0.0

        def done(d: Drive) -> bool:
            nonlocal peak
            peak = max(peak, d.telemetry().bus_v)
            return d.read(Reg.STATUS1) in (4, 6)

        end = until(drive, done, 15.0)
        took = (end or 15.0) - 5.0
        if stall:
            rows.append(
                (
                    "0.5 s stop from 3000 rpm, 10x rotor inertia, F11.03 = 1",
                    "no trip; the ramp is held while the bus is above 120 % (GD20 P11.03/P11.04; CHE100 PB.04/05 p. 74)",
                    f"{fault_name(drive)}; stopped in {took:.2f} s; bus peak {peak:.1f} V = {peak / nominal:.0%}",
                )
            )
        else:
            rows.append(
                (
                    "the same stop, F11.03 = 0",
                    "OV2 (a fast stop without stall prevention)",
                    f"{fault_name(drive)} after {took * 1000:.0f} ms; bus {peak:.1f} V",
                )
            )
    return rows


def stall_regulator(profile: Profile) -> list[Row]:
    """A heavy stop (170x the rotor, 0.1 s asked) polled every 1 ms: how long, and how smooth 3004H is."""
    inertia = 170 * profile.motor.inertia_kg_m2
    drive = run(profile, 3000, inertia=inertia, t=0.0)
    until(drive, lambda d: d.read(Reg.MOTOR_SPEED) == 3000, 30.0)
    drive.write(cell(profile, Reg.DECEL_TIME), 1)
    drive.write(Reg.COMMAND, 5)
    began, jump = drive.t, 0
    last: int | None = None  # from the stop's first millisecond: the step to it is the command's

    def watch(d: Drive) -> bool:
        nonlocal last, jump
        now = d.read(Reg.OUTPUT_CURRENT)
        if (
            last is not None and d.state is State.DECELERATING
        ):  # the stop's last step, to braking at zero, is not the regulator's
            jump = max(jump, abs(now - last))
        last = now
        return d.read(Reg.STATUS1) in (4, 6)

    end = until(drive, watch, began + 60.0) or began + 60.0
    stall_v = profile.supply.voltage_v * 1.2
    power = stall_v**2 / profile.supply.brake_resistor_ohm
    energy = 0.5 * (inertia + profile.motor.inertia_kg_m2) * (3000 * RPM) ** 2
    slew = STALL_SLEW_SHARE * profile.protection.current_limit_a
    return [
        (
            "stop from 3000 rpm, 170x rotor inertia, 0.1 s asked, F11.03 = 1; 3004H read every 1 ms",
            f"the rotor's {energy:.0f} J into the brake resistor at the stall level ({power:.0f} W): "
            f"{energy / power:.2f} s (assumed: no other loss); 3004H moves at most the stall regulator's "
            f"slew, {slew:.1f} A per ms (assumed)",
            f"{fault_name(drive)}; stopped in {end - began:.2f} s; largest 1 ms step of 3004H {jump / 100:.2f} A",
        )
    ]


def automatic(profile: Profile) -> list[Row]:
    """Issue 42's behaviours against the figures their physics gives: a ride-through's length, an S curve's time."""
    m = profile.motor
    inertia = 30 * m.inertia_kg_m2
    load = 0.3 * m.kt_nm_per_a * m.rated_current_a
    drive = run(profile, 1500, inertia=inertia, t=0.0)
    drive.write(fcode_address(11, 1), 1)  # F11.01: ride-through on
    drive.set_load_torque(load)
    drive.advance_to(5.0)
    drive.set_supply_voltage(0.0)
    end = until(drive, lambda d: d.read(Reg.FAULT_CODE) != 0, 20.0) or 20.0
    speed_at_trip = drive.read(Reg.MOTOR_SPEED)
    omega = 1500 * RPM
    torque = load + m.friction_nm + m.viscous_nm_per_krpm * 1.5 / 2  # the drag at the mean speed
    coast = (m.inertia_kg_m2 + inertia) * (omega - speed_at_trip * RPM) / torque
    rows = [
        (
            "supply lost at 1500 rpm, 30x rotor inertia, 30 % load, F11.01 = 1",
            f"rides through while the rotor slows under its load: J dw / T = {coast:.2f} s to {speed_at_trip} rpm "
            "(assumed: the drive takes only what holds the bus); then UV",
            f"{fault_name(drive)} after {end - 5.0:.2f} s, at {speed_at_trip} rpm",
        )
    ]
    drive = Drive(profile)
    drive.write(fcode_address(1, 5), 1)  # F01.05: S curve, 30 % / 30 %
    drive.write(cell(profile, Reg.ACCEL_TIME), 20)
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    reached = until(drive, lambda d: d.motion.ramp == 3000.0, 5.0)
    rows.append(
        (
            "S-curve ramp (F01.05 = 1, 30 % / 30 %), 2003H = 2.0 s, 0 to 3000 rpm",
            "the ramp time kept, the rate's peak 1 / 0.7 of the linear one (INVT P01.05-P01.07, as remembered)",
            f"ramp at 3000 rpm after {reached or 5.0:.3f} s",
        )
    )
    return rows


def overload_seconds(profile: Profile, amps: float, coefficient_raw: int) -> tuple[float, str]:
    """Seconds a fresh budget lasts at ``amps`` (1500 rpm), from the settled current; and the fault."""
    m = profile.motor
    drive = Drive(profile)
    drive.write(F_MOTOR_OVERLOAD_COEFFICIENT, coefficient_raw)
    drive.write(F_CURRENT_LIMITING, 0)  # a start carrying 180 % of the drive's rating passes the 160 % level
    drive.write(cell(profile, Reg.ACCEL_TIME), 50)
    drive.set_load_torque(amps * m.kt_nm_per_a - m.friction_nm - m.viscous_nm_per_krpm * 1.5)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)
    drive.advance_to(4.0)
    tel = drive.telemetry()
    left = 1.0 - max(tel.motor_overload, tel.drive_overload)
    end = until(drive, lambda d: d.read(Reg.STATUS1) == 4, 8000.0, 0.01)
    assert end is not None
    return (end - 4.0) / left, fault_name(drive)


def overload(profile: Profile) -> list[Row]:
    rows = []
    motor_amps = 0.5 * profile.motor.rated_current_a  # F02.27 = 50 %: the motor trips before the drive
    for multiple, published in ((1.16, "about 1 h"), (1.5, "12 min"), (1.8, "5 min"), (2.0, "60 s")):
        seconds, name = overload_seconds(profile, motor_amps * multiple, 500)
        rows.append(
            (
                f"motor overload at {multiple:.0%} of rated x F02.27",
                f"{published} (INVT motor overload curve, GD350-IP55 manual p. 143)",
                f"{name} after {seconds:.1f} s",
            )
        )
    drive_amps = profile.protection.drive_rated_current_a
    for multiple, published in ((1.5, "60 s"), (1.8, "10 s")):
        seconds, name = overload_seconds(profile, drive_amps * multiple, 1000)
        rows.append(
            (
                f"drive overload at {multiple:.0%} of the drive's {drive_amps:g} A (F11.05 = 0)",
                f"{published} (INVT G type, GD20 specifications)",
                f"{name} after {seconds:.1f} s",
            )
        )
    limit = profile.protection.current_limit_a / drive_amps
    rows.append(("current limit / drive rated current", "at least 180 % (G type)", f"{limit:.0%}"))
    return rows


def speed_loop(profile: Profile) -> list[Row]:
    m = profile.motor
    drive = run(profile, 1500)
    torque = 0.5 * m.rated_current_a * m.kt_nm_per_a
    drive.set_load_torque(torque)
    lowest = 1500.0
    for i in range(1, 1001):
        drive.advance_to(3.0 + i * STEP)
        lowest = min(lowest, drive.telemetry().speed_rpm)
    w = 2 * math.pi * profile.control.speed_loop_hz
    expected = 2 * torque / (m.inertia_kg_m2 * w * math.e) / RPM
    slow = run(profile, 5)
    slow.set_load_torque(0.5 * torque)
    slow.advance_to(6.0)
    return [
        (
            f"speed dip, 0 -> {torque:.2f} N m (50 % rated) at 1500 rpm",
            f"assumed {profile.control.speed_loop_hz:g} Hz loop: 2 T / (J w e) = {expected:.0f} rpm",
            f"{1500 - lowest:.0f} rpm; back at 1500 rpm within 1 s",
        ),
        (
            "set speed 5 rpm, under load",
            "runs at the minimum, about 100 rpm (small BLDC drives; assumed)",
            f"3006H = {slow.read(Reg.MOTOR_SPEED)} rpm",
        ),
    ]


def heating(profile: Profile) -> list[Row]:
    th, m = profile.thermal, profile.motor
    amps = 0.95 * profile.protection.current_limit_a
    drive = run(profile, 0)
    drive.write(F_CURRENT_LIMITING, 0)  # 95 % of the clamp is above the limiting level
    drive.set_active_load(amps * m.kt_nm_per_a)
    drive.advance_to(5.0)
    before = drive.telemetry().temperature_c
    drive.advance_to(8.0)
    rise = drive.telemetry().temperature_c - before
    loss = th.conduction_resistance_ohm * amps**2 + th.switching_loss_w_per_a * amps
    gap = loss * th.resistance_k_per_w - (before - th.ambient_c)
    expected = gap * (1 - math.exp(-3.0 / th.time_constant_s))
    return [
        (
            f"inverter heating, 3 s holding {amps:g} A at standstill (F11.05 = 0)",
            f"assumed losses {loss:.0f} W (I^2 R + W/A): +{expected:.2f} K",
            f"+{rise:.2f} K",
        )
    ]


def undervoltage(profile: Profile) -> list[Row]:
    s = profile.supply
    drive = Drive(profile)
    volts = s.voltage_v
    trip = back = None
    while volts > 1.0 and trip is None:  # down in 0.1 V steps until status 5
        volts = round(volts - 0.1, 1)
        drive.set_supply_voltage(volts)
        drive.advance_to(drive.t + 1.0)
        if drive.read(Reg.STATUS1) == 5:
            trip = volts
    while back is None and volts < s.voltage_v:
        volts = round(volts + 0.1, 1)
        drive.set_supply_voltage(volts)
        drive.advance_to(drive.t + 1.0)
        if drive.read(Reg.STATUS1) == 3:
            back = volts
    return [
        (
            "supply at which a stopped drive goes off / comes back",
            f"off below {s.undervoltage_v:g} V, back above {s.undervoltage_recover_v:g} V (assumed)",
            f"off at {trip} V, back at {back} V",
        )
    ]


def start_stop(
    profile: Profile, inertia: float, limiting: int, stall: int = 1, stop_limiting: int = -1
) -> tuple[str, str]:
    """Run to 3000 rpm on the 0.5 s ramp, then stop with a 0.1 s decel (2004H = 1): what each did, in words.

    ``stop_limiting`` (F11.05 for the stop; -1: as for the start) lets a stop be measured after a start that
    limiting off would have tripped."""
    drive = run(profile, 3000, inertia=inertia, t=0.0)
    drive.write(F_CURRENT_LIMITING, limiting)
    peak = 0.0

    def watch(d: Drive) -> bool:
        nonlocal peak
        peak = max(peak, abs(d.telemetry().current_a))
        return d.read(Reg.STATUS1) == 4 or d.read(Reg.MOTOR_SPEED) == 3000

    end = until(drive, watch, 30.0) or 30.0
    if drive.read(Reg.STATUS1) == 4:
        return f"{fault_name(drive)} at {end * 1000:.0f} ms", "-"
    started = f"{end:.2f} s, at most {peak:.1f} A"
    drive.write(F_OV_STALL, stall)
    if stop_limiting >= 0:
        drive.write(F_CURRENT_LIMITING, stop_limiting)
    drive.write(cell(profile, Reg.DECEL_TIME), 1)
    drive.write(Reg.COMMAND, 5)
    began = drive.t
    stop = until(drive, lambda d: d.read(Reg.STATUS1) in (4, 6), began + 60.0) or began + 60.0
    if drive.read(Reg.STATUS1) == 4:
        return started, f"{fault_name(drive)} at {(stop - began) * 1000:.0f} ms"
    return started, f"{stop - began:.2f} s"


def current_limiting(profile: Profile) -> list[Row]:
    """Start (0.5 s ramp) and stop (0.1 s ramp) times against the coupled inertia, with and without limiting."""
    m, p = profile.motor, profile.protection
    level = p.drive_rated_current_a * 1.6
    rows = []
    for times in (0, 3, 10, 30, 100, 170):
        inertia = times * m.inertia_kg_m2
        asks = (m.inertia_kg_m2 + inertia) * 3000 * RPM / 0.5 / m.kt_nm_per_a
        on_start, on_stop = start_stop(profile, inertia, 1)
        off_start, _ = start_stop(profile, inertia, 0)
        _, off_stop = start_stop(profile, inertia, 1, stop_limiting=0)
        rows.append(
            (
                f"{inertia:.4f} kg m^2 coupled ({times}x rotor): start 0.5 s ramp (asks {asks:.0f} A) / stop 0.1 s",
                f"limiting on (F11.05 = 1, GD20 P11.05): no trip, held at {level:.1f} A (160 %); "
                f"off: OC1/OC2 above the {p.overcurrent_a:g} A trip",
                f"on: start {on_start}, stop {on_stop}; off: start {off_start}, stop {off_stop}",
            )
        )
    inertia = 0.05 * m.inertia_kg_m2 / 0.0003  # 0.05 kg m^2 on the 400 W rotor, scaled by the rotor
    _, stall_off = start_stop(profile, inertia, 1, stall=0)
    rows.append(
        (
            f"{inertia:.3f} kg m^2: the same stop, F11.03 = 0 (stall prevention off)",
            "OV2: the regenerated energy pumps the bus up",
            f"stop {stall_off}",
        )
    )
    return rows


def hall(profile: Profile) -> list[Row]:
    drive = run(profile, 3000)
    seen: list[int] = []
    for i in range(1, 201):
        drive.advance_to(3.0 + i * STEP / 10)
        code = drive.read(Reg.HALL)
        if not seen or seen[-1] != code:
            seen.append(code)
    skips = sum(1 for a, b in itertools.pairwise(seen) if HALL_SEQUENCE[(HALL_SEQUENCE.index(a) + 1) % 6] != b)
    stuck = Drive(profile)
    stuck.set_hall_fault("stuck7")
    stuck.advance_to(0.01)
    return [
        ("3009H read every 0.1 ms at 3000 rpm", "every code, in order", f"{len(seen)} codes, {skips} out of order"),
        ("Hall code 7 at standstill", "a fault (codes 0 and 7 are impossible)", fault_name(stuck)),
    ]


def comm_actions(profile: Profile) -> list[Row]:
    outcomes = []
    for action in range(4):
        drive = run(profile, 1500)
        drive.write(F_COMM_TIMEOUT, 10)
        drive.write(F_COMM_ACTION, action)
        drive.communicated(3.0)
        drive.advance_to(10.0)
        outcomes.append(f"{action}: {drive.telemetry().state}, {fault_name(drive)}")
    return [
        (
            "comm timeout 1 s, F08.03 = 0 / 1 / 2 / 3",
            "alarm + coast / keep running / ramp stop / ramp stop (GD20 P14.05)",
            "; ".join(outcomes),
        )
    ]


def active_load(profile: Profile) -> list[Row]:
    m, s = profile.motor, profile.supply
    rated = m.rated_current_a * m.kt_nm_per_a
    drive = run(profile, 1500)
    drive.set_active_load(0.5 * rated)
    drive.advance_to(8.0)
    tel = drive.telemetry()
    pulling = 0.9 * profile.protection.current_limit_a * m.kt_nm_per_a
    fast = run(profile, 3000)
    fast.set_active_load(pulling)
    tripped = until(fast, lambda d: d.read(Reg.STATUS1) == 4, 13.0)
    fast.advance_to(60.0)  # tripped: the output off, the load's characteristic and the friction bound the rotor
    free = fast.telemetry().speed_rpm
    held = run(profile, 0)
    held.set_active_load(-0.5 * rated)
    held.advance_to(8.0)
    return [
        (
            f"hoist lowering at 1500 rpm, {0.5 * rated:.2f} N m pushing",
            f"regenerates at constant speed; chopper above {s.brake_chopper_v:g} V",
            f"{tel.speed_rpm:.0f} rpm, {tel.current_a:.2f} A, bus {tel.bus_v:.1f} V, {fault_name(drive)}",
        ),
        (
            f"the same at 3000 rpm, {pulling:.2f} N m (90 % of the current limit)",
            "OV3 once the regenerated power passes the chopper's",
            f"{fault_name(fast)}" + (f" after {tripped - 3.0:.2f} s" if tripped else ""),
        ),
        (
            "the tripped drive's rotor, 60 s on: speed / 3006H",
            f"settles where the load's pull (full to {m.rated_speed_rpm:g} rpm, none at "
            f"{m.active_load_free_rpm:g} rpm; assumed) meets the friction / the sheet's top, 3000",
            f"{free:.1f} rpm / {fast.read(Reg.MOTOR_SPEED)}",
        ),
        (
            f"held at 0 rpm against {0.5 * rated:.2f} N m",
            "draws the current that holds it",
            f"{held.telemetry().speed_rpm:.0f} rpm, {held.telemetry().current_a:.2f} A",
        ),
    ]


def free_stop(profile: Profile) -> list[Row]:
    drive = run(profile, 1400)
    drive.write(Reg.COMMAND, 6)
    drive.advance_to(3.1)
    read = drive.read
    return [
        (
            "0.1 s after a free stop from 1400 rpm: 3001H 3003H 3004H 3007H / 3006H",
            "output stage off: 0 0 0 0 / the coasting speed",
            f"{read(Reg.OUTPUT_FREQUENCY)} {read(Reg.OUTPUT_VOLTAGE)} {read(Reg.OUTPUT_CURRENT)} "
            f"{read(Reg.OUTPUT_POWER)} / {read(Reg.MOTOR_SPEED)} rpm",
        )
    ]


def main() -> None:
    for name in available_profiles():
        profile = load_profile(name)
        rows: list[Row] = []
        for part in (
            stall_prevention,
            stall_regulator,
            automatic,
            overload,
            speed_loop,
            heating,
            undervoltage,
            current_limiting,
            hall,
            comm_actions,
            active_load,
            free_stop,
        ):
            rows += part(profile)
        print(f"### {name}\n")
        print("| quantity | reference | model |")
        print("|---|---|---|")
        for quantity, reference, model in rows:
            print(f"| {quantity} | {reference} | {model} |")
        print()


if __name__ == "__main__":
    main()

"""The settings the step works from, derived from the parameters, the RAM registers and the bench's conditions."""

from __future__ import annotations

import itertools
import math

from c20sim.drive.config import (
    CHANNEL_DIAL,
    CHANNEL_KEYPAD,
    CHANNEL_TERMINAL,
    DIAL_SPEED_SOURCE,
    F_MOTOR_OVERLOAD_COEFFICIENT,
    F_OV_STALL,
    SOURCE_DIAL,
    Conditions,
    configure,
    limit_speed,
)
from c20sim.drive.face import RAM_REGISTERS
from c20sim.drive.model import Drive
from c20sim.drive.params import ParameterStore
from c20sim.drive.profile import Profile
from c20sim.drive.terminals import Input
from c20sim.wire.registers import Reg, fcode_address


def parts(profile: Profile) -> tuple[ParameterStore, dict[int, int], Conditions]:
    ram = dict.fromkeys(RAM_REGISTERS, 0)
    return ParameterStore(profile), ram, Conditions(supply=48.0, ambient=25.0)


def test_the_communication_source_takes_2001h_between_the_minimum_and_the_maximum(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    assert P.get(Reg.SPEED_SOURCE) == 3
    for setpoint, rpm in ((1500, 1500.0), (50, 100.0), (0, 0.0), (9000, 3000.0)):  # min 100 rpm, max F00.03
        ram[Reg.SPEED_SETPOINT] = setpoint
        assert configure(profile, P, ram, bench).reference_rpm == rpm
    assert limit_speed(profile, 50.0, 80.0) == 80.0  # a maximum below the minimum speed wins


def test_ramps_are_rpm_per_step_of_the_maximum_speed(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    cfg = configure(profile, P, ram, bench)
    assert (cfg.max_rpm, cfg.up, cfg.down) == (3000.0, 6.0, 6.0)  # 0.5 s to 3000 rpm, 1 ms steps
    P.set(Reg.ACCEL_TIME, 20)
    P.set(Reg.DECEL_TIME, 0)  # 0 is taken as the shortest ramp, 0.1 s
    cfg = configure(profile, P, ram, bench)
    assert (cfg.up, cfg.down) == (1.5, 30.0)


def test_the_inputs_are_the_physical_ones_or_the_virtual_ones_in_nine_bits(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    bench.physical_inputs = Input.FWD
    ram[Reg.VIRTUAL_INPUTS] = Input.EF | 0x200
    assert configure(profile, P, ram, bench).inputs == Input.FWD | Input.EF


def test_the_dial_switches_select_the_run_channel_and_the_speed_source(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    P.set(Reg.RUN_CHANNEL, CHANNEL_DIAL)
    P.set(Reg.SPEED_SOURCE, SOURCE_DIAL)
    bench.ai[:2] = [5.0, 2.5]
    P.set(fcode_address(5, 0), 1200)  # multi-speed segment 0: S1-S3 all off
    seen = set()
    for sw2, sw3 in itertools.product((False, True), repeat=2):
        bench.dial = (False, sw2, sw3)
        cfg = configure(profile, P, ram, bench)
        assert cfg.channel == (CHANNEL_TERMINAL if sw3 else CHANNEL_KEYPAD)
        assert cfg.source == DIAL_SPEED_SOURCE[sw2, sw3]
        seen.add((cfg.source, cfg.reference_rpm))
    # keypad F00.10 = 50.00 Hz at 4 pole pairs, AI1 5 V and AI2 2.5 V of 10 V at 3000 rpm, F05.00
    assert seen == {(0, 750.0), (1, 1500.0), (2, 750.0), (4, 1200.0)}


def test_the_load_and_its_inertia_add_to_the_motors_and_set_the_speed_loop(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    bench.load, bench.load_inertia, bench.active = 0.5, 0.01, -0.2
    cfg = configure(profile, P, ram, bench)
    inertia = 0.0003 + 0.01
    bandwidth = 2.0 * math.pi * 20.0
    assert (cfg.hold, cfg.inertia, cfg.active, cfg.viscous) == (0.02 + 0.5, inertia, -0.2, 0.03 / 1000.0)
    assert (cfg.kp, cfg.ki) == (inertia * bandwidth, inertia * bandwidth * bandwidth / 4.0)


def test_stall_prevention_and_the_overload_coefficient_come_from_their_function_codes(profile: Profile) -> None:
    P, ram, bench = parts(profile)
    cfg = configure(profile, P, ram, bench)
    assert (cfg.stall_v, cfg.motor_rated_a) == (48.0 * 120 / 100.0, 10.0)  # F11.04 120 %, F02.27 100.0 %
    P.set(F_OV_STALL, 0)
    P.set(F_MOTOR_OVERLOAD_COEFFICIENT, 500)
    cfg = configure(profile, P, ram, bench)
    assert (cfg.stall_v, cfg.motor_rated_a) == (0.0, 5.0)


def test_a_set_speed_write_leaves_the_settings_configure_would_derive(profile: Profile) -> None:
    # A 2001H write changes the reference alone (where 2007H takes it from communication), without deriving
    # the rest anew: the settings must be exactly those configure derives from everything, at every source.
    drive = Drive(profile)
    for source in (3, 0, 1, 2, 4, SOURCE_DIAL, 3):
        drive.write(Reg.SPEED_SOURCE, source)
        for setpoint in (1500, 50, 0, 9000, 2999, 1500):
            drive.write(Reg.SPEED_SETPOINT, setpoint)
            assert drive.motion.cfg == configure(profile, drive.parameters, drive.ram, drive.bench), (source, setpoint)
        drive.write(Reg.VIRTUAL_INPUTS, 0b100)  # another input between: the settings follow it too
        drive.write(Reg.SPEED_SETPOINT, 700)
        assert drive.motion.cfg == configure(profile, drive.parameters, drive.ram, drive.bench)
    assert drive.motion.cfg.reference_rpm == 700.0  # the communication source at the end: 2001H is the reference

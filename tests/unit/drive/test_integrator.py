"""The integrator: one fixed step of motor, speed loop, bus, heat and overload, and its steady segments."""

from __future__ import annotations

import pytest

from c20sim.drive.config import Conditions, configure
from c20sim.drive.face import RAM_REGISTERS
from c20sim.drive.integrator import Integrator, target_rpm
from c20sim.drive.params import ParameterStore
from c20sim.drive.physics import STEP
from c20sim.drive.profile import Profile
from c20sim.drive.sensors import Hall
from c20sim.drive.statemachine import State
from c20sim.wire.registers import Reg


def integrator(profile: Profile, rpm: int = 1500, **bench: float) -> Integrator:
    """An integrator of ``profile`` at power-up, set to ``rpm`` over the communication channel."""
    ram = dict.fromkeys(RAM_REGISTERS, 0)
    ram[Reg.SPEED_SETPOINT] = rpm
    conditions = Conditions(supply=profile.supply.voltage_v, ambient=profile.thermal.ambient_c)
    for name, value in bench.items():
        setattr(conditions, name, value)
    motion = Integrator(profile, conditions, Hall(), 0.0)
    motion.cfg = configure(profile, ParameterStore(profile), ram, conditions)
    motion.power_up()
    return motion


def test_the_bus_rests_below_the_supply_by_the_bleed_and_is_zero_without_one(profile: Profile) -> None:
    motion = integrator(profile)
    g_source, g_bleed = 1.0 / 0.15, 1000e-6 / 2.0
    assert motion.bus == 48.0 * g_source / (g_source + g_bleed)
    assert motion.bus_rest(0.0) == 0.0


def test_the_target_is_the_reference_signed_by_direction_and_the_jog_speed_jogging(profile: Profile) -> None:
    cfg = integrator(profile).cfg
    targets = {state: target_rpm(state, cfg) for state in State}
    assert targets[State.FORWARD] == 1500.0 and targets[State.REVERSE] == -1500.0
    assert targets[State.JOG_FORWARD] == 300.0 and targets[State.JOG_REVERSE] == -300.0
    assert {s for s, t in targets.items() if t == 0.0} == set(State) - {
        State.FORWARD,
        State.REVERSE,
        State.JOG_FORWARD,
        State.JOG_REVERSE,
    }


def test_a_stopped_drive_stays_at_rest_and_enters_a_segment(profile: Profile) -> None:
    motion = integrator(profile)
    bus = motion.bus
    motion.step(State.STOPPED)
    assert (motion.k, motion.speed, motion.current, motion.ramp, motion.bus) == (1, 0.0, 0.0, 0.0, bus)
    assert motion.bus_settled
    motion.try_segment(State.STOPPED)
    assert motion.segment is not None and motion.segment.k0 == 1


def test_a_start_ramps_by_the_acceleration_and_the_loop_settles_exactly(profile: Profile) -> None:
    motion = integrator(profile)
    motion.entered(False, True)
    motion.step(State.FORWARD)
    assert motion.ramp == 6.0  # 3000 rpm in 0.5 s
    assert motion.speed > 0.0 and motion.current > 0.0 and motion.demand == motion.current
    for _ in range(2000):
        motion.step(State.FORWARD)
    assert (motion.ramp, motion.speed, motion.limited) == (1500.0, 1500.0, False)
    friction = 0.02 + 0.03 / 1000.0 * 1500.0  # Coulomb plus viscous, N m
    assert motion.current == pytest.approx(friction / 0.127, rel=1e-12)
    motion.try_segment(State.FORWARD)
    assert motion.segment is not None


def test_the_output_going_off_drops_the_current_and_a_start_catches_the_rotor(profile: Profile) -> None:
    motion = integrator(profile)
    motion.entered(False, True)
    for _ in range(300):
        motion.step(State.FORWARD)
    speed = motion.speed
    motion.entered(True, False)
    assert (motion.ramp, motion.current, motion.power, motion.loss, motion.integ, motion.demand) == (0.0,) * 6
    assert motion.speed == speed  # the rotor turns on
    motion.step(State.COASTING)
    assert 0.0 < motion.speed < speed
    motion.entered(False, True)
    assert motion.ramp == motion.speed


def test_a_load_past_the_current_limit_is_clamped_and_counted_as_stalled(profile: Profile) -> None:
    motion = integrator(profile, load=5.0)  # 40 A to hold against a 20 A limit
    motion.entered(False, True)
    currents, limited = [], []
    for _ in range(200):
        motion.step(State.FORWARD)
        currents.append(motion.current)
        limited.append(motion.limited)
        assert motion.speed == 0.0
    assert max(currents) == 20.0 and any(limited)
    assert all(c == 20.0 for c, at_limit in zip(currents, limited, strict=True) if at_limit)
    assert motion.stall_steps == 200  # asked for 1500 rpm, turning below 30 rpm from the first step


def test_a_segment_jumps_to_the_state_stepping_reaches(profile: Profile) -> None:
    stepped, skipped = integrator(profile, load=0.8), integrator(profile, load=0.8)
    for motion in (stepped, skipped):
        motion.entered(False, True)
        for _ in range(2000):
            motion.step(State.FORWARD)
    skipped.try_segment(State.FORWARD)
    assert skipped.advance_segment(2000 + 60_000, lambda k: False) is False
    for _ in range(60_000):
        stepped.step(State.FORWARD)
    assert skipped.k == stepped.k == 62_000
    assert skipped.speed == stepped.speed == 1500.0
    assert skipped.temp == pytest.approx(stepped.temp, rel=1e-9)
    assert skipped.motor_i2t == pytest.approx(stepped.motor_i2t, rel=1e-9, abs=1e-12)
    assert skipped.hall.code() == stepped.hall.code()


def test_a_segment_stops_at_the_first_step_a_protection_trips_on(profile: Profile) -> None:
    motion = integrator(profile)
    motion.try_segment(State.STOPPED)
    assert motion.segment is not None
    looked: list[int] = []

    def expired(k: int) -> bool:
        looked.append(k)
        return k >= 4321

    assert motion.advance_segment(10_000, expired) is True
    assert motion.k == 4321
    assert len(looked) < 20  # found by bisection, not by stepping
    assert motion.t0 + motion.k * STEP == pytest.approx(4.321)

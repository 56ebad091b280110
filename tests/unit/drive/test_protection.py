"""The protections and guards beside the state table: what trips, what a reset needs, which causes are present."""

from __future__ import annotations

import pytest

from c20sim.drive.config import Conditions, configure
from c20sim.drive.face import RAM_REGISTERS
from c20sim.drive.integrator import Integrator
from c20sim.drive.params import ParameterStore
from c20sim.drive.physics import STEP
from c20sim.drive.profile import FaultCause, Profile, load_profile
from c20sim.drive.protection import Machine
from c20sim.drive.sensors import Hall, HallFault
from c20sim.drive.statemachine import Event, State
from c20sim.drive.terminals import Input
from c20sim.wire.registers import Reg, RunChannel, fcode_address


class Parts:
    """A machine and the parts it reads, as a Drive composes them, at power-up."""

    def __init__(self, profile: Profile, supply: float | None = None) -> None:
        self.profile = profile
        self.ram = dict.fromkeys(RAM_REGISTERS, 0)
        self.params = ParameterStore(profile)
        self.bench = Conditions(
            supply=profile.supply.voltage_v if supply is None else supply, ambient=profile.thermal.ambient_c
        )
        self.hall = Hall()
        self.motion = Integrator(profile, self.bench, self.hall, 0.0)
        self.machine = Machine(profile, self.motion, self.hall, 0.0)
        self.configure()
        self.motion.power_up()
        self.machine.power_up()

    def configure(self) -> None:
        self.motion.cfg = configure(self.profile, self.params, self.ram, self.bench)

    def steps(self, n: int) -> None:
        for _ in range(n):
            self.motion.step(self.machine.state)
            self.machine.protect()
            self.machine.auto_events()


def code(profile: Profile, cause: FaultCause) -> int:
    return next(spec.code for spec in profile.faults.values() if spec.cause is cause)


def test_power_up_is_stopped_with_a_bus_and_off_without(profile: Profile) -> None:
    assert Parts(profile).machine.state is State.STOPPED
    off = Parts(profile, supply=21.0)  # the bus rests below the 22 V recover level
    assert (off.machine.state, off.machine.bus_ok) == (State.OFF, False)
    off.bench.supply = 48.0
    off.steps(50)
    assert off.machine.state is State.STOPPED  # power back, and at zero speed at once stopped


def test_a_bus_lost_while_running_trips_undervoltage_and_while_stopped_powers_off(profile: Profile) -> None:
    running, stopped = Parts(profile), Parts(profile)
    running.machine.apply(Event.FORWARD)
    for parts in (running, stopped):
        parts.motion.bus = 19.0  # below the 20 V trip level
        parts.machine.protect()
    assert (running.machine.state, running.machine.fault) == (State.FAULT, 0x0A)
    assert running.machine.cause is FaultCause.UNDERVOLTAGE
    assert (stopped.machine.state, stopped.machine.fault) == (State.OFF, 0)


def test_the_protections_trip_in_a_fixed_order(profile: Profile) -> None:
    parts = Parts(profile)
    parts.machine.apply(Event.FORWARD)
    parts.motion.temp = 90.0  # past the 85 degC trip
    parts.bench.physical_inputs = Input.EF
    parts.configure()
    parts.machine.protect()
    assert parts.machine.fault == code(profile, FaultCause.OVERHEAT)  # overheat is checked before EF


def test_a_protection_the_profile_has_no_code_for_does_not_trip() -> None:
    profile = load_profile("c20-400hr")
    parts = Parts(profile)
    parts.machine.codes = {c: v for c, v in parts.machine.codes.items() if c is not FaultCause.EXTERNAL}
    parts.bench.physical_inputs = Input.EF
    parts.configure()
    parts.machine.protect()
    assert parts.machine.state is State.STOPPED


def test_a_reset_waits_for_the_cause_to_go(profile: Profile) -> None:
    parts = Parts(profile)
    parts.bench.physical_inputs = Input.EF
    parts.configure()
    parts.machine.protect()
    assert parts.machine.state is State.FAULT and parts.machine.cause_persists()
    assert parts.machine.reset() is False
    parts.bench.physical_inputs = 0
    parts.configure()
    assert parts.machine.reset() is True
    assert (parts.machine.state, parts.machine.fault, parts.machine.cause) == (State.COASTING, 0, None)


def test_a_persistent_forced_fault_holds_until_released(profile: Profile) -> None:
    parts = Parts(profile)
    parts.machine.force(0x15, True)
    assert (parts.machine.state, parts.machine.held_fault) == (State.FAULT, 0x15)
    assert parts.machine.reset() is False
    parts.machine.forced_hold = False
    assert parts.machine.held_fault is None and parts.machine.reset() is True


def test_the_overheat_condition_goes_before_its_fault_may_be_reset(profile: Profile) -> None:
    """present asks the condition, the reset guard its effect: the module is still hot."""
    parts = Parts(profile)
    parts.bench.ambient = 150.0
    assert parts.machine.present(FaultCause.OVERHEAT)
    parts.motion.temp = 86.0
    parts.machine.protect()
    assert parts.machine.cause is FaultCause.OVERHEAT
    parts.bench.ambient = 25.0
    assert not parts.machine.present(FaultCause.OVERHEAT)
    assert parts.machine.cause_persists() and parts.machine.reset() is False
    parts.motion.temp = 79.9  # below the trip level less the 5 K reset band
    assert parts.machine.reset() is True


def test_undervoltage_is_present_at_once_and_its_reset_waits_for_the_recover_level(profile: Profile) -> None:
    parts = Parts(profile)
    parts.machine.apply(Event.FORWARD)
    parts.bench.supply = 10.0
    assert parts.machine.present(FaultCause.UNDERVOLTAGE) and parts.machine.state is State.FORWARD
    parts.steps(2000)
    assert parts.machine.cause is FaultCause.UNDERVOLTAGE
    parts.bench.supply = 48.0
    assert not parts.machine.present(FaultCause.UNDERVOLTAGE)
    assert parts.machine.reset() is False  # the bus is still below 22 V
    parts.steps(2000)
    assert parts.machine.reset() is True


@pytest.mark.parametrize(
    ("change", "present"),
    [
        ({}, set()),
        ({"supply": 10.0}, {FaultCause.UNDERVOLTAGE}),
        (
            {"supply": 70.0},
            {FaultCause.OVERVOLTAGE_ACCEL, FaultCause.OVERVOLTAGE_DECEL, FaultCause.OVERVOLTAGE_CONSTANT},
        ),
        # 2.29 N m: 18 A, past the 10 A rating within the 20 A limit (and the drive's 11 A rating)
        ({"load": 2.29}, {FaultCause.MOTOR_OVERLOAD, FaultCause.DRIVE_OVERLOAD}),
        ({"load": 3.81}, {FaultCause.STALL}),  # 30 A: past the limit, a stall, not an overload
        ({"load": 5.2}, {FaultCause.STALL, *(f for f in FaultCause if f.value.startswith("overcurrent"))}),
        # a start at the 0.5 s ramp of 0.01 kg m^2 more would ask 51 A: current limiting holds the ramp instead
        ({"load_inertia": 0.01}, set()),
        ({"ambient": 86.0}, {FaultCause.OVERHEAT}),
        ({"physical_inputs": int(Input.EF)}, {FaultCause.EXTERNAL}),
    ],
)
def test_each_cause_is_present_for_the_conditions_that_trip_it(
    profile: Profile, change: dict[str, float], present: set[FaultCause]
) -> None:
    parts = Parts(profile)
    for name, value in change.items():
        setattr(parts.bench, name, value)
    parts.configure()
    assert {cause for cause in FaultCause if parts.machine.present(cause)} == present


def test_the_hall_and_ef_causes_are_present_whoever_set_them(profile: Profile) -> None:
    parts = Parts(profile)
    parts.hall.fault = HallFault.SEQUENCE
    parts.ram[Reg.VIRTUAL_INPUTS] = Input.EF  # a master's 200AH, not the bench's terminals
    parts.configure()
    assert {cause for cause in FaultCause if parts.machine.present(cause)} == {FaultCause.HALL, FaultCause.EXTERNAL}


def test_the_communication_timeout_runs_from_the_last_request(profile: Profile) -> None:
    parts = Parts(profile)
    parts.params.set(fcode_address(8, 2), 15)  # F08.02 = 1.5 s
    parts.configure()
    assert parts.motion.cfg.channel == RunChannel.COMMUNICATION
    assert not parts.machine.comm_expired(10_000)  # no request yet: not armed
    parts.machine.last_comm = 1.0
    assert not parts.machine.comm_expired(round(2.5 / STEP))
    assert parts.machine.comm_expired(round(2.5 / STEP) + 1)
    assert parts.machine.present(FaultCause.COMMUNICATION) is False  # at step 0
    parts.motion.k = 3000
    assert parts.machine.present(FaultCause.COMMUNICATION) is True
    parts.machine.protect()
    assert (parts.machine.cause, parts.machine.last_comm) == (FaultCause.COMMUNICATION, None)


def test_a_stop_ramps_to_zero_brakes_for_the_hold_and_stops(profile: Profile) -> None:
    parts = Parts(profile)
    parts.machine.apply(Event.FORWARD)
    parts.steps(1000)
    parts.machine.apply(Event.STOP)
    seen = [parts.machine.state]
    for _ in range(2000):
        parts.steps(1)
        if parts.machine.state is not seen[-1]:
            seen.append(parts.machine.state)
    assert seen == [State.DECELERATING, State.BRAKING, State.STOPPED]


def test_the_terminals_run_and_reset_on_the_terminal_channel(profile: Profile) -> None:
    parts = Parts(profile)
    parts.params.set(Reg.RUN_CHANNEL, RunChannel.TERMINALS)
    parts.configure()
    for bits, state in ((Input.FWD, State.FORWARD), (Input.FWD | Input.REV, State.DECELERATING)):
        before = parts.motion.cfg.inputs
        parts.bench.physical_inputs = bits
        parts.configure()
        parts.machine.inputs_changed(before)
        assert parts.machine.state is state
    parts.machine.force(0x15, False)
    before = parts.motion.cfg.inputs
    parts.bench.physical_inputs = Input.CLR
    parts.configure()
    parts.machine.inputs_changed(before)
    assert parts.machine.state is State.COASTING  # CLR's rising edge reset the fault


def test_with_current_limiting_off_a_heavy_inertia_is_an_overcurrent_cause(profile: Profile) -> None:
    parts = Parts(profile)
    parts.params.set(fcode_address(11, 5), 0)  # F11.05 = 0: the ramp asks what the inertia needs
    parts.bench.load_inertia = 0.01  # the 0.5 s ramp asks 51 A, above the 40 A trip
    parts.configure()
    assert parts.motion.cfg.limit_a == 0.0
    overcurrent = {f for f in FaultCause if f.value.startswith("overcurrent")}
    assert {cause for cause in FaultCause if parts.machine.present(cause)} == overcurrent

"""Steady segments: a settled drive with constant inputs skips ahead exactly, bit for bit as if it had stepped.

:class:`SteadySegments` is the integrator's fast-forward, a part of :class:`~c20sim.drive.integrator.Integrator`:
it enters a :class:`~c20sim.drive.physics.Segment` when the drive has settled, and jumps along its closed
forms to a later step, or to the first step a protection would trip on: each cause's row
(:data:`~c20sim.drive.trips.TRIPS`) says whether it can trip along a segment and at which step.
An idle drive so costs no CPU, and the state at a time is the same whatever the polling rate.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .config import Conditions, Config
from .physics import RPM, STEP, Segment
from .profile import Profile
from .sensors import Hall
from .statemachine import DRIVEN, State
from .trips import foreseen

__all__ = ["SteadySegments", "target_rpm"]


def target_rpm(state: State, cfg: Config) -> float:
    """The signed speed the ramp heads for in ``state``."""
    if state is State.FORWARD:
        return cfg.reference_rpm
    if state is State.REVERSE:
        return -cfg.reference_rpm
    if state is State.JOG_FORWARD:
        return cfg.jog_rpm
    if state is State.JOG_REVERSE:
        return -cfg.jog_rpm
    return 0.0


class SteadySegments:
    """The integrator's fast-forward (a mixin of :class:`~c20sim.drive.integrator.Integrator`, whose state it
    reads and moves)."""

    __slots__ = ("drive_i2t", "k", "motor_i2t", "segment", "temp", "watching")  #: what a jump along a segment moves
    profile: Profile
    bench: Conditions
    hall: Hall
    cfg: Config
    t0: float
    k: int
    speed: float
    speed_before: float
    ramp: float
    current: float
    loss: float
    temp: float
    temp_rate: float
    motor_i2t: float
    drive_i2t: float
    bus_settled: bool
    limited: bool
    stall_steps: int
    segment: Segment | None
    #: the rows' ``trips_at`` of the causes that can trip along the segment
    watching: tuple[Callable[[Any, Segment, int], bool], ...]

    def motor_rate(self, current: float) -> float:
        raise NotImplementedError  # the integrator's

    def drive_rate(self, current: float) -> float:
        raise NotImplementedError  # the integrator's

    def rest_rpm(self, ramp: float) -> float:
        raise NotImplementedError  # the integrator's

    def try_segment(self, state: State) -> None:
        """Enter a steady segment if the drive in ``state`` has settled and every input is constant."""
        if state in (State.DECELERATING, State.BRAKING, State.COASTING) or not self.bus_settled:
            return
        if self.speed != self.speed_before:
            return
        if state in DRIVEN:
            if self.limited or self.stall_steps or self.hall.fault is not None:
                return
            if self.ramp != target_rpm(state, self.cfg) or self.speed != self.rest_rpm(self.ramp):
                return
        elif self.current != 0.0:
            return  # the diodes still conduct
        elif self.speed != 0.0 and self.hall.fault is not None:
            return  # a broken sensor on a turning rotor glitches
        # Output off, the rotor at rest or where an active load and the friction balance (a fixed point: the
        # same speed from one step to the next, every input constant).
        watch = state not in (State.FAULT, State.OFF)
        thermal = self.profile.thermal
        temp_ss = self.bench.ambient + self.loss * thermal.resistance_k_per_w
        motor_rate = STEP * self.motor_rate(self.current)
        drive_rate = STEP * self.drive_rate(self.current)
        self.hall.mark_segment()
        self.segment = Segment(
            k0=self.k,
            temp0=self.temp,
            temp_ss=temp_ss,
            temp_rate=self.temp_rate,
            motor_i2t0=self.motor_i2t,
            motor_rate=motor_rate,
            drive_i2t0=self.drive_i2t,
            drive_rate=drive_rate,
            theta0=self.hall.theta,
            theta_rate=self.speed * RPM * self.cfg.pole_pairs * STEP,
        )
        watching: tuple[Callable[[Any, Segment, int], bool], ...] = ()
        if watch:  # the causes that can trip along it, from their rows
            for trip in foreseen():
                if trip.foresee is not None and trip.trips_at is not None and trip.foresee(self, self.segment):
                    watching += (trip.trips_at,)
        self.watching = watching

    def segment_event(self, seg: Segment, n: int, expired: Callable[[int], bool]) -> bool:
        """True if a protection trips at step ``n`` of the segment (monotone in ``n``)."""
        for trips_at in self.watching:
            if trips_at(self, seg, n):
                return True
        return expired(seg.k0 + n)

    def advance_segment(self, target: int, expired: Callable[[int], bool]) -> bool:
        """Jump along the segment to step ``target``, or to the first step a protection trips on (True)."""
        seg = self.segment
        assert seg is not None
        first, last = self.k + 1 - seg.k0, target - seg.k0
        event = self.segment_event(seg, last, expired)
        n = last
        if event:  # find the first step that trips: the same step a 1 ms poll would find
            low, high = first, last
            while low < high:
                mid = (low + high) // 2
                if self.segment_event(seg, mid, expired):
                    high = mid
                else:
                    low = mid + 1
            n = low
        self.k = seg.k0 + n
        self.temp = seg.temp(n)
        self.motor_i2t = seg.motor_i2t(n)
        self.drive_i2t = seg.drive_i2t(n)
        self.hall.skip(seg, n, self.t0 + seg.k0 * STEP, self.cfg.pole_pairs)
        return event

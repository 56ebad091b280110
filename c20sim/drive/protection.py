"""The protections and the guards beside the state table: what decides that a transition happens.

:class:`Machine` holds one drive's state and its fault latch, and feeds
events to :data:`~c20sim.drive.statemachine.TRANSITIONS`. Every decision
about them is made here: each protection watches a physical condition that
the integrator (:mod:`~c20sim.drive.integrator`) and the Hall sensors
(:mod:`~c20sim.drive.sensors`) give it, and trips by a transition of the
table with the profile's code, in a fixed order; the bus comes and goes with
an undervoltage recover level; the automatic events (at zero, hold done) and
the terminals' run and reset inputs become events; and a latched fault is
released by a reset only once its cause is gone (:meth:`Machine.cause_persists`).

What each cause trips on, whether it is present and whether it persists are
the rows of :data:`~c20sim.drive.trips.TRIPS`, one row a cause: the step tries
them in their fixed order, and :meth:`Machine.present` and
:meth:`Machine.cause_persists` ask the row of the cause. "Is this cause present"
is answered here and nowhere else, for every
:class:`~c20sim.drive.profile.FaultCause` from the conditions the drive is in,
whoever set them; the control layer's causes (:mod:`c20sim.control.causes`) ask
it through :meth:`Drive.cause_present <c20sim.drive.model.Drive.cause_present>`.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from .config import CHANNEL_COMM, CHANNEL_TERMINAL, COMM_CONTINUE, COMM_STOP_ANY, COMM_TRIP
from .physics import STEP
from .profile import FaultCause, Profile
from .sensors import Hall
from .statemachine import DRIVEN, RUNNING, Event, State, next_state
from .terminals import Input
from .trips import Trip, checked

if TYPE_CHECKING:
    from .integrator import Integrator

__all__ = ["TRIPS_ON_UNDERVOLTAGE", "Machine"]


#: States in which a bus below the undervoltage level trips (fault 0x0A) instead of powering off.
TRIPS_ON_UNDERVOLTAGE = RUNNING | {State.DECELERATING}
#: The run an undervoltage trip in each state takes up again once the power is back, with F01.21 = 1 (a jog is
#: a held key, a stop was ending anyway: neither restarts).
RESTARTS = {State.FORWARD: Event.FORWARD, State.REVERSE: Event.REVERSE}


Checks = tuple[tuple[Callable[[Any, Any], bool], Trip], ...]
#: The rows armed per profile, the latest few (a simulator's drives share one profile): profile's id -> (the
#: profile, weakly, the rows they were armed from, the checks by state).
_ARMED: dict[int, tuple[weakref.ref[Profile], tuple[Trip, ...], dict[State, Checks]]] = {}
_ARMED_MAX = 16


def _checks(profile: Profile, codes: Mapping[FaultCause, int]) -> dict[State, Checks]:
    """The rows the step tries in each state, in their fixed order, armed for ``profile``: those that can trip in
    the state and whose causes the profile has a code for (a cause without one is a protection this drive
    lacks: it never trips)."""
    rows = checked()
    kept = _ARMED.get(id(profile))
    if kept is not None and kept[0]() is profile and kept[1] is rows:
        return kept[2]
    coded = {cause.value for cause in codes}
    armed = [(t.detect(profile), t) for t in rows if t.detect is not None and any(c in coded for c in t.causes)]
    by_state = {state: tuple(a for a in armed if a[1].states is None or state in a[1].states) for state in State}
    while len(_ARMED) >= _ARMED_MAX:
        del _ARMED[next(iter(_ARMED))]
    _ARMED[id(profile)] = (weakref.ref(profile), rows, by_state)
    return by_state


class Machine:
    """One drive's state, its fault latch, the 2000H command in force and the guards that move it through
    :data:`~c20sim.drive.statemachine.TRANSITIONS`."""

    state: State
    cause: FaultCause | None
    last_comm: float | None

    def __init__(self, profile: Profile, motion: Integrator, hall: Hall, t0: float) -> None:
        self.profile, self.motion, self.hall, self.t0 = profile, motion, hall, t0
        s, p = profile.supply, profile.protection
        self.codes: Mapping[FaultCause, int] = {
            spec.cause: spec.code for spec in profile.faults.values() if spec.cause is not None
        }
        self.recover_v = s.undervoltage_recover_v or s.undervoltage_v
        self.stall_steps_limit = max(1, round(p.stall_time_s / STEP))
        #: Called with the fault code at each trip, before the output goes off (the drive's fault record).
        self.on_trip: Callable[[int], None] | None = None
        #: Called with True when the inverter starts driving the motor, False when it stops.
        self.on_drive: Callable[[bool], None] | None = None
        self.brake_steps_limit = round(p.brake_hold_s / STEP)
        #: the causes the step tries in each state, in order: (detect, row)
        self.checks = _checks(profile, self.codes)

    def power_up(self) -> None:
        """No fault, no request seen, no command in force; off until the bus is above the recover level."""
        self.bus_ok = self.motion.bus >= self.recover_v
        self.command: int = 0  # 2000H (annotated: mypyc's own type pass cannot infer it)
        self.fault = 0
        self.cause = None
        self.forced_hold = False
        self.last_comm = None
        self.state = State.STOPPED if self.bus_ok else State.OFF
        self.watching = self.checks[self.state]  #: the rows the step tries in this state
        self.auto_resets = 0  #: automatic fault resets since power-up or the last manual reset (F08.28)
        self.reset_due: int | None = None  #: the step of the next automatic reset
        self.restart_event: Event | None = None  #: the run to take up again once the power is back (F01.21)
        self.restart_due: int | None = None  #: the step of that restart, once the bus is back
        #: the last automatic action, in words with its time ("" if none since power-up): a dashboard names it
        self.auto_note = ""
        self.riding = False  #: the integrator's ride-through, as last seen (to name it when it changes)

    # --- Transitions.

    def apply(self, event: Event) -> None:
        """Feed one event to the state table."""
        if event is Event.RESET:
            self.reset()
            return
        new = next_state(self.state, event)
        if new is not self.state:
            self.enter(new)

    def enter(self, new: State) -> None:
        old = self.state
        if new is State.FAULT or old is State.FAULT or (old in RUNNING and new not in RUNNING):
            # The drive drops the command written to 2000H: a trip, a reset, or a run ended; the register
            # face stores a command written after applying it, so 2000H reads it (assumed: see face.py).
            self.command = 0
        self.motion.entered(old in DRIVEN, new in DRIVEN)
        self.state = new
        self.watching = self.checks[new]
        if (old in DRIVEN) != (new in DRIVEN) and self.on_drive is not None:
            self.on_drive(new in DRIVEN)  # the running-hour counter

    def trip(self, code: int, cause: FaultCause | None) -> None:
        if self.state is State.FAULT:
            return
        if self.on_trip is not None:
            self.on_trip(code)  # the fault record, while the output still shows what the trip met
        self.fault, self.cause = code, cause
        if cause is FaultCause.COMMUNICATION:
            self.last_comm = None  # re-armed by the next request
        cfg, k = self.motion.cfg, self.motion.k
        self.restart_event = self.reset_due = self.restart_due = None
        if cause is FaultCause.UNDERVOLTAGE and cfg.power_restart and self.state in RESTARTS:
            self.restart_event = RESTARTS[self.state]  # taken up again once the power is back (F01.21)
        elif cfg.auto_reset_trials > self.auto_resets:
            self.reset_due = k + cfg.auto_reset_steps  # F08.28 trials, F08.29 apart
        self.enter(next_state(self.state, Event.TRIP))

    def trip_on(self, cause: FaultCause) -> bool:
        code = self.codes.get(cause)
        if code is None:
            return False  # the profile has no code for it: this drive lacks the protection
        self.trip(code, cause)
        return True

    def force(self, code: int, persistent: bool) -> None:
        """Latch fault ``code`` now; with ``persistent`` a reset fails until released."""
        self.forced_hold = persistent
        if self.state is State.FAULT:
            self.fault, self.cause = code, None
        else:
            self.trip(code, None)

    @property
    def held_fault(self) -> int | None:
        """The code of a fault forced with ``persistent`` and not yet released, else None."""
        return self.fault if self.forced_hold and self.cause is None and self.fault else None

    # --- Guards.

    def reset(self, *, auto: bool = False) -> bool:
        """A fault reset: released only once the cause is gone; False if refused. A manual one (a master's, the
        keypad's, the terminals') also clears the automatic reset's count and any restart pending."""
        if self.state is not State.FAULT or self.cause_persists():
            return False
        self.fault, self.cause = 0, None
        if not auto:
            self.auto_resets = 0
            self.reset_due = self.restart_event = self.restart_due = None
        self.enter(next_state(self.state, Event.RESET))
        return True

    def due(self, k: int) -> bool:
        """Whether something the drive does by itself is due by step ``k`` (monotone in ``k``: a steady segment
        stops there): the communication timeout, an automatic reset, a restart after power."""
        if self.state is State.FAULT:
            if self.reset_due is not None and k >= self.reset_due:
                return True
            if self.restart_due is not None and k >= self.restart_due:
                return True
        return self.comm_expired(k)

    def automatic_reset(self) -> None:
        """The timers of a latched fault: the restart after power (F01.21/F01.22), the automatic reset
        (F08.28/F08.29). An automatic reset whose cause persists is refused and counts as a trial."""
        k, cfg, t = self.motion.k, self.motion.cfg, self.t0 + self.motion.k * STEP
        if self.restart_due is not None and k >= self.restart_due:
            event, self.restart_event, self.restart_due = self.restart_event, None, None
            if event is not None and self.reset(auto=True):
                self.apply(event)
                self.command = event.value if isinstance(event.value, int) else 0
                self.auto_note = f"restart after power at {t:.3f} s ({event.name.lower()})"
            return
        if self.reset_due is not None and k >= self.reset_due:
            self.auto_resets += 1
            trial = f"automatic reset {self.auto_resets} of {cfg.auto_reset_trials} at {t:.3f} s"
            code = self.fault
            if self.reset(auto=True):
                self.reset_due = None
                self.auto_note = f"{trial}: fault 0x{code:02X} cleared"
            else:
                more = self.auto_resets < cfg.auto_reset_trials
                self.reset_due = k + cfg.auto_reset_steps if more else None
                self.auto_note = f"{trial}: refused, the cause persists" + ("" if more else "; no trials left")

    def cause_persists(self) -> bool:
        """The reset guard: whether the latched fault's cause still holds it (the fault may outlast the
        condition that tripped it: a bus still below its recover level, a hot module, a spent budget): the
        cause's row says (no ``persists``: stall, communication, the reset itself is the retry)."""
        cause = self.cause
        if cause is None:
            return self.forced_hold
        persists = cause.trip.persists
        return persists is not None and bool(persists(self))

    def present(self, cause: FaultCause) -> bool:
        """Whether the condition that trips ``cause`` is there now, whoever set it (a bench, a master, a behaviour).

        The condition, not its effect: a supply below the undervoltage level is present at once, before
        the bus has fallen, and gone at once when the supply is back, while the reset guard
        (:meth:`cause_persists`) may still refuse. Faults the model has no physical cause for (a power
        stage, the EEPROM, ...) are never present: they are latched (:meth:`force`). The cause's row says.
        """
        present = cause.trip.present
        return present is not None and bool(present(self))

    def load_current(self) -> float:
        """The current (A) the motor needs to hold its load: friction, load torque and active load."""
        cfg = self.motion.cfg
        return (cfg.hold + abs(cfg.active)) / self.profile.motor.kt_nm_per_a

    def inputs_changed(self, before: int) -> None:
        """The input terminals changed from ``before``: CLR resets on its rising edge; the run inputs command."""
        cfg = self.motion.cfg
        after = cfg.inputs
        if after & ~before & Input.CLR:
            self.reset()
        run_bits = Input.FWD | Input.REV | Input.JOGF | Input.JOGR
        if cfg.channel != CHANNEL_TERMINAL or not (before ^ after) & run_bits:
            return
        fwd, rev = bool(after & Input.FWD), bool(after & Input.REV)
        jogf, jogr = bool(after & Input.JOGF), bool(after & Input.JOGR)
        if fwd != rev:
            self.apply(Event.FORWARD if fwd else Event.REVERSE)
        elif not fwd and jogf != jogr:
            self.apply(Event.JOG_FORWARD if jogf else Event.JOG_REVERSE)
        else:
            self.apply(Event.STOP)

    def protect(self) -> None:
        """Trip on the first cause present, in a fixed order; handle the bus coming and going."""
        state, motion = self.state, self.motion
        supply = self.profile.supply
        if motion.riding is not self.riding:  # name a ride-through when it begins and when it ends
            self.riding = motion.riding
            t, v = self.t0 + motion.k * STEP, motion.bus
            self.auto_note = (
                f"ride-through from {t:.3f} s: bus {v:.1f} V, slowing on the load's energy"
                if self.riding
                else f"ride-through ended at {t:.3f} s: bus {v:.1f} V"
            )
        was_ok = self.bus_ok
        if motion.bus < supply.undervoltage_v:
            self.bus_ok = False
        elif motion.bus >= self.recover_v:
            self.bus_ok = True  # back only above the recover level: no flicker around the trip level
        if state is State.FAULT:
            if self.restart_event is not None and self.bus_ok != was_ok:  # the power back, or gone again
                self.restart_due = motion.k + motion.cfg.power_restart_steps if self.bus_ok else None
            return
        if not self.bus_ok:
            if state in TRIPS_ON_UNDERVOLTAGE:
                self.trip_on(FaultCause.UNDERVOLTAGE)
            elif state is not State.OFF:
                self.apply(Event.POWER_LOST)
            return
        if state is State.OFF:
            self.apply(Event.POWER_BACK)
            return
        # The rows in their fixed order (overvoltage, overcurrent, Hall, stall, overloads, overheat, EF,
        # communication): the first present trips, by the ramp's phase for a cause that has phases. The current
        # the loop asks this step flows for the microseconds the limit takes to act: with current limiting off, a
        # ramp of a heavy load that asks more than the trip level trips on overcurrent; with it on, the ramp holds
        # at the level, and only a load step faster than the limit (a shock) trips; a load beyond the limit slows
        # the rotor. A bad Hall code trips whenever the bus is up.
        for detect, trip in self.watching:
            if detect(self, motion) and self.trip_on(
                FaultCause(f"{trip.name}_{motion.phase}" if trip.phases else trip.name)
            ):
                return
        if motion.cfg.comm_action != COMM_TRIP and self.comm_expired(motion.k):
            # F08.03 = 2 or 3: no alarm, ramp to stop; re-armed by the next request
            self.last_comm = None
            self.apply(Event.STOP if state not in (State.JOG_FORWARD, State.JOG_REVERSE) else Event.JOG_STOP)

    def comm_expired(self, k: int) -> bool:
        """True if the communication timeout has run out by step ``k``."""
        cfg = self.motion.cfg
        return (
            cfg.comm_timeout > 0.0
            and cfg.comm_action != COMM_CONTINUE
            and (cfg.channel == CHANNEL_COMM or cfg.comm_action == COMM_STOP_ANY)
            and self.last_comm is not None
            and self.state not in (State.FAULT, State.OFF)
            and self.t0 + k * STEP - self.last_comm > cfg.comm_timeout
        )

    def auto_events(self) -> None:
        """The events the model raises itself: the rotor at zero, the brake's hold done, a latched fault's timers."""
        state, motion = self.state, self.motion
        if state is State.FAULT:
            if self.reset_due is not None or self.restart_due is not None:
                self.automatic_reset()
        elif state is State.DECELERATING and motion.speed == 0.0 and motion.ramp == 0.0:
            self.apply(Event.AT_ZERO)
        elif state is State.BRAKING and motion.brake_steps >= self.brake_steps_limit:
            self.apply(Event.HOLD_DONE)
        elif state is State.COASTING and motion.speed == 0.0:
            self.apply(Event.AT_ZERO)

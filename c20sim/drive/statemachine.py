"""The drive's states and what moves them, as one table.

Every change of state is a row of :data:`TRANSITIONS`: a 2000H command (or the
same command from the keypad or the terminals), or an event the model raises
(bus lost or back, the ramp reached zero, the brake hold ended, a trip). A
pair missing from the table is ignored, as the drive ignores a jog command
while running.

What decides whether an event happens (the protections that trip, the bus
coming and going, the reset guard: is the fault's cause gone?) lives beside
the table, in :mod:`~c20sim.drive.protection`; the table only says where each
accepted event leads.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping

from ..wire.registers import Command

__all__ = [
    "DRIVEN",
    "RUNNING",
    "RUN_COMMANDS",
    "STATUS_WORD",
    "TRANSITIONS",
    "Event",
    "State",
    "next_state",
]


class State(enum.Enum):
    """What the drive is doing."""

    OFF = "off"  #: bus voltage not established (status 5)
    STOPPED = "stopped"  #: ready, output off (status 3)
    FORWARD = "forward"  #: running forward (status 1)
    REVERSE = "reverse"  #: running reverse (status 2)
    JOG_FORWARD = "jog forward"  #: inching forward (status 1)
    JOG_REVERSE = "jog reverse"  #: inching reverse (status 2)
    DECELERATING = "decelerating"  #: ramping down to stop (status 1 or 2, by rotation)
    BRAKING = "braking"  #: electronic brake holding the stopped rotor (status 6); assumed
    COASTING = "coasting"  #: output off, rotor spinning down freely (status 3)
    FAULT = "fault"  #: a trip is latched, output off (status 4)


class Event(enum.Enum):
    """Commands (the 2000H values of :class:`~c20sim.wire.registers.Command`) and the model's own events."""

    FORWARD = int(Command.FORWARD)
    REVERSE = int(Command.REVERSE)
    JOG_FORWARD = int(Command.JOG_FORWARD)
    JOG_REVERSE = int(Command.JOG_REVERSE)
    STOP = int(Command.STOP)  #: ramp down
    COAST = int(Command.FREE_STOP)  #: output off at once
    RESET = int(Command.RESET)  #: the model lets it through only once the cause is gone
    JOG_STOP = int(Command.JOG_STOP)
    POWER_LOST = "power lost"  #: bus fell below the undervoltage level while not running
    POWER_BACK = "power back"  #: bus rose above the undervoltage level while off
    AT_ZERO = "at zero"  #: the rotor (and the ramp) reached zero speed
    HOLD_DONE = "hold done"  #: the electronic brake's hold time ended
    TRIP = "trip"  #: a protection tripped or a fault was forced


#: States in which the inverter drives the motor: W/R* registers are locked.
DRIVEN = frozenset(
    {State.FORWARD, State.REVERSE, State.JOG_FORWARD, State.JOG_REVERSE, State.DECELERATING, State.BRAKING}
)

#: 2100H for each state; DECELERATING reports the direction of rotation instead (0 here).
STATUS_WORD: Mapping[State, int] = {
    State.OFF: 5,
    State.STOPPED: 3,
    State.FORWARD: 1,
    State.REVERSE: 2,
    State.JOG_FORWARD: 1,
    State.JOG_REVERSE: 2,
    State.DECELERATING: 0,
    State.BRAKING: 6,
    State.COASTING: 3,
    State.FAULT: 4,
}


def _table() -> dict[tuple[State, Event], State]:
    S, E = State, Event
    run = {
        E.FORWARD: S.FORWARD,
        E.REVERSE: S.REVERSE,
        E.JOG_FORWARD: S.JOG_FORWARD,
        E.JOG_REVERSE: S.JOG_REVERSE,
    }
    table: dict[tuple[State, Event], State] = {}
    # From rest, or while stopping, any run or jog command starts (a coasting rotor is caught on the fly).
    for state in (S.STOPPED, S.DECELERATING, S.BRAKING, S.COASTING):
        for event, target in run.items():
            table[state, event] = target
    # Running: the other direction reverses through zero on the ramp; jog commands are ignored.
    for state in (S.FORWARD, S.REVERSE):
        table[state, E.FORWARD] = S.FORWARD
        table[state, E.REVERSE] = S.REVERSE
        table[state, E.STOP] = S.DECELERATING
    # Jogging: the other jog direction or a run command takes over; jog stop or stop ramps down.
    for state in (S.JOG_FORWARD, S.JOG_REVERSE):
        for event, target in run.items():
            table[state, event] = target
        table[state, E.JOG_STOP] = S.DECELERATING
        table[state, E.STOP] = S.DECELERATING
    for state in (S.FORWARD, S.REVERSE, S.JOG_FORWARD, S.JOG_REVERSE, S.DECELERATING):
        table[state, E.COAST] = S.COASTING
    table[S.BRAKING, E.COAST] = S.STOPPED
    table[S.DECELERATING, E.AT_ZERO] = S.BRAKING
    table[S.BRAKING, E.HOLD_DONE] = S.STOPPED
    table[S.COASTING, E.AT_ZERO] = S.STOPPED
    # The bus: lost while not running means "off" (status 5); while running it trips undervoltage.
    for state in (S.STOPPED, S.COASTING, S.BRAKING):
        table[state, E.POWER_LOST] = S.OFF
    table[S.OFF, E.POWER_BACK] = S.COASTING  # at zero speed COASTING gives way to STOPPED at once
    # A trip is a transition from anywhere but a latched fault; reset releases it (the rotor may still turn).
    for state in State:
        if state is not S.FAULT:
            table[state, E.TRIP] = S.FAULT
    table[S.FAULT, E.RESET] = S.COASTING
    return table


#: (state, event) -> next state. Pairs not listed leave the state as it is.
TRANSITIONS: Mapping[tuple[State, Event], State] = _table()


def next_state(state: State, event: Event) -> State:
    """Where ``event`` leads from ``state`` (the same state if the table has no row)."""
    return TRANSITIONS.get((state, event), state)


#: The commands that start the motor (refused from a run channel other than the one F00.01 selects).
RUN_COMMANDS = frozenset({Event.FORWARD, Event.REVERSE, Event.JOG_FORWARD, Event.JOG_REVERSE})
#: States in which the drive runs toward a set speed (DRIVEN less stopping on the ramp and braking).
RUNNING = frozenset({State.FORWARD, State.REVERSE, State.JOG_FORWARD, State.JOG_REVERSE})

"""The state table: every row leads where the sheet's commands say."""

from __future__ import annotations

import pytest

from c20sim.drive.statemachine import DRIVEN, STATUS_WORD, TRANSITIONS, Event, State, next_state


def test_every_state_has_a_status_word() -> None:
    assert set(STATUS_WORD) == set(State)
    assert STATUS_WORD[State.OFF] == 5
    assert STATUS_WORD[State.FAULT] == 4
    assert STATUS_WORD[State.BRAKING] == 6


@pytest.mark.parametrize("state", [s for s in State if s is not State.FAULT])
def test_a_trip_leads_to_fault_from_anywhere(state: State) -> None:
    assert next_state(state, Event.TRIP) is State.FAULT


def test_a_latched_fault_ignores_everything_but_reset() -> None:
    for event in Event:
        expected = State.COASTING if event is Event.RESET else State.FAULT
        assert next_state(State.FAULT, event) is expected


def test_reversing_while_running_stays_driven() -> None:
    assert next_state(State.FORWARD, Event.REVERSE) is State.REVERSE
    assert next_state(State.REVERSE, Event.FORWARD) is State.FORWARD


def test_jog_is_ignored_while_running_and_jog_stop_stops_a_jog() -> None:
    assert next_state(State.FORWARD, Event.JOG_FORWARD) is State.FORWARD
    assert next_state(State.FORWARD, Event.JOG_STOP) is State.FORWARD
    assert next_state(State.JOG_FORWARD, Event.JOG_STOP) is State.DECELERATING


def test_stopping_runs_through_the_brake() -> None:
    assert next_state(State.FORWARD, Event.STOP) is State.DECELERATING
    assert next_state(State.DECELERATING, Event.AT_ZERO) is State.BRAKING
    assert next_state(State.BRAKING, Event.HOLD_DONE) is State.STOPPED
    assert next_state(State.FORWARD, Event.COAST) is State.COASTING
    assert next_state(State.COASTING, Event.AT_ZERO) is State.STOPPED


def test_power_comes_and_goes_only_when_not_running() -> None:
    assert next_state(State.STOPPED, Event.POWER_LOST) is State.OFF
    assert next_state(State.OFF, Event.POWER_BACK) is State.COASTING
    assert (State.FORWARD, Event.POWER_LOST) not in TRANSITIONS  # running, it trips undervoltage instead
    assert next_state(State.OFF, Event.FORWARD) is State.OFF


def test_driven_states_are_the_ones_that_lock_w_r_star() -> None:
    assert State.STOPPED not in DRIVEN
    assert State.COASTING not in DRIVEN
    assert {State.FORWARD, State.DECELERATING, State.BRAKING} <= DRIVEN

"""Scenario expectations beyond a value now: a refusal (expect_exception), a silence, an eventual state (within)."""

from __future__ import annotations

import pytest

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario.timeline import POLL, ScenarioError, parse_scenario, run

START = {"at": 0, "write": {"2001H": 1500, "2000H": 1}}


def play(*steps: dict[str, object]) -> list[tuple[int, bool, str]]:
    report = run(parse_scenario({"step": list(steps)}, "s.toml"), Simulator(load_profile()))
    return [(o.step.index, o.ok, o.text) for o in report.outcomes]


def test_a_write_refused_with_the_expected_code_passes() -> None:
    assert play(START, {"at": 0.1, "write": {"2002H": 4}, "expect_exception": 8})[2] == (
        2,
        True,
        "write 2002H = 4: refused with exception 0x08 (parameter cannot be changed while running), as expected",
    )


def test_a_write_taken_or_refused_otherwise_fails() -> None:
    # stopped, pole pairs (W/R*) are writable: taken, where 0x08 was expected
    assert play({"at": 0, "write": {"2002H": 4}, "expect_exception": 8}) == [
        (1, False, "write 2002H = 4: taken, expected exception 0x08 (parameter cannot be changed while running)")
    ]
    # a function code while 200EH = 0 is refused with 0x04, not 0x08
    assert play({"at": 0, "write": {"F00.10": 2500}, "expect_exception": 8}) == [
        (
            1,
            False,
            "write F00.10 = 2500: exception 0x04 to write: operation failed, "
            "expected exception 0x08 (parameter cannot be changed while running)",
        )
    ]


def test_silence_from_an_offline_drive_passes_and_an_answer_fails() -> None:
    assert play(
        {"at": 0, "link": {"offline": True}, "expect_silence": True},
        {"at": 0.5, "write": {"2001H": 1000}, "expect_silence": True},
        {"at": 1, "clear_link": True, "expect_silence": True},
        {"at": 1, "write": {"2001H": 900}, "expect_silence": True},
    ) == [
        (1, True, "read 2100H: no reply, as expected"),
        (2, True, "write 2001H = 1000: no reply, as expected"),
        (3, False, "read 2100H: answered (2100H = 0003: stopped), expected no reply"),
        (4, False, "write 2001H = 900: answered (write 2001H = 0384: 900 rpm), expected no reply"),
    ]


def test_an_offline_drive_refuses_nothing_silently_when_a_reply_was_expected() -> None:
    assert play({"at": 0, "link": {"offline": True}, "write": {"2002H": 4}, "expect_exception": 8}) == [
        (1, False, "write 2002H = 4: no reply, expected exception 0x08 (parameter cannot be changed while running)")
    ]


def test_within_polls_in_model_time_until_true() -> None:
    sim = Simulator(load_profile())
    scenario = parse_scenario(
        {"step": [START, {"at": 0, "within": 2.0, "expect": {"motor_speed": 1500, "status1": 1}}]}, "s.toml"
    )
    report = run(scenario, sim)
    assert report.ok
    met = report.outcomes[-1].t
    # the ramp takes time: met after the first poll, well before the deadline, on the poll grid
    assert POLL < met < 2.0
    assert abs(met / POLL - round(met / POLL)) < 1e-6
    assert sim.now() == pytest.approx(met)
    assert report.outcomes[-2].text == f"3006H (motor speed) = 1500 (1500 rpm), expected 1500 (after {met:.3g} s)"
    # one poll earlier, it was not there yet
    early = Simulator(load_profile())
    run(parse_scenario({"step": [START]}, "s.toml"), early)
    early.run_until(met - POLL)
    assert early.drive().telemetry().speed_rpm != 1500


def test_within_fails_with_the_last_value_seen() -> None:
    outcomes = play(START, {"at": 0, "within": 0.1, "expect": {"motor_speed": 1500}})
    assert outcomes[-1] == (
        2,
        False,
        "3006H (motor speed) = 588 (588 rpm), expected 1500 (1500 rpm) (still after 0.1 s)",
    )


def test_within_waits_for_its_expectations_beside_the_audits_findings() -> None:
    """The audit's outcomes come after the expectations': the wait reads the expectations again, not the last
    outcomes, and keeps the audit's (it once took the audit's for an expectation, stopped at once, and dropped it)."""
    outcomes = play(
        START, {"at": 0.1, "within": 2.0, "expect": {"motor_speed": 1500}, "forbid_findings": ["eeprom-wear"]}
    )
    assert outcomes[2:] == [
        (2, True, "3006H (motor speed) = 1500 (1500 rpm), expected 1500 (after 0.19 s)"),
        (2, True, "audit: no eeprom-wear finding"),
    ]


def test_a_later_step_whose_time_has_passed_runs_when_the_wait_ends() -> None:
    sim = Simulator(load_profile())
    scenario = parse_scenario(
        {
            "step": [
                START,
                {"at": 0, "within": 1.0, "expect": {"fault_code": 1}},  # never: waits the whole second
                {"at": 0.5, "expect": {"status1": 1}},
            ]
        },
        "s.toml",
    )
    report = run(scenario, sim)
    assert [o.ok for o in report.outcomes] == [True, True, False, True]
    assert report.outcomes[-1].t == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("step", "message"),
    [
        (
            {"expect_exception": 8},
            "key 'expect_exception': the step has no write to be refused; give write = { ... } too",
        ),
        (
            {"write": {"2001H": 1}, "expect_exception": 9},
            "key 'expect_exception': expected an exception code 1-8, such as 8",
        ),
        (
            {"write": {"2001H": 1}, "expect_exception": True},
            "key 'expect_exception': expected an exception code 1-8, such as 8",
        ),
        ({"expect_silence": "yes"}, "key 'expect_silence': expected true or false"),
        (
            {"write": {"2001H": 1}, "expect_exception": 8, "expect_silence": True},
            "key 'expect_silence': a write cannot be both refused and unanswered; give one of the two",
        ),
        ({"within": 2.0}, "key 'within': nothing to wait for; give expect = { ... } too"),
        (
            {"within": 0, "expect": {"status1": 1}},
            "key 'within': expected seconds of model time, > 0 and <= 3600, such as 2.0",
        ),
        (
            {"within": float("inf"), "expect": {"status1": 1}},
            "key 'within': expected seconds of model time, > 0 and <= 3600, such as 2.0",
        ),
        (
            {"within": "2", "expect": {"status1": 1}},
            "key 'within': expected seconds of model time, > 0 and <= 3600, such as 2.0",
        ),
    ],
)
def test_bad_expectations_name_the_step_and_key(step: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario({"step": [{"at": 1, **step}]}, "s.toml")
    assert str(caught.value) == f"s.toml: step 1 (at 1 s), {message}"


async def test_play_polls_a_realtime_clock_until_true() -> None:
    from c20sim.core.clock import RealtimeClock
    from c20sim.scenario.timeline import play

    sim = Simulator(load_profile(), (1,), clock=RealtimeClock(speed=20))
    scenario = parse_scenario({"step": [START, {"at": 0, "within": 5.0, "expect": {"motor_speed": 1500}}]}, "rt")
    report = await play(scenario, sim)  # the ramp's model time passes 20 times faster than the wall's
    assert [(o.step.index, o.ok) for o in report.outcomes] == [(1, True), (1, True), (2, True)]
    assert 0 < report.outcomes[-1].t < 5.0
    assert abs(sim.drive().telemetry().speed_rpm - 1500) < 1  # the speed loop settles on it (3006H read 1500)


async def test_served_refusal_and_silence_go_through_the_line() -> None:
    from c20sim.scenario.timeline import play
    from c20sim.transport.line import Line

    sim = Simulator(load_profile(), (1,))  # a virtual clock: play advances it to each step
    line = Line(sim)
    scenario = parse_scenario(
        {
            "step": [
                START,
                {"at": 0.1, "write": {"2002H": 4}, "expect_exception": 8},
                {"at": 0.2, "link": {"offline": True}, "expect_silence": True},
            ]
        },
        "s.toml",
    )
    report = await play(scenario, sim, line=line)
    assert [(o.step.index, o.ok, o.text) for o in report.outcomes] == [
        (1, True, "write 2001H = 1500: taken"),
        (1, True, "write 2000H = 1: taken"),
        (
            2,
            True,
            "write 2002H = 4: refused with exception 0x08 (parameter cannot be changed while running), as expected",
        ),
        (3, True, "read 2100H: no reply, as expected"),
    ]
    rx = [(r.direction, r.data.hex(" ").upper(), r.note) for r in sim.bus.records][-1]
    assert rx == ("rx", "01 03 21 00 00 01 8E 36", "drive offline (injected)")

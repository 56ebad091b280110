"""A scenario step kind is one row: a throwaway kind, added to the table and nowhere else, is read at load
(refusing a bad value in one line), played (its act's outcome in the report and in run-scenario's output),
in the JSON Schema (which validates with it), and in the docs check (the docs page must list it)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from c20sim import cli
from c20sim.control import ops
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario import stepkinds
from c20sim.scenario.schema import SCENARIO_DOCS, build, render, shipped, step_keys_docs
from c20sim.scenario.steps import Outcome, Reading, Step, StepKind
from c20sim.scenario.timeline import ScenarioError, parse_scenario, run

KEY = "bus_at_least"


def _parse(value: object, reading: Reading) -> dict[str, object]:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 65535:
        raise reading.fail(KEY, "expected a raw bus voltage 0-65535 (3008H, 0.1 V)")
    return {KEY: value}


def _check(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    least = step.value(KEY)
    assert isinstance(least, int)
    raw = ops.read_register(sim, address, 0x3008)["raw"]
    return [Outcome(step, t, raw >= least, f"bus 3008H = {raw}, at least {least}")]


ROW = StepKind(
    KEY,
    _parse,
    lambda: {"type": "integer", "minimum": 0, "maximum": 65535, "description": "a test's throwaway check"},
    "raw 0-65535",
    "the bus voltage must read at least this (a test's throwaway step kind)",
    _check,
    after_writes=True,
)


@pytest.fixture
def with_row() -> Iterator[None]:
    table = stepkinds.table()
    table.add(ROW)
    try:
        yield
    finally:
        table.remove(KEY)


def scenario(**step: object) -> dict[str, Any]:
    return {"name": "bus", "step": [{"at": 0.0}, {"at": 0.5, **step}]}


def played(data: dict[str, Any]) -> list[tuple[bool, str]]:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    return [(o.ok, o.text) for o in run(parse_scenario(data, "bus.toml"), sim).outcomes]


def test_a_new_step_kind_is_read_and_played(with_row: None) -> None:
    step = parse_scenario(scenario(bus_at_least=400), "bus.toml").steps[1]
    assert step.value(KEY) == 400 and step.more == {KEY: 400} and KEY in step.given
    assert played(scenario(bus_at_least=400)) == [(True, "bus 3008H = 480, at least 400")]
    # played at its step's time: the supply dropped to 20 V at 0 s has let the bus sag to 37.4 V by 0.5 s
    sagged = {"name": "bus", "step": [{"at": 0.0, "set": {"supply_v": 20}}, {"at": 0.5, KEY: 400}]}
    assert played(sagged) == [(False, "bus 3008H = 374, at least 400")]
    with pytest.raises(ScenarioError) as bad:
        parse_scenario(scenario(bus_at_least="high"), "bus.toml")
    assert str(bad.value) == "bus.toml: step 2 (at 0.5 s), key 'bus_at_least': expected a raw bus voltage 0-65535 " + (
        "(3008H, 0.1 V)"
    )
    with pytest.raises(ScenarioError, match=r"unknown key 'bus_at_lest'; did you mean 'bus_at_least'\?"):
        parse_scenario(scenario(bus_at_lest=400), "bus.toml")


def test_run_scenario_plays_a_new_step_kind(with_row: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bus.toml"
    path.write_text('name = "bus"\n[[step]]\nat = 0.0\nbus_at_least = 400\n[[step]]\nat = 0.1\nbus_at_least = 500\n')
    assert cli.main(["run-scenario", "--jobs", "1", str(path)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert "  ok   step 1 (at 0 s): bus 3008H = 480, at least 400" in out
    assert "  FAIL step 2 (at 0.1 s): bus 3008H = 480, at least 500" in out


def test_a_new_step_kind_is_in_the_schema_and_the_docs(with_row: None) -> None:
    step = build("scenario")["properties"]["step"]["items"]
    assert step["properties"][KEY] == ROW.schema()
    validator = jsonschema.Draft7Validator(build("scenario"))
    assert [e.message for e in validator.iter_errors(scenario(bus_at_least=400))] == []
    assert [e.message for e in validator.iter_errors(scenario(bus_at_least=-1))] == ["-1 is less than the minimum of 0"]
    assert json.loads(render("scenario")) != json.loads(shipped("scenario"))  # the shipped-schema test asks to rewrite
    # the docs check: the page as the rows write it has the kind's line; the page as it is does not, so the
    # docs test fails until python -m c20sim.scenario.schema writes it
    text = SCENARIO_DOCS.read_text(encoding="utf-8")
    line = "| `bus_at_least` | raw 0-65535 | the bus voltage must read at least this (a test's throwaway step kind) |"
    assert line in step_keys_docs(text).splitlines()
    assert step_keys_docs(text) != text


def test_a_removed_step_kind_is_gone_everywhere() -> None:
    assert KEY not in stepkinds.table()
    with pytest.raises(ScenarioError, match=r"unknown key 'bus_at_least'"):
        parse_scenario(scenario(bus_at_least=400), "bus.toml")
    assert KEY not in build("scenario")["properties"]["step"]["items"]["properties"]
    assert f"`{KEY}`" not in step_keys_docs(SCENARIO_DOCS.read_text(encoding="utf-8"))
    with pytest.raises(ValueError, match=r"^step kind 'at': declared twice$"):
        stepkinds.table().add(next(iter(stepkinds.table())))


async def _ping(step: Step, sim: Simulator) -> Outcome:
    return Outcome(step, sim.now(), True, f"ping {step.value('ping')}: answered on the served drive")


PING = StepKind(
    "ping",
    lambda value, reading: {"ping": reading.checked("ping", lambda: ops.integer("ping", value, 1, 9))},
    lambda: {"type": "integer", "minimum": 1, "maximum": 9},
    "1-9",
    "a test's throwaway step kind that plays only on a served drive",
    served=_ping,
    served_only="a ping needs a served drive: serve --scenario FILE",
    against=lambda step, sim: None if len(sim.drives) == 1 else "a ping wants one drive on the bus",
)


@pytest.fixture
def with_ping() -> Iterator[None]:
    table = stepkinds.table()
    table.add(PING)
    try:
        yield
    finally:
        table.remove("ping")


async def test_a_new_served_step_kind_plays_only_on_a_served_drive(with_ping: None) -> None:
    from c20sim.core.clock import RealtimeClock
    from c20sim.scenario.timeline import play

    data = {"name": "ping", "step": [{"at": 0.0, "ping": 3}]}
    with pytest.raises(ScenarioError) as refused:  # run-scenario: virtual time, no master
        run(parse_scenario(data, "ping.toml"), Simulator(load_profile(), (1,), clock=VirtualClock()))
    assert str(refused.value) == "ping.toml: step 1 (at 0 s): ping: a ping needs a served drive: serve --scenario FILE"
    report = await play(parse_scenario(data, "ping.toml"), Simulator(load_profile(), (1,), clock=RealtimeClock()))
    assert [(o.ok, o.text) for o in report.outcomes] == [(True, "ping 3: answered on the served drive")]
    with pytest.raises(ScenarioError) as two:  # its check against the simulator, before anything plays
        await play(parse_scenario(data, "ping.toml"), Simulator(load_profile(), (1, 2), clock=RealtimeClock()))
    assert str(two.value) == "ping.toml: step 1 (at 0 s), key 'ping': a ping wants one drive on the bus"
    with pytest.raises(ScenarioError, match=r"^ping\.toml: step 1 \(at 0 s\), key 'ping': ping: 12 is outside 1-9$"):
        parse_scenario({"step": [{"at": 0.0, "ping": 12}]}, "ping.toml")

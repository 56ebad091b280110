"""A fault cause is one row, a condition is one row: a throwaway of each reaches every front end, and is gone after.

The rows are :data:`c20sim.drive.trips.TRIPS` and :data:`c20sim.drive.conditions.CONDITIONS`. A program registers
a row before it imports its front ends (they build their tables when imported), so the full walk runs in a child
interpreter: one row of each, registered first, then the profile parser and its schema, the drive's protection,
the control API over HTTP (served on port 0), OpenAPI, ``c20sim ctl``, the scenarios and their schema, the
dashboard's bench and its conditions view, and the docs checks. This process never sees them: the last test
shows every front end here without them. The causes' front ends (the API's causes and OpenAPI, the scenarios
and their schema, the dashboard's switches) read the cause rows when asked: a cause registered in this process,
after they were imported, reaches them too (``warm_row``). The drive's own use of a row (protection iterates the rows) is shown in
this process too, with a fixture that registers the row and takes it away.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from c20sim.cli import render_profile
from c20sim.control import causes, ops, routes
from c20sim.control.openapi import document
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive import conditions, trips
from c20sim.drive.model import Drive
from c20sim.drive.profile import FaultCause, Profile, load_profile, parse_profile
from c20sim.drive.trips import docs_table
from c20sim.scenario.schema import build, shipped
from c20sim.scenario.steps import ScenarioError
from c20sim.scenario.timeline import parse_scenario
from c20sim.tui.widgets import CONDITION_FIELDS
from c20sim.tui.workbench import DEVICE_SWITCHES, Workbench
from c20sim.wire.errors import ProfileError
from c20sim.wire.registers import Command, Reg
from tests.unit.throwaway_rows import (
    CONDENSATION,
    HUMIDITY,
    PROFILE,
    ROOT,
    WET_FAULT,
    causes_block,
    undocumented_conditions,
    unnamed_profile_keys,
)

# --- The docs checks: what a new row must say.


def test_the_faults_page_lists_every_cause_row() -> None:
    assert causes_block() == docs_table(), (
        "docs/faults.md's causes table is stale: paste c20sim.drive.trips.docs_table() between its markers"
    )


def test_the_profile_page_names_every_cause() -> None:
    text = (ROOT / "docs" / "profile-format.md").read_text(encoding="utf-8")
    assert [c.value for c in FaultCause if f"`{c.value}`" not in text] == []


def test_every_condition_is_documented() -> None:
    assert undocumented_conditions() == []


# --- The drive iterates the rows: a row registered in this process trips it, and is gone after.


@pytest.fixture
def wet_rows() -> Iterator[None]:
    conditions.register(HUMIDITY)
    trips.register(CONDENSATION)
    try:
        yield
    finally:
        trips.unregister("condensation")
        conditions.unregister("humidity_pct")


def test_a_registered_cause_trips_the_drive_and_holds_its_reset(wet_rows: None) -> None:
    profile = parse_profile(PROFILE.read_text() + WET_FAULT, "wet.toml")
    assert profile.fault_code(FaultCause("condensation")) == 99
    sim = Simulator(profile, (1,), clock=VirtualClock())
    drive = sim.drives[1]
    assert HUMIDITY.get(drive) == 40.0  # kept in the drive's conditions, at its initial value until set
    sim.advance(0.1)
    assert drive.read(Reg.FAULT_CODE) == 0
    HUMIDITY.set(drive, 99.0)
    assert drive.bench.extra == {"humidity_pct": 99.0}
    assert drive.cause_present(FaultCause("condensation")) is True
    sim.advance(0.1)
    assert drive.read(Reg.FAULT_CODE) == 99  # protection tried the row, in its place
    assert drive.keypad(Command.RESET) is False  # persists: the reset guard asked the row
    HUMIDITY.set(drive, 40.0)
    assert drive.cause_present(FaultCause("condensation")) is False
    assert drive.keypad(Command.RESET) is True
    assert drive.read(Reg.FAULT_CODE) == 0


def test_a_registered_cause_is_gone_after(wet_rows: None) -> None:
    trips.unregister("condensation")
    conditions.unregister("humidity_pct")
    try:
        with pytest.raises(ValueError, match=r"^'condensation' is not a valid FaultCause$"):
            FaultCause("condensation")
        with pytest.raises(ProfileError, match=r"unknown cause 'condensation'"):
            parse_profile(PROFILE.read_text() + WET_FAULT, "wet.toml")
    finally:
        conditions.register(HUMIDITY)
        trips.register(CONDENSATION)


#: A throwaway cause that moves along a steady segment: the module past 40 °C, foreseen by the segment's closed form.
WARM = trips.Trip(
    "warm",
    "the module past 40 °C (a test's throwaway cause)",
    check=6.5,
    detect=lambda p: lambda m, mo: bool(mo.temp >= 40.0),
    present=lambda m: bool(m.motion.temp >= 40.0),
    foresee=lambda it, seg: seg.temp_ss > 40.0,
    trips_at=lambda it, seg, n: seg.temp(n) >= 40.0,
)
WARM_FAULT = '\n[[fault]]\ncode = 98\nname = "WRM"\ncause = "warm"\n'
#: The bench's causes of the shipped rows, in their rank.
BUILT_IN = ["undervoltage", "overvoltage", "overcurrent", "overload", "stall", "overheat", "hall", "external"]


def warm_trip_step(fault: str = WARM_FAULT, *, every_ms: int | None = None) -> tuple[bool, int, int]:
    """(whether it was on a steady segment at 60 s, the fault code, the step it tripped on) of a stopped drive in a
    60 °C ambient, advanced 150 s: at once, or polled ``every_ms`` (each advance ends a segment at its target, so
    a 1 ms poll integrates every step: no subclass of the drive, which the compiled core does not allow)."""
    drive = Drive(parse_profile(PROFILE.read_text() + fault, "warm.toml"))
    steps: list[int] = []
    drive.machine.on_trip = lambda code: steps.append(drive.motion.k)
    drive.set_ambient(60.0)
    if every_ms is None:
        drive.advance_to(60.0)
        steady = drive.motion.segment is not None
        drive.advance_to(150.0)
    else:
        for ms in range(every_ms, 150_001, every_ms):
            drive.advance_to(ms / 1000)
        steady = False
    return steady, drive.read(Reg.FAULT_CODE), steps[0] if steps else -1


def test_a_steady_segment_stops_where_a_registered_cause_trips() -> None:
    """The segments iterate the rows: a row that foresees its trip along a segment trips on the same step as a
    drive stepped every millisecond (134 s: 240 s x ln(35 / 20), the module heading for 60 °C from 25 °C)."""
    trips.register(WARM)
    try:
        segmented, stepped = warm_trip_step(), warm_trip_step(every_ms=1)
    finally:
        trips.unregister("warm")
    assert segmented[:2] == (True, 98)  # it skipped along a segment, and tripped
    assert stepped[:2] == (False, 98)
    assert segmented[2] == stepped[2]  # on the same step
    assert 134_000 <= segmented[2] <= 135_000
    assert warm_trip_step("") == (True, 0, -1)  # the row gone: nothing trips at 40 °C
    with pytest.raises(ProfileError, match=r"unknown cause 'warm'"):
        warm_trip_step()


def test_a_row_declared_twice_is_refused() -> None:
    with pytest.raises(ValueError, match=r"^fault cause stall: declared twice$"):
        trips.register(trips.Trip("stall", "again"))
    with pytest.raises(ValueError, match=r"^condition supply_v: declared twice$"):
        conditions.register(conditions.Condition("supply_v", "V", 0, 1))


# --- The front ends read the cause rows when asked: a row registered after they were imported reaches them.

#: A throwaway cause a bench brings about with a condition every drive has (the cabinet at 60 °C), so that it needs no
#: throwaway condition: the module past its own profile key, ``thermal.warm_trip_c`` (40 °C unless the profile says),
#: trips it. Its row carries the key: the profile's parser, schema, docs check and errors take it from there.
WARM_LEVEL = trips.Level(
    "thermal", "warm_trip_c", 40.0, 30, 80, "degC", "the module's temperature the warm cause trips at"
)


def _warm(p: Any) -> float:
    return float(p.level("thermal.warm_trip_c"))


def _warm_detect(p: Any) -> Callable[[Any, Any], bool]:
    level = _warm(p)  # armed once per drive, as the shipped rows' detectors
    return lambda m, mo: bool(mo.temp >= level)


WARM_CABINET = trips.Trip(
    "warm",
    "the module past `thermal.warm_trip_c` (a test's throwaway cause)",
    check=6.5,
    detect=_warm_detect,
    present=lambda m: bool(m.motion.temp >= _warm(m.profile)),
    foresee=lambda it, seg: seg.temp_ss > _warm(it.profile),
    trips_at=lambda it, seg, n: seg.temp(n) >= _warm(it.profile),
    bench=trips.Bench(
        "warm",
        "w",
        "warm cabinet",
        "the cabinet at 60 °C",
        lambda p, c: {"ambient_c": 60.0},
        lambda p, c: {"ambient_c": 25.0},
        rank=9,
    ),
    levels=(WARM_LEVEL, trips.Level("cabinet", "door_open", False, doc="the cabinet's door is open", source="field")),
)


@pytest.fixture
def warm_row() -> Iterator[None]:
    trips.register(WARM_CABINET)
    try:
        yield
    finally:
        trips.unregister("warm")


def _fault_body(spec: dict[str, Any], method: str = "post") -> dict[str, Any]:
    """The fault route's body (POST: its ``{"cause": ...}`` form; DELETE: ``{"reset": ..., "cause": ...}``)."""
    body: dict[str, Any] = spec["paths"]["/drives/{address}/fault"][method]["requestBody"]["content"]
    schema: dict[str, Any] = body["application/json"]["schema"]
    return schema["oneOf"][0] if method == "post" else schema


def test_a_cause_registered_after_import_reaches_the_api_scenarios_and_dashboard(warm_row: None) -> None:
    """This process imported every front end at the top: the row registered now is in each, read when asked."""
    assert list(causes.CAUSES)[-1] == "warm"
    latched = ["power_stage_u", "power_stage_v", "power_stage_w", "drive_overload", "output_phase_loss"]
    latched += ["communication", "current_detection", "eeprom"]
    every = [*BUILT_IN, "warm", *latched]
    assert causes.every_name() == tuple(every)
    # OpenAPI: the fault body's cause is an enum of the rows
    spec = document(routes.table())
    assert _fault_body(spec)["properties"]["cause"]["enum"] == every
    assert _fault_body(spec, "delete")["properties"]["cause"]["enum"] == every
    # the scenarios and their schema
    steps = parse_scenario(
        {"step": [{"at": 1, "fault": {"cause": "warm"}}, {"at": 2, "clear_fault": {"cause": "warm"}}]}, "w.toml"
    ).steps
    assert (steps[0].cause, steps[1].release) == ("warm", "warm")
    fault = build("scenario")["properties"]["step"]["items"]["properties"]["fault"]["oneOf"][0]
    assert fault["properties"]["cause"]["enum"] == every
    # the dashboard: its switch, the switch's cause brought about, the trip, and what holds the reset
    assert [(s.key, s.label) for s in DEVICE_SWITCHES][-1] == ("w", "warm cabinet")
    sim = Simulator(parse_profile(PROFILE.read_text() + WARM_FAULT, "warm.toml"), (1,), clock=VirtualClock())
    bench = Workbench(sim)
    assert [s.key for s in bench.device_switches][-1] == "w"
    assert bench.toggle_device_fault(1, "w") == "drive 1: warm: ambient_c 60"
    assert bench.device_fault_active(1, "w") is False  # the module is still cool
    sim.advance(200.0)
    assert sim.drives[1].read(Reg.FAULT_CODE) == 98
    assert bench.device_fault_active(1, "w") is True
    assert bench.holding(1) == "its cause, warm, is still present; press w (F4) to end it"


def test_a_cause_taken_away_after_import_is_gone_from_them(warm_row: None) -> None:
    assert "warm" in causes.CAUSES
    trips.unregister("warm")
    try:
        assert list(causes.CAUSES) == BUILT_IN
        assert "w" not in [s.key for s in DEVICE_SWITCHES]
        spec = document(routes.table())
        assert "warm" not in _fault_body(spec)["properties"]["cause"]["enum"]
        assert "warm" not in _fault_body(spec, "delete")["properties"]["cause"]["enum"]
        with pytest.raises(ScenarioError, match=r"unknown cause 'warm'"):
            parse_scenario({"step": [{"at": 1, "fault": {"cause": "warm"}}]}, "w.toml")
    finally:
        trips.register(WARM_CABINET)


def _warm_profile(extra: str = "", thermal: str = "") -> Profile:
    text = PROFILE.read_text().replace("[thermal]\n", f"[thermal]\n{thermal}")
    return parse_profile(text + WARM_FAULT + extra, "warm.toml")


def test_a_cause_rows_profile_keys_are_parsed_from_the_row(warm_row: None) -> None:
    assert _warm_profile().levels == {"thermal.warm_trip_c": 40.0, "cabinet.door_open": False}  # the defaults
    given = _warm_profile("\n[cabinet]\ndoor_open = true\n", "warm_trip_c = 45\n")
    assert given.levels == {"thermal.warm_trip_c": 45.0, "cabinet.door_open": True}
    assert given.level("thermal.warm_trip_c") == 45.0
    # c20sim profiles show
    shown = render_profile(given)
    assert "the fault causes' own keys\n  thermal.warm_trip_c      45.0\n  cabinet.door_open        True\n" in shown
    assert "own keys\n  thermal.warm_trip_c      40.0\n" in render_profile(load_profile())  # the row's default
    # the profile's errors name the file, the key and the row's allowed range
    errors = {
        "warm.toml: thermal.warm_trip_c: 90 is out of range; allowed 30 to 80 degC": ("", "warm_trip_c = 90\n"),
        "warm.toml: thermal.warm_trip_c: must be a number, not 'hot'": ("", 'warm_trip_c = "hot"\n'),
        "warm.toml: cabinet.door_open: must be true or false, not 1": ("\n[cabinet]\ndoor_open = 1\n", ""),
        "warm.toml: cabinet.door: unknown key (did you mean 'door_open'?); allowed: door_open": (
            "\n[cabinet]\ndoor = true\n",
            "",
        ),
    }
    for message, (extra, thermal) in errors.items():
        with pytest.raises(ProfileError) as caught:
            _warm_profile(extra, thermal)
        assert str(caught.value) == message
    with pytest.raises(ProfileError, match=r"^warm\.toml: cabinet: must be a table, not int$"):
        parse_profile("cabinet = 1\n" + PROFILE.read_text() + WARM_FAULT, "warm.toml")
    with pytest.raises(
        ProfileError, match=r"^warm\.toml: thermal\.warm_trip: unknown key \(did you mean 'warm_trip_c'"
    ):
        _warm_profile("", "warm_trip = 45\n")


def test_a_cause_rows_profile_key_sets_where_it_trips(warm_row: None) -> None:
    """The row's detector and its segment's foresight read the key: at 45 °C it trips later than at 40 °C (the
    module heading for 60 °C from 25 °C with a 240 s time constant: 240 x ln(35 / 15) = 203 s)."""
    stepped = []
    for thermal in ("", "warm_trip_c = 45\n"):
        drive = Drive(_warm_profile("", thermal))
        steps: list[int] = []
        drive.machine.on_trip = lambda code, steps=steps, drive=drive: steps.append(drive.motion.k)
        drive.set_ambient(60.0)
        drive.advance_to(250.0)
        assert drive.read(Reg.FAULT_CODE) == 98
        stepped.append(steps[0])
    assert 134_000 <= stepped[0] <= 135_000
    assert 203_000 <= stepped[1] <= 204_000


def test_a_cause_rows_profile_keys_reach_the_schema_and_the_docs_check(warm_row: None) -> None:
    schema = build("profile")
    assert schema["properties"]["thermal"]["properties"]["warm_trip_c"] == {
        "type": "number",
        "minimum": 30,
        "maximum": 80,
        "default": 40.0,
        "description": "degC; the module's temperature the warm cause trips at; source: assumed",
    }
    assert schema["properties"]["cabinet"] == {
        "type": "object",
        "properties": {
            "door_open": {
                "type": "boolean",
                "default": False,
                "description": "the cabinet's door is open; source: field",
            }
        },
        "additionalProperties": False,
    }
    # the shipped file is what its tool (python -m c20sim.scenario.schema) writes: stale until it is run again
    assert json.loads(shipped("profile")) != schema
    assert json.loads(shipped("profile"))["properties"]["thermal"]["properties"].keys() < (
        schema["properties"]["thermal"]["properties"].keys()
    )
    # docs/profile-format.md's check finds the row's keys it does not name
    assert unnamed_profile_keys() == ["cabinet", "door_open", "warm_trip_c"]


def test_a_profile_key_two_rows_declare_is_refused(warm_row: None) -> None:
    with pytest.raises(ValueError, match=r"^fault cause warmer: profile key thermal.warm_trip_c is another row's$"):
        trips.register(trips.Trip("warmer", "again", levels=(WARM_LEVEL,)))
    bad = trips.Level("thermal", "x_c", 90.0, 30, 80)
    with pytest.raises(
        ValueError, match=r"^fault cause warmer: profile key thermal.x_c: its default outside its range$"
    ):
        trips.register(trips.Trip("warmer", "again", levels=(bad,)))
    assert "warmer" not in trips.TRIPS


def test_without_the_row_its_profile_keys_are_unknown() -> None:
    with pytest.raises(ProfileError, match=r"^warm\.toml: thermal\.warm_trip_c: unknown key"):
        parse_profile(PROFILE.read_text().replace("[thermal]\n", "[thermal]\nwarm_trip_c = 45\n"), "warm.toml")
    with pytest.raises(ProfileError, match=r"^warm\.toml: cabinet: unknown key"):
        parse_profile(PROFILE.read_text() + "\n[cabinet]\ndoor_open = true\n", "warm.toml")
    assert "warm_trip_c" not in json.dumps(build("profile")) and unnamed_profile_keys() == []
    assert load_profile().levels == {}
    assert "own keys" not in render_profile(load_profile())


def test_the_openapi_fault_body_lists_the_causes() -> None:
    body = _fault_body(document(routes.table()))
    assert body["properties"]["cause"]["enum"][: len(BUILT_IN)] == BUILT_IN
    assert body["properties"]["cause"]["enum"][len(BUILT_IN) :] == [c.value for c in FaultCause if c.trip.bench is None]


# --- Every front end: in a child interpreter, the rows registered before the front ends are imported.

CHILD = r"""
import contextlib, io, json, re, sys
from pathlib import Path

from tests.unit.throwaway_rows import CONDENSATION, HUMIDITY, PROFILE, WET_FAULT, causes_block, undocumented_conditions
from c20sim.drive import conditions, trips

conditions.register(HUMIDITY)  # the two rows: nothing else is edited
trips.register(CONDENSATION)

from c20sim import cli
from c20sim.control import routes
from c20sim.control.client import ControlClient
from c20sim.control.openapi import document
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.model import Drive
from c20sim.drive.profile import FaultCause, load_profile, parse_profile
from c20sim.drive.trips import docs_table
from c20sim.scenario.schema import build
from c20sim.scenario.timeline import parse_scenario
from c20sim.serve import ServeOptions, Server
from c20sim.tui.widgets import CONDITION_FIELDS
from c20sim.tui.workbench import DEVICE_SWITCHES, Workbench
from tests.tui.conftest import _LoopThread

out = {}
profile = parse_profile(PROFILE.read_text() + WET_FAULT, "wet.toml")
out["profile code"] = profile.fault_code(FaultCause("condensation"))
schema = build("profile")
out["profile schema"] = "condensation" in schema["properties"]["fault"]["items"]["properties"]["cause"]["enum"]

# the control API over HTTP, on a served simulator
sim = Simulator(profile, (1,), clock=VirtualClock())
thread = _LoopThread()
async def start():
    server = Server(sim, ServeOptions(tcp=None, control="127.0.0.1:0"))
    await server.start()
    return server
server = thread.run(start())
try:
    api = ControlClient(server.control.url)
    out["api set"] = api.call("PATCH", "/drives/1/conditions", {"humidity_pct": 50})["conditions"]["humidity_pct"]
    out["api refuses"] = None
    try:
        api.call("PATCH", "/drives/1/conditions", {"humidity_pct": 101})
    except Exception as exc:
        out["api refuses"] = str(exc)
    out["api fault"] = api.call("POST", "/drives/1/fault", {"cause": "condensation"})["note"]
    api.call("POST", "/time/advance", {"seconds": 0.1})
    out["api fault code"] = api.call("GET", "/drives/1")["fault_code"]
    out["api causes"] = api.call("GET", "/drives/1/causes")["causes"]["condensation"]
    spec = api.call("GET", "/openapi.json")
    body = spec["paths"]["/drives/{address}/conditions"]["patch"]["requestBody"]["content"]["application/json"]
    out["openapi"] = body["schema"]["properties"]["humidity_pct"]["oneOf"][0]
    # c20sim ctl, against the same server
    for name, argv in (
        ("ctl causes", ["ctl", "--url", server.control.url, "--format", "json", "causes"]),
        ("ctl clear", ["ctl", "--url", server.control.url, "--format", "json", "clear", "--cause", "condensation"]),
        ("ctl set", ["ctl", "--url", server.control.url, "--format", "json", "set", "humidity_pct=70"]),
    ):
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            code = cli.main(argv)
        out[name] = [code, json.loads(printed.getvalue())]
    causes_now = out["ctl causes"][1]["causes"]
    out["ctl causes"] = [out["ctl causes"][0], list(causes_now), causes_now["condensation"]]
    cleared = out["ctl clear"][1]
    out["ctl clear"] = [out["ctl clear"][0], cleared["reset"], cleared["note"], cleared["fault_code"]]
    out["ctl set"] = [out["ctl set"][0], out["ctl set"][1]["conditions"]["humidity_pct"]]
finally:
    thread.run(server.aclose())
    thread.stop()
printed = io.StringIO()
with contextlib.redirect_stdout(printed), contextlib.suppress(SystemExit):
    cli.main(["ctl", "--help"])
out["ctl help"] = "humidity_pct" in " ".join(printed.getvalue().split())

# the scenarios and their schema
steps = parse_scenario(
    {"step": [{"at": 0, "set": {"humidity_pct": 99}}, {"at": 1, "fault": {"cause": "condensation"}}]}, "wet.toml"
).steps
out["scenario"] = [dict(steps[0].set), steps[1].fault.cause]
step = build("scenario")["properties"]["step"]["items"]["properties"]
out["scenario schema"] = ["humidity_pct" in step["set"]["properties"], "condensation" in json.dumps(step["fault"])]

# the dashboard: its fault switch, its marks, its conditions view
local = Simulator(profile, (1,), clock=VirtualClock())
bench = Workbench(local)
out["switch"] = [[s.key, s.label] for s in DEVICE_SWITCHES if s.key == "w"]
out["dashboard on"] = bench.toggle_device_fault(1, "w")
out["dashboard mark"] = bench.device_fault_active(1, "w")
out["dashboard conditions"] = bench.conditions(1).humidity_pct
out["dashboard field"] = list(CONDITION_FIELDS["humidity"])

# the docs checks: the new rows are what they find missing
out["docs causes"] = "condensation" in docs_table() and "condensation" not in causes_block()
out["docs conditions"] = undocumented_conditions()
print(json.dumps(out))
"""


def test_a_new_cause_and_condition_reach_every_front_end() -> None:
    done = subprocess.run(
        [sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=120, check=False, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == {
        "profile code": 99,
        "profile schema": True,
        "api set": 50.0,
        "api refuses": "humidity_pct: 101 is outside 0-100",
        "api fault": "drive 1: condensation: humidity_pct 99",
        "api fault code": 99,
        "api causes": True,
        "openapi": {"type": "number", "minimum": 0, "maximum": 100},
        # the bench's causes in their rank, the new one last, then the profile's latched faults
        "ctl causes": [0, [*causes.CAUSES, "condensation", *causes.latched(load_profile())], True],
        "ctl clear": [0, True, "drive 1: condensation gone: humidity_pct 40 (reset to clear the fault)", 0],
        "ctl set": [0, 70.0],
        "ctl help": True,
        "scenario": [{"humidity_pct": 99}, "condensation"],
        "scenario schema": [True, True],
        "switch": [["w", "condensation"]],
        "dashboard on": "drive 1: condensation: humidity_pct 99",
        "dashboard mark": True,
        "dashboard conditions": 99.0,
        "dashboard field": ["humidity", "%", 5.0, "humidity_pct"],
        "docs causes": True,
        "docs conditions": ["humidity_pct"],
    }


def test_without_the_rows_no_front_end_has_them() -> None:
    assert "condensation" not in [c.value for c in FaultCause]
    assert "condensation" not in causes.CAUSES
    assert "humidity_pct" not in ops.CONDITIONS
    assert "w" not in [s.key for s in DEVICE_SWITCHES]
    assert "humidity" not in CONDITION_FIELDS
    assert "humidity_pct" not in json.dumps(document(routes.table()))
    assert "condensation" not in json.dumps(build("profile"))
    assert "humidity_pct" not in json.dumps(build("scenario"))
    with pytest.raises(ProfileError, match=r"unknown cause 'condensation'"):
        parse_profile(PROFILE.read_text() + WET_FAULT, "wet.toml")

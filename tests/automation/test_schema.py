"""The JSON Schemas of the profile and scenario formats: shipped as built, passed by every shipped file,
and refusing what the loaders refuse."""

from __future__ import annotations

import copy
import json
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any

import jsonschema
import pytest

from c20sim.drive.profile import parse_profile
from c20sim.scenario.schema import KINDS, SCENARIO_DOCS, build, render, shipped, shipped_path, step_keys_docs
from c20sim.scenario.timeline import parse_scenario
from c20sim.wire.errors import C20SimError

ROOT = Path(__file__).resolve().parents[2]
PROFILES = sorted((ROOT / "profiles").glob("*.toml"))
SCENARIOS = sorted((ROOT / "scenarios").glob("*.toml"))


def validator(kind: str) -> jsonschema.Draft7Validator:
    schema = json.loads(shipped(kind))
    jsonschema.Draft7Validator.check_schema(schema)
    return jsonschema.Draft7Validator(schema)


@pytest.mark.parametrize("kind", KINDS)
def test_the_shipped_schema_is_the_one_the_loaders_tables_build(kind: str) -> None:
    assert shipped_path(kind).read_text(encoding="utf-8") == render(kind), (
        f"{shipped_path(kind)} is stale: run python -m c20sim.scenario.schema"
    )


def test_there_are_files_to_check() -> None:
    assert len(PROFILES) >= 2 and len(SCENARIOS) >= 4


@pytest.mark.parametrize("path", PROFILES, ids=lambda p: p.name)
def test_every_shipped_profile_passes_the_schema(path: Path) -> None:
    errors = [e.message for e in validator("profile").iter_errors(tomllib.loads(path.read_text()))]
    assert errors == []


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.name)
def test_every_shipped_scenario_passes_the_schema(path: Path) -> None:
    errors = [e.message for e in validator("scenario").iter_errors(tomllib.loads(path.read_text()))]
    assert errors == []


def profile_data() -> dict[str, Any]:
    return tomllib.loads((ROOT / "profiles" / "c20-400hr.toml").read_text())


def to_toml(data: dict[str, Any]) -> str:
    """Enough TOML for a profile: tables of scalars and arrays of tables."""

    def scalar(v: Any) -> str:
        return json.dumps(v) if not isinstance(v, bool) else ("true" if v else "false")

    def inline(v: Any) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{json.dumps(k)} = {inline(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(inline(x) for x in v) + "]"
        return scalar(v)

    lines = [f"{k} = {inline(v)}" for k, v in data.items() if not isinstance(v, dict | list) or k == "behaviours"]
    for k, v in data.items():
        if isinstance(v, dict):
            lines += [f"[{k}]", *(f"{x} = {inline(y)}" for x, y in v.items())]
        elif isinstance(v, list) and k != "behaviours":
            for item in v:
                lines += [f"[[{k}]]", *(f"{x} = {inline(y)}" for x, y in item.items())]
    return "\n".join(lines) + "\n"


def broken_profiles() -> list[tuple[str, dict[str, Any]]]:
    cases = []

    def case(name: str, change: Any) -> None:
        data = profile_data()
        change(data)
        cases.append((name, data))

    case("misspelt key", lambda d: d["motor"].update(rated_sped_rpm=3000))
    case("out of range", lambda d: d["motor"].update(rated_speed_rpm=99999))
    case("missing section", lambda d: d.pop("thermal"))
    case("fault code", lambda d: d["fault"][0].update(code=300))
    case("fault cause", lambda d: d["fault"][0].update(cause="lightning"))
    case("access", lambda d: d["parameter"][0].update(access="RW"))
    case("source", lambda d: d["parameter"][0].update(source="guess"))
    case("behaviours", lambda d: d.update(behaviours=["a", "a"]))
    case("whole number", lambda d: d["protocol"].update(max_read_registers=1.5))
    return cases


@pytest.mark.parametrize(("name", "data"), broken_profiles(), ids=[c[0] for c in broken_profiles()])
def test_the_profile_schema_refuses_what_the_loader_refuses(name: str, data: dict[str, Any]) -> None:
    assert list(validator("profile").iter_errors(data)), f"the schema takes a profile with a bad {name}"
    with pytest.raises(C20SimError):
        parse_profile(to_toml(data), "broken.toml")


def test_the_round_trip_of_a_good_profile_loads() -> None:
    assert parse_profile(to_toml(profile_data()), "good.toml").name == "c20-400hr"


SCENARIO: dict[str, Any] = {
    "name": "s",
    "step": [{"at": 0.0, "write": {"2001H": 1500}, "set": {"supply_v": {"ramp": 30, "over": 5}}}],
}


@pytest.mark.parametrize(
    ("name", "step"),
    [
        ("unknown key", {"at": 0, "sett": {}}),
        ("no time", {"note": "x"}),
        ("negative time", {"at": -1}),
        ("condition range", {"at": 0, "set": {"supply_v": 5000}}),
        ("unknown condition", {"at": 0, "set": {"suply_v": 5}}),
        ("ramp without over", {"at": 0, "set": {"supply_v": {"ramp": 30}}}),
        ("generator on a non-continuous condition", {"at": 0, "set": {"terminal_inputs": {"ramp": 3, "over": 1}}}),
        ("raw value", {"at": 0, "write": {"2001H": 70000}}),
        ("tolerance", {"at": 0, "expect": {"status1": {"value": 1, "tolerance": -1}}}),
        ("keypad", {"at": 0, "keypad": "fwd"}),
        ("cause", {"at": 0, "fault": {"cause": "lightning"}}),
        ("link fault", {"at": 0, "link": {"ofline": True}}),
    ],
)
def test_the_scenario_schema_refuses_what_the_loader_refuses(name: str, step: dict[str, Any]) -> None:
    data = copy.deepcopy(SCENARIO)
    data["step"].append(step)
    assert list(validator("scenario").iter_errors(data)), f"the schema takes a scenario with a bad {name}"
    with pytest.raises(C20SimError):
        parse_scenario(data, "broken.toml")


def test_a_good_scenario_passes_both() -> None:
    assert list(validator("scenario").iter_errors(SCENARIO)) == []
    assert parse_scenario(SCENARIO).steps[0].set == {"supply_v": {"ramp": 30, "over": 5}}


@pytest.mark.parametrize("kind", KINDS)
def test_c20sim_schema_prints_the_shipped_file(kind: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "schema", kind], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert (done.returncode, done.stderr) == (0, "")
    assert json.loads(done.stdout) == build(kind)


def test_an_unknown_schema_is_a_usage_error() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", "schema", "drive"], capture_output=True, text=True, timeout=60, cwd=ROOT
    )
    assert done.returncode == 2 and done.stderr.startswith("c20sim schema: argument kind: invalid choice: 'drive'")


# --- The reference pages name everything the formats and the API have.

DOCS = ROOT / "docs"


def test_the_profile_page_names_every_key() -> None:
    text = (DOCS / "profile-format.md").read_text()
    schema = build("profile")
    keys = set(schema["properties"])
    for prop in schema["properties"].values():
        keys |= set(prop.get("properties", {})) | set(prop.get("items", {}).get("properties", {}))
    missing = sorted(k for k in keys if f"`{k}`" not in text and f"[{k}]" not in text)
    assert missing == []


def test_the_scenario_page_names_every_key_condition_and_link_fault() -> None:
    text = (DOCS / "scenario-format.md").read_text()
    schema = build("scenario")
    step = schema["properties"]["step"]["items"]["properties"]
    keys = set(schema["properties"]) | set(step) | set(step["set"]["properties"]) | set(step["link"]["properties"])
    missing = sorted(k for k in keys if f"`{k}`" not in text and f"[[{k}]]" not in text)
    assert missing == []


def test_the_step_keys_table_is_the_step_kinds_rows() -> None:
    text = SCENARIO_DOCS.read_text(encoding="utf-8")
    assert step_keys_docs(text) == text, f"{SCENARIO_DOCS}'s step keys are stale: run python -m c20sim.scenario.schema"


def test_the_api_page_names_every_route() -> None:
    from c20sim.control.http import ROUTES

    text = (DOCS / "api.md").read_text()
    missing = sorted(key for key in ROUTES if key.split(" ", 1)[1] + "`" not in text)
    assert missing == []

"""JSON Schemas of the profile and scenario formats, for TOML editors and other tools.

Built from the tables the loaders check against (the profile's dataclass
fields and their ranges, the fault causes and the profile keys their rows
declare, the conditions, link faults and keys of :mod:`c20sim.control.ops`),
each read when a schema is built, and shipped in the package as
``c20sim/schemas/profile.schema.json`` and ``scenario.schema.json``; a test
checks that the shipped files are what this module builds, and that every
shipped profile and scenario passes them. ``c20sim schema profile|scenario``
prints one.

A schema says what shape a file has; the loader checks more (a mirror's range
against the sheet's, undervoltage below the supply, times that run forwards).
Draft-07, which the TOML editors' language servers (Taplo, Even Better TOML) read;
point one at a file with a ``#:schema PATH`` comment on its first line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

from ..drive.profile import (
    _FAULT_KEYS,
    _PARAM_KEYS,
    _SOURCES,
    _TOP_KEYS,
    REQUIRED_MIRRORS,
    ControlParams,
    FaultCause,
    MotorParams,
    ProtectionParams,
    ProtocolParams,
    SupplyParams,
    ThermalParams,
)
from ..drive.profilecheck import own_sections, section_levels
from ..drive.trips import Level
from ..wire.errors import C20SimError
from ..wire.registers import Access

__all__ = ["KINDS", "add_schema_command", "build", "shipped", "shipped_path", "step_keys_docs"]

DRAFT = "http://json-schema.org/draft-07/schema#"
KINDS = ("profile", "scenario")
SCHEMA_DIR = Path(__file__).resolve().parent.parent / "schemas"


def _level(level: Level) -> dict[str, Any]:
    """A cause row's profile key (:class:`~c20sim.drive.trips.Level`): its type, range, default and source."""
    kind = {bool: "boolean", int: "integer", float: "number"}[level.kind]
    prop: dict[str, Any] = {"type": kind}
    if level.kind is not bool:
        prop["minimum"], prop["maximum"] = level.low, level.high
    text = "; ".join(t for t in (level.unit, level.doc, f"source: {level.source}") if t)
    return {**prop, "description": text, "default": level.default}


def _own_section(name: str) -> dict[str, Any]:
    """A table only cause rows declare: their keys, each optional."""
    props = {lv.name: _level(lv) for lv in section_levels(name)}
    return {"type": "object", "properties": props, "additionalProperties": False}


def _section(cls: type, name: str) -> dict[str, Any]:
    props: dict[str, Any] = {}
    required = []
    for f in dataclasses.fields(cls):
        kind = {"bool": "boolean", "int": "integer", "float": "number"}.get(str(f.type), "string")
        prop: dict[str, Any] = {"type": kind}
        if str(f.type).startswith("tuple[tuple[float, float]"):  # an inverse-time curve: [[multiple, seconds], ...]
            pair = {"type": "array", "items": {"type": "number", "exclusiveMinimum": 0}, "minItems": 2, "maxItems": 2}
            prop = {"type": "array", "items": pair, "minItems": 2}
        meta = f.metadata
        if "min" in meta:
            prop["minimum"], prop["maximum"] = meta["min"], meta["max"]
        text = "; ".join(t for t in (meta.get("unit", ""), meta.get("doc", "")) if t)
        if text:
            prop["description"] = text
        if f.default is not dataclasses.MISSING:
            prop["default"] = f.default
        else:
            required.append(f.name)
        props[f.name] = prop
    props.update((lv.name, _level(lv)) for lv in section_levels(name))  # the cause rows' keys of this section
    schema: dict[str, Any] = {"type": "object", "properties": props, "additionalProperties": False}
    if cls.__doc__:
        schema["description"] = cls.__doc__.strip().splitlines()[0]
    if required:
        schema["required"] = required
    return schema


SOURCE = {"enum": list(_SOURCES), "default": "assumed", "description": "sheet, notes, field or assumed"}


def profile_schema() -> dict[str, Any]:
    fault: dict[str, Any] = {
        "type": "object",
        "properties": {
            "code": {"type": "integer", "minimum": 1, "maximum": 255, "description": "the code 2102H reads"},
            "name": {"type": "string", "minLength": 1, "description": "the short name the panel shows"},
            "meaning": {"type": "string"},
            "cause": {"enum": [c.value for c in FaultCause], "description": "what the model trips it on"},
            "source": SOURCE,
        },
        "required": ["code", "name"],
        "additionalProperties": False,
    }
    word = {"type": "integer", "minimum": -32768, "maximum": 65535}
    parameter: dict[str, Any] = {
        "type": "object",
        "properties": {
            "code": {"type": "string", "pattern": "^[Ff][0-9]{1,2}\\.[0-9]{1,3}$", "description": "such as F00.10"},
            "name": {"type": "string", "minLength": 1},
            "default": word,
            "min": word,
            "max": word,
            "unit": {"type": "string"},
            "scale": {"type": "number", "minimum": 1e-6, "maximum": 1e6, "default": 1},
            "access": {"enum": [a.value for a in Access], "default": "W/R"},
            "mirror": {
                "type": "string",
                "description": "the 20xxH register that mirrors it: "
                + ", ".join(f"{r:04X}H" for r in REQUIRED_MIRRORS),
            },
            "signed": {"type": "boolean", "default": False},
            "values": {
                "type": "object",
                "patternProperties": {"^[0-9]+$": {"type": "string"}},
                "additionalProperties": False,
                "description": 'what each value means, as "number" = "meaning"',
            },
            "source": SOURCE,
        },
        "required": ["code", "name", "default"],
        "additionalProperties": False,
    }
    assert set(fault["properties"]) == set(_FAULT_KEYS) and set(parameter["properties"]) == set(_PARAM_KEYS)
    props: dict[str, Any] = {
        "name": {"type": "string", "minLength": 1, "description": "the profile's name, such as c20-400hr"},
        "description": {"type": "string"},
        "software_version": {"type": "number", "minimum": 1, "maximum": 99, "description": "300AH, such as 1.00"},
        "protocol": _section(ProtocolParams, "protocol"),
        "motor": _section(MotorParams, "motor"),
        "supply": _section(SupplyParams, "supply"),
        "protection": _section(ProtectionParams, "protection"),
        "thermal": _section(ThermalParams, "thermal"),
        "control": _section(ControlParams, "control"),
        "fault": {"type": "array", "items": fault, "minItems": 1},
        "parameter": {"type": "array", "items": parameter, "minItems": 1},
        "behaviours": {
            "type": "array",
            "items": {"type": "string", "minLength": 1},
            "uniqueItems": True,
            "description": "named behaviours (entry-point group c20sim.behaviours) hooking registers or the step",
        },
    }
    assert set(props) == set(_TOP_KEYS)
    props.update((name, _own_section(name)) for name in own_sections())
    return {
        "$schema": DRAFT,
        "title": "c20sim drive profile",
        "description": "One C20 variant: protocol quirks, motor and drive physics, faults, function codes. "
        "See docs/profile-format.md.",
        "type": "object",
        "properties": props,
        "required": ["name", "motor", "supply", "protection", "thermal", "fault", "parameter"],
        "additionalProperties": False,
    }


def scenario_schema() -> dict[str, Any]:
    """The scenario format: its top-level keys, and a step as the step kinds' rows make it (:mod:`.stepkinds`)."""
    from .stepkinds import table
    from .timeline import TOP_KEYS

    step = table().schema()
    props: dict[str, Any] = {
        "name": {"type": "string"},
        "description": {"type": "string"},
        "profile": {"type": "string", "description": "profile name or path"},
        "drives": {
            "type": "array",
            "items": {"type": "integer", "minimum": 1, "maximum": 247},
            "minItems": 1,
        },
        "step": {"type": "array", "items": step, "minItems": 1},
    }
    assert set(props) == set(TOP_KEYS)
    return {
        "$schema": DRAFT,
        "title": "c20sim scenario",
        "description": "A timeline of conditions, faults, writes and expectations in virtual time. "
        "See docs/scenario-format.md.",
        "type": "object",
        "properties": props,
        "required": ["step"],
        "additionalProperties": False,
    }


def build(kind: str) -> dict[str, Any]:
    """The schema of ``kind`` (profile or scenario), built from the loaders' tables."""
    if kind == "profile":
        return profile_schema()
    if kind == "scenario":
        return scenario_schema()
    raise C20SimError(f"unknown schema {kind!r}; use {' or '.join(KINDS)}")


def render(kind: str) -> str:
    """The schema as the shipped file holds it."""
    return json.dumps(build(kind), indent=2, ensure_ascii=False) + "\n"


def shipped_path(kind: str) -> Path:
    return SCHEMA_DIR / f"{kind}.schema.json"


def shipped(kind: str) -> str:
    """The shipped schema file's text."""
    build(kind)  # the name check
    return shipped_path(kind).read_text(encoding="utf-8")


def cmd_schema(args: argparse.Namespace) -> int:
    print(shipped(args.kind), end="")
    return 0


def add_schema_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "schema",
        help="print the JSON Schema of the profile or scenario format (for TOML editors)",
        description="Print the JSON Schema (draft-07) of a file format; save it and point a TOML editor at it "
        "with a '#:schema PATH' first line.",
    )
    parser.add_argument("kind", choices=KINDS)
    parser.set_defaults(func=cmd_schema)


#: The markers around docs/scenario-format.md's step keys table, which the step kinds' rows write.
STEP_KEYS_BEGIN = "<!-- step keys: written from the step kinds' rows by python -m c20sim.scenario.schema -->\n"
STEP_KEYS_END = "<!-- end of step keys -->\n"
SCENARIO_DOCS = Path(__file__).resolve().parents[2] / "docs" / "scenario-format.md"


def step_keys_docs(text: str) -> str:
    """``text`` (docs/scenario-format.md) with its step keys table as the step kinds' rows make it now."""
    from .stepkinds import table

    head, begin, rest = text.partition(STEP_KEYS_BEGIN)
    _, end, tail = rest.partition(STEP_KEYS_END)
    if not begin or not end:
        raise C20SimError(f"the scenario docs have no step keys table between {STEP_KEYS_BEGIN.strip()} and its end")
    return head + begin + table().docs_table() + end + tail


if __name__ == "__main__":  # python -m c20sim.scenario.schema: write the shipped files, and the docs' step keys
    SCHEMA_DIR.mkdir(exist_ok=True)
    for each in KINDS:
        shipped_path(each).write_text(render(each), encoding="utf-8")
    if SCENARIO_DOCS.exists():  # in a checkout
        SCENARIO_DOCS.write_text(step_keys_docs(SCENARIO_DOCS.read_text(encoding="utf-8")), encoding="utf-8")

"""The step kinds a scenario's ``[[step]]`` table may hold, one row each: what happens at the step's time.

The rows of the step's actions (its time, drive, conditions, faults, writes, keypad, drill) are here; the
checks (``expect`` and the rest) are in :mod:`c20sim.scenario.stepchecks`. :data:`TABLE` holds them all in the
order a step is read and played; a new step kind is one :class:`~c20sim.scenario.steps.StepKind` added to it.
"""

from __future__ import annotations

import asyncio
import functools
import math
from typing import TYPE_CHECKING, Any

from ..control import causes, drills, ops
from ..control.schemas import conditions_schema, link_schema
from ..drill import INCIDENTS, read_plan
from ..wire.errors import C20SimError
from .stepchecks import CHECKS
from .steps import Kinds, Outcome, Reading, Step, StepKind, missing_register

if TYPE_CHECKING:
    from ..core.simulator import Simulator

__all__ = ["TABLE", "parse_step", "table"]


def _cause(value: object, key: str, reading: Reading) -> str:
    """A cause a scenario may name: every one of the rows as they are now (whether the profile has a latched one
    is checked against the simulator)."""
    names = causes.every_name()
    if not isinstance(value, str) or value not in names:
        message = str(ops.unknown("cause", value, names)) if isinstance(value, str) else "expected a cause's name"
        raise reading.fail(key, message)
    return value


# --- The parsers: each key's value, checked once at load.


def _at(value: object, reading: Reading) -> dict[str, object]:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
        raise reading.fail("at", "give the step's time in seconds from the start, >= 0")
    return {"at": float(value)}


def _drive(value: object, reading: Reading) -> dict[str, object]:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= 247:
        raise reading.fail("drive", "expected a drive address 1-247")
    return {"drive": value}


def _note(value: object, reading: Reading) -> dict[str, object]:
    if not isinstance(value, str):
        raise reading.fail("note", "expected a string")
    return {"note": value}


def _conditions(value: object, reading: Reading) -> dict[str, object]:
    conditions = reading.table("set", value)
    if conditions:
        reading.checked("set", lambda: ops.check_conditions(conditions))
    return {"set": conditions}


def _link(value: object, reading: Reading) -> dict[str, object]:
    link = reading.table("link", value)
    if link:
        reading.checked("link", lambda: ops.check_link_faults(link))
    return {"link": link}


def _flag(key: str) -> Any:
    return lambda value, reading: {key: reading.flag(key, value)}


def _fault(value: object, reading: Reading) -> dict[str, object]:
    read = functools.partial(causes.read_fault, value, causes.TOML, names=list(causes.every_name()))
    return {"fault": reading.checked("fault", read)}


def _clear_fault(value: object, reading: Reading) -> dict[str, object]:
    if isinstance(value, dict):
        if set(value) != {"cause"}:
            raise reading.fail("clear_fault", 'give true, or a cause to end, such as { cause = "undervoltage" }')
        return {"clear_fault": True, "release": _cause(value["cause"], "clear_fault", reading)}
    if not isinstance(value, bool):
        raise reading.fail("clear_fault", 'expected true or false, or { cause = "undervoltage" }')
    return {"clear_fault": value}


def _write(value: object, reading: Reading) -> dict[str, object]:
    writes: list[tuple[str, int, int]] = []
    for register, raw in reading.table("write", value).items():
        reading.unquoted("write", register, raw)
        address = reading.checked("write", functools.partial(ops.register_address, register))
        if isinstance(raw, bool) or not isinstance(raw, int) or not 0 <= raw <= 0xFFFF:
            raise reading.fail("write", f"{register}: expected a raw value 0-65535, got {raw!r}")
        writes.append((register, address, raw))
    return {"write": tuple(writes)}


def _keypad(value: object, reading: Reading) -> dict[str, object]:
    reading.checked("keypad", lambda: ops.key_command(value))
    return {"keypad": value}


def _drill(value: object, reading: Reading) -> dict[str, object]:
    items = [value] if isinstance(value, str | dict) else value
    if not isinstance(items, list) or not items:
        raise reading.fail("drill", 'expected an incident or a list of them, such as ["crc", { incident = "trip" }]')
    drill = tuple({"incident": x} if isinstance(x, str) else dict(x) for x in items)
    try:
        read_plan({"drill": list(drill)}, "drill")
    except C20SimError as exc:
        raise reading.fail("drill", str(exc).removeprefix("drill: ")) from None
    return {"drill": drill}


# --- The acts: what each key does when its step is played.


def _set_conditions(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.set:
        ops.set_conditions(sim, address, step.set)
    return []


def _set_link(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.link:
        ops.set_link_faults(sim, address, step.link)
    return []


def _clear_link(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.clear_link:
        ops.clear_link_faults(sim, address)
    return []


def _bring_fault(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.fault is not None:
        causes.fault(sim, address, step.fault)
    return []


def _end_fault(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.release is not None:
        causes.release(sim, address, step.release)
    if step.clear_fault:
        ops.clear_fault(sim, address, True)
    return []


def _power_cycle(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.power_cycle:
        ops.power_cycle(sim, address)
    return []


def _press(step: Step, sim: Simulator, address: int, t: float) -> list[Outcome]:
    if step.keypad is None:
        return []
    taken = ops.press_key(sim, address, step.keypad)
    return [Outcome(step, t, taken, f"keypad {step.keypad}: {'taken' if taken else 'refused by the drive'}")]


async def _play_drill(step: Step, sim: Simulator) -> Outcome:
    """Play the step's drill on the master polling the served drive; the outcome is its verdicts."""
    t = sim.now()
    service = drills.of(sim)
    service.start({"plan": [dict(item) for item in step.drill]})
    while (state := service.status())["state"] == "running":
        await asyncio.sleep(0.2)
    if state["state"] == "failed":
        return Outcome(step, t, False, f"drill: {state['error']}")
    report = state["report"]
    verdicts = report["verdicts"]
    failed = [v for v in verdicts if not v["passed"]]
    text = f"drill: {len(verdicts) - len(failed)} of {len(verdicts)} drills passed"
    if failed:
        first = failed[0]
        figures = "; ".join(c["figure"] for c in first["checks"] if not c["passed"])
        text += f"; {first['index']} {first['incident']}: {figures}"
    if report.get("problem"):
        text += f"; {report['problem']}"
    return Outcome(step, t, bool(report["passed"]) and not report.get("ended_early"), text)


# --- The checks against the simulator, before anything plays.


def _drive_here(step: Step, sim: Simulator) -> str | None:
    if step.drive is not None and step.drive not in sim.drives:
        return f"no drive at address {step.drive}; drives: {', '.join(map(str, sim.drives))}"
    return None


def _cause_here(name: str | None, sim: Simulator) -> str | None:
    if name is not None and name not in causes.cause_names(sim.profile):
        return f"the profile {sim.profile.name} has no cause {name!r}"
    return None


# --- The schema fragments that are more than a line.


def _fault_schema() -> dict[str, Any]:
    cause = {"type": "object", "properties": {"cause": {"enum": list(causes.every_name())}}, "required": ["cause"]}
    code = {
        "type": "object",
        "properties": {"code": {"type": "integer", "minimum": 1, "maximum": 255}, "persistent": {"type": "boolean"}},
        "required": ["code"],
        "additionalProperties": False,
    }
    return {
        "oneOf": [{**cause, "additionalProperties": False}, code, {"type": "integer", "minimum": 1, "maximum": 255}],
        "description": "a fault's cause brought about, or a fault code latched",
    }


def _clear_fault_schema() -> dict[str, Any]:
    cause = {"type": "object", "properties": {"cause": {"enum": list(causes.every_name())}}, "required": ["cause"]}
    return {"oneOf": [{"type": "boolean"}, {**cause, "additionalProperties": False}]}


def _drill_schema() -> dict[str, Any]:
    incident = {"type": "object", "required": ["incident"], "properties": {"incident": {"enum": list(INCIDENTS)}}}
    one = [{"enum": list(INCIDENTS)}, incident]
    return {
        "description": "a drill on the master polling the served drive (docs/drill.md): an incident, or a "
        'list of incidents by name or as tables ({ incident = "trip", hold = 1.0 })',
        "oneOf": [*one, {"type": "array", "minItems": 1, "items": {"oneOf": one}}],
    }


def _boolean() -> dict[str, Any]:
    return {"type": "boolean"}


ACTIONS = (
    StepKind(
        "at",
        _at,
        lambda: {"type": "number", "minimum": 0, "description": "seconds from the start; steps in time order"},
        "number >= 0, required",
        "seconds from the start; steps are in time order",
        required=True,
    ),
    StepKind(
        "drive",
        _drive,
        lambda: {"type": "integer", "minimum": 1, "maximum": 247, "description": "default: the first drive"},
        "address 1-247",
        "the drive the step acts on (default: the first)",
        against=_drive_here,
    ),
    StepKind("note", _note, lambda: {"type": "string"}, "string", "shown in the report"),
    StepKind(
        "set",
        _conditions,
        lambda: {**conditions_schema(), "description": "conditions: a value, or a generator for a continuous one"},
        "table",
        "conditions: a value, or a generator (below)",
        _set_conditions,
    ),
    StepKind(
        "link",
        _link,
        lambda: {**link_schema(), "description": "link faults of the step's drive"},
        "table",
        "link faults of the step's drive, as the control API names them",
        _set_link,
    ),
    StepKind(
        "clear_link",
        _flag("clear_link"),
        _boolean,
        "boolean",
        "clear every link fault of the step's drive",
        _clear_link,
    ),
    StepKind(
        "fault",
        _fault,
        _fault_schema,
        "`{ cause = NAME }`, `{ code = N, persistent = BOOL }` or `N`",
        "bring a fault's cause about, or latch a fault code",
        _bring_fault,
        against=lambda step, sim: _cause_here(step.cause, sim),
    ),
    StepKind(
        "clear_fault",
        _clear_fault,
        _clear_fault_schema,
        "`true` or `{ cause = NAME }`",
        "end the cause (if given) and press fault reset",
        _end_fault,
        against=lambda step, sim: _cause_here(step.release, sim),
    ),
    StepKind("power_cycle", _flag("power_cycle"), _boolean, "boolean", "switch the drive off and on", _power_cycle),
    StepKind(
        "write",
        _write,
        lambda: {
            "type": "object",
            "additionalProperties": {"type": "integer", "minimum": 0, "maximum": 65535},
            "description": "registers a master writes (setpoint, 2001H, 0x2001, 8193, F00.10, status1 ...) = raw value",
        },
        "table `REGISTER = raw`",
        "a master's single-register writes (0x06), in order",  # played by the player, as a master's frames
        against=lambda step, sim: missing_register((w[:2] for w in step.write), sim),
    ),
    StepKind(
        "keypad",
        _keypad,
        lambda: {"oneOf": [{"enum": list(ops.KEYS)}, {"type": "integer", "minimum": 1, "maximum": 8}]},
        "key name or 1-8",
        "press a key on the drive's panel",
        _press,
        after_writes=True,
    ),
)

DRILL = StepKind(
    "drill",
    _drill,
    _drill_schema,
    'an incident, or a list of incidents by name or as tables (`{ incident = "trip", hold = 1.0 }`)',
    "a drill ([drill.md](drill.md)) on the master polling the served drive; only under `serve --scenario` with the "
    "realtime clock (`run-scenario` refuses it); the step passes when every drill passes",
    served=_play_drill,
    served_only="a drill plays on a real master: serve --scenario FILE with the realtime clock, and a master "
    "polling the serve (docs/drill.md)",
)

#: Every step kind, in the order a step is read and played.
TABLE = Kinds((*ACTIONS, *CHECKS, DRILL))


def table() -> Kinds:
    """The step kinds (a test may add one, and the loader, player, schema and docs check see it)."""
    return TABLE


def parse_step(raw: object, index: int, path: str) -> Step:
    """One ``[[step]]`` table, read by the rows of :data:`TABLE`."""
    return TABLE.parse(raw, index, path)

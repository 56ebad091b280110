"""A drill plan: the warm-up, then the incidents in order, checked once; the built-in standard plan.

Pure: :func:`read_plan` takes the TOML document already parsed (a mapping) and the name to give in errors;
the front end reads the file. Every error names the place (``plan.toml: drill 3: replies``), the value and
what is allowed, as :class:`~c20sim.wire.errors.C20SimError`.

The TOML form::

    seed = 1                 # the faults' randomness (noise)
    warmup = 3.0             # seconds of the master's own rhythm before the first incident
    poll_period = 0.1        # optional: given, not learned
    timeout = 0.25           # optional: given, not learned (a timeout probe is then not played)
    settle = 0.5             # seconds between one drill's watch and the next incident

    [[drill]]
    incident = "crc"
    replies = 3

    [[drill]]
    incident = "trip"
    cause = "external"
    hold = 2.0
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass

from ..wire.errors import C20SimError
from .incidents import INCIDENTS, TRIP_CAUSES, Incident

__all__ = ["MAX_DRILLS", "STANDARD", "Drill", "Plan", "read_plan", "standard_plan"]

#: The most drills a plan may hold.
MAX_DRILLS = 200
_TOP = ("seed", "warmup", "poll_period", "timeout", "settle", "drill")


@dataclass(frozen=True, slots=True)
class Drill:
    """One incident of a plan, with its parameters checked and completed with the defaults."""

    index: int  #: from 1, in the plan's order
    incident: Incident
    values: Mapping[str, object]

    @property
    def name(self) -> str:
        return self.incident.name

    @property
    def label(self) -> str:
        """``3 crc`` : its place and name, as reports show it."""
        return f"{self.index} {self.name}"

    def as_dict(self) -> dict[str, object]:
        return {"index": self.index, "incident": self.name, **dict(self.values)}


@dataclass(frozen=True, slots=True)
class Plan:
    name: str
    seed: int
    warmup: float
    settle: float
    drills: tuple[Drill, ...]
    poll_period: float | None = None
    timeout: float | None = None


def _suggest(word: str, known: list[str]) -> str:
    close = difflib.get_close_matches(word, known, n=1)
    return f"did you mean {close[0]!r}? " if close else ""


def _number(where: str, key: str, value: object, low: float, high: float, *, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise C20SimError(f"{where}: {key}: expected a number from {low:g} to {high:g}, got {value!r}")
    if integer and value != int(value):
        raise C20SimError(f"{where}: {key}: expected a whole number from {low:g} to {high:g}, got {value!r}")
    if not low <= value <= high:
        raise C20SimError(f"{where}: {key}: {value!r} is outside {low:g}-{high:g}")
    return int(value) if integer else float(value)


def _drill(name: str, index: int, item: object) -> Drill:
    where = f"{name}: drill {index}"
    if not isinstance(item, Mapping):
        raise C20SimError(f'{where}: expected a table such as {{ incident = "crc" }}, got {item!r}')
    incident_name = item.get("incident")
    known = list(INCIDENTS)
    if not isinstance(incident_name, str):
        raise C20SimError(f"{where}: incident: give one of {', '.join(known)}")
    incident = INCIDENTS.get(incident_name)
    if incident is None:
        raise C20SimError(
            f"{where}: incident {incident_name!r} is unknown; {_suggest(incident_name, known)}"
            f"the incidents are {', '.join(known)}"
        )
    values: dict[str, object] = {}
    allowed = ["incident", *incident.params, *(["cause"] if incident.name == "trip" else [])]
    for key, value in item.items():
        if key == "incident":
            continue
        if key == "cause" and incident.name == "trip":
            if value not in TRIP_CAUSES:
                raise C20SimError(f"{where}: cause {value!r}: give one of {', '.join(TRIP_CAUSES)}")
            values["cause"] = value
            continue
        param = incident.params.get(key)
        if param is None:
            raise C20SimError(
                f"{where}: {key!r} is not a parameter of {incident.name}; {_suggest(key, allowed)}"
                f"it takes {', '.join(allowed[1:]) or 'none'}"
            )
        values[key] = _number(where, key, value, param.low, param.high, integer=param.integer)
    for key, param in incident.params.items():
        values.setdefault(key, int(param.default) if param.integer else param.default)
    if incident.name == "trip":
        values.setdefault("cause", "external")
    return Drill(index, incident, values)


def read_plan(doc: Mapping[str, object], name: str) -> Plan:
    """The plan in ``doc`` (a parsed TOML document); C20SimError naming ``name``, the key and the range."""
    for key in doc:
        if key not in _TOP:
            raise C20SimError(
                f"{name}: {key!r} is not a plan key; {_suggest(key, list(_TOP))}the keys are {', '.join(_TOP)}"
            )
    items = doc.get("drill", [])
    if not isinstance(items, list) or not items:
        raise C20SimError(f'{name}: no drill; give at least one [[drill]] with incident = "..."')
    if len(items) > MAX_DRILLS:
        raise C20SimError(f"{name}: {len(items)} drills; at most {MAX_DRILLS}")
    seed = int(_number(name, "seed", doc.get("seed", 1), 0, 2**32 - 1, integer=True))
    warmup = _number(name, "warmup", doc.get("warmup", 3.0), 0.5, 600.0)
    settle = _number(name, "settle", doc.get("settle", 0.5), 0.0, 60.0)
    period = doc.get("poll_period")
    timeout = doc.get("timeout")
    return Plan(
        name,
        seed,
        warmup,
        settle,
        tuple(_drill(name, i, item) for i, item in enumerate(items, 1)),
        None if period is None else _number(name, "poll_period", period, 0.001, 60.0),
        None if timeout is None else _number(name, "timeout", timeout, 0.001, 60.0),
    )


#: The built-in standard plan but its drills: every incident of :data:`INCIDENTS` once, with its defaults, as the
#: table holds them when the plan is made (about 100 s against a master polling every 100 ms with a
#: 250 ms timeout).
STANDARD: Mapping[str, object] = {
    "seed": 1,
    "warmup": 3.0,
    "settle": 0.5,
}


def standard_plan(seed: int = 1, transport: str | None = None) -> Plan:
    """The standard plan; for ``transport``, only the incidents it can carry."""
    drills = [{"incident": name} for name in INCIDENTS]
    plan = read_plan({**STANDARD, "seed": seed, "drill": drills}, "the standard plan")
    if transport is None:
        return plan
    kept = [d for d in plan.drills if transport in d.incident.transports]
    return Plan(
        plan.name,
        plan.seed,
        plan.warmup,
        plan.settle,
        tuple(Drill(i, d.incident, d.values) for i, d in enumerate(kept, 1)),
    )

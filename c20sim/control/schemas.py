"""JSON Schemas of the values the control surface takes, built from the tables the operations check them by.

The conditions (:data:`~c20sim.control.ops.CONDITIONS`, with their generators), the fault causes (the rows of
:data:`c20sim.drive.trips.TRIPS`, through :func:`~c20sim.control.causes.every_name`) and the link faults
(:data:`~c20sim.core.linkfaults.KNOBS`): a condition, cause or link fault added there is described here too, for
the OpenAPI document, the route table and the scenario format's schema alike. Each is built when asked, from the
rows as they are then.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

from ..core.generators import MAX_SECONDS, MIN_PERIOD
from ..core.linkfaults import KNOBS
from . import causes, ops

__all__ = ["Live", "cause_schema", "conditions_schema", "generator_schema", "link_schema"]


def generator_schema(low: float, high: float) -> dict[str, Any]:
    """A generator for a condition of range ``low``-``high`` (c20sim.core.generators)."""
    value = {"type": "number", "minimum": low, "maximum": high}
    seconds = {"type": "number", "minimum": 0, "maximum": MAX_SECONDS}
    period = {"type": "number", "minimum": MIN_PERIOD, "maximum": MAX_SECONDS}
    spread = {"type": "number", "minimum": 0, "maximum": high - low}
    return {
        "oneOf": [
            {
                "title": "ramp",
                "description": "from the value now to `ramp` over `over` seconds, then held",
                "type": "object",
                "properties": {"ramp": value, "over": seconds},
                "required": ["ramp", "over"],
                "additionalProperties": False,
            },
            {
                "title": "sine",
                "description": "center (default: the value now) + sine * sin(2 pi t / period)",
                "type": "object",
                "properties": {"sine": spread, "period": period, "center": value},
                "required": ["sine", "period"],
                "additionalProperties": False,
            },
            {
                "title": "noise",
                "description": "center + noise * N(0, 1), a new sample every `every` s (default 0.1), seeded",
                "type": "object",
                "properties": {"noise": spread, "seed": {"type": "integer"}, "every": period, "center": value},
                "required": ["noise"],
                "additionalProperties": False,
            },
        ]
    }


def conditions_schema() -> dict[str, Any]:
    props: dict[str, Any] = {}
    for name, c in ops.CONDITIONS.items():
        if c.continuous and c.low is not None and c.high is not None:
            plain = {"type": "number", "minimum": c.low, "maximum": c.high}
            props[name] = {"description": c.unit, "oneOf": [plain, generator_schema(c.low, c.high)]}
        elif c.choices is not None:
            props[name] = {"enum": [None, *c.choices], "description": c.help}
        else:
            props[name] = {"type": "integer", "minimum": c.low, "maximum": c.high, "description": c.help}
    return {"type": "object", "properties": props, "additionalProperties": False, "minProperties": 1}


class Live(Mapping[str, Any]):
    """A schema built when read (``Live(cause_schema)``): for a route field, which is made at import, to describe
    the rows as they are when the document is asked for."""

    def __init__(self, build: Callable[[], Mapping[str, Any]]) -> None:
        self._build = build

    def __getitem__(self, key: str) -> Any:
        return self._build()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._build())

    def __len__(self) -> int:
        return len(self._build())


def cause_schema() -> dict[str, Any]:
    """A fault's cause by name: every cause of the rows now (the physical ones, then those only latched; a drive
    takes those its profile has)."""
    return {
        "enum": list(causes.every_name()),
        "description": "a fault's cause: a physical one, or a fault the profile has with no physical cause",
    }


_KIND_SCHEMAS: Mapping[str, Any] = {
    "flag": {"type": "boolean"},
    "count": {"type": "integer", "minimum": 0, "maximum": 1_000_000},
    "percent": {"type": "number", "minimum": 0, "maximum": 100},
    "seconds": {"type": "number", "minimum": 0, "maximum": 60},
    "bytes": {"type": "string", "description": 'hex bytes, such as "FF 00"'},
    "address": {"type": ["integer", "null"], "minimum": 0, "maximum": 255},
    "exception": {
        "description": "an exception code 1-8, its name, or null",
        "type": ["integer", "string", "null"],
    },
}


def link_schema() -> dict[str, Any]:
    props = {name: {**_KIND_SCHEMAS[knob.kind], "title": knob.label} for name, knob in KNOBS.items()}
    return {"type": "object", "properties": props, "additionalProperties": False, "minProperties": 1}

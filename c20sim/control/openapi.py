"""``GET /openapi.json``: the control API described as OpenAPI 3.1, from the tables the API itself uses.

Every route of :data:`c20sim.control.http.ROUTES` is described; the request
bodies are built from :data:`~c20sim.control.ops.CONDITIONS`,
:data:`~c20sim.core.linkfaults.KNOBS`, :data:`~c20sim.control.ops.KEYS` and the
causes, so a condition or link fault added there is described here too. A
test checks the document against the routes the app really serves.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from .. import __version__
from ..core.generators import MAX_SECONDS, MIN_PERIOD
from ..core.linkfaults import KNOBS
from . import ops

__all__ = ["document", "generator_schema", "route_key"]

JSON = "application/json"

#: Routes served under another route's line in ROUTES ("PATCH too", "PATCH and DELETE as for a drive").
ALSO: Mapping[str, str] = {
    "PATCH /drives/{address}/conditions": "PUT /drives/{address}/conditions",
    "PATCH /link": "PATCH /drives/{address}/link",
    "DELETE /link": "DELETE /drives/{address}/link",
}


def route_key(method: str, path: str) -> str:
    return f"{method.upper()} {path}"


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
        elif name == "hall_fault":
            props[name] = {"enum": [None, "stuck0", "stuck7", "sequence"], "description": c.help}
        else:
            props[name] = {"type": "integer", "minimum": c.low, "maximum": c.high, "description": c.help}
    return {"type": "object", "properties": props, "additionalProperties": False, "minProperties": 1}


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


def _object(props: Mapping[str, Any], required: tuple[str, ...] = ()) -> dict[str, Any]:
    schema: dict[str, Any] = {"type": "object", "properties": dict(props), "additionalProperties": False}
    if required:
        schema["required"] = list(required)
    return schema


def request_bodies() -> dict[str, dict[str, Any]]:
    """Request body schemas by route."""
    key = {"oneOf": [{"enum": list(ops.KEYS)}, {"type": "integer", "minimum": 1, "maximum": 8}]}
    return {
        "POST /time/advance": _object(
            {"seconds": {"type": "number", "minimum": 0, "maximum": ops.MAX_ADVANCE}}, ("seconds",)
        ),
        "PUT /drives/{address}/conditions": conditions_schema(),
        "PATCH /drives/{address}/conditions": conditions_schema(),
        "POST /drives/{address}/fault": {
            "oneOf": [
                _object({"cause": {"type": "string"}}, ("cause",)),
                _object(
                    {"code": {"type": "integer", "minimum": 1, "maximum": 255}, "persistent": {"type": "boolean"}},
                    ("code",),
                ),
            ]
        },
        "DELETE /drives/{address}/fault": _object({"reset": {"type": "boolean"}, "cause": {"type": "string"}}),
        "POST /drives/{address}/keypad": _object({"key": key}, ("key",)),
        "PATCH /drives/{address}/link": link_schema(),
        "PATCH /link": link_schema(),
        "PUT /clock/speed": _object(
            {"speed": {"type": "number", "minimum": ops.SPEED_RANGE[0], "maximum": ops.SPEED_RANGE[1]}}, ("speed",)
        ),
        "POST /reset": _object(
            {"setup": {"type": "string", "description": '"defaults", or the path of a state file (--state)'}}
        ),
        "DELETE /drives/{address}/generators": _object(
            {"condition": {"enum": [n for n, c in ops.CONDITIONS.items() if c.continuous]}}
        ),
    }


#: Responses other than 200 that a route may give, with why.
ERRORS: Mapping[str, str] = {
    "400": "a bad request: the message says which field and what is allowed",
    "404": "no such drive or route",
    "409": "not now: the motor runs, or the clock is not the one the operation needs",
}


def _parameter(name: str) -> dict[str, Any]:
    schema: dict[str, Any] = (
        {"type": "integer", "minimum": 1, "maximum": 247} if name == "address" else {"type": "string"}
    )
    text = {
        "address": "the drive's bus address",
        "register": "2100H, 0x2100, F00.10 or a name such as status1",
    }.get(name, name)
    return {"name": name, "in": "path", "required": True, "schema": schema, "description": text}


def document(routes: Mapping[str, str]) -> dict[str, Any]:
    """The OpenAPI 3.1 document of ``routes`` (method path -> what to send), and the routes of :data:`ALSO`."""
    bodies = request_bodies()
    error = {"type": "object", "properties": {"error": {"type": "string"}}, "required": ["error"]}
    paths: dict[str, dict[str, Any]] = {}
    keys = [*routes, *(k for k in ALSO if k not in routes)]
    for key in keys:
        method, path = key.split(" ", 1)
        text = routes.get(key) or routes.get(ALSO.get(key, ""), "")
        operation: dict[str, Any] = {
            "summary": f"{method} {path}",
            "description": text if text != "-" else "",
            "operationId": re.sub(r"[^a-zA-Z0-9]+", "_", f"{method.lower()} {path}").strip("_"),
            "responses": {
                "200": {"description": "the result, as JSON", "content": {JSON: {"schema": {"type": "object"}}}},
                **{code: {"description": why, "content": {JSON: {"schema": error}}} for code, why in ERRORS.items()},
            },
        }
        if path == "/health":
            operation["responses"]["503"] = {
                "description": "not serving yet",
                "content": {JSON: {"schema": {"type": "object"}}},
            }
        params = re.findall(r"{(\w+)}", path)
        if params:
            operation["parameters"] = [_parameter(p) for p in params]
        if path == "/frames" and method == "GET":
            operation["parameters"] = [
                {"name": n, "in": "query", "required": False, "schema": {"type": "integer", "minimum": low}}
                for n, low in (("last", 1), ("slave", 0), ("since", 0))
            ]
        if key in bodies:
            operation["requestBody"] = {
                "required": method in ("PUT", "PATCH"),
                "content": {JSON: {"schema": bodies[key]}},
            }
        paths.setdefault(path, {})[method.lower()] = operation
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "c20sim control API",
            "version": __version__,
            "description": "A running c20sim: its clock, drives, conditions, faults, link faults and frame log. "
            'Errors are JSON {"error": sentence}.',
        },
        "paths": paths,
    }

"""``GET /openapi.json``: the control API described as OpenAPI 3.1, from its route table.

Every row of :data:`c20sim.control.routes.TABLE` is described, with its
request body's schema from the row (built from
:data:`~c20sim.control.ops.CONDITIONS`, :data:`~c20sim.core.linkfaults.KNOBS`,
:data:`~c20sim.control.ops.KEYS` and the causes), so an operation, condition or
link fault added there is described here too. A test checks the document
against the routes the app really serves.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from importlib import metadata
from typing import Any

from .routes import Route

__all__ = ["document", "parameter"]

JSON = "application/json"

#: Responses other than 200 that a route may give, with why.
ERRORS: Mapping[str, str] = {
    "400": "a bad request: the message says which field and what is allowed",
    "404": "no such drive or route",
    "409": "not now: the motor runs, or the clock is not the one the operation needs",
}


def parameter(name: str) -> dict[str, Any]:
    schema: dict[str, Any] = (
        {"type": "integer", "minimum": 1, "maximum": 247} if name == "address" else {"type": "string"}
    )
    text = {
        "address": "the drive's bus address",
        "register": "2100H, 0x2100, F00.10 or a name such as status1",
    }.get(name, name)
    return {"name": name, "in": "path", "required": True, "schema": schema, "description": text}


def _version() -> str:
    """The installed c20sim's version (the package's own, without importing the package from this layer)."""
    try:
        return metadata.version("c20sim")
    except metadata.PackageNotFoundError:
        return "0+unknown"


def document(routes: Mapping[str, Route]) -> dict[str, Any]:
    """The OpenAPI 3.1 document of ``routes`` (the route table, by ``METHOD path``)."""
    error = {"type": "object", "properties": {"error": {"type": "string"}}, "required": ["error"]}
    paths: dict[str, dict[str, Any]] = {}
    for row in routes.values():
        method, path = row.method, row.path
        operation: dict[str, Any] = {
            "summary": f"{method} {path}",
            "description": row.doc if row.doc != "-" else "",
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
        if row.parameters:
            operation["parameters"] = [parameter(p) for p in row.parameters]
        if path == "/frames" and method == "GET":
            operation["parameters"] = [
                {"name": n, "in": "query", "required": False, "schema": {"type": "integer", "minimum": low}}
                for n, low in (("last", 1), ("slave", 0), ("since", 0))
            ]
        schema = row.schema()
        if schema is not None:
            operation["requestBody"] = {
                "required": method in ("PUT", "PATCH"),
                "content": {JSON: {"schema": schema}},
            }
        paths.setdefault(path, {})[method.lower()] = operation
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "c20sim control API",
            "version": _version(),
            "description": "A running c20sim: its clock, drives, conditions, faults, link faults and frame log. "
            'Errors are JSON {"error": sentence}.',
        },
        "paths": paths,
    }

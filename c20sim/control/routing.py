"""The control surface's row type: a :class:`Route` (method, path, the function that does it, its fields, its
doc), the :class:`Table` of rows and :func:`invoke`, which checks a row's fields and does its operation.

The rows themselves are declared by operation family (:mod:`c20sim.control.routes` gathers them).
"""

from __future__ import annotations

import re
import urllib.parse
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from ..core.simulator import Simulator
from . import ops
from .ops import ControlError, unknown

__all__ = ["Field", "Route", "Schema", "Table", "invoke", "path_parameters"]

Schema = Mapping[str, Any]


@dataclass(frozen=True)
class Field:
    """One field of a request body: its JSON Schema, whether it must be given, and what it is."""

    name: str
    schema: Schema
    required: bool = False
    doc: str = ""
    #: ctl takes it as an optional word after the path's (``ctl write accel 2.5``), not as ``--name``
    positional: bool = False


@dataclass(frozen=True)
class Route:
    """One operation of the control surface."""

    method: str
    path: str
    #: the operation's name: ``RemoteOps.call(name)``, ``LocalOps.call(name)``, and ctl's action unless ``cli``
    name: str
    #: what to send and what it does, in words (``GET /`` lists it)
    doc: str
    #: ``call(sim, **path parameters, **fields)`` -> the JSON answer; None for a route the API serves itself
    call: Callable[..., Any] | None = None
    fields: tuple[Field, ...] = ()
    #: the body is one value handed to ``call`` under this name, its schema :attr:`body_schema`
    whole: str | None = None
    body_schema: Callable[[], Schema] | None = None
    #: what to say when a required field is missing
    missing: str = ""
    #: whether it changes the drives, the clock or the log (a viewer reads the state again after it)
    changes: bool = False
    #: ctl's action for it ("" = the name, with dashes); None: not a ctl action
    cli: str | None = ""
    #: shown in ``GET /``'s list; False for a second method described by another row ("PATCH too")
    listed: bool = True
    #: what it does, in one line (ctl's help); the doc where empty
    help: str = ""
    #: work that may block (a file read), done before the call on the fields as given: ``(sim, fields) ->
    #: fields``; the API runs it in a worker thread, off the serving loop. It may read the simulator, never
    #: change it.
    offload: Callable[[Simulator, dict[str, Any]], dict[str, Any]] | None = None
    #: a tool of ``c20sim mcp`` (:mod:`c20sim.mcpserver`); False for a route no request and reply carry (the
    #: WebSocket: what it streams, the assistant reads as MCP resources)
    tool: bool = True

    @property
    def key(self) -> str:
        return f"{self.method} {self.path}"

    @property
    def parameters(self) -> tuple[str, ...]:
        return path_parameters(self.path)

    @property
    def action(self) -> str | None:
        if self.cli is None:
            return None
        return self.cli or self.name.replace("_", "-")

    @property
    def said(self) -> str:
        """What it does in one line: its help, or its doc without the "- (...)" of a route that takes no body."""
        if self.help:
            return self.help
        return self.doc.removeprefix("- (").removesuffix(")") if self.doc.startswith("- (") else self.doc

    def schema(self) -> Schema | None:
        """The request body's JSON Schema, or None for a route that takes none."""
        if self.body_schema is not None:
            return self.body_schema()
        if not self.fields:
            return None
        out: dict[str, Any] = {
            "type": "object",
            "properties": {f.name: dict(f.schema) for f in self.fields},
            "additionalProperties": False,
        }
        required = [f.name for f in self.fields if f.required]
        if required:
            out["required"] = required
        return out

    def url(self, **parameters: object) -> str:
        """The path with its parameters filled in, quoted (``motor speed`` is ``motor%20speed``; a register given
        as a number as ``2100H``)."""

        def fill(match: re.Match[str]) -> str:
            value = parameters[match.group(1)]
            if match.group(1) == "register" and isinstance(value, int):
                return f"{value:04X}H"
            return urllib.parse.quote(str(value), safe="")

        return re.sub(r"{(\w+)}", fill, self.path)


def path_parameters(path: str) -> tuple[str, ...]:
    return tuple(re.findall(r"{(\w+)}", path))


class Table(Mapping[str, Route]):
    """The rows, by ``METHOD path``; :meth:`named` finds one by its operation name."""

    def __init__(self, rows: Iterable[Route]) -> None:
        self._rows: dict[str, Route] = {}
        self._names: dict[str, Route] = {}
        for row in rows:
            self.add(row)

    def add(self, row: Route) -> None:
        if row.key in self._rows or row.name in self._names:
            raise ValueError(f"route {row.key} ({row.name}): declared twice")
        self._rows[row.key] = row
        self._names[row.name] = row

    def remove(self, name: str) -> None:
        row = self._names.pop(name)
        del self._rows[row.key]

    def named(self, name: str) -> Route:
        try:
            return self._names[name]
        except KeyError:
            raise unknown("operation", name, self._names) from None

    def __getitem__(self, key: str) -> Route:
        return self._rows[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._rows)

    def __len__(self) -> int:
        return len(self._rows)

    def listing(self) -> dict[str, str]:
        """``METHOD path`` -> what to send, for ``GET /``."""
        return {key: row.doc for key, row in self._rows.items() if row.listed}


def invoke(
    sim: Simulator,
    row: Route,
    parameters: Mapping[str, Any],
    data: Mapping[str, Any],
    path: str = "",
    *,
    offloaded: bool = False,
) -> Any:
    """Check ``data`` against ``row``'s fields and do the operation; ControlError says what is wrong.
    ``offloaded``: the row's :attr:`~Route.offload` has been run on ``data`` already (in a worker thread)."""
    if row.offload is not None and not offloaded:
        data = row.offload(sim, dict(data))
    if row.call is None:
        raise ControlError(f"{row.key} is served by the API itself", status=404)
    if "address" in parameters:
        ops.drive(sim, parameters["address"])  # 404 for a drive that is not there, before any field
    if row.whole is not None:
        return row.call(sim, **parameters, **{row.whole: dict(data)})
    names = [f.name for f in row.fields]
    if not names and data:
        raise ControlError(f"{row.method} {path or row.path} takes no fields; got {', '.join(map(repr, data))}")
    for key in data:
        if key not in names:
            raise unknown("field", key, names)
    for f in row.fields:
        if f.required and f.name not in data:
            raise ControlError(row.missing or f"give {f.name}")
    return row.call(sim, **parameters, **data)

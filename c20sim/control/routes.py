"""The control surface, one row per operation: method, path, the function that does it, its fields, its doc.

Every front end is derived from :data:`TABLE`: the aiohttp app
(:mod:`c20sim.control.http` serves a row with one generic handler unless it
names its own), the OpenAPI document (:mod:`c20sim.control.openapi`), the
remote client and the dashboard's operations (:mod:`c20sim.control.client`,
:class:`LocalOps`), ``c20sim ctl`` (:mod:`c20sim.control.ctl`) and the MCP tools of
``c20sim mcp`` (:mod:`c20sim.mcpserver`). Nothing
else writes a path or a field list. A new operation is its function plus one
row: ``call(sim, **path parameters, **fields)`` returns the JSON answer.

A row's fields are checked here, the same way for every caller: an unknown
field names the known ones, a missing one says what to send; the values are
then checked by the operation itself (:mod:`c20sim.control.ops`). A row with
``whole`` takes the request body as one value (the conditions, the link
faults, a fault request) and leaves its checking to the operation.
"""

from __future__ import annotations

import re
import urllib.parse
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from ..core.simulator import Simulator
from . import causes, drills, liveaudit, ops
from .ops import ControlError, unknown
from .schemas import conditions_schema, link_schema

__all__ = ["TABLE", "Field", "Route", "Table", "invoke", "path_parameters", "table"]

Schema = Mapping[str, Any]


@dataclass(frozen=True)
class Field:
    """One field of a request body: its JSON Schema, whether it must be given, and what it is."""

    name: str
    schema: Schema
    required: bool = False
    doc: str = ""


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


# --- The answers: what each operation returns over the API.


def _state(sim: Simulator, address: int) -> dict[str, Any]:
    return ops.drive_state(sim, address)


def _live_audit(sim: Simulator) -> liveaudit.LiveAudit:
    found = liveaudit.of(sim)
    if found is None:
        raise ControlError("the audit is off (serve --no-audit)", status=409)
    return found


def _audit(sim: Simulator) -> dict[str, Any]:
    return _live_audit(sim).report()


def _clear_audit(sim: Simulator) -> dict[str, Any]:
    audit = _live_audit(sim)
    audit.restart()
    return audit.report()


def _drill(sim: Simulator) -> dict[str, Any]:
    return drills.of(sim).status()


def _start_drill(sim: Simulator, **fields: Any) -> dict[str, Any]:
    if sim.virtual:
        raise ControlError("a drill needs the realtime clock: serve without --clock virtual", status=409)
    return drills.of(sim).start(fields)


def _stop_drill(sim: Simulator) -> dict[str, Any]:
    return drills.of(sim).stop()


_SECONDS = {"type": "number", "exclusiveMinimum": 0, "maximum": 600}
_DRILL_FIELDS = (
    Field(
        "plan",
        {"type": ["array", "null"], "items": {"type": ["string", "object"]}, "maxItems": 200},
        doc='incidents by name or as tables ({"incident": "trip", "hold": 1}); null: the standard plan',
    ),
    Field("warmup", _SECONDS, doc="seconds of the master's rhythm first (3)"),
    Field("poll_period", _SECONDS, doc="the master's poll period, given instead of learned"),
    Field("timeout", _SECONDS, doc="the master's timeout, given instead of learned"),
    Field("seed", {"type": "integer", "minimum": 0}, doc="the faults' randomness (1)"),
    Field("wait", _SECONDS, doc="seconds to wait for the master's first request (60)"),
)


def _counters(sim: Simulator, address: int) -> dict[str, object]:
    """The drive's traffic counters, and the line demand of the live audit (the line the drive is on)."""
    counters = ops.counters(sim, address)
    audit = liveaudit.of(sim)
    if audit is not None:
        counters["line_demand"] = audit.line_demand().as_dict()
    return counters


def _time(sim: Simulator) -> dict[str, Any]:
    return {"t": sim.now(), "clock": "virtual" if sim.virtual else "realtime"}


def _advance(sim: Simulator, seconds: object) -> dict[str, Any]:
    return {"t": ops.advance(sim, seconds)}


def _drives(sim: Simulator) -> dict[str, Any]:
    return {"drives": [ops.drive_state(sim, a) for a in sim.drives]}


def _registers(sim: Simulator, address: int) -> dict[str, Any]:
    return {"registers": ops.registers(sim, address)}


def _conditions(sim: Simulator, address: int, values: Mapping[str, object]) -> dict[str, Any]:
    ops.set_conditions(sim, address, values)
    return ops.drive_state(sim, address)


def _fault(sim: Simulator, address: int, request: Mapping[str, object]) -> dict[str, Any]:
    note = causes.request(sim, address, request)
    return {"note": note, **ops.drive_state(sim, address)}


def _clear_fault(sim: Simulator, address: int, reset: object = True, cause: object = None) -> dict[str, Any]:
    """End ``cause`` (by default every cause present now, and no other condition) and press reset."""
    ending = [cause] if cause is not None else [name for name, on in causes.active(sim, address).items() if on]
    notes = [causes.release(sim, address, name) for name in ending]
    press = ops.flag("reset", reset)
    cleared = ops.clear_fault(sim, address, reset) if press else False
    state = ops.drive_state(sim, address)
    if press and not cleared and state["fault_code"]:
        notes.append(
            f"drive {address} kept its fault: reset again once the cause has gone (the bus recovers as time runs)"
        )
    return {"reset": cleared, "note": "; ".join(notes), **state}


def _causes(sim: Simulator, address: int) -> dict[str, Any]:
    return {"causes": causes.active(sim, address)}


def _clear_causes(sim: Simulator, address: int) -> dict[str, Any]:
    causes.clear_all(sim, address)
    return {"causes": causes.active(sim, address)}


def _keypad(sim: Simulator, address: int, key: object) -> dict[str, Any]:
    accepted = ops.press_key(sim, address, key)
    return {"accepted": accepted, **ops.drive_state(sim, address)}


def _power_cycle(sim: Simulator, address: int) -> dict[str, Any]:
    ops.power_cycle(sim, address)
    return ops.drive_state(sim, address)


def _run_channel(sim: Simulator, address: int, channel: object) -> dict[str, Any]:
    chosen = ops.set_run_channel(sim, address, channel)
    return {"channel": int(chosen), **ops.drive_state(sim, address)}


def _restore_defaults(sim: Simulator, address: int) -> dict[str, Any]:
    ops.restore_defaults(sim, address)
    return ops.drive_state(sim, address)


def _link(sim: Simulator, address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.links(sim, address))


def _set_link(sim: Simulator, values: Mapping[str, object], address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.set_link_faults(sim, address, values))


def _clear_link(sim: Simulator, address: int | None = None) -> dict[str, Any]:
    return ops.link_state(ops.clear_link_faults(sim, address))


def _read_setup(sim: Simulator, fields: dict[str, Any]) -> dict[str, Any]:
    """The state file a reset names, read (bounded) before the reset: the blocking part, off the loop."""
    if "setup" in fields:
        fields["setup"] = ops.read_setup(sim, fields["setup"])
    return fields


def _generators(sim: Simulator, address: int) -> dict[str, Any]:
    return {"generators": ops.generators(sim, address)}


def _clear_generators(sim: Simulator, address: int, condition: object = None) -> dict[str, Any]:
    return {"generators": ops.clear_generators(sim, address, condition)}


# --- Field schemas.

_VALUE = Field("value", {"type": "integer", "minimum": 0, "maximum": 0xFFFF}, True, "the raw value: 1500, 0x5DC")
_KEY = {"oneOf": [{"enum": list(ops.KEYS)}, {"type": "integer", "minimum": 1, "maximum": 8}]}


def _fault_schema() -> Schema:
    def obj(props: Mapping[str, Any], required: tuple[str, ...]) -> dict[str, Any]:
        return {"type": "object", "properties": dict(props), "additionalProperties": False, "required": list(required)}

    return {
        "oneOf": [
            obj({"cause": {"type": "string"}}, ("cause",)),
            obj(
                {"code": {"type": "integer", "minimum": 1, "maximum": 255}, "persistent": {"type": "boolean"}},
                ("code",),
            ),
        ]
    }


def _conditions_body() -> Schema:
    return conditions_schema()


def _link_body() -> Schema:
    return link_schema()


_D = "/drives/{address}"

#: The control surface. ``listed=False`` rows are second methods of a listed row (its doc says so).
TABLE = Table(
    [
        Route("GET", "/", "index", "-", cli="info", help="profile, drives, clock and the API's routes"),
        Route(
            "GET",
            "/telemetry",
            "telemetry",
            "- (every drive's telemetry, conditions, causes and link faults: one stream message)",
            help="every drive's state at once, as one stream message",
        ),
        Route("GET", "/profile", "profile", "- (the served profile's TOML)", cli=None),
        Route(
            "GET",
            "/stream",
            "stream",
            "WebSocket (query: hz=0.1-50, frame_hz=0.1-100, buffer=1-10000, frames=0|1): telemetry, frames",
            cli=None,
            tool=False,
        ),
        Route("GET", "/time", "time", "-", _time, help="the model's time"),
        Route(
            "POST",
            "/time/advance",
            "advance",
            '{"seconds": 1.5} (virtual clock only; 409 otherwise)',
            _advance,
            (Field("seconds", {"type": "number", "minimum": 0, "maximum": ops.MAX_ADVANCE}, True),),
            missing='give the time to advance by, such as {"seconds": 1.5}',
            changes=True,
            help="advance virtual time (serve --clock virtual)",
        ),
        Route(
            "GET",
            "/drives",
            "drives",
            "-",
            _drives,
            cli="state",
            help="a drive's telemetry (every drive without --drive)",
        ),
        Route(
            "GET",
            _D,
            "drive",
            "-",
            _state,
            cli="state",
            help="one drive's telemetry: state, speeds, current, bus voltage, temperature, fault",
        ),
        Route(
            "GET",
            f"{_D}/registers",
            "registers",
            "- (every register and function code, grouped as the sheet groups them)",
            _registers,
            help="every register and function code with its value, access and group",
        ),
        Route(
            "GET",
            f"{_D}/registers/{{register}}",
            "read_register",
            "- (register: speed, motor_speed, 3006H, 0x3006, 12294 or F00.10)",
            ops.read_register,
            cli="read",
            help="read a register: a name (speed, status, fault), 3006H, 0x3006, 12294 or F00.10",
        ),
        Route(
            "PUT",
            f"{_D}/registers/{{register}}",
            "write_register",
            '{"value": 1500} (a master\'s rules; a refusal is 409 with its exception)',
            ops.write_register,
            (_VALUE,),
            missing='give the raw value, such as {"value": 1500}',
            changes=True,
            cli="write",
            help="write a register by a master's rules (a refusal names its exception code)",
        ),
        Route(
            "GET",
            f"{_D}/counters",
            "counters",
            "- (requests, replies, exceptions by code, CRC errors, silences, injected; line_demand: the audit's)",
            _counters,
            help="the drive's traffic: requests, replies, exceptions by code, CRC errors, silences",
        ),
        Route(
            "PUT",
            f"{_D}/panel/{{register}}",
            "keypad_edit",
            "{\"value\": 3} (the drive's own panel: a master's rules but 200EH and the password)",
            ops.keypad_edit,
            (_VALUE,),
            missing='give the raw value, such as {"value": 1500}',
            changes=True,
            cli="panel",
            help="edit a register from the drive's own panel (200EH allowed, no password)",
        ),
        Route(
            "PUT",
            f"{_D}/conditions",
            "set_conditions",
            '{"supply_v": 30, "load_torque_nm": 2, ...} (PATCH too)',
            _conditions,
            whole="values",
            body_schema=_conditions_body,
            changes=True,
            cli="set",
            help=f"set conditions: {', '.join(ops.CONDITIONS)}",
        ),
        Route(
            "PATCH",
            f"{_D}/conditions",
            "patch_conditions",
            '{"supply_v": 30, ...}: as PUT',
            _conditions,
            whole="values",
            body_schema=_conditions_body,
            changes=True,
            help="set conditions, as set_conditions does (the API's PATCH)",
            cli=None,
            listed=False,
        ),
        Route(
            "POST",
            f"{_D}/fault",
            "fault",
            '{"cause": "undervoltage"} or {"code": 16, "persistent": false}',
            _fault,
            whole="request",
            body_schema=_fault_schema,
            changes=True,
            help="bring about a fault's cause (--cause undervoltage), or latch a fault by code",
        ),
        Route(
            "DELETE",
            f"{_D}/fault",
            "clear_fault",
            '{"reset": true, "cause": "undervoltage"} (both optional)',
            _clear_fault,
            (Field("reset", {"type": "boolean"}), Field("cause", {"type": "string"})),
            changes=True,
            cli="clear",
            help="end a fault's cause (--cause NAME; default: every cause) and press reset",
        ),
        Route(
            "GET",
            f"{_D}/causes",
            "causes",
            "- (every fault cause of the profile: whether it is there now)",
            _causes,
            help="every fault cause of the profile, and whether it is there now",
        ),
        Route(
            "POST",
            f"{_D}/keypad",
            "press_key",
            '{"key": "reset"} (forward, reverse, stop, free_stop, reset, ...)',
            _keypad,
            (Field("key", _KEY, True),),
            missing=f'give the key, such as {{"key": "reset"}}; keys: {", ".join(ops.KEYS)}',
            changes=True,
            cli="key",
            help=f"press a keypad key: {', '.join(ops.KEYS)}",
        ),
        Route(
            "POST",
            f"{_D}/power-cycle",
            "power_cycle",
            "-",
            _power_cycle,
            changes=True,
            help="switch the drive off and on",
        ),
        Route(
            "DELETE",
            f"{_D}/causes",
            "clear_causes",
            "- (ends every fault cause; faults stay until reset)",
            _clear_causes,
            changes=True,
            help="end every fault cause (the faults stay until reset)",
        ),
        Route(
            "POST",
            f"{_D}/run-channel",
            "set_run_channel",
            '{"channel": "keypad"} (F00.01 from the panel: a channel name or its number)',
            _run_channel,
            (Field("channel", {"oneOf": [{"type": "string"}, {"type": "integer", "minimum": 0, "maximum": 2}]}, True),),
            missing='give the run channel, such as {"channel": "keypad"} or {"channel": 0}',
            changes=True,
            cli="run-channel",
            help="set F00.01 from the panel: keypad, terminals or communication",
        ),
        Route(
            "POST",
            f"{_D}/restore-defaults",
            "restore_defaults",
            "- (200FH = 1 from the panel; 409 while running)",
            _restore_defaults,
            changes=True,
            help="restore the function codes' defaults from the panel (only while stopped)",
        ),
        Route(
            "GET",
            f"{_D}/link",
            "drive_link",
            "-",
            _link,
            cli="link",
            help="show, set (KEY=VALUE) or --clear link faults (the bus without --drive)",
        ),
        Route(
            "PATCH",
            f"{_D}/link",
            "set_drive_link",
            '{"offline": true, "drop_next": 2, "delay": 0.5, ...}',
            _set_link,
            whole="values",
            body_schema=_link_body,
            changes=True,
            help="set a drive's link faults: offline, drop_next, delay, corrupt_crc, ...",
            cli="link",
        ),
        Route(
            "DELETE",
            f"{_D}/link",
            "clear_drive_link",
            "- (clears every link fault of the drive)",
            _clear_link,
            changes=True,
            cli="link",
        ),
        Route("GET", "/link", "link", "- (the whole bus's link faults; PATCH and DELETE as for a drive)", _link),
        Route(
            "PATCH",
            "/link",
            "set_link",
            '{"offline": true, ...}: as for a drive, on the whole bus',
            _set_link,
            whole="values",
            body_schema=_link_body,
            changes=True,
            help="set the whole bus's link faults: offline, drop_next, delay, corrupt_crc, ...",
            cli="link",
            listed=False,
        ),
        Route(
            "DELETE",
            "/link",
            "clear_link",
            "- (clears every link fault of the bus)",
            _clear_link,
            changes=True,
            cli="link",
            listed=False,
        ),
        Route(
            "GET",
            "/frames",
            "frames",
            "- (query: last=N (N >= 1), slave=N, since=SEQ); log_dropped: records --log-frames lost",
            help="the frame log",
        ),
        Route(
            "GET",
            "/audit",
            "audit",
            "- (what the masters would do wrong on a real line: findings, line demand; docs/audit.md)",
            _audit,
            help="the audit's findings and the line demand (docs/audit.md)",
        ),
        Route(
            "DELETE",
            "/audit",
            "clear_audit",
            "- (the audit starts afresh: findings and line demand forgotten)",
            _clear_audit,
            help="start the audit afresh",
        ),
        Route(
            "GET",
            "/drill",
            "drill",
            "- (the drill: idle, running (what it plays now), done (its report: a verdict per drill) or failed)",
            _drill,
            help="the drill's state and report (docs/drill.md)",
        ),
        Route(
            "POST",
            "/drill",
            "start_drill",
            '{"plan": ["crc", {"incident": "trip", "hold": 1}], "warmup": 3} (plays incidents on the master that '
            "polls this serve and judges how it survives them, off the serving loop; realtime clock; docs/drill.md)",
            _start_drill,
            _DRILL_FIELDS,
            changes=True,
            help="start a drill on the master polling this serve (docs/drill.md)",
        ),
        Route(
            "DELETE",
            "/drill",
            "stop_drill",
            "- (asks the running drill to stop: the plant is left healthy, the drills played so far judged; GET /drill says when)",
            _stop_drill,
            changes=True,
            help="stop the running drill",
        ),
        Route(
            "DELETE", "/frames", "clear_frames", "- (empties the frame log)", changes=True, help="empty the frame log"
        ),
        # the service routes: health, the document, the clock, set-ups, generators
        Route(
            "GET",
            "/metrics",
            "metrics",
            "- (Prometheus text format: each drive's counters, state and telemetry, the line's reply latency)",
            cli=None,
        ),
        Route(
            "GET",
            "/health",
            "health",
            "- (200 once serving, 503 before; for orchestrators)",
            help="whether the server is serving",
        ),
        Route("GET", "/openapi.json", "openapi", "- (this API as OpenAPI 3.1)", cli=None),
        Route(
            "GET",
            "/clock",
            "clock",
            "- (clock, t, paused, speed)",
            ops.clock_state,
            help="the clock: virtual or realtime, t, paused, speed",
        ),
        Route(
            "POST",
            "/clock/pause",
            "pause",
            "- (realtime clock: model time stops; 409 for a virtual clock)",
            ops.pause,
            changes=True,
            help="stop the model's time (realtime clock)",
        ),
        Route(
            "POST",
            "/clock/resume",
            "resume",
            "- (realtime clock: model time runs on)",
            ops.resume,
            changes=True,
            help="let the model's time run on (realtime clock)",
        ),
        Route(
            "PUT",
            "/clock/speed",
            "set_speed",
            '{"speed": 10} (realtime clock: model seconds per wall second, 0.001-1000)',
            lambda sim, speed: ops.set_speed(sim, speed),
            (Field("speed", {"type": "number", "minimum": ops.SPEED_RANGE[0], "maximum": ops.SPEED_RANGE[1]}, True),),
            missing='give the speed factor, such as {"speed": 10}',
            changes=True,
            cli="speed",
            help="set the realtime clock's speed factor, such as 10",
        ),
        Route(
            "POST",
            "/reset",
            "reset",
            '{"setup": "defaults"} or {"setup": "PATH of a state file"}: every drive anew, no restart',
            ops.reset,
            (Field("setup", {"type": "string", "description": '"defaults", or the path of a state file (--state)'}),),
            changes=True,
            help="every drive anew, no restart: defaults, or a state file's function codes",
            offload=_read_setup,
        ),
        Route(
            "GET",
            f"{_D}/generators",
            "generators",
            "- (the generators running on the drive's conditions)",
            _generators,
            help="the generators on a drive's conditions; --clear [CONDITION] stops them",
        ),
        Route(
            "DELETE",
            f"{_D}/generators",
            "clear_generators",
            '{"condition": "supply_v"} (optional; all without)',
            _clear_generators,
            (Field("condition", {"enum": [n for n, c in ops.CONDITIONS.items() if c.continuous]}),),
            changes=True,
            help="stop the generators on a drive's conditions: one condition's, or all",
            cli="generators",
        ),
    ]
)


def table() -> Table:
    """The control surface's rows (a test may add one, and every front end built after sees it)."""
    return TABLE

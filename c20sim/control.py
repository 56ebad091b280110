"""Out-of-band control of a running simulator: what CI in any language needs besides Modbus.

Two halves. The first is a small vocabulary of operations on a
:class:`~c20sim.simulator.Simulator` (read a drive's state, set conditions,
inject and clear device and link faults, press keypad keys, power cycle, read
the frame log), plain functions that check their inputs and raise
:class:`ControlError` with the HTTP status and a sentence saying what is wrong.
The pytest plugin and the scenario runner use the same functions, so a
condition or a fault means the same thing everywhere.

The second is an aiohttp application serving that vocabulary as JSON
(``c20sim serve --control HOST:PORT``). Handlers run on the serving loop, the
same thread that serves Modbus, so a request never sees a drive half-way
through a frame. aiohttp is imported only when the API is started: it is the
slowest import of the package.
"""

from __future__ import annotations

import argparse
import itertools
import json
import logging
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from . import httpguard
from .errors import C20SimError
from .linkfaults import LinkFaults
from .protocol import ExceptionCode
from .registers import Reg, parse_fcode
from .simulator import Simulator

if TYPE_CHECKING:
    from aiohttp import web

    from .drive.model import Drive

log = logging.getLogger(__name__)

__all__ = [
    "CONDITIONS",
    "CONDITION_RANGES",
    "KEYPAD",
    "ControlApi",
    "ControlError",
    "add_ctl_command",
    "advance",
    "call",
    "check_conditions",
    "check_fault",
    "check_link_faults",
    "clear_fault",
    "drive_state",
    "frames",
    "inject_fault",
    "key_command",
    "link_state",
    "make_app",
    "parse_register",
    "power_cycle",
    "press_key",
    "read_register",
    "register_address",
    "set_conditions",
    "set_link_faults",
    "unknown",
]


class ControlError(C20SimError):
    """A control request that cannot be served: ``status`` is the HTTP status to answer with."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


# --- Checking JSON values.


def _number(key: str, value: object, low: float | None = None, high: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ControlError(f"{key}: expected a number, got {json.dumps(value)}")
    if not math.isfinite(value):
        raise ControlError(f"{key}: expected a finite number, got {value}")
    if (low is not None and value < low) or (high is not None and value > high):
        bounds = f"{low:g}-{high:g}" if low is not None and high is not None else f">= {low:g}"
        raise ControlError(f"{key}: {value:g} is outside {bounds}")
    return float(value)


def _integer(key: str, value: object, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ControlError(f"{key}: expected an integer, got {json.dumps(value)}")
    if not low <= value <= high:
        raise ControlError(f"{key}: {value} is outside {low}-{high}")
    return value


def _flag(key: str, value: object) -> bool:
    if not isinstance(value, bool):
        raise ControlError(f"{key}: expected true or false, got {json.dumps(value)}")
    return value


def unknown(kind: str, key: str, known: Mapping[str, object] | Sequence[str]) -> ControlError:
    """The error for an unknown name: the closest known one, and all of them."""
    import difflib

    names = list(known)
    close = difflib.get_close_matches(key, names, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return ControlError(f"unknown {kind} {key!r}{hint} (known: {', '.join(names)})")


# --- The drives.


def model(sim: Simulator, address: int) -> Drive:
    """The behavioural drive at ``address``; 404 if there is none."""
    from .drive.model import Drive

    if address not in sim.drives:
        raise ControlError(
            f"no drive at address {address}; drives: {', '.join(map(str, sim.drives))}",
            status=404,
        )
    drive = sim.drives[address]
    if not isinstance(drive, Drive):
        raise ControlError(f"the drive at address {address} is not the behavioural model", status=409)
    return drive


def drive_state(sim: Simulator, address: int) -> dict[str, Any]:
    """The drive's telemetry now, as JSON-ready values, with its link faults."""
    drive = model(sim, address)
    sim.sync()
    state = asdict(drive.telemetry())
    state["address"] = address
    state["link_faults"] = link_state(sim.link_faults(address))
    return state


def register_address(text: object) -> int:
    """``2100H``, ``0x2100``, ``2100``, ``F00.10``, ``status1`` (or ``fault code``) or an int -> an address 0-FFFFH.

    The spelling only: whether a profile has the register is :func:`parse_register`'s question.
    """
    if isinstance(text, bool) or not isinstance(text, str | int):
        raise ControlError(f"register: expected a name or an address, got {json.dumps(text)}")
    if isinstance(text, int):
        address = text
    else:
        body = text.strip()
        name = body.upper().replace("-", "_").replace(" ", "_")
        if name in Reg.__members__:
            return int(Reg[name])
        if body.upper().startswith("F") and "." in body:
            try:
                return parse_fcode(body)
            except ValueError as exc:
                raise ControlError(f"register {text!r}: {exc}") from None
        digits = body[2:] if body.lower().startswith("0x") else body.removesuffix("H").removesuffix("h")
        try:
            address = int(digits, 16)
        except ValueError:
            raise ControlError(
                f"register {text!r}: give an address such as 2100H or 0x2100, a function code such as F00.10, "
                f"or a name such as status1"
            ) from None
    if not 0 <= address <= 0xFFFF:
        raise ControlError(f"register {text!r}: an address is 0000H-FFFFH")
    return address


def parse_register(sim: Simulator, text: str | int) -> int:
    """A register as :func:`register_address` reads it, which the simulator's profile must have."""
    address = register_address(text)
    if address not in sim.profile.registers:
        raise ControlError(f"register {text!r}: the profile {sim.profile.name} has no register {address:04X}H")
    return address


def read_register(sim: Simulator, address: int, register: str | int) -> dict[str, Any]:
    """A register's value as a master would read it, without counting as communication."""
    drive = model(sim, address)
    reg = parse_register(sim, register)
    spec = sim.profile.registers[reg]
    sim.sync()
    raw = drive.read(sim.profile.registers.canonical(reg))
    return {
        "register": spec.label,
        "address": reg,
        "name": spec.name,
        "raw": raw,
        "value": spec.engineering(raw),
        "unit": spec.unit,
        "text": spec.describe(raw),
    }


def _hall(key: str, value: object) -> Callable[[Drive], None]:
    if value is not None and value not in ("stuck0", "stuck7", "sequence"):
        raise ControlError(f"{key}: expected null, 'stuck0', 'stuck7' or 'sequence', got {json.dumps(value)}")
    return lambda d: d.set_hall_fault(value)


def _num_setter(
    low: float, high: float, setter: Callable[[Drive, float], None]
) -> Callable[[str, object], Callable[[Drive], None]]:
    def check(key: str, value: object) -> Callable[[Drive], None]:
        number = _number(key, value, low, high)
        return lambda d: setter(d, number)

    return check


def _terminals(key: str, value: object) -> Callable[[Drive], None]:
    bits = _integer(key, value, 0, 0x1FF)
    return lambda d: d.set_terminal_inputs(bits)


#: The range of each numeric condition, the one the API, the scenarios and the dashboard all accept.
CONDITION_RANGES: Mapping[str, tuple[float, float]] = {
    "supply_v": (0, 2000),
    "load_torque_nm": (0, 1000),
    "load_inertia_kg_m2": (0, 100),
    "ambient_c": (-50, 150),
    "ai1_v": (0, 10),
    "ai2_v": (0, 10),
    "ai3_v": (0, 10),
}

#: Condition name -> checker of a JSON value -> the change to make.
CONDITIONS: Mapping[str, Callable[[str, object], Callable[[Drive], None]]] = {
    "supply_v": _num_setter(*CONDITION_RANGES["supply_v"], lambda d, v: d.set_supply_voltage(v)),
    "load_torque_nm": _num_setter(*CONDITION_RANGES["load_torque_nm"], lambda d, v: d.set_load_torque(v)),
    "load_inertia_kg_m2": _num_setter(*CONDITION_RANGES["load_inertia_kg_m2"], lambda d, v: d.set_load_inertia(v)),
    "ambient_c": _num_setter(*CONDITION_RANGES["ambient_c"], lambda d, v: d.set_ambient(v)),
    "hall_fault": _hall,
    "ai1_v": _num_setter(*CONDITION_RANGES["ai1_v"], lambda d, v: d.set_ai(1, v)),
    "ai2_v": _num_setter(*CONDITION_RANGES["ai2_v"], lambda d, v: d.set_ai(2, v)),
    "ai3_v": _num_setter(*CONDITION_RANGES["ai3_v"], lambda d, v: d.set_ai(3, v)),
    "terminal_inputs": _terminals,
}


def check_conditions(values: object) -> list[Callable[[Drive], None]]:
    """Check conditions by their :data:`CONDITIONS` names; returns the changes to make."""
    if not isinstance(values, Mapping) or not values:
        raise ControlError(f'give conditions as an object, such as {{"supply_v": 30}}; known: {", ".join(CONDITIONS)}')
    changes = []
    for key, value in values.items():
        check = CONDITIONS.get(key)
        if check is None:
            raise unknown("condition", key, CONDITIONS)
        changes.append(check(key, value))
    return changes


def set_conditions(sim: Simulator, address: int, values: Mapping[str, object]) -> None:
    """Set conditions at the drive's current time; all are checked before any is applied."""
    drive = model(sim, address)
    changes = check_conditions(values)
    sim.sync()
    for change in changes:
        change(drive)


def check_fault(code: object, persistent: object = False) -> tuple[int, bool]:
    """A device fault to inject: ``code`` 1-255, and whether it is ``persistent``."""
    return _integer("code", code, 1, 0xFF), _flag("persistent", persistent)


def inject_fault(sim: Simulator, address: int, code: object, persistent: object = False) -> None:
    """Latch device fault ``code`` now; ``persistent`` makes resets fail until :func:`clear_fault`."""
    drive = model(sim, address)
    number, hold = check_fault(code, persistent)
    sim.sync()
    drive.force_fault(number, persistent=hold)


def clear_fault(sim: Simulator, address: int, reset: object = True) -> bool:
    """Release an injected fault's cause and (with ``reset``) press fault reset; True if the drive left the fault."""
    drive = model(sim, address)
    press = _flag("reset", reset)
    sim.sync()
    drive.release_fault()
    return drive.keypad(7) if press else False


#: Keypad key name -> 2000H command value.
KEYPAD: Mapping[str, int] = {
    "forward": 1,
    "reverse": 2,
    "jog_forward": 3,
    "jog_reverse": 4,
    "stop": 5,
    "free_stop": 6,
    "reset": 7,
    "jog_stop": 8,
}


def key_command(key: object) -> int:
    """A keypad key (a name of :data:`KEYPAD` or a 2000H value 1-8) -> its 2000H value."""
    if isinstance(key, str):
        if key not in KEYPAD:
            raise unknown("key", key, KEYPAD)
        return KEYPAD[key]
    return _integer("key", key, 1, 8)


def press_key(sim: Simulator, address: int, key: object) -> bool:
    """Press a keypad key (a name of :data:`KEYPAD` or a 2000H value 1-8); False if the drive refused it."""
    drive = model(sim, address)
    command = key_command(key)
    sim.sync()
    return drive.keypad(command)


#: The longest step :func:`advance` takes: ten years of model time.
MAX_ADVANCE = 10 * 365 * 86400


def advance(sim: Simulator, seconds: object) -> float:
    """Move a virtual clock on by ``seconds`` (finite, 0 to ten years); returns the new time."""
    step = _number("seconds", seconds, 0, MAX_ADVANCE)
    if not sim.virtual:
        raise ControlError("time runs on the wall clock; start the server with --clock virtual to advance it", 409)
    return sim.advance(step)


def power_cycle(sim: Simulator, address: int) -> None:
    drive = model(sim, address)
    sim.sync()
    drive.power_cycle()


def _links(sim: Simulator, address: int | None) -> LinkFaults:
    if address is not None:
        model(sim, address)
    return sim.link_faults(address)


def link_state(link: LinkFaults) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in fields(link):
        value = getattr(link, f.name)
        if isinstance(value, bytes):
            value = value.hex(" ").upper()
        elif isinstance(value, ExceptionCode):
            value = int(value)
        out[f.name] = value
    out["active"] = link.active
    return out


def _hex_bytes(key: str, value: object) -> bytes:
    if not isinstance(value, str):
        raise ControlError(f'{key}: expected hex bytes such as "FF 00", got {json.dumps(value)}')
    try:
        return bytes.fromhex(value)
    except ValueError:
        raise ControlError(f'{key}: {value!r} is not hex bytes such as "FF 00"') from None


def _exception_code(key: str, value: object) -> ExceptionCode | None:
    if value is None:
        return None
    if isinstance(value, str) and value.upper() in ExceptionCode.__members__:
        return ExceptionCode[value.upper()]
    number = _integer(key, value, 1, 0xFF) if not isinstance(value, str) else -1
    try:
        return ExceptionCode(number)
    except ValueError:
        codes = ", ".join(f"{c.name} ({int(c)})" for c in ExceptionCode)
        raise ControlError(f"{key}: {json.dumps(value)} is not an exception code; use one of {codes}") from None


LINK_CHECKS: Mapping[str, Callable[[str, object], object]] = {
    "offline": _flag,
    "drop_next": lambda k, v: _integer(k, v, 0, 1_000_000),
    "drop_percent": lambda k, v: _number(k, v, 0, 100),
    "delay": lambda k, v: _number(k, v, 0, 60),
    "delay_jitter": lambda k, v: _number(k, v, 0, 60),
    "corrupt_crc": _flag,
    "truncate": _flag,
    "garbage_before": _hex_bytes,
    "garbage_after": _hex_bytes,
    "wrong_address": lambda k, v: None if v is None else _integer(k, v, 0, 255),
    "forced_exception": _exception_code,
}


def check_link_faults(values: object) -> dict[str, object]:
    """Check link faults by their :data:`LINK_CHECKS` names; returns the values to set."""
    if not isinstance(values, Mapping) or not values:
        raise ControlError(
            f'give link faults as an object, such as {{"offline": true}}; known: {", ".join(LINK_CHECKS)}'
        )
    checked = {}
    for key, value in values.items():
        check = LINK_CHECKS.get(key)
        if check is None:
            raise unknown("link fault", key, LINK_CHECKS)
        checked[key] = check(key, value)
    return checked


def set_link_faults(sim: Simulator, address: int | None, values: Mapping[str, object]) -> LinkFaults:
    """Switch link faults of one drive (or the bus for None); all are checked before any is set."""
    link = _links(sim, address)
    for key, value in check_link_faults(values).items():
        setattr(link, key, value)
    return link


def clear_link_faults(sim: Simulator, address: int | None) -> LinkFaults:
    link = _links(sim, address)
    link.clear()
    return link


def frames(
    sim: Simulator, *, last: int | None = None, slave: int | None = None, since: int = 0, first_seq: int = 0
) -> list[dict[str, Any]]:
    """The frame log, oldest first, each record with its sequence number ``seq`` (from ``first_seq``).

    ``last`` keeps the newest N (N >= 1) of the records left after ``since`` and ``slave``;
    only the records kept are put in words, which is what costs.
    """
    if last is not None and (isinstance(last, bool) or last < 1):
        raise ControlError(f"last={last} must be at least 1")
    records = sim.bus.records
    skip = min(max(0, since - first_seq), len(records))
    kept = [
        (first_seq + i, record)
        for i, record in enumerate(itertools.islice(records, skip, None), start=skip)
        if slave is None or record.slave == slave
    ]
    if last is not None:
        kept = kept[-last:]
    return [{"seq": seq, **record.as_dict()} for seq, record in kept]


# --- The HTTP API.


class ControlApi:
    """The JSON API around ``sim``: ``await start(host, port)``, then ``url``; ``await close()``."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.url = ""
        self.host = ""  #: the HOST the API is bound to, for the guard's Host check
        self.frame_log: Any = None  #: serve's --log-frames writer (transport.framelog.FrameLog), for its drop count
        self._runner: web.AppRunner | None = None
        #: frames recorded since start; with the ring's length it numbers the records in the ring
        self._seen = len(sim.bus.records)
        self._unsubscribe = sim.bus.subscribe(self._count)

    def _count(self, _record: object) -> None:
        self._seen += 1

    @property
    def first_seq(self) -> int:
        return self._seen - len(self.sim.bus.records)

    async def start(self, host: str, port: int) -> None:
        from aiohttp import web

        self.host = host
        if (warning := httpguard.check_bind(host)) is not None:
            print(f"c20sim: {warning}", file=sys.stderr, flush=True)
        httpguard.quiet_logs()
        runner = web.AppRunner(make_app(self), access_log=None, **httpguard.run_app_kwargs())
        await runner.setup()
        site = httpguard.site(runner, host, port)  # a TCPSite with a connection cap and a header timeout
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            raise C20SimError(
                f"--control {f'[{host}]' if ':' in host else host}:{port}: cannot listen: {exc.strerror or exc}; choose another port (0 picks a free one)"
            ) from None
        self._runner = runner
        bound_port = next((a[1] for a in runner.addresses if isinstance(a, tuple)), port)
        shown = f"[{host}]" if ":" in host else host
        self.url = f"http://{shown}:{bound_port}"

    async def close(self) -> None:
        self._unsubscribe()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None


def make_app(api: ControlApi) -> web.Application:
    """The aiohttp application serving ``api``'s simulator."""
    from aiohttp import web

    sim = api.sim

    def reply(data: object, status: int = 200) -> web.Response:
        return web.json_response(data, status=status)

    @web.middleware
    async def errors(request: web.Request, handler: Any) -> web.StreamResponse:
        try:
            response: web.StreamResponse = await handler(request)
            return response
        except ControlError as exc:
            return reply({"error": str(exc)}, exc.status)
        except C20SimError as exc:
            return reply({"error": str(exc)}, 400)
        except web.HTTPException as exc:
            if exc.status >= 400:
                message = f"{request.method} {request.path}: {exc.reason}"
                if exc.status == 404:
                    message += "; see GET / for the routes"
                return reply({"error": message}, exc.status)
            raise
        except Exception as exc:  # a bug: say so in JSON, log the traceback, keep serving
            log.exception("control API: bug while serving %s %s", request.method, request.path)
            message = (
                f"{request.method} {request.path}: internal error ({type(exc).__name__}: {exc}); see the server's log"
            )
            return reply({"error": message}, 500)

    def not_json(name: str) -> object:
        raise ControlError(f"the body is not JSON: {name} is not a JSON number; give a finite number")

    async def body(request: web.Request) -> dict[str, Any]:
        if not request.body_exists:  # not can_read_body: the guard has read (and checked) the body already
            return {}
        text = await request.text()
        if not text.strip():
            return {}
        try:
            data = json.loads(text, parse_constant=not_json)
        except json.JSONDecodeError as exc:
            raise ControlError(f"the body is not JSON: {exc}") from None
        if not isinstance(data, dict):
            raise ControlError(f"the body must be a JSON object, not {type(data).__name__}")
        return data

    def address(request: web.Request) -> int:
        text = request.match_info["address"]
        try:
            number = int(text)
        except ValueError:
            raise ControlError(f"drive address {text!r} is not a number", status=404) from None
        model(sim, number)
        return number

    def only(data: Mapping[str, Any], *allowed: str) -> None:
        for key in data:
            if key not in allowed:
                raise unknown("field", key, list(allowed))

    async def index(request: web.Request) -> web.Response:
        sim.sync()
        return reply(
            {
                "profile": sim.profile.name,
                "drives": list(sim.drives),
                "clock": "virtual" if sim.virtual else "realtime",
                "t": sim.now(),
                "routes": ROUTES,
            }
        )

    async def get_time(request: web.Request) -> web.Response:
        return reply({"t": sim.now(), "clock": "virtual" if sim.virtual else "realtime"})

    async def post_advance(request: web.Request) -> web.Response:
        data = await body(request)
        only(data, "seconds")
        if "seconds" not in data:
            raise ControlError('give the time to advance by, such as {"seconds": 1.5}')
        return reply({"t": advance(sim, data["seconds"])})

    async def list_drives(request: web.Request) -> web.Response:
        return reply({"drives": [drive_state(sim, a) for a in sim.drives]})

    async def get_drive(request: web.Request) -> web.Response:
        return reply(drive_state(sim, address(request)))

    async def get_register(request: web.Request) -> web.Response:
        return reply(read_register(sim, address(request), request.match_info["register"]))

    async def put_conditions(request: web.Request) -> web.Response:
        where = address(request)
        set_conditions(sim, where, await body(request))
        return reply(drive_state(sim, where))

    async def post_fault(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "code", "persistent")
        if "code" not in data:
            raise ControlError('give the fault code, such as {"code": 16, "persistent": false}')
        inject_fault(sim, where, data["code"], data.get("persistent", False))
        return reply(drive_state(sim, where))

    async def delete_fault(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "reset")
        reset = data.get("reset", True)
        cleared = clear_fault(sim, where, reset)
        return reply({"reset": cleared, **drive_state(sim, where)})

    async def post_keypad(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "key")
        if "key" not in data:
            raise ControlError(f'give the key, such as {{"key": "reset"}}; keys: {", ".join(KEYPAD)}')
        accepted = press_key(sim, where, data["key"])
        return reply({"accepted": accepted, **drive_state(sim, where)})

    async def post_power_cycle(request: web.Request) -> web.Response:
        where = address(request)
        power_cycle(sim, where)
        return reply(drive_state(sim, where))

    def link_address(request: web.Request) -> int | None:
        return address(request) if "address" in request.match_info else None

    async def get_link(request: web.Request) -> web.Response:
        return reply(link_state(_links(sim, link_address(request))))

    async def patch_link(request: web.Request) -> web.Response:
        where = link_address(request)
        return reply(link_state(set_link_faults(sim, where, await body(request))))

    async def delete_link(request: web.Request) -> web.Response:
        return reply(link_state(clear_link_faults(sim, link_address(request))))

    async def get_frames(request: web.Request) -> web.Response:
        query = request.query

        def arg(name: str, low: int) -> int | None:
            if name not in query:
                return None
            try:
                value = int(query[name])
            except ValueError:
                raise ControlError(f"{name}={query[name]!r} is not a number") from None
            if value < low:
                raise ControlError(f"{name}={value} must be at least {low}")
            return value

        for key in query:
            if key not in ("last", "slave", "since"):
                raise unknown("query parameter", key, ["last", "slave", "since"])
        records = frames(
            sim,
            last=arg("last", 1),
            slave=arg("slave", 0),
            since=arg("since", 0) or 0,
            first_seq=api.first_seq,
        )
        dropped = api.frame_log.dropped if api.frame_log is not None else 0
        return reply({"frames": records, "next": api._seen, "log_dropped": dropped})

    async def delete_frames(request: web.Request) -> web.Response:
        sim.bus.records.clear()
        return reply({"frames": [], "next": api._seen})

    app = web.Application(middlewares=[*httpguard.middlewares(api.host), errors])
    r = app.router
    r.add_get("/", index)
    r.add_get("/time", get_time)
    r.add_post("/time/advance", post_advance)
    r.add_get("/drives", list_drives)
    r.add_get("/drives/{address}", get_drive)
    r.add_get("/drives/{address}/registers/{register}", get_register)
    r.add_put("/drives/{address}/conditions", put_conditions)
    r.add_patch("/drives/{address}/conditions", put_conditions)
    r.add_post("/drives/{address}/fault", post_fault)
    r.add_delete("/drives/{address}/fault", delete_fault)
    r.add_post("/drives/{address}/keypad", post_keypad)
    r.add_post("/drives/{address}/power-cycle", post_power_cycle)
    r.add_get("/drives/{address}/link", get_link)
    r.add_patch("/drives/{address}/link", patch_link)
    r.add_delete("/drives/{address}/link", delete_link)
    r.add_get("/link", get_link)
    r.add_patch("/link", patch_link)
    r.add_delete("/link", delete_link)
    r.add_get("/frames", get_frames)
    r.add_delete("/frames", delete_frames)
    return app


#: The routes, for GET / and the docs: method path -> body.
ROUTES: Mapping[str, str] = {
    "GET /": "-",
    "GET /time": "-",
    "POST /time/advance": '{"seconds": 1.5} (virtual clock only; 409 otherwise)',
    "GET /drives": "-",
    "GET /drives/{address}": "-",
    "GET /drives/{address}/registers/{register}": "- (register: 2100H, 0x2100, F00.10 or status1)",
    "PUT /drives/{address}/conditions": '{"supply_v": 30, "load_torque_nm": 2, ...} (PATCH too)',
    "POST /drives/{address}/fault": '{"code": 16, "persistent": false}',
    "DELETE /drives/{address}/fault": '{"reset": true} (optional)',
    "POST /drives/{address}/keypad": '{"key": "reset"} (forward, reverse, stop, free_stop, reset, ...)',
    "POST /drives/{address}/power-cycle": "-",
    "GET /drives/{address}/link": "-",
    "PATCH /drives/{address}/link": '{"offline": true, "drop_next": 2, "delay": 0.5, ...}',
    "DELETE /drives/{address}/link": "- (clears every link fault of the drive)",
    "GET /link": "- (the whole bus's link faults; PATCH and DELETE as for a drive)",
    "GET /frames": "- (query: last=N (N >= 1), slave=N, since=SEQ); log_dropped: records --log-frames lost",
    "DELETE /frames": "- (empties the frame log)",
}


# --- ``c20sim ctl``: the API from a shell, with the standard library only.


def _ctl_url(args: argparse.Namespace) -> str:
    if args.url:
        from urllib.parse import urlsplit

        given = str(args.url).rstrip("/")
        try:
            parts = urlsplit(given)
            valid = parts.scheme in ("http", "https") and bool(parts.hostname) and parts.port is not None
        except ValueError:
            valid = False
        if not valid:
            raise C20SimError(
                f"--url {args.url!r}: give the API's address as http://HOST:PORT, such as http://127.0.0.1:8020"
            )
        return given
    if args.ready_file:
        try:
            data = json.loads(Path(args.ready_file).read_text())
        except OSError as exc:
            raise C20SimError(f"--ready-file {args.ready_file}: cannot read: {exc.strerror}") from None
        except json.JSONDecodeError:
            raise C20SimError(f"--ready-file {args.ready_file}: not JSON; is it the file serve wrote?") from None
        url = data.get("control") if isinstance(data, dict) else None
        if not isinstance(url, str):
            raise C20SimError(
                f"--ready-file {args.ready_file}: no control address; start the server with --control 127.0.0.1:0"
            )
        return url.rstrip("/")
    raise C20SimError("give the API's address: --url http://HOST:PORT or --ready-file PATH (from serve --ready-file)")


def call(url: str, method: str, path: str, data: object = None, timeout: float = 10.0) -> Any:
    """One API request with urllib; a 4xx/5xx answer raises C20SimError with the API's error message."""
    import urllib.error
    import urllib.request

    payload = json.dumps(data).encode() if data is not None else None
    request = urllib.request.Request(url + path, data=payload, method=method)
    if method != "GET":  # the API takes state changes only as JSON, even without a body
        request.add_header("Content-Type", "application/json")
    try:
        with urllib.request.urlopen(request, timeout=timeout) as response:
            return json.loads(response.read() or b"null")
    except urllib.error.HTTPError as exc:
        text = exc.read().decode(errors="replace")
        try:
            message = json.loads(text)["error"]
        except (ValueError, KeyError, TypeError):
            message = text.strip() or exc.reason
        raise C20SimError(f"{method} {path}: {exc.code}: {message}") from None
    except urllib.error.URLError as exc:
        raise C20SimError(
            f"{url}: cannot reach the control API ({exc.reason}); is c20sim serve --control running?"
        ) from None


def _pairs(words: list[str]) -> dict[str, object]:
    """``supply_v=30 hall_fault=stuck0 offline=true`` -> values, each read as JSON where it parses."""
    out: dict[str, object] = {}
    for word in words:
        key, eq, text = word.partition("=")
        if not eq or not key:
            raise C20SimError(f"{word!r}: give KEY=VALUE, such as supply_v=30")
        try:
            out[key] = json.loads(text)
        except json.JSONDecodeError:
            out[key] = text
    return out


def _at_least_one(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} must be at least 1")
    return value


def cmd_ctl(args: argparse.Namespace) -> int:
    url = _ctl_url(args)
    action: str = args.action
    drive = args.drive
    if drive is None and action not in ("time", "advance", "frames", "info", "link"):
        drive = call(url, "GET", "/")["drives"][0]
    at = f"/drives/{drive}"
    result: Any
    if action == "info":
        result = call(url, "GET", "/")
    elif action == "state":
        result = call(url, "GET", at if args.drive is not None else "/drives")
    elif action == "read":
        result = call(url, "GET", f"{at}/registers/{args.register}")
    elif action == "set":
        result = call(url, "PUT", f"{at}/conditions", _pairs(args.values))
    elif action == "fault":
        result = call(url, "POST", f"{at}/fault", {"code": args.code, "persistent": args.persistent})
    elif action == "clear":
        result = call(url, "DELETE", f"{at}/fault", {"reset": not args.no_reset})
    elif action == "key":
        key: object = int(args.key) if args.key.isdigit() else args.key
        result = call(url, "POST", f"{at}/keypad", {"key": key})
    elif action == "power-cycle":
        result = call(url, "POST", f"{at}/power-cycle")
    elif action == "link":
        where = f"/drives/{drive}/link" if drive is not None else "/link"
        if args.clear:
            result = call(url, "DELETE", where)
        elif args.values:
            result = call(url, "PATCH", where, _pairs(args.values))
        else:
            result = call(url, "GET", where)
    elif action == "advance":
        result = call(url, "POST", "/time/advance", {"seconds": args.seconds})
    elif action == "time":
        result = call(url, "GET", "/time")
    else:  # frames
        query = "&".join(f"{k}={v}" for k, v in (("last", args.last), ("slave", args.slave)) if v is not None)
        result = call(url, "GET", "/frames" + (f"?{query}" if query else ""))
        if not args.json:
            for record in result["frames"]:
                note = f"  ({record['note']})" if record["note"] else ""
                print(f"{record['t']:>12.6f} {record['dir']} {record['hex']:<26} {record['text']}{note}")
            return 0
    print(json.dumps(result, indent=2))
    return 0


def add_ctl_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """``c20sim ctl``: the subcommand and its actions."""
    ctl = sub.add_parser(
        "ctl",
        help="call a running server's control API (serve --control)",
        description="Call the control API of c20sim serve --control HOST:PORT; prints the JSON answer.",
    )
    where = ctl.add_mutually_exclusive_group()
    where.add_argument("--url", help="the API's address, such as http://127.0.0.1:8020")
    where.add_argument("--ready-file", metavar="PATH", help="read the API's address from serve's ready file")
    ctl.add_argument("--drive", type=int, metavar="N", help="drive address (default: the first drive)")
    # --drive is taken before or after the action; after, it must not reset the value given before
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--drive", type=int, metavar="N", default=argparse.SUPPRESS, help="drive address")
    actions = ctl.add_subparsers(dest="action", metavar="ACTION", required=True)

    def action(name: str, help: str) -> argparse.ArgumentParser:
        return actions.add_parser(name, help=help, parents=[common])

    action("info", help="profile, drives, clock and the API's routes")
    action("state", help="a drive's telemetry (every drive without --drive)")
    read = action("read", help="read a register: 2100H, 0x2100, F00.10 or status1")
    read.add_argument("register")
    conditions = action("set", help=f"set conditions: {', '.join(CONDITIONS)}")
    conditions.add_argument("values", nargs="+", metavar="KEY=VALUE")
    fault = action("fault", help="inject a device fault by code")
    fault.add_argument("code", type=int)
    fault.add_argument("--persistent", action="store_true", help="a reset fails until the fault is cleared")
    clear = action("clear", help="clear an injected fault and press reset")
    clear.add_argument("--no-reset", action="store_true", help="release the cause only")
    key = action("key", help=f"press a keypad key: {', '.join(KEYPAD)}")
    key.add_argument("key")
    action("power-cycle", help="switch the drive off and on")
    link = action("link", help="show, set (KEY=VALUE) or --clear link faults (the bus without --drive)")
    link.add_argument("values", nargs="*", metavar="KEY=VALUE")
    link.add_argument("--clear", action="store_true")
    advance = action("advance", help="advance virtual time (serve --clock virtual)")
    advance.add_argument("seconds", type=float)
    action("time", help="the model's time")
    log = action("frames", help="the frame log")
    log.add_argument("--last", type=_at_least_one, metavar="N", help="only the newest N frames (N >= 1)")
    log.add_argument("--slave", type=int, metavar="N")
    log.add_argument("--json", action="store_true", help="print JSON, not one line per frame")
    ctl.set_defaults(func=cmd_ctl)

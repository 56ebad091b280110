"""The control API: the operations (:mod:`c20sim.control.ops`) served as JSON over HTTP.

``c20sim serve --control HOST:PORT``. Each route is one operation, with the
operation's own checks; a :class:`~c20sim.control.ops.ControlError` becomes
its status and a JSON ``{"error": ...}``. Handlers run on the serving loop,
the same thread that serves Modbus, so a request never sees a drive half-way
through a frame. This is the only module that imports aiohttp, and only when
the API is started: it is the slowest import of the package.
"""

from __future__ import annotations

import json
import logging
import sys
from collections.abc import Mapping
from typing import Any

from aiohttp import web

from .. import httpguard
from ..errors import C20SimError
from ..simulator import Simulator
from . import causes, ops, service
from .ops import ControlError, unknown

log = logging.getLogger(__name__)

__all__ = ["ROUTES", "ControlApi", "make_app"]


# --- The HTTP API.


class ControlApi:
    """The JSON API around ``sim``: ``await start(host, port)``, then ``url``; ``await close()``."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.url = ""
        self.host = ""  #: the HOST the API is bound to, for the guard's Host check
        self.frame_log: Any = None  #: serve's --log-frames writer (transport.framelog.FrameLog), for its drop count
        self._runner: web.AppRunner | None = None
        #: set by the server once every endpoint is up: GET /health answers 200 from then on
        self.serving = False
        #: frames recorded since start; with the ring's length it numbers the records in the ring
        self._seen = len(sim.bus.records)
        self._unsubscribe = sim.bus.subscribe(self._count)

    def _count(self, _record: object) -> None:
        self._seen += 1

    @property
    def first_seq(self) -> int:
        return self._seen - len(self.sim.bus.records)

    async def start(self, host: str, port: int) -> None:
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
    sim = api.sim

    def reply(data: object, status: int = 200) -> web.Response:
        return web.json_response(data, status=status)

    @web.middleware
    async def errors(request: web.Request, handler: Any) -> web.StreamResponse:
        try:
            response: web.StreamResponse = await handler(request)
            return response
        except ControlError as exc:
            body: dict[str, object] = {"error": str(exc)}
            if exc.exception is not None:
                body["exception"] = exc.exception
            return reply(body, exc.status)
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
        ops.drive(sim, number)
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
        return reply({"t": ops.advance(sim, data["seconds"])})

    async def list_drives(request: web.Request) -> web.Response:
        return reply({"drives": [ops.drive_state(sim, a) for a in sim.drives]})

    async def get_drive(request: web.Request) -> web.Response:
        return reply(ops.drive_state(sim, address(request)))

    async def get_register(request: web.Request) -> web.Response:
        return reply(ops.read_register(sim, address(request), request.match_info["register"]))

    async def put_register(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "value")
        if "value" not in data:
            raise ControlError('give the raw value, such as {"value": 1500}')
        return reply(ops.write_register(sim, where, request.match_info["register"], data["value"]))

    async def list_registers(request: web.Request) -> web.Response:
        return reply({"registers": ops.registers(sim, address(request))})

    async def get_counters(request: web.Request) -> web.Response:
        return reply(ops.counters(sim, address(request)))

    async def put_conditions(request: web.Request) -> web.Response:
        where = address(request)
        ops.set_conditions(sim, where, await body(request))
        return reply(ops.drive_state(sim, where))

    async def post_fault(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "code", "persistent", "cause")
        if "cause" in data:
            only(data, "cause")
            causes.trip(sim, where, data["cause"])
        elif "code" in data:
            ops.inject_fault(sim, where, data["code"], data.get("persistent", False))
        else:
            raise ControlError(
                'give the fault by cause, such as {"cause": "undervoltage"}, or by code, such as {"code": 16}; '
                f"causes: {', '.join(causes.cause_names(sim.profile))}"
            )
        return reply(ops.drive_state(sim, where))

    async def delete_fault(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "reset", "cause")
        reset = data.get("reset", True)
        if "cause" in data:
            causes.release(sim, where, data["cause"])
            cleared = ops.clear_fault(sim, where, reset) if ops.flag("reset", reset) else False
        else:
            cleared = ops.clear_fault(sim, where, reset)
        return reply({"reset": cleared, **ops.drive_state(sim, where)})

    async def get_causes(request: web.Request) -> web.Response:
        return reply({"causes": causes.active(sim, address(request))})

    async def post_keypad(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "key")
        if "key" not in data:
            raise ControlError(f'give the key, such as {{"key": "reset"}}; keys: {", ".join(ops.KEYS)}')
        accepted = ops.press_key(sim, where, data["key"])
        return reply({"accepted": accepted, **ops.drive_state(sim, where)})

    async def post_power_cycle(request: web.Request) -> web.Response:
        where = address(request)
        ops.power_cycle(sim, where)
        return reply(ops.drive_state(sim, where))

    def link_address(request: web.Request) -> int | None:
        return address(request) if "address" in request.match_info else None

    async def get_link(request: web.Request) -> web.Response:
        return reply(ops.link_state(ops.links(sim, link_address(request))))

    async def patch_link(request: web.Request) -> web.Response:
        where = link_address(request)
        return reply(ops.link_state(ops.set_link_faults(sim, where, await body(request))))

    async def delete_link(request: web.Request) -> web.Response:
        return reply(ops.link_state(ops.clear_link_faults(sim, link_address(request))))

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
        records = ops.frames(
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
    r.add_get("/drives/{address}/registers", list_registers)
    r.add_get("/drives/{address}/registers/{register}", get_register)
    r.add_put("/drives/{address}/registers/{register}", put_register)
    r.add_get("/drives/{address}/counters", get_counters)
    r.add_put("/drives/{address}/conditions", put_conditions)
    r.add_patch("/drives/{address}/conditions", put_conditions)
    r.add_post("/drives/{address}/fault", post_fault)
    r.add_delete("/drives/{address}/fault", delete_fault)
    r.add_get("/drives/{address}/causes", get_causes)
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
    service.add_routes(app, api, body=body, address=address, only=only)
    return app


#: The routes, for GET / and the docs: method path -> body.
ROUTES: Mapping[str, str] = {
    "GET /": "-",
    "GET /time": "-",
    "POST /time/advance": '{"seconds": 1.5} (virtual clock only; 409 otherwise)',
    "GET /drives": "-",
    "GET /drives/{address}": "-",
    "GET /drives/{address}/registers": "- (every register and function code, grouped as the sheet groups them)",
    "GET /drives/{address}/registers/{register}": "- (register: 2100H, 0x2100, F00.10 or status1)",
    "PUT /drives/{address}/registers/{register}": '{"value": 1500} (a master\'s rules; a refusal is 409 with its exception)',
    "GET /drives/{address}/counters": "- (requests, replies, exceptions by code, CRC errors, silences, injected)",
    "PUT /drives/{address}/conditions": '{"supply_v": 30, "load_torque_nm": 2, ...} (PATCH too)',
    "POST /drives/{address}/fault": '{"cause": "undervoltage"} or {"code": 16, "persistent": false}',
    "DELETE /drives/{address}/fault": '{"reset": true, "cause": "undervoltage"} (both optional)',
    "GET /drives/{address}/causes": "- (every fault cause of the profile: whether it is there now)",
    "POST /drives/{address}/keypad": '{"key": "reset"} (forward, reverse, stop, free_stop, reset, ...)',
    "POST /drives/{address}/power-cycle": "-",
    "GET /drives/{address}/link": "-",
    "PATCH /drives/{address}/link": '{"offline": true, "drop_next": 2, "delay": 0.5, ...}',
    "DELETE /drives/{address}/link": "- (clears every link fault of the drive)",
    "GET /link": "- (the whole bus's link faults; PATCH and DELETE as for a drive)",
    "GET /frames": "- (query: last=N (N >= 1), slave=N, since=SEQ); log_dropped: records --log-frames lost",
    "DELETE /frames": "- (empties the frame log)",
}
ROUTES = {**ROUTES, **service.ROUTES}

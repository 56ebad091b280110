"""The control API: the operations (:mod:`c20sim.control.ops`) served as JSON over HTTP.

``c20sim serve --control HOST:PORT``. Each route is one operation, with the
operation's own checks; a :class:`~c20sim.control.ops.ControlError` becomes
its status and a JSON ``{"error": ...}``. Handlers run on the serving loop,
the same thread that serves Modbus, so a request never sees a drive half-way
through a frame. This is the only module that imports aiohttp, and only when
the API is started: it is the slowest import of the package.

``GET /stream`` is a WebSocket of telemetry (at ``?hz=``) and frame records
(each with its sequence number ``seq``). Each client has a bounded buffer of
frames and one slot of telemetry: a client that reads slowly, or not at all,
skips frames and is told how many (``missed``); it never holds the serving
loop or a reply. With a token (``--control-token``, or generated for a listener
beyond loopback) every request must carry it (``Authorization: Bearer TOKEN``,
or ``?token=`` where a header cannot be set, as for a browser's WebSocket);
without it the answer is 401.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import math
import secrets
import sys
from collections import deque
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from aiohttp import web

from ..core.bus import FrameRecord
from ..core.simulator import Simulator
from ..transport.wallclock import WALL_OFFSET
from ..wire.errors import C20SimError
from ..wire.registers import Reg
from . import causes, httpguard, ops, service
from .ops import ControlError, unknown

log = logging.getLogger(__name__)

__all__ = ["ROUTES", "ControlApi", "is_loopback", "make_app", "new_token", "snapshot"]

#: The telemetry rates a stream client may ask for (``?hz=``), and the default.
STREAM_HZ = (0.1, 50.0)
DEFAULT_HZ = 5.0
#: A stream client's frame buffer (``?buffer=``): at most this many frames wait for it; older ones are skipped.
STREAM_BUFFER = (1, 10_000)
DEFAULT_BUFFER = 1000
#: Stream readers at once: each costs a buffer and a sender; beyond this the answer is 503.
MAX_STREAMS = 32
#: The query parameters of ``GET /stream``.
STREAM_QUERY = ("hz", "frame_hz", "buffer", "frames", "token")
#: Frame batches a second a client may ask for (``?frame_hz=``), and the default: a busy bus costs a reader at
#: most ``buffer`` frames a batch.
FRAME_HZ = (0.1, 100.0)
DEFAULT_FRAME_HZ = 20.0
#: Frames put in words per turn of the loop: a big batch is cut so that a request waits for no more than one chunk.
CHUNK = 32


def is_loopback(host: str) -> bool:
    """Whether ``host`` is reachable only from this machine (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A fresh random token for a control API beyond loopback."""
    return secrets.token_urlsafe(24)


#: Registers the stream adds to each drive's telemetry, by the names the dashboard reads.
SNAPSHOT_REGISTERS: Mapping[str, Reg] = {
    "status2": Reg.STATUS2,
    "output_frequency": Reg.OUTPUT_FREQUENCY,
    "set_frequency": Reg.SET_FREQUENCY,
}


def snapshot(sim: Simulator) -> dict[str, Any]:
    """Every drive's state now (telemetry, conditions, causes, link faults, a few registers) and the bus's link
    faults: one telemetry message of the stream, and ``GET /telemetry``."""
    sim.sync()
    drives = []
    for address, found in sim.drives.items():
        state = ops.drive_state(sim, address)
        state["held_fault"] = ops.held_fault(sim, address)
        state["causes"] = causes.active(sim, address)
        state["registers"] = {name: found.read(int(reg)) for name, reg in SNAPSHOT_REGISTERS.items()}
        drives.append(state)
    clock = ops.clock_state(sim)
    return {
        "type": "telemetry",
        "t": sim.now(),
        "speed": clock["speed"],
        "paused": clock["paused"],
        "drives": drives,
        "link": ops.link_state(sim.link_faults(None)),
        "notices": list(sim.notices),
    }


class StreamClient:
    """One stream reader: a bounded buffer of frames (the oldest skipped when full) and a wake-up."""

    def __init__(self, buffer: int) -> None:
        self.frames: deque[tuple[int, FrameRecord]] = deque(maxlen=buffer)
        self.wake = asyncio.Event()
        self.sent = -1  #: the seq of the last frame sent (or skipped past)

    def push(self, seq: int, record: FrameRecord) -> None:
        self.frames.append((seq, record))  # a full deque drops its oldest: that is the skip
        if not self.wake.is_set():
            self.wake.set()


# --- The HTTP API.


class ControlApi:
    """The JSON API around ``sim``: ``await start(host, port)``, then ``url``; ``await close()``."""

    def __init__(
        self,
        sim: Simulator,
        *,
        token: str | None = None,
        endpoints: Callable[[], dict[str, str]] | None = None,
    ) -> None:
        self.sim = sim
        self.url = ""
        self.host = ""  #: the HOST the API is bound to, for the guard's Host check
        self.frame_log: Any = None  #: serve's --log-frames writer (transport.framelog.FrameLog), for its drop count
        #: the token every request must carry, or None (loopback without --control-token)
        self.token = token
        #: where masters connect (the ready file's endpoints), shown by GET / for a dashboard's title
        self.endpoints = endpoints or dict
        self._runner: web.AppRunner | None = None
        #: set by the server once every endpoint is up: GET /health answers 200 from then on
        self.serving = False
        #: frames recorded since start; with the ring's length it numbers the records in the ring
        self._seen = len(sim.bus.records)
        self._unsubscribe = sim.bus.subscribe(self._count)
        self.streams: set[StreamClient] = set()
        self.closing = False
        #: stream readers attached now (with frames or not)
        self.readers = 0
        #: telemetry snapshots made so far: numbers them, so a client can tell the newest
        self.snapshots = 0

    def _count(self, record: FrameRecord) -> None:
        seq = self._seen
        self._seen += 1
        for client in self.streams:
            client.push(seq, record)

    def snapshot(self) -> dict[str, Any]:
        self.snapshots += 1
        dropped = self.frame_log.dropped if self.frame_log is not None else 0  # --log-frames records lost
        return {**snapshot(self.sim), "n": self.snapshots, "log_dropped": dropped}

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
        self.closing = True  # the streams end first: a server stopping waits for no viewer
        self._unsubscribe()
        for client in self.streams:
            client.wake.set()
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

    @web.middleware
    async def token(request: web.Request, handler: Any) -> web.StreamResponse:
        if api.token is not None:
            given = request.query.get("token", "")
            header = request.headers.get("Authorization", "")
            if header.startswith("Bearer "):
                given = header.removeprefix("Bearer ").strip()
            if not hmac.compare_digest(given.encode(), api.token.encode()):
                why = "a wrong token" if given else "no token"
                return reply(
                    {
                        "error": f"{request.method} {request.path}: {why}; this control API needs its token: "
                        "send Authorization: Bearer TOKEN (the token is in the server's ready file)"
                    },
                    401,
                )
        response: web.StreamResponse = await handler(request)
        return response

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
                "endpoints": api.endpoints(),
                "stream_readers": api.readers,
                "routes": ROUTES,
            }
        )

    async def get_telemetry(request: web.Request) -> web.Response:
        return reply(api.snapshot())

    async def get_profile(request: web.Request) -> web.Response:
        path = sim.profile.path
        if path is None:
            raise ControlError(f"the profile {sim.profile.name} was not loaded from a file", status=404)
        return web.Response(text=Path(path).read_text(encoding="utf-8"), content_type="application/toml")

    def query_number(request: web.Request, name: str, default: float, bounds: tuple[float, float]) -> float:
        if name not in request.query:
            return default
        text = request.query[name]
        try:
            value = float(text)
        except ValueError:
            raise ControlError(f"{name}={text!r} is not a number; give {bounds[0]:g}-{bounds[1]:g}") from None
        if not bounds[0] <= value <= bounds[1]:
            raise ControlError(f"{name}={text}: outside {bounds[0]:g}-{bounds[1]:g}")
        return value

    async def stream(request: web.Request) -> web.StreamResponse:
        for key in request.query:
            if key not in STREAM_QUERY:
                raise unknown("query parameter", key, STREAM_QUERY)
        hz = query_number(request, "hz", DEFAULT_HZ, STREAM_HZ)
        frame_period = 1.0 / query_number(request, "frame_hz", DEFAULT_FRAME_HZ, FRAME_HZ)
        size = int(query_number(request, "buffer", DEFAULT_BUFFER, STREAM_BUFFER))
        with_frames = request.query.get("frames", "1") not in ("0", "false", "no")
        if api.readers >= MAX_STREAMS:
            raise ControlError(f"{MAX_STREAMS} stream readers are attached already; close one first", status=503)
        # no compression: it would cost the serving loop CPU per message; a peer gone quiet delays a close by 1 s
        ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096, compress=False, timeout=1.0)
        client = StreamClient(size)
        api.readers += 1  # counted from here: the upgrade below awaits, and others may come meanwhile
        try:
            await ws.prepare(request)
            client.sent = api._seen - 1
            if with_frames:
                api.streams.add(client)
            # what the client sends is read (and ignored) beside the sender; it ends when the client goes
            reader: asyncio.Future[Any] = asyncio.ensure_future(_drain(ws))
            try:
                await _serve_stream(api, ws, client, 1.0 / hz, frame_period, reader)
            except ConnectionResetError:
                pass  # the reader went away mid-message: it has left, nothing else to do
            finally:
                reader.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await reader  # the close below reads the peer's answer itself
                await ws.close()
        finally:
            api.readers -= 1
            api.streams.discard(client)
        return ws

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

    async def register_write(request: web.Request) -> tuple[int, str, object]:
        """(drive, register, value) of a register write's route and body ``{"value": N}``."""
        where = address(request)
        data = await body(request)
        only(data, "value")
        if "value" not in data:
            raise ControlError('give the raw value, such as {"value": 1500}')
        return where, request.match_info["register"], data["value"]

    async def put_register(request: web.Request) -> web.Response:
        return reply(ops.write_register(sim, *await register_write(request)))

    async def put_panel(request: web.Request) -> web.Response:
        return reply(ops.keypad_edit(sim, *await register_write(request)))

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
        note = ""
        if "cause" in data:
            only(data, "cause")
            note = causes.trip(sim, where, data["cause"])
        elif "code" in data:
            ops.inject_fault(sim, where, data["code"], data.get("persistent", False))
        else:
            raise ControlError(
                'give the fault by cause, such as {"cause": "undervoltage"}, or by code, such as {"code": 16}; '
                f"causes: {', '.join(causes.cause_names(sim.profile))}"
            )
        return reply({"note": note, **ops.drive_state(sim, where)})

    async def delete_fault(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "reset", "cause")
        reset = data.get("reset", True)
        note = ""
        if "cause" in data:
            note = causes.release(sim, where, data["cause"])
            cleared = ops.clear_fault(sim, where, reset) if ops.flag("reset", reset) else False
        else:
            cleared = ops.clear_fault(sim, where, reset)
        return reply({"reset": cleared, "note": note, **ops.drive_state(sim, where)})

    async def get_causes(request: web.Request) -> web.Response:
        return reply({"causes": causes.active(sim, address(request))})

    async def delete_causes(request: web.Request) -> web.Response:
        where = address(request)
        causes.clear_all(sim, where)
        return reply({"causes": causes.active(sim, where)})

    async def post_run_channel(request: web.Request) -> web.Response:
        where = address(request)
        data = await body(request)
        only(data, "channel")
        if "channel" not in data:
            raise ControlError('give the run channel, such as {"channel": "keypad"} or {"channel": 0}')
        channel = ops.set_run_channel(sim, where, data["channel"])
        return reply({"channel": int(channel), **ops.drive_state(sim, where)})

    async def post_restore_defaults(request: web.Request) -> web.Response:
        where = address(request)
        ops.restore_defaults(sim, where)
        return reply(ops.drive_state(sim, where))

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
            wall_offset=WALL_OFFSET,
        )
        dropped = api.frame_log.dropped if api.frame_log is not None else 0
        return reply({"frames": records, "next": api._seen, "log_dropped": dropped})

    async def delete_frames(request: web.Request) -> web.Response:
        sim.bus.records.clear()
        return reply({"frames": [], "next": api._seen})

    app = web.Application(middlewares=[*httpguard.middlewares(api.host), errors, token])
    r = app.router
    r.add_get("/", index)
    r.add_get("/telemetry", get_telemetry)
    r.add_get("/profile", get_profile)
    r.add_get("/stream", stream)
    r.add_get("/time", get_time)
    r.add_post("/time/advance", post_advance)
    r.add_get("/drives", list_drives)
    r.add_get("/drives/{address}", get_drive)
    r.add_get("/drives/{address}/registers", list_registers)
    r.add_get("/drives/{address}/registers/{register}", get_register)
    r.add_put("/drives/{address}/registers/{register}", put_register)
    r.add_get("/drives/{address}/counters", get_counters)
    r.add_put("/drives/{address}/panel/{register}", put_panel)
    r.add_put("/drives/{address}/conditions", put_conditions)
    r.add_patch("/drives/{address}/conditions", put_conditions)
    r.add_post("/drives/{address}/fault", post_fault)
    r.add_delete("/drives/{address}/fault", delete_fault)
    r.add_get("/drives/{address}/causes", get_causes)
    r.add_post("/drives/{address}/keypad", post_keypad)
    r.add_post("/drives/{address}/power-cycle", post_power_cycle)
    r.add_delete("/drives/{address}/causes", delete_causes)
    r.add_post("/drives/{address}/run-channel", post_run_channel)
    r.add_post("/drives/{address}/restore-defaults", post_restore_defaults)
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


async def _drain(ws: web.WebSocketResponse) -> None:
    async for _message in ws:
        pass


async def _serve_stream(
    api: ControlApi,
    ws: web.WebSocketResponse,
    client: StreamClient,
    period: float,
    frame_period: float,
    reader: asyncio.Future[Any],
) -> None:
    """Send telemetry every ``period`` and the frames as they come, until the client goes or the API closes.

    Sending waits for the client (a full socket holds this task only); meanwhile its frame buffer fills and
    the oldest frames are skipped, counted in the next message's ``missed``.
    """
    loop = asyncio.get_running_loop()
    due = frames_due = loop.time()
    while not ws.closed and not reader.done() and not api.closing:
        now = loop.time()
        if now >= due:
            await ws.send_str(json.dumps(api.snapshot()))
            due = _next_beat(due, period, loop.time())
            continue
        if client.frames and now >= frames_due:
            await _send_frames(ws, client)
            frames_due = _next_beat(frames_due, frame_period, loop.time())
            continue
        waits: list[asyncio.Future[Any]] = [reader]
        if client.frames:  # frames wait for their beat: more of them coming need not wake this task
            wake_at = min(due, frames_due)
        else:
            wake_at = due
            client.wake.clear()
            waits.append(asyncio.ensure_future(client.wake.wait()))
        await asyncio.wait(waits, timeout=max(0.0, wake_at - now), return_when=asyncio.FIRST_COMPLETED)
        for wait in waits[1:]:
            wait.cancel()


def _next_beat(last: float, period: float, now: float) -> float:
    """The first beat after ``now`` of a clock that ticked at ``last`` every ``period``: telemetry and frames asked
    for at the same rate go out together (one redraw for a viewer), and a late tick is not made up for."""
    return last + period * (math.floor((now - last) / period) + 1)


async def _send_frames(ws: web.WebSocketResponse, client: StreamClient) -> None:
    """The frames waiting, in words, as one message; ``missed``: how many were skipped since the last one."""
    batch: list[tuple[int, FrameRecord]] = []
    while client.frames:
        batch.append(client.frames.popleft())
    missed = batch[0][0] - client.sent - 1
    client.sent = batch[-1][0]
    records: list[dict[str, Any]] = []
    for start in range(0, len(batch), CHUNK):
        if start:
            await asyncio.sleep(0)  # let a request in between chunks
        records += [{"seq": seq, **record.as_dict(WALL_OFFSET)} for seq, record in batch[start : start + CHUNK]]
    await ws.send_str(json.dumps({"type": "frames", "missed": max(0, missed), "frames": records}))


#: The routes, for GET / and the docs: method path -> body.
ROUTES: Mapping[str, str] = {
    "GET /": "-",
    "GET /telemetry": "- (every drive's telemetry, conditions, causes and link faults: one stream message)",
    "GET /profile": "- (the served profile's TOML)",
    "GET /stream": "WebSocket (query: hz=0.1-50, frame_hz=0.1-100, buffer=1-10000, frames=0|1): telemetry, frames",
    "GET /time": "-",
    "POST /time/advance": '{"seconds": 1.5} (virtual clock only; 409 otherwise)',
    "GET /drives": "-",
    "GET /drives/{address}": "-",
    "GET /drives/{address}/registers": "- (every register and function code, grouped as the sheet groups them)",
    "GET /drives/{address}/registers/{register}": "- (register: 2100H, 0x2100, F00.10 or status1)",
    "PUT /drives/{address}/registers/{register}": '{"value": 1500} (a master\'s rules; a refusal is 409 with its exception)',
    "PUT /drives/{address}/panel/{register}": "{\"value\": 3} (the drive's own panel: a master's rules but 200EH and the password)",
    "GET /drives/{address}/counters": "- (requests, replies, exceptions by code, CRC errors, silences, injected)",
    "PUT /drives/{address}/conditions": '{"supply_v": 30, "load_torque_nm": 2, ...} (PATCH too)',
    "POST /drives/{address}/fault": '{"cause": "undervoltage"} or {"code": 16, "persistent": false}',
    "DELETE /drives/{address}/fault": '{"reset": true, "cause": "undervoltage"} (both optional)',
    "GET /drives/{address}/causes": "- (every fault cause of the profile: whether it is there now)",
    "POST /drives/{address}/keypad": '{"key": "reset"} (forward, reverse, stop, free_stop, reset, ...)',
    "POST /drives/{address}/power-cycle": "-",
    "DELETE /drives/{address}/causes": "- (ends every fault cause; faults stay until reset)",
    "POST /drives/{address}/run-channel": '{"channel": "keypad"} (F00.01 from the panel: a channel name or its number)',
    "POST /drives/{address}/restore-defaults": "- (200FH = 1 from the panel; 409 while running)",
    "GET /drives/{address}/link": "-",
    "PATCH /drives/{address}/link": '{"offline": true, "drop_next": 2, "delay": 0.5, ...}',
    "DELETE /drives/{address}/link": "- (clears every link fault of the drive)",
    "GET /link": "- (the whole bus's link faults; PATCH and DELETE as for a drive)",
    "GET /frames": "- (query: last=N (N >= 1), slave=N, since=SEQ); log_dropped: records --log-frames lost",
    "DELETE /frames": "- (empties the frame log)",
}
ROUTES = {**ROUTES, **service.ROUTES}

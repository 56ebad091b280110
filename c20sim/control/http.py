"""The control API: the operations (:mod:`c20sim.control.ops`) served as JSON over HTTP.

``c20sim serve --control HOST:PORT``. Each route is one operation, with the
operation's own checks; a :class:`~c20sim.control.ops.ControlError` becomes
its status and a JSON ``{"error": ...}``. Handlers run on the serving loop,
the same thread that serves Modbus, so a request never sees a drive half-way
through a frame. This module and the ones it serves each kind of row with
are the control API's aiohttp servers (imported only when the API is
started: the slowest import of the package; ``c20sim web`` serves its page on
aiohttp too, from tui/web.py): httpbody.py (every row with an operation),
httpserved.py (the service rows the API answers itself), httpstream.py
(``GET /stream``, a WebSocket of telemetry and frame records, each reader
with a bounded buffer; ``GET``/``DELETE /frames``); httpguard.py guards them.

With a token (``--control-token``, or generated for a listener
beyond loopback) every request must carry it (``Authorization: Bearer TOKEN``,
or ``?token=`` where a header cannot be set, as for a browser's WebSocket);
without it the answer is 401.
"""

from __future__ import annotations

import errno
import hmac
import ipaddress
import logging
import secrets
import sys
from collections.abc import Callable, Mapping
from typing import Any

from aiohttp import web
from aiohttp.typedefs import Middleware

from ..core.bus import FrameRecord
from ..core.simulator import Simulator
from ..transport.line import Line
from ..wire.errors import C20SimError
from ..wire.registers import Reg
from . import causes, httpguard, httpserved, httpstream, liveaudit, ops, routes
from .httpbody import Handler, operation, reply
from .httpstream import StreamClient
from .ops import ControlError
from .scrapes import Scrapes

log = logging.getLogger(__name__)

__all__ = ["ROUTES", "ControlApi", "is_loopback", "make_app", "new_token", "snapshot"]


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
    audit = liveaudit.of(sim)
    return {
        "type": "telemetry",
        "t": sim.now(),
        "speed": clock["speed"],
        "paused": clock["paused"],
        "drives": drives,
        "link": ops.link_state(sim.link_faults(None)),
        "audit": None if audit is None else audit.summary(),
        "notices": list(sim.notices),
    }


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
        self.any_host = False  #: answer any Host (the read-only --metrics listener)
        self.frame_log: Any = None  #: serve's --log-frames writer (transport.framelog.FrameLog), for its drop count
        self.line: Line | None = None  #: serve's line, for its latency and busy time in GET /metrics
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
        #: GET /metrics' answers: cached briefly, rendered off the serving loop
        self.scrapes = Scrapes(sim)

    async def scrape(self, accept: str) -> tuple[bytes, str]:
        """GET /metrics' body and Content-Type (:class:`~c20sim.control.scrapes.Scrapes`)."""
        return await self.scrapes.scrape(accept, self.line)

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
    def seen(self) -> int:
        """Frames recorded since start (the next frame's sequence number)."""
        return self._seen

    @property
    def first_seq(self) -> int:
        return self._seen - len(self.sim.bus.records)

    async def start(
        self, host: str, port: int, *, table: routes.Table | None = None, option: str = "--control"
    ) -> None:
        """Listen on ``host``:``port``, serving ``table`` (the whole control surface by default; serve's
        ``--metrics`` listener serves its one row)."""
        self.host = host
        # the --metrics listener is read-only and tokenless: a scrape by any Host name (a Kubernetes Service's DNS
        # name) is answered; the control API keeps its Host check against DNS rebinding
        self.any_host = option == "--metrics"
        if option == "--control" and (warning := httpguard.check_bind(host)) is not None:
            print(f"c20sim: {warning}", file=sys.stderr, flush=True)
        httpguard.quiet_logs()
        runner = web.AppRunner(make_app(self, table), access_log=None, **httpguard.run_app_kwargs())
        await runner.setup()
        site = httpguard.site(runner, host, port)  # a TCPSite with a connection cap and a header timeout
        try:
            await site.start()
        except OSError as exc:
            await runner.cleanup()
            where = f"{option} {f'[{host}]' if ':' in host else host}:{port}"
            if exc.errno == errno.EADDRINUSE:  # worded as serve words it for --tcp and the other ports
                raise C20SimError(
                    f"{where}: the port is in use; stop the program holding it or choose another port (0 picks a free one)"
                ) from None
            raise C20SimError(
                f"{where}: cannot listen: {exc.strerror or exc}; choose another port (0 picks a free one)"
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
        self.scrapes.close()


def make_app(api: ControlApi, table: routes.Table | None = None) -> web.Application:
    """The aiohttp application serving ``api``'s simulator: every row of ``table`` (the control surface's), each by
    its kind: a row with an operation by the one handler of :func:`~c20sim.control.httpbody.operation`, a service
    row by :mod:`~c20sim.control.httpserved`, the frame log's by :mod:`~c20sim.control.httpstream`."""
    table = routes.table() if table is None else table
    #: what a 404 points to: GET / where it is served, else this listener's own routes (serve --metrics)
    served = "index" if any(row.name == "index" for row in table.values()) else ", ".join(table)
    own = {**httpserved.handlers(api, table), **httpstream.handlers(api)}
    app = web.Application(
        middlewares=[*httpguard.middlewares(api.host, any_host=api.any_host), _errors(served), _token(api)]
    )
    for row in table.values():
        if row.call is None and row.name not in own:
            raise ValueError(f"route {row.key} ({row.name}): no operation and no handler of the API's own")
        app.router.add_route(row.method, row.path, own[row.name] if row.call is None else operation(api.sim, row))
    return app


def _errors(served: str) -> Middleware:
    """The middleware that answers every error in JSON: a refusal with its status, a bug with 500 (logged)."""

    @web.middleware
    async def errors(request: web.Request, handler: Handler) -> web.StreamResponse:
        try:
            return await handler(request)
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
                    message += (
                        "; see GET / for the routes" if served == "index" else f"; this listener serves {served} only"
                    )
                return reply({"error": message}, exc.status)
            raise
        except Exception as exc:  # a bug: say so in JSON, log the traceback, keep serving
            log.exception("control API: bug while serving %s %s", request.method, request.path)
            message = (
                f"{request.method} {request.path}: internal error ({type(exc).__name__}: {exc}); see the server's log"
            )
            return reply({"error": message}, 500)

    return errors


def _token(api: ControlApi) -> Middleware:
    """The middleware that asks every request for the API's token, where it has one (401 without it)."""

    @web.middleware
    async def token(request: web.Request, handler: Handler) -> web.StreamResponse:
        if api.token is not None:
            given = request.query.get("token", "")
            header = request.headers.get("Authorization", "")
            if header.startswith("Bearer "):
                given = header.removeprefix("Bearer ").strip()
            # a header that is not UTF-8 comes surrogate-escaped: compared as the bytes sent, it is just wrong
            if not hmac.compare_digest(given.encode("utf-8", "surrogateescape"), api.token.encode()):
                why = "a wrong token" if given else "no token"
                return reply(
                    {
                        "error": f"{request.method} {request.path}: {why}; this control API needs its token: "
                        "send Authorization: Bearer TOKEN (the token is in the server's ready file)"
                    },
                    401,
                )
        return await handler(request)

    return token


#: The control surface's rows by ``METHOD path`` (:mod:`c20sim.control.routes`), as this module serves them.
ROUTES = routes.TABLE

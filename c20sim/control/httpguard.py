"""The control API's guard: only its own pages and programs may change the drive, and no input crashes it.

A browser lets any web page send a form (``text/plain`` or form-encoded, no
script needed) to a port on 127.0.0.1, and a DNS-rebinding page can even read
the answers under a foreign ``Host``. So, before any handler runs:

- a ``Host`` that is neither a loopback name or address nor the address the
  request came in on (nor the bound name) gets 403;
- an ``Origin`` other than the API's own (``http://`` + ``Host``) gets 403,
  ``null`` (file:// pages, sandboxes) included;
- a state-changing request (POST, PUT, PATCH, DELETE) must say
  ``Content-Type: application/json``, else 415: a form cannot;
- a body that is not UTF-8, or JSON nested deeper than :data:`MAX_DEPTH`, gets
  400 with one line, not a traceback.

Errors come back as ``{"error": "..."}`` like the API's own. aiohttp's
traceback for malformed HTTP (a request line too long, smuggling attempts) is
cut to one line by :func:`quiet_logs`. :func:`check_bind` gives the warning
for a control API reachable beyond this machine; :func:`run_app_kwargs` the
server's limits.

Connections: :func:`site` listens like aiohttp's ``TCPSite`` but holds at
most :func:`connection_cap` connections (a quarter of the file descriptors,
so the wire's endpoints always have room), one client (peer address) at most
:func:`client_share` of them. A request's headers must come within
:data:`HEADER_TIMEOUT` (from the opening, or a later request's first byte),
its body within :data:`BODY_TIMEOUT` (else 408), and an idle keep-alive
connection is closed after :data:`IDLE_TIMEOUT`. At the cap (or a client's
share) the connection idle longest is closed for the newcomer, or else the
one whose request has been coming longest (for at least :data:`GRACE`); one
being answered never is. A newcomer with no room is answered 503 with a
sentence, then closed once its request has come in (not reset before it can
read the answer). A client
that leaves mid-body gets no traceback.

The public surface is these functions, so the routes module installs the
guard in a few lines.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import resource
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from aiohttp import web

__all__ = [
    "MAX_DEPTH",
    "check_bind",
    "client_share",
    "connection_cap",
    "host_allowed",
    "is_loopback",
    "json_depth",
    "middlewares",
    "quiet_logs",
    "run_app_kwargs",
    "site",
]

log = logging.getLogger(__name__)

#: Methods that change something: they take a JSON body or none, never a form.
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})

#: Nesting of arrays and objects a body may have; the API's own bodies are one level deep.
MAX_DEPTH = 32

#: Seconds a keep-alive connection may stay idle between requests.
IDLE_TIMEOUT = 30.0

#: Seconds a request's headers may take: from the connection's opening, or from a later request's first byte.
HEADER_TIMEOUT = 10.0

#: Seconds a request's body may take once its headers have come.
BODY_TIMEOUT = 10.0

#: Seconds a connection whose request is coming (or a new one, not yet sent) is safe from being closed for a
#: newcomer: a request takes milliseconds to send. An idle connection (between requests) has no such grace: it is
#: closed for a newcomer first, the one idle longest first, as HTTP lets a server close one.
GRACE = 1.0

#: Refused connections kept open at once until their request has come in (so the 503 is read, not reset).
MAX_LINGERING = 64

#: Seconds a refused connection is kept open for that.
LINGER = 1.0

#: The most control-API connections at once, whatever the file descriptors allow.
MAX_CONNECTIONS = 256

Handler = Callable[["web.Request"], Awaitable["web.StreamResponse"]]


def is_loopback(host: str) -> bool:
    """``localhost``, a name under ``.localhost``, or a loopback address (127.0.0.0/8, ::1), brackets allowed."""
    name = host.strip("[]").lower().rstrip(".")
    if name == "localhost" or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


def _split_host(value: str) -> str:
    """The host part of a ``Host`` header value: ``[::1]:8080`` -> ``::1``, ``a.b:80`` -> ``a.b``."""
    value = value.strip()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value[1:]
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def host_allowed(host_header: str, local_address: str | None, bound_host: str = "") -> bool:
    """True for a loopback host, the address the connection came in on, or the name the API was bound to."""
    host = _split_host(host_header).lower().rstrip(".")
    if not host:
        return False
    if is_loopback(host):
        return True
    if local_address and host == local_address.split("%", 1)[0].lower():
        return True
    bound = bound_host.strip("[]").lower().rstrip(".")
    return bool(bound) and bound not in ("0.0.0.0", "::") and host == bound


def json_depth(data: bytes) -> int:
    """The deepest nesting of ``[`` and ``{`` in a JSON text, strings skipped; a cheap check before parsing."""
    depth = deepest = 0
    in_string = escaped = False
    for byte in data:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:  # quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):
            depth += 1
            deepest = max(deepest, depth)
        elif byte in (0x5D, 0x7D):
            depth -= 1
    return deepest


def _refuse(status: int, message: str) -> web.Response:
    from aiohttp import web

    return web.json_response({"error": message}, status=status)


def middlewares(bound_host: str = "", *, any_host: bool = False) -> list[Any]:
    """The guard's aiohttp middlewares, outermost first; ``bound_host`` is the HOST of ``--control``;
    ``any_host``: no Host check (a read-only listener, whose answers a rebinding page gains nothing from)."""
    from aiohttp import ClientPayloadError, web
    from aiohttp.http_exceptions import HttpProcessingError

    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        conn = _LIVE.get(id(request.transport)) if request.transport is not None else None
        if conn is None:
            return await checked(request, handler)
        conn.begin()  # no deadline of the guard's while the handler runs (a stream reader stays)
        try:
            return await checked(request, handler)
        finally:
            conn.end()

    async def checked(request: web.Request, handler: Handler) -> web.StreamResponse:
        where = f"{request.method} {request.path}"
        host = request.headers.get("Host", "")
        sockname = request.transport.get_extra_info("sockname") if request.transport is not None else None
        local = str(sockname[0]) if isinstance(sockname, tuple) and sockname else None
        if host and not any_host and not host_allowed(host, local, bound_host):
            return _refuse(
                403, f"{where}: Host {host!r} is not this API's; use a loopback address or the address it is bound to"
            )
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower().rstrip("/") != f"http://{host}".lower():
            return _refuse(403, f"{where}: requests from other origins ({origin}) are refused")
        if request.method in STATE_CHANGING:
            if request.content_type != "application/json":
                given = request.headers.get("Content-Type", "none")
                return _refuse(415, f"{where}: Content-Type must be application/json, not {given}")
            try:
                body = await asyncio.wait_for(request.read(), BODY_TIMEOUT)
            except web.HTTPException as exc:  # 413: a body over client_max_size
                return _refuse(exc.status, f"{where}: {exc.reason}")
            except TimeoutError:
                response = _refuse(408, f"{where}: the body did not come within {BODY_TIMEOUT:g} s")
                response.force_close()
                return response
            except (ConnectionError, ClientPayloadError, HttpProcessingError):  # the client left mid-body
                log.debug("control API: %s: the client left before its body was whole", where)
                response = _refuse(400, f"{where}: the connection closed before the body was whole")
                response.force_close()
                return response
            try:
                body.decode("utf-8")
            except UnicodeDecodeError as exc:
                return _refuse(400, f"the body is not JSON: not UTF-8 text (byte {exc.start})")
            if json_depth(body) > MAX_DEPTH:
                return _refuse(400, f"the body is not JSON this API takes: nested deeper than {MAX_DEPTH} levels")
        return await handler(request)

    return [guard]


def run_app_kwargs() -> dict[str, Any]:
    """Keyword arguments for ``web.AppRunner``: the request handler's limits."""
    return {"keepalive_timeout": IDLE_TIMEOUT, "max_line_size": 8190, "max_field_size": 8190, "max_headers": 64}


def check_bind(host: str) -> str | None:
    """The warning for a control API bound beyond loopback, or None when only this machine can reach it."""
    if is_loopback(host):
        return None
    shown = f"[{host}]" if ":" in host else host
    return (
        f"warning: --control {shown}: the control API is reachable from other machines; every request must "
        "carry its token (--control-token, or the one written to the ready file), and whoever has it can trip, "
        "stop or power-cycle the drives. Bind 127.0.0.1 unless you mean it."
    )


class _OneLine(logging.Filter):
    """aiohttp logs a traceback for every malformed request; one line says the same."""

    def filter(self, record: logging.LogRecord) -> bool:
        from aiohttp.http_exceptions import HttpProcessingError

        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            peer = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            text = " ".join(str(exc).split())
            record.msg = "control API: malformed HTTP request from %s refused: %s"
            record.args = (peer, text[:200])
            record.exc_info = None
            record.exc_text = None
            record.levelno, record.levelname = logging.WARNING, "WARNING"
        return True


_filter = _OneLine()


def quiet_logs() -> None:
    """Cut aiohttp's tracebacks for malformed HTTP to one line (idempotent)."""
    server_log = logging.getLogger("aiohttp.server")
    if _filter not in server_log.filters:
        server_log.addFilter(_filter)


def connection_cap() -> int:
    """Control-API connections allowed at once: a quarter of the file descriptors, 16 to MAX_CONNECTIONS."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return MAX_CONNECTIONS
    return max(16, min(MAX_CONNECTIONS, soft // 4))


def client_share(cap: int) -> int:
    """The most connections one client (peer address) may hold: half the cap, so others always have room."""
    return max(4, cap // 2)


class _Connections:
    """The connections of one listening site: counted, by client, and the refusals and closings, for the log."""

    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.share = client_share(cap)
        self.live: set[_Guarded] = set()
        self.by_client: dict[str, set[_Guarded]] = {}
        self.refused = 0
        self.evicted = 0
        self.lingering = 0

    @property
    def open(self) -> int:
        return len(self.live)

    def add(self, conn: _Guarded) -> None:
        self.live.add(conn)
        self.by_client.setdefault(conn.client, set()).add(conn)

    def remove(self, conn: _Guarded) -> None:
        self.live.discard(conn)
        mine = self.by_client.get(conn.client)
        if mine is not None:
            mine.discard(conn)
            if not mine:
                del self.by_client[conn.client]

    def stalest(self, among: set[_Guarded], now: float) -> _Guarded | None:
        """The connection to close for a newcomer: the one idle the longest, else the one waiting for its request
        the longest (for at least :data:`GRACE`); never one whose request is being answered (a stream reader
        included)."""
        best: _Guarded | None = None
        for conn in among:
            if conn.busy or (not conn.idle and now - conn.since < GRACE):
                continue
            if best is None or (conn.idle, -conn.since) > (best.idle, -best.since):
                best = conn
        return best

    def admit(self, client: str, now: float) -> str | None:
        """Make room for a new connection from ``client`` (closing a stale one if need be); the sentence of a
        refusal, or None when it may come in."""
        mine = self.by_client.get(client, set())
        if len(mine) >= self.share:
            victim = self.stalest(mine, now)
            if victim is None:
                return (
                    f"this client ({client}) has {len(mine)} connections open to the control API, its share of "
                    f"the {self.cap} allowed, and none is idle; close one, or reuse one (keep-alive), and try again"
                )
        elif self.open >= self.cap:
            victim = self.stalest(self.live, now)
            if victim is None:
                return (
                    f"the control API has {self.open} connections open, its cap, and none is idle; "
                    "try again in a moment"
                )
        else:
            return None
        victim.evict()
        self.evicted += 1
        if self.evicted == 1 or self.evicted % 1000 == 0:
            log.warning(
                "control API: at its cap of connections (%d, %d a client): the one idle longest is closed for "
                "each new one (%d so far)",
                self.cap,
                self.share,
                self.evicted,
            )
        return None


#: The live connections by their transport, for the guard middleware to find the connection of a request.
_LIVE: dict[int, _Guarded] = {}


class _Guarded(asyncio.Protocol):
    """aiohttp's request handler behind the guard's cap, share and deadlines.

    A connection is in one of three phases: ``idle`` (between requests: closed after :data:`IDLE_TIMEOUT`),
    ``request`` (a request's headers are coming: from the connection's opening or the next request's first
    byte, closed after :data:`HEADER_TIMEOUT`) and ``busy`` (a handler runs: the guard middleware reads the
    body within :data:`BODY_TIMEOUT`; a stream reader stays busy while it reads).
    """

    def __init__(self, inner: Any, connections: _Connections) -> None:
        self._inner = inner
        self._connections = connections
        self._counted = False
        self._refusing = False
        self.client = "?"
        self.busy = 0
        self.since = 0.0  #: when the present phase began (loop time): the stalest is closed first
        self.idle = False  #: between requests (answered, the next not begun)
        self._timer: asyncio.TimerHandle | None = None
        self._transport: asyncio.BaseTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        connections = self._connections
        peer = transport.get_extra_info("peername")
        self.client = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        loop = asyncio.get_running_loop()
        now = loop.time()
        refusal = connections.admit(self.client, now)
        self._transport = transport
        if refusal is not None:
            self._refuse(transport, refusal)
            return
        connections.add(self)
        _LIVE[id(transport)] = self
        self._counted = True
        self._request(now)
        self._inner.connection_made(transport)

    def _refuse(self, transport: asyncio.BaseTransport, sentence: str) -> None:
        """Answer 503 with the sentence at once, then close: after the client's request has come in (or a
        second), so that closing with its request unread does not reset the connection before it reads."""
        connections = self._connections
        connections.refused += 1
        if connections.refused == 1 or connections.refused % 1000 == 0:
            log.warning("control API: a connection refused (503): %s (%d so far)", sentence, connections.refused)
        writer = cast("asyncio.Transport", transport)  # uvloop's transports are not asyncio's classes
        body = json.dumps({"error": f"503 Service Unavailable: {sentence}"}).encode()
        head = (
            "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n"
        ).encode()
        writer.write(head + body)
        if connections.lingering >= MAX_LINGERING or not writer.can_write_eof():
            writer.close()
            return
        self._refusing = True
        connections.lingering += 1
        writer.write_eof()
        self._timer = asyncio.get_running_loop().call_later(LINGER, transport.close)

    def _set_timer(self, seconds: float) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = asyncio.get_running_loop().call_later(seconds, self._expire)

    def _request(self, now: float) -> None:
        self.idle = False
        self.since = now
        self._set_timer(HEADER_TIMEOUT)

    def _expire(self) -> None:
        self._timer = None
        if self._transport is not None and not self.busy:
            self._transport.close()  # headers too slow, or idle too long

    def evict(self) -> None:
        """Close this connection to make room for another (it was idle, or its request too slow)."""
        if self._transport is not None:
            self._transport.close()

    def begin(self) -> None:
        """A request's headers have come and its handler starts (called by the guard middleware)."""
        self.busy += 1
        self.idle = False
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def end(self) -> None:
        """The handler has answered: the connection is idle until the next request's first byte."""
        self.busy = max(0, self.busy - 1)
        if not self.busy and self._counted:
            self.idle = True
            self.since = asyncio.get_running_loop().time()
            self._set_timer(IDLE_TIMEOUT)

    def data_received(self, data: bytes) -> None:
        if self._refusing and self._transport is not None:
            self._transport.close()  # its request has come and is read: closing now resets nothing unread
            return
        if not self._counted:
            return
        if self.idle:
            self._request(asyncio.get_running_loop().time())
        self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        if self._refusing and self._transport is not None:
            self._transport.close()
            return None
        return self._inner.eof_received() if self._counted else None

    def connection_lost(self, exc: Exception | None) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._refusing:
            self._refusing = False
            self._connections.lingering -= 1
        if not self._counted:
            return
        self._counted = False
        self._connections.remove(self)
        if self._transport is not None:
            _LIVE.pop(id(self._transport), None)
        self._inner.connection_lost(exc)

    def pause_writing(self) -> None:
        if self._counted:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        if self._counted:
            self._inner.resume_writing()


def site(runner: web.AppRunner, host: str, port: int) -> web.TCPSite:
    """A ``TCPSite`` whose connections are capped, shared out among clients, and given deadlines."""
    from aiohttp import web

    connections = _Connections(connection_cap())

    class GuardedSite(web.TCPSite):
        async def start(self) -> None:
            await web.BaseSite.start(self)
            handler = self._runner.server
            assert handler is not None
            self._server = await asyncio.get_running_loop().create_server(
                lambda: _Guarded(handler(), connections),
                self._host,
                self._port,
                backlog=self._backlog,
                reuse_address=self._reuse_address,
            )
            sockets = self._server.sockets
            self._bound_port = sockets[0].getsockname()[1] if sockets else self._port

    return GuardedSite(runner, host, port)

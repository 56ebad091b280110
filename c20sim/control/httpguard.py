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
so the wire's endpoints always have room), closes one that has not finished
its first request's headers within :data:`HEADER_TIMEOUT` (slowloris), and
keep-alive connections idle for :data:`IDLE_TIMEOUT` are closed by aiohttp.

The public surface is these functions, so the routes module installs the
guard in a few lines.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import resource
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from aiohttp import web

__all__ = [
    "MAX_DEPTH",
    "check_bind",
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

#: Seconds a new connection has to send its first request's headers.
HEADER_TIMEOUT = 10.0

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


def middlewares(bound_host: str = "") -> list[Any]:
    """The guard's aiohttp middlewares, outermost first; ``bound_host`` is the HOST of ``--control``."""
    from aiohttp import web

    @web.middleware
    async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
        where = f"{request.method} {request.path}"
        host = request.headers.get("Host", "")
        sockname = request.transport.get_extra_info("sockname") if request.transport is not None else None
        local = str(sockname[0]) if isinstance(sockname, tuple) and sockname else None
        if host and not host_allowed(host, local, bound_host):
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
                body = await request.read()
            except web.HTTPException as exc:  # 413: a body over client_max_size
                return _refuse(exc.status, f"{where}: {exc.reason}")
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


class _Connections:
    def __init__(self, cap: int) -> None:
        self.cap = cap
        self.open = 0
        self.refused = 0


class _Guarded(asyncio.Protocol):
    """aiohttp's request handler behind a cap on connections and a deadline for the first headers."""

    def __init__(self, inner: Any, connections: _Connections) -> None:
        self._inner = inner
        self._connections = connections
        self._counted = False
        self._headers_done = False
        self._tail = b""
        self._timer: asyncio.TimerHandle | None = None
        self._transport: asyncio.BaseTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        connections = self._connections
        if connections.open >= connections.cap:
            connections.refused += 1
            if connections.refused == 1 or connections.refused % 1000 == 0:
                log.warning(
                    "control API: %d connections open, the cap; new ones are closed at once (%d so far)",
                    connections.open,
                    connections.refused,
                )
            transport.close()
            return
        connections.open += 1
        self._counted = True
        self._transport = transport
        self._timer = asyncio.get_running_loop().call_later(HEADER_TIMEOUT, self._too_slow)
        self._inner.connection_made(transport)

    def _too_slow(self) -> None:
        self._timer = None
        if not self._headers_done and self._transport is not None:
            self._transport.close()

    def data_received(self, data: bytes) -> None:
        if not self._counted:
            return
        if not self._headers_done:
            if b"\r\n\r\n" in self._tail + data:
                self._headers_done = True
                if self._timer is not None:
                    self._timer.cancel()
                    self._timer = None
            else:
                self._tail = (self._tail + data)[-3:]
        self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self._inner.eof_received() if self._counted else None

    def connection_lost(self, exc: Exception | None) -> None:
        if not self._counted:
            return
        self._counted = False
        self._connections.open -= 1
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._inner.connection_lost(exc)

    def pause_writing(self) -> None:
        if self._counted:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        if self._counted:
            self._inner.resume_writing()


def site(runner: web.AppRunner, host: str, port: int) -> web.TCPSite:
    """A ``TCPSite`` whose connections are capped and must send their first headers in time."""
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

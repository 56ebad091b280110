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
server's limits. The public surface is these functions, so the routes module
installs the guard in a few lines.
"""

from __future__ import annotations

import ipaddress
import logging
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from aiohttp import web

__all__ = [
    "MAX_DEPTH",
    "check_bind",
    "host_allowed",
    "is_loopback",
    "json_depth",
    "middlewares",
    "quiet_logs",
    "run_app_kwargs",
]

log = logging.getLogger(__name__)

#: Methods that change something: they take a JSON body or none, never a form.
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})

#: Nesting of arrays and objects a body may have; the API's own bodies are one level deep.
MAX_DEPTH = 32

#: Seconds a keep-alive connection may stay idle between requests.
IDLE_TIMEOUT = 30.0

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
            body = await request.read()
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
        f"warning: --control {shown}: the control API is reachable from other machines and has no "
        "authentication; anyone who can reach it can trip, stop or power-cycle the drives. "
        "Bind 127.0.0.1 unless you mean it."
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

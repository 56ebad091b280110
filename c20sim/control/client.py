"""A client of the control API: a blocking JSON caller, and the dashboard's operations over it.

:class:`ControlClient` calls a running ``c20sim serve --control`` over one
kept-alive HTTP connection (stdlib only), with the token where the server asks
for one; an error reply becomes a :class:`~c20sim.control.ops.ControlError`
with the server's own sentence and status, and a server that cannot be
reached becomes one too (status 503), so a front end has one error to show.

:class:`RemoteOps` is the dashboard's bench over that client: every action is
one API call, made from its row of the route table (:meth:`RemoteOps.call`),
and what the dashboard reads comes from the latest telemetry
snapshot (``GET /telemetry``, or a ``/stream`` message handed to
:meth:`RemoteOps.update`), so a redraw asks the server nothing. After an
action the snapshot is fetched again, so what is shown is what was done.

:func:`attach_target` turns ``--attach ready.json`` or ``--attach
http://HOST:PORT`` into the API's URL and token.
"""

from __future__ import annotations

import dataclasses
import http.client
import json
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from ..drive.files import FileReadError, read_bytes
from ..drive.model import Telemetry
from ..drive.profile import Profile, load_profile
from ..wire.errors import C20SimError
from ..wire.registers import Reg
from . import routes
from .ops import ControlError

#: The environment variable that may carry the control API's token: to serve (instead of --control-token, which
#: the process list shows), to a dashboard's ``--attach`` (``c20sim web`` sets it for its dashboards).
TOKEN_ENV = "C20SIM_CONTROL_TOKEN"

__all__ = ["TOKEN_ENV", "ControlClient", "Refused", "RemoteOps", "Unreachable", "attach_target"]

#: Seconds a call may take before the server counts as unreachable.
TIMEOUT = 5.0
#: The registers a snapshot carries, by address (the rest are read with a call).
_SNAPSHOT_REGISTERS = {
    Reg.STATUS2: "status2",
    Reg.OUTPUT_FREQUENCY: "output_frequency",
    Reg.SET_FREQUENCY: "set_frequency",
}
_TELEMETRY_FIELDS = tuple(f.name for f in dataclasses.fields(Telemetry))


def attach_target(target: str, token: str | None = None) -> tuple[str, str | None]:
    """``http://HOST:PORT`` (with ``token``), or a ready file's path -> (url, token); C20SimError if neither."""
    if target.startswith(("http://", "https://")):
        parts = urlsplit(target)
        if parts.scheme != "http" or not parts.hostname or parts.port is None:
            raise C20SimError(f"--attach {target}: give http://HOST:PORT (the ready file's control), or a ready file")
        return f"http://{parts.netloc}", token
    path = Path(target)
    try:
        data = json.loads(read_bytes(path, "ready file"))
    except FileReadError as exc:
        raise C20SimError(f"--attach {target}: cannot read the ready file: {exc.reason}") from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise C20SimError(f"--attach {target}: not a ready file (not JSON: {exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("control"), str):
        raise C20SimError(
            f"--attach {target}: the ready file has no control address; start serve with --control 127.0.0.1:0"
        )
    found = data.get("token")
    return data["control"], token if token is not None else (found if isinstance(found, str) else None)


class Unreachable(ControlError):
    """The API did not answer as the API (status 503): ``stage`` says how. ``"connect"``: nothing accepted the
    connection; ``"timeout"``: connected, no answer in time; ``"reply"``: something answered, not in HTTP (or the
    connection broke); ``"not json"``: an HTTP answer that is not JSON where JSON was asked for. ``cause``: the
    error as raised."""

    def __init__(self, message: str, stage: str, cause: BaseException | None = None) -> None:
        super().__init__(message, status=503)
        self.stage = stage
        self.cause = cause


class Refused(ControlError):
    """An error answer of the API (4xx/5xx): its status, and ``said``, the server's own sentence (its JSON
    ``error``, else the answer's text, else the status's reason)."""

    def __init__(self, message: str, status: int, said: str) -> None:
        super().__init__(message, status=status)
        self.said = said


class ControlClient:
    """Blocking JSON calls to the control API at ``url`` (``http://HOST:PORT``), over one kept-alive connection:
    the one HTTP client of the API (the dashboard's operations, ``c20sim ctl``, ``c20sim mcp``)."""

    def __init__(self, url: str, token: str | None = None, timeout: float = TIMEOUT) -> None:
        parts = urlsplit(url)
        if parts.scheme != "http" or not parts.hostname:
            raise C20SimError(f"control API {url!r}: give http://HOST:PORT")
        self.url = url.rstrip("/")
        self.token = token
        self._host, self._port = parts.hostname, parts.port or 80
        self.timeout = timeout
        self._conn: http.client.HTTPConnection | None = None

    def headers(self) -> dict[str, str]:
        out = {"Accept": "application/json"}
        if self.token is not None:
            out["Authorization"] = f"Bearer {self.token}"
        return out

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def _exchange(self, method: str, path: str, body: object = None) -> tuple[int, bytes, str, str]:
        """One request: the status, the body, its media type (``application/json``, ``text/plain``, ...) and the
        status's reason. A state change is always sent as JSON, even without a body (the API takes no other)."""
        data = None if body is None else json.dumps(body).encode()
        headers = self.headers()
        if data is not None or method != "GET":
            headers["Content-Type"] = "application/json"
        for attempt in (1, 2):  # a kept-alive connection the server closed is opened again, once
            fresh = self._conn is None
            if self._conn is None:
                self._conn = http.client.HTTPConnection(self._host, self._port, timeout=self.timeout)
            try:
                if fresh:
                    self._conn.connect()
            except OSError as exc:
                self.close()
                if attempt == 2 or isinstance(exc, TimeoutError):
                    raise self._unreachable(exc, "connect") from None
                continue
            try:
                self._conn.request(method, path, body=data, headers=headers)
                response = self._conn.getresponse()
                raw = response.read()
                return response.status, raw, response.headers.get_content_type(), response.reason
            except (OSError, http.client.HTTPException) as exc:
                self.close()
                stage = "timeout" if isinstance(exc, TimeoutError) else "reply"
                if attempt == 2 or stage == "timeout":
                    raise self._unreachable(exc, stage) from None
        raise AssertionError("unreachable")

    def _unreachable(self, exc: BaseException, stage: str) -> Unreachable:
        return Unreachable(f"the control API at {self.url} does not answer: {exc}", stage, exc)

    def call(self, method: str, path: str, body: object = None, *, strict: bool = False) -> Any:
        """One call; the decoded JSON reply, or :class:`Refused` with the server's message. ``strict``: an answer
        that is not JSON is :class:`Unreachable` (``"not json"``), not None."""
        status, raw, _, reason = self._exchange(method, path, body)
        return self._decoded(method, path, status, raw, reason, strict)

    def answer(self, method: str, path: str, body: object = None) -> Any:
        """As :meth:`call`, for any route: the decoded JSON reply, or the reply's text where it is not JSON
        (``GET /profile``'s TOML, ``GET /metrics``)."""
        status, raw, media, reason = self._exchange(method, path, body)
        if status < 400 and media != "application/json":
            return raw.decode("utf-8", errors="replace")
        return self._decoded(method, path, status, raw, reason, False)

    def _decoded(self, method: str, path: str, status: int, raw: bytes, reason: str, strict: bool) -> Any:
        try:
            data = json.loads(raw) if raw else None
        except (json.JSONDecodeError, UnicodeDecodeError):
            if strict and status < 400:
                raise Unreachable(f"{self.url}: its answer to {method} {path} is not JSON", "not json") from None
            data = None
        if status >= 400:
            message = data.get("error") if isinstance(data, dict) else None
            said = str(message or raw.decode("utf-8", errors="replace").strip() or reason)
            raise Refused(str(message or f"{method} {path}: HTTP {status}"), status, said)
        return data

    def text(self, path: str) -> str:
        status, raw, _, _ = self._exchange("GET", path)
        if status >= 400:
            raise ControlError(f"GET {path}: HTTP {status}", status=status)
        return raw.decode("utf-8")


class RemoteOps:
    """The dashboard's bench over the control API (see the module's docstring)."""

    def __init__(self, client: ControlClient) -> None:
        self.client = client
        index = self.call("index")
        self.index: dict[str, Any] = index
        self.addresses: tuple[int, ...] = tuple(index["drives"])
        self.virtual: bool = index["clock"] == "virtual"
        self.endpoints: dict[str, str] = dict(index.get("endpoints", {}))
        self.profile: Profile = self._load_profile(index["profile"])
        self.latest: dict[str, Any] = {}
        self.refresh()

    def _load_profile(self, name: str) -> Profile:
        """The served profile, from its TOML as the server has it (the two machines may differ)."""
        text = self.client.text(routes.table().named("profile").path)
        with tempfile.TemporaryDirectory(prefix="c20sim-") as tmp:
            path = Path(tmp) / f"{name}.toml"
            path.write_text(text, encoding="utf-8")
            return load_profile(str(path))

    # --- the snapshot

    def update(self, snapshot: Mapping[str, Any]) -> bool:
        """Take a telemetry snapshot (from the stream) if it is newer than the one held; True if taken."""
        if snapshot.get("n", 0) <= self.latest.get("n", -1):
            return False
        self.latest = {**snapshot, "by_address": {d["address"]: d for d in snapshot["drives"]}}
        return True

    def refresh(self) -> None:
        self.update(self.call("telemetry"))

    def _drive(self, address: int) -> dict[str, Any]:
        try:
            found: dict[str, Any] = self.latest["by_address"][address]
        except KeyError:
            raise ControlError(f"no drive at address {address}", status=404) from None
        return found

    def _act(self, method: str, path: str, body: object | None = None) -> Any:
        body = {} if body is None else body  # always JSON: the API takes application/json only
        try:
            return self.client.call(method, path, body)
        finally:
            self.refresh()

    # --- reading

    def now(self) -> float:
        return float(self.latest["t"])

    def telemetry(self, address: int) -> Telemetry:
        state = self._drive(address)
        return Telemetry(**{name: state[name] for name in _TELEMETRY_FIELDS})

    def conditions(self, address: int) -> dict[str, object]:
        return dict(self._drive(address)["conditions"])

    def held_fault(self, address: int) -> int | None:
        held = self._drive(address)["held_fault"]
        return None if held is None else int(held)

    def register(self, address: int, register: int) -> int:
        if register in _SNAPSHOT_REGISTERS:
            return int(self._drive(address)["registers"][_SNAPSHOT_REGISTERS[Reg(register)]])
        return int(self.call("read_register", address=address, register=int(register))["raw"])

    def causes(self, address: int) -> dict[str, bool]:
        return dict(self._drive(address)["causes"])

    def link(self, scope: int | None) -> dict[str, Any]:
        return dict(self.latest["link"] if scope is None else self._drive(scope)["link_faults"])

    # --- every operation of the route table: one call each

    def call(self, name: str, /, **arguments: Any) -> Any:
        """The operation ``name`` of the route table (:mod:`c20sim.control.routes`) with its path parameters and
        fields as keywords; its JSON answer. After one that changes state, the snapshot is fetched again."""
        row = routes.table().named(name)
        path = row.url(**{p: arguments.pop(p) for p in row.parameters})
        body: object = dict(arguments[row.whole]) if row.whole is not None else arguments
        if row.changes:
            return self._act(row.method, path, body)
        return self.client.call(row.method, path, body if row.method != "GET" else None)

"""``c20sim mcp``: the control surface as Model Context Protocol tools, for an assistant at the bench.

An MCP server over stdio, built on the official ``mcp`` SDK's low-level server, and a client of the control
API as the dashboard is: it attaches to a running serve (``--attach ready.json`` or ``--attach
http://HOST:PORT``; the token from ``--control-token-file``, ``$C20SIM_CONTROL_TOKEN`` or the ready file) or
starts one of its own with serve's options, stopped when the session ends (the client closes stdin, or
SIGTERM; SIGINT too, exit code 130).

**Tools.** Every row of the route table (:mod:`c20sim.control.routes`) is a tool, made from the row when
the tools are listed, so a row added there is a tool with no edit here: its name is the operation's name,
its description the row's help and doc, its input schema the row's JSON Schema with the path parameters
added as properties (the drive's ``address``, the first drive when left out; a ``register``). A row whose
body is one of several objects (a fault: by cause or by code) has them merged into one object, its
properties all optional, since assistants' APIs refuse ``oneOf`` at a schema's top; the API checks the
combination. The one row that is no tool is the WebSocket (``Route.tool``): what it streams is here as
resources.

**Calls.** Each call is one request through :class:`~c20sim.control.client.ControlClient`, so the API's
token, ``Host`` and content-type rules and all its checks apply: nothing the API refuses is possible here.
The arguments are split into the path (checked here, so a value cannot make another path) and the body;
an unknown argument is named with the known ones. Any error (a bad argument, a refusal, the API out of
reach) is the tool's error result (``isError``) with one sentence naming the field, never a crash.

**Resources.** ``c20sim://telemetry`` (every drive's state), ``c20sim://frames`` (the newest
:data:`FRAMES_SHOWN` frames; ``c20sim://frames?last=N&slave=S`` for others), ``c20sim://audit``,
``c20sim://drill`` (the drill's state and report).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import re
import signal
import stat
import sys
from collections.abc import AsyncIterator, Iterable, Mapping
from io import TextIOWrapper
from typing import Any, cast
from urllib.parse import parse_qsl, quote, urlencode, urlsplit

import anyio
import mcp.types as types
from mcp.server.lowlevel import Server
from mcp.server.lowlevel.helper_types import ReadResourceContents
from mcp.server.stdio import stdio_server
from pydantic import AnyUrl

from .control import routes
from .control.client import ControlClient, attach_target
from .control.openapi import parameter
from .control.ops import ControlError, unknown
from .wire.errors import C20SimError

__all__ = ["FRAMES_SHOWN", "RESOURCES", "Bench", "build_server", "input_schema", "run_mcp", "tool"]

#: The frames ``c20sim://frames`` shows: the newest this many (the log holds 2000).
FRAMES_SHOWN = 100
#: The routes that are resources too, as ``c20sim://NAME``: what the stream carries, and the audit.
RESOURCES = ("telemetry", "frames", "audit", "drill")
#: The query parameters ``c20sim://frames`` takes (passed on to ``GET /frames``, which checks them).
FRAMES_QUERY = ("last", "slave")
#: Seconds a call to the control API may take (a long virtual advance, a reset from a state file).
TIMEOUT = 30.0
#: The longest message the client may send, in bytes; a longer one ends the session.
MAX_MESSAGE = 16 * 1024 * 1024
#: A path parameter other than the address (a register): a word that stays one path segment.
_WORD = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,31}\Z")

INSTRUCTIONS = (
    "c20sim is a simulated ZBLD.C20 brushless DC motor drive behind a Modbus RTU slave. Each tool is one "
    "operation of its control API (the tool's description gives the HTTP route). A drive's tools take its bus "
    "address (default: the first drive). The panel's run keys (press_key forward) work only on the keypad run "
    "channel (set_run_channel keypad); a master runs the drive by writing 2000H. Faults come by cause (fault "
    'with {"cause": "undervoltage"}); the audit tool says what the masters would do wrong on a real line.'
)


# --- The tools, from the rows.


def tool(row: routes.Route) -> types.Tool:
    """The MCP tool of a route-table row."""
    route = f"{row.method} {row.path}" + ("" if row.doc in ("-", f"- ({row.said})") else f": {row.doc}")
    return types.Tool(
        name=row.name,
        description=f"{row.said}\n\n{route}" if row.said != "-" else route,
        inputSchema=input_schema(row),
        annotations=types.ToolAnnotations(readOnlyHint=row.method == "GET"),
    )


def input_schema(row: routes.Route) -> dict[str, Any]:
    """The row's JSON Schema with its path parameters as properties, as one object at the top."""
    props: dict[str, Any] = {}
    for name in row.parameters:
        described = parameter(name)
        text = described["description"] + (" (default: the first drive)" if name == "address" else "")
        props[name] = {**described["schema"], "description": text}
    required = [name for name in row.parameters if name != "address"]
    body = row.schema() or {"type": "object", "properties": {}, "additionalProperties": False}
    out = _one_object(body)
    out["properties"] = {**props, **out.get("properties", {})}
    required += out.get("required", [])
    if required:
        out["required"] = required
    return out


def _one_object(schema: Mapping[str, Any]) -> dict[str, Any]:
    """``schema`` as one object schema: alternatives at the top (``oneOf``, ``anyOf``) merged into one object of
    their properties, each optional, the alternatives said in the description."""
    alternatives = [*schema.get("oneOf", ()), *schema.get("anyOf", ())]
    if not alternatives:
        return {**schema, "type": "object"}
    out = {k: v for k, v in schema.items() if k not in ("oneOf", "anyOf")}
    props: dict[str, Any] = {}
    for branch in alternatives:
        for name, spec in branch.get("properties", {}).items():
            if name in props and props[name] != spec:
                props[name] = {"anyOf": [props[name], spec]}
            else:
                props[name] = spec
    ways = " | ".join(_said_branch(branch) for branch in alternatives)
    out.update(type="object", properties=props, additionalProperties=False)
    out["description"] = (out.get("description", "") + f" One of: {ways}.").strip()
    return out


def _said_branch(branch: Mapping[str, Any]) -> str:
    needed = list(branch.get("required", ()))
    optional = [f"[{name}]" for name in branch.get("properties", {}) if name not in needed]
    return "{" + ", ".join([*needed, *optional]) + "}"


def _shown(value: object) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


class ArgumentError(ControlError):
    """A tool's argument that makes no request: said as the tool's error, naming the argument."""


def _path_value(name: str, value: object) -> int | str:
    """A path parameter's value, checked to stay one path segment (the API judges the rest)."""
    number = isinstance(value, int) and not isinstance(value, bool)
    if name == "address":
        if not number:
            raise ArgumentError(f"address: {_shown(value)} is not a drive address; give a whole number, such as 1")
        return cast(int, value)
    if number and 0 <= cast(int, value) <= 0xFFFF:
        return cast(int, value)
    if isinstance(value, str) and _WORD.match(value):
        return value
    raise ArgumentError(f"{name}: {_shown(value)} is not a {name}; give {parameter(name)['description']}")


class Bench:
    """The control API as the tools and resources call it: one client, one request at a time, off the loop."""

    def __init__(self, client: ControlClient) -> None:
        self.client = client
        self._lock = anyio.Lock()
        self._first_drive: int | None = None

    async def request(self, method: str, path: str, body: object = None) -> Any:
        async with self._lock:
            return await anyio.to_thread.run_sync(self.client.answer, method, path, body)

    async def first_drive(self) -> int:
        if self._first_drive is None:
            index = routes.table().named("index")
            self._first_drive = int((await self.request(index.method, index.path))["drives"][0])
        return self._first_drive

    async def call(self, name: str, arguments: Mapping[str, Any]) -> types.CallToolResult:
        """The tool ``name``: its row's request with ``arguments``; its answer, or its error in one sentence."""
        try:
            row = routes.table().named(name)
            if not row.tool:
                raise ControlError(f"{name} is not a tool; read its resources (c20sim://telemetry, c20sim://frames)")
            path, body = await self._request_of(row, arguments)
            answer = await self.request(row.method, path, body)
        except C20SimError as exc:
            return types.CallToolResult(content=[types.TextContent(type="text", text=str(exc))], isError=True)
        text = answer if isinstance(answer, str) else json.dumps(answer)
        structured = answer if isinstance(answer, dict) else None
        return types.CallToolResult(content=[types.TextContent(type="text", text=text)], structuredContent=structured)

    async def _request_of(self, row: routes.Route, arguments: Mapping[str, Any]) -> tuple[str, object]:
        """The path and body of ``row``'s request for ``arguments``: path parameters out, the rest the body."""
        data = dict(arguments)
        if row.whole is None:
            known = [*row.parameters, *(f.name for f in row.fields)]
            for key in data:
                if key not in known:
                    if not known:
                        raise ArgumentError(f"{row.name} takes no arguments; got {key!r}")
                    raise unknown("argument", key, known)
        values: dict[str, int | str] = {}
        for name in row.parameters:
            if name in data:
                values[name] = _path_value(name, data.pop(name))
            elif name == "address":
                values[name] = await self.first_drive()
            else:
                raise ArgumentError(f"{name}: missing; give {parameter(name)['description']}")
        path = quote(row.url(**values), safe="/")
        return path, (None if row.method == "GET" else data)

    async def resource(self, uri: str) -> str:
        """The text (JSON) of a resource, ``c20sim://NAME[?query]``."""
        parts = urlsplit(uri)
        if parts.scheme != "c20sim" or parts.netloc not in RESOURCES or parts.path not in ("", "/"):
            known = ", ".join(f"c20sim://{name}" for name in RESOURCES)
            raise ControlError(f"no resource {uri}; resources: {known}")
        row = routes.table().named(parts.netloc)
        query = dict(parse_qsl(parts.query, keep_blank_values=True))
        if row.name == "frames":
            for key in query:
                if key not in FRAMES_QUERY:
                    raise unknown("query parameter", key, FRAMES_QUERY)
            query.setdefault("last", str(FRAMES_SHOWN))
        elif query:
            raise ControlError(f"c20sim://{row.name} takes no query; got {parts.query!r}")
        answer = await self.request(row.method, row.path + (f"?{urlencode(query)}" if query else ""))
        return answer if isinstance(answer, str) else json.dumps(answer)


def build_server(bench: Bench) -> Server[Any, Any]:
    """The MCP server of ``bench``'s control API: the route table's tools (listed anew each time), the resources."""
    server: Server[Any, Any] = Server("c20sim", version=_version(), instructions=INSTRUCTIONS)

    @server.list_tools()
    async def list_tools() -> list[types.Tool]:
        return [tool(row) for row in routes.table().values() if row.tool]

    @server.call_tool(validate_input=False)  # the API checks, in its words, naming the field
    async def call_tool(name: str, arguments: dict[str, Any]) -> types.CallToolResult:
        return await bench.call(name, arguments)

    @server.list_resources()
    async def list_resources() -> list[types.Resource]:
        table = routes.table()
        return [
            types.Resource(
                uri=AnyUrl(f"c20sim://{name}"),
                name=name,
                description=table.named(name).help or table.named(name).doc,
                mimeType="application/json",
            )
            for name in RESOURCES
        ]

    @server.list_resource_templates()
    async def list_resource_templates() -> list[types.ResourceTemplate]:
        return [
            types.ResourceTemplate(
                uriTemplate="c20sim://frames{?last,slave}",
                name="frames",
                description="the frame log: the newest `last` frames (1-2000), of drive `slave` alone if given",
                mimeType="application/json",
            )
        ]

    @server.read_resource()
    async def read_resource(uri: AnyUrl) -> Iterable[ReadResourceContents]:
        return [ReadResourceContents(await bench.resource(str(uri)), "application/json")]

    return server


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("c20sim")
    except metadata.PackageNotFoundError:
        return "0+unknown"


# --- The session over stdio.


class _Lines:
    """The client's messages, a line each, read by the event loop from a pipe: a read that a signal's cancel
    ends at once (the SDK's own reader is a thread blocked in read(), which nothing but input ends)."""

    def __init__(self, reader: asyncio.StreamReader) -> None:
        self._reader = reader

    def __aiter__(self) -> _Lines:
        return self

    async def __anext__(self) -> str:
        try:
            line = await self._reader.readline()
        except ValueError:  # over MAX_MESSAGE
            print(f"c20sim: mcp: a message over {MAX_MESSAGE >> 20} MiB from the client; ending", file=sys.stderr)
            raise StopAsyncIteration from None
        if not line:
            raise StopAsyncIteration
        return line.decode("utf-8", errors="replace")


@contextlib.asynccontextmanager
async def _stdin() -> AsyncIterator[_Lines | None]:
    """stdin as :class:`_Lines` where it is a pipe, a socket or a terminal (as an assistant starts the server);
    None (the SDK's reader) where the event loop cannot watch it: a regular file, or a device such as /dev/null
    (asyncio takes any character device, then epoll refuses it in a callback and the input never ends)."""
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader(limit=MAX_MESSAGE)
    fd = sys.stdin.fileno()
    mode = os.fstat(fd).st_mode
    if not (stat.S_ISFIFO(mode) or stat.S_ISSOCK(mode) or os.isatty(fd)):
        yield None
        return
    try:
        transport, _ = await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    except (ValueError, OSError):
        yield None
        return
    try:
        yield _Lines(reader)
    finally:
        transport.close()


async def serve_stdio(server: Server[Any, Any], stdout: TextIOWrapper) -> None:
    """Run ``server`` on stdin and ``stdout`` until the client closes stdin, or SIGTERM."""
    async with anyio.create_task_group() as group:

        async def end_on_signal() -> None:
            with anyio.open_signal_receiver(signal.SIGTERM) as signals:  # SIGINT: KeyboardInterrupt, exit 130
                async for _ in signals:
                    group.cancel_scope.cancel()
                    return

        group.start_soon(end_on_signal)
        async with _stdin() as lines, stdio_server(cast(Any, lines), anyio.wrap_file(stdout)) as (read, write):
            await server.run(read, write, server.create_initialization_options())
        group.cancel_scope.cancel()


class _Ended(Exception):
    """SIGTERM before or after the session: ``c20sim mcp`` ends as at the end of its input."""


def _end(signum: int, frame: object) -> None:
    raise _Ended


def run_mcp(args: argparse.Namespace, parser_defaults: dict[str, object]) -> int:
    """``c20sim mcp``: attach to ``--attach``, or to a serve started for the options; serve MCP on stdio.

    SIGTERM ends it at any time, as the end of its input does, stopping the serve it started (that serve is
    in a session of its own: a signal to this process's group does not reach it)."""
    from .tui.session import check_attach_options, served

    previous = signal.signal(signal.SIGTERM, _end)  # while starting: unwinds, stopping the serve
    interrupt = signal.getsignal(signal.SIGINT)
    try:
        with contextlib.ExitStack() as stack:
            if args.attach:
                check_attach_options(args, parser_defaults)
                url, token = attach_target(args.attach, args.control_token)
            else:
                url, token = stack.enter_context(served(args))
            client = ControlClient(url, token, timeout=TIMEOUT)
            stack.callback(client.close)
            try:
                client.call("GET", routes.table().named("index").path)
            except C20SimError as exc:
                raise C20SimError(f"cannot attach to {url}: {exc}") from None
            stdout = TextIOWrapper(sys.stdout.buffer, encoding="utf-8")
            with contextlib.redirect_stdout(sys.stderr):  # a stray print must not break the protocol on stdout
                anyio.run(serve_stdio, build_server(Bench(client)), stdout)  # SIGTERM: the session's own handler
            for number in (signal.SIGTERM, signal.SIGINT):  # ending already: let the serve be stopped
                signal.signal(number, signal.SIG_IGN)
    except _Ended:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, interrupt)
    return 0

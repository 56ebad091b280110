"""``c20sim mcp``: the control surface as MCP tools, driven by the ``mcp`` SDK's own client.

``c20sim mcp`` runs as a subprocess on stdio, as an assistant starts it: its tools are the route table's
operations (every row but the WebSocket), the run key it presses is seen by a pymodbus master over Modbus TCP,
and a bad argument is the tool's error naming the field. A throwaway row added to the route table in the
test is a tool with no other edit: that test runs the MCP server object in this process (over the SDK's
in-memory streams) against a serve in this process, since a subprocess cannot see a row the test adds.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from mcp import ClientSession, StdioServerParameters
from mcp.client.stdio import stdio_client
from mcp.shared.exceptions import McpError
from mcp.shared.memory import create_connected_server_and_client_session
from mcp.types import CallToolResult, TextContent
from pydantic import AnyUrl
from pymodbus.client import AsyncModbusTcpClient

from c20sim import cli
from c20sim.control import ops, routes
from c20sim.control.client import TOKEN_ENV, ControlClient
from c20sim.mcpserver import FRAMES_SHOWN, MAX_MESSAGE, Bench, build_server, input_schema
from tests.conftest import wait_for_ready_file
from tests.tui.conftest import serving

#: Every route's operation but the WebSocket's (its telemetry and frames are resources).
TOOLS = [row.name for row in routes.table().values() if row.name != "stream"]
ADDRESS = {
    "type": "integer",
    "minimum": 1,
    "maximum": 247,
    "description": "the drive's bus address (default: the first drive)",
}


def text(result: CallToolResult) -> str:
    assert len(result.content) == 1 and isinstance(result.content[0], TextContent), result
    return result.content[0].text


def answer(result: CallToolResult) -> dict[str, Any]:
    assert not result.isError, text(result)
    assert result.structuredContent is not None
    assert json.loads(text(result)) == result.structuredContent
    return result.structuredContent


def error(result: CallToolResult) -> str:
    assert result.isError, result
    return text(result)


@asynccontextmanager
async def mcp_process(tmp_path: Path, *argv: str, env: dict[str, str] | None = None) -> AsyncIterator[ClientSession]:
    """``c20sim mcp ARGV`` started by the SDK's stdio client, its session initialised."""
    params = StdioServerParameters(
        command=sys.executable,
        args=["-m", "c20sim", "mcp", *argv],
        env={**os.environ, **(env or {})},
    )
    with (tmp_path / "mcp.stderr").open("w") as errlog:
        async with stdio_client(params, errlog=errlog) as (read, write), ClientSession(read, write) as session:
            await session.initialize()
            yield session


async def holding(port: int, register: int) -> int:
    """One read of ``register`` by a pymodbus master over Modbus TCP."""
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
    assert await client.connect()
    try:
        response = await client.read_holding_registers(register, count=1, device_id=1)
        assert not response.isError(), response
        return int(response.registers[0])
    finally:
        client.close()


async def until_read(port: int, register: int, expected: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while (value := await holding(port, register)) != expected:
        assert time.monotonic() < deadline, f"{register:04X}H reads {value}, not {expected}, after {timeout:g} s"
        await asyncio.sleep(0.05)


def refused(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=1).close()
    except ConnectionRefusedError:
        return True
    return False


def port_of(address: str) -> int:
    return int(address.rsplit(":", 1)[1])


# --- The schemas, from the rows.


def test_every_tool_schema_is_one_object_json_schema() -> None:
    for row in routes.table().values():
        schema = input_schema(row)
        jsonschema.Draft202012Validator.check_schema(schema)
        assert schema["type"] == "object", row.name
        # assistants' APIs refuse a tool whose schema has alternatives at its top
        assert not {"oneOf", "anyOf", "allOf"} & set(schema), row.name
        assert list(schema["properties"])[: len(row.parameters)] == list(row.parameters), row.name


def test_a_fault_by_cause_or_code_is_one_object_saying_both() -> None:
    assert input_schema(routes.table().named("fault")) == {
        "type": "object",
        "properties": {
            "address": ADDRESS,
            "cause": {
                "enum": [
                    "undervoltage",
                    "overvoltage",
                    "overcurrent",
                    "overload",
                    "stall",
                    "overheat",
                    "hall",
                    "external",
                    "power_stage_u",
                    "power_stage_v",
                    "power_stage_w",
                    "drive_overload",
                    "output_phase_loss",
                    "communication",
                    "current_detection",
                    "eeprom",
                ],
                "description": "a fault's cause: a physical one, or a fault the profile has with no physical cause",
            },  # fmt: skip (the causes' rows, drive/trips.py, and the faults the profile has without a cause)
            "code": {"type": "integer", "minimum": 1, "maximum": 255},
            "persistent": {"type": "boolean"},
        },
        "additionalProperties": False,
        "description": "One of: {cause} | {code, [persistent]}.",
    }


def test_docs_list_every_tool() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "mcp.md").read_text(encoding="utf-8")
    section = text.split("## The tools", 1)[1].split("\n## ", 1)[0]
    rows = [line.split("|")[2] for line in section.splitlines() if line.startswith("| ") and "`" in line]
    listed = [name for cell in rows for name in re.findall(r"`(\w+)`", cell)]
    assert sorted(listed) == sorted(TOOLS)


# --- c20sim mcp on stdio, as an assistant starts it.


async def test_the_tools_are_the_route_table_and_the_run_key_runs_the_drive(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    argv = ("--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0", "--ready-file", str(ready))
    async with mcp_process(tmp_path, *argv) as session:
        modbus = port_of(json.loads(ready.read_text())["modbus_tcp"])
        listed = (await session.list_tools()).tools
        assert [t.name for t in listed] == TOOLS
        tools = {t.name: t for t in listed}
        assert tools["advance"].inputSchema == routes.table().named("advance").schema()  # no path: the row's own
        assert tools["write_register"].inputSchema == {
            "type": "object",
            "properties": {
                "address": ADDRESS,
                "register": {"type": "string", "description": "2100H, 0x2100, F00.10 or a name such as status1"},
                "value": {
                    "oneOf": [
                        {"type": "integer", "minimum": 0, "maximum": 0xFFFF},
                        {"type": "number"},
                        {"type": "string"},
                    ]
                },
                "raw": {"type": "integer", "minimum": 0, "maximum": 0xFFFF},
            },
            "additionalProperties": False,
            "required": ["register"],
        }
        key = routes.table().named("press_key")
        assert tools["press_key"].description == f"{key.help}\n\nPOST /drives/{{address}}/keypad: {key.doc}"
        assert tools["drive"].annotations is not None and tools["drive"].annotations.readOnlyHint is True
        assert tools["press_key"].annotations is not None and tools["press_key"].annotations.readOnlyHint is False

        assert await holding(modbus, 0x2100) == 3  # stopped
        # on the communication channel (the default) the panel's run key is refused: the drive's answer, no error
        assert answer(await session.call_tool("press_key", {"key": "forward"}))["accepted"] is False
        assert answer(await session.call_tool("set_run_channel", {"channel": "keypad"}))["channel"] == 0
        pressed = answer(await session.call_tool("press_key", {"address": 1, "key": "forward"}))
        assert pressed["accepted"] is True
        await until_read(modbus, 0x2100, 1)  # forward running, read over the wire

        # bad arguments: the tool's error, naming the field, and the session goes on
        known = ", ".join(ops.KEYS)
        assert (
            error(await session.call_tool("press_key", {"key": "sideways"}))
            == f"unknown key 'sideways' (known: {known})"
        )
        assert error(await session.call_tool("press_key", {"key": 9})) == "key: 9 is outside 1-8"
        write = {"register": "2001H", "value": 70000}
        assert error(await session.call_tool("write_register", write)) == "value: 70000 is outside 0-65535"
        assert (
            error(await session.call_tool("press_key", {"adress": 1, "key": "stop"}))
            == "unknown argument 'adress'; did you mean 'address'? (known: address, key)"
        )
        assert (
            error(await session.call_tool("press_key", {"address": "one", "key": "stop"}))
            == 'address: "one" is not a drive address; give a whole number, such as 1'
        )
        assert (
            error(await session.call_tool("press_key", {"address": 9, "key": "stop"}))
            == "no drive at address 9; drives: 1"
        )
        assert (
            error(await session.call_tool("read_register", {"register": "../../reset"}))
            == 'register: "../../reset" is not a register; give 2100H, 0x2100, F00.10 or a name such as status1'
        )
        assert error(await session.call_tool("time", {"seconds": 1})) == "time takes no arguments; got 'seconds'"
        assert error(await session.call_tool("stream", {})) == (
            "stream is not a tool; read its resources (c20sim://telemetry, c20sim://frames)"
        )
        assert error(await session.call_tool("spin", {})).startswith("unknown operation 'spin'")
        assert answer(await session.call_tool("read_register", {"register": "status1"}))["raw"] == 1
        assert answer(await session.call_tool("read_register", {"register": 0x2100}))["raw"] == 1
        profile = await session.call_tool("profile", {})  # a route that answers text, not JSON
        assert not profile.isError and text(profile).startswith("# ") and profile.structuredContent is None

        # the resources: what the stream carries, and the audit
        uris = [str(r.uri) for r in (await session.list_resources()).resources]
        assert uris == ["c20sim://telemetry", "c20sim://frames", "c20sim://audit", "c20sim://drill"]
        drill = json.loads((await session.read_resource(AnyUrl("c20sim://drill"))).contents[0].text)  # type: ignore[union-attr]
        assert drill["state"] == "idle", drill
        telemetry = json.loads((await session.read_resource(AnyUrl("c20sim://telemetry"))).contents[0].text)  # type: ignore[union-attr]
        assert telemetry["drives"][0]["status"] == 1
        frames = json.loads((await session.read_resource(AnyUrl("c20sim://frames"))).contents[0].text)  # type: ignore[union-attr]
        assert 0 < len(frames["frames"]) <= FRAMES_SHOWN
        assert any("2100H" in f["text"] for f in frames["frames"])  # the master's reads, in words
        last = json.loads((await session.read_resource(AnyUrl("c20sim://frames?last=1"))).contents[0].text)  # type: ignore[union-attr]
        assert len(last["frames"]) == 1
        audit = json.loads((await session.read_resource(AnyUrl("c20sim://audit"))).contents[0].text)  # type: ignore[union-attr]
        assert "findings" in audit
        with pytest.raises(McpError, match=r"unknown query parameter 'lst'; did you mean 'last'\?"):
            await session.read_resource(AnyUrl("c20sim://frames?lst=1"))
    # the session ended (stdin closed): the serve it started is stopped
    deadline = time.monotonic() + 10
    while not refused(modbus):
        assert time.monotonic() < deadline, "the serve c20sim mcp started still serves"
        await asyncio.sleep(0.05)


async def test_serve_options_reach_the_serve_it_starts(tmp_path: Path) -> None:
    async with mcp_process(tmp_path, "--no-audit", "--clock", "virtual", "--tcp", "127.0.0.1:0") as session:
        assert answer(await session.call_tool("time", {}))["clock"] == "virtual"
        assert error(await session.call_tool("audit", {})) == "the audit is off (serve --no-audit)"
        with pytest.raises(McpError, match=r"^the audit is off \(serve --no-audit\)$"):
            await session.read_resource(AnyUrl("c20sim://audit"))


@pytest.mark.parametrize("when", ["starting", "in session"])
@pytest.mark.parametrize(("number", "code"), [(signal.SIGTERM, 0), (signal.SIGINT, 130)], ids=["SIGTERM", "SIGINT"])
def test_a_signal_stops_the_serve_it_started(tmp_path: Path, when: str, number: int, code: int) -> None:
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "mcp", "--modbus-tcp", "127.0.0.1:0", "--ready-file", str(ready)],
        stdin=subprocess.PIPE,  # held open: no end of input, only the signal
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdin is not None and proc.stdout is not None
    try:
        modbus = port_of(wait_for_ready_file(ready, proc, timeout=30)["modbus_tcp"])
        assert not refused(modbus)
        if when == "in session":  # the handshake's first answer: the session waits for the next message
            initialize = {
                "jsonrpc": "2.0",
                "id": 1,
                "method": "initialize",
                "params": {
                    "protocolVersion": "2025-06-18",
                    "capabilities": {},
                    "clientInfo": {"name": "t", "version": "1"},
                },
            }
            proc.stdin.write(json.dumps(initialize).encode() + b"\n")
            proc.stdin.flush()
            reply = json.loads(proc.stdout.readline())
            assert reply["id"] == 1 and reply["result"]["serverInfo"]["name"] == "c20sim"
        proc.send_signal(number)
        out, err = proc.communicate(timeout=15)
        assert proc.returncode == code, err
        assert b"Traceback" not in err, err.decode()
        assert out == b""  # nothing on stdout but the MCP messages
        assert refused(modbus)
        assert not ready.exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_input_from_dev_null_is_a_session_that_ends_at_once(tmp_path: Path) -> None:
    """``c20sim mcp < /dev/null``: no messages, so the session ends, exit 0, its serve stopped (it hung, with a
    traceback, where the event loop was handed the device)."""
    ready = tmp_path / "ready.json"
    with open(os.devnull, "rb") as nothing:
        done = subprocess.run(
            [sys.executable, "-m", "c20sim", "mcp", "--tcp", "127.0.0.1:0", "--ready-file", str(ready)],
            stdin=nothing,
            capture_output=True,
            timeout=60,
        )
    assert (done.returncode, done.stdout, b"Traceback" in done.stderr) == (0, b"", False), done.stderr.decode()
    assert not ready.exists()


def test_a_message_over_the_bound_ends_the_session(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "mcp", "--tcp", "127.0.0.1:0", "--ready-file", str(ready)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        port = port_of(wait_for_ready_file(ready, proc, timeout=30)["tcp"])
        # a line of MAX_MESSAGE + 1 bytes: read up to the bound, then the session ends; the rest is never read
        out, err = proc.communicate(b"x" * (MAX_MESSAGE + 1) + b"\n", timeout=30)  # a closed pipe: ignored
        assert proc.wait(30) == 0
        assert out == b""
        assert err.decode().splitlines()[-1] == "c20sim: mcp: a message over 16 MiB from the client; ending"
        assert refused(port)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# --- Attaching: the token rules are the API's.


@pytest.fixture
def guarded(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A serve with a token, and a ready file naming it (as serve writes beyond loopback)."""
    with serving(token="bench-token") as served:
        ready = tmp_path / "ready.json"
        ready.write_text(json.dumps({"control": served.url, "token": "bench-token"}))
        yield served.url, ready


async def test_attached_with_the_ready_file_token(guarded: tuple[str, Path], tmp_path: Path) -> None:
    _, ready = guarded
    async with mcp_process(tmp_path, "--attach", str(ready), env={TOKEN_ENV: ""}) as session:
        assert answer(await session.call_tool("time", {})) == {"t": 0.0, "clock": "virtual"}
        assert answer(await session.call_tool("advance", {"seconds": 0.5})) == {"t": 0.5}


def test_a_wrong_token_is_one_line_and_exit_2(guarded: tuple[str, Path]) -> None:
    url, ready = guarded
    for target, env in ((url, {}), (str(ready), {TOKEN_ENV: "wrong"})):
        done = subprocess.run(
            [sys.executable, "-m", "c20sim", "mcp", "--attach", target],
            env={**os.environ, TOKEN_ENV: "", **env},
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert done.returncode == 2
        assert done.stdout == ""
        why = "a wrong token" if env else "no token"
        assert done.stderr == (
            f"c20sim: cannot attach to {url}: GET /: {why}; this control API needs its token: "
            "send Authorization: Bearer TOKEN (the token is in the server's ready file)\n"
        )


def test_attach_takes_the_server_as_it_is(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["mcp", "--attach", "http://127.0.0.1:9", "--clock", "virtual"]) == 2
    assert capsys.readouterr().err == (
        "c20sim: --attach: --clock is the server's option; give it to the serve you attach to, "
        "or leave out --attach to start one\n"
    )


def test_without_the_sdk_one_line_says_how_to_install(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "mcp", None)  # import mcp fails, as where it is not installed
    monkeypatch.delitem(sys.modules, "c20sim.mcpserver")
    assert cli.main(["mcp"]) == 2
    assert capsys.readouterr().err == (
        "c20sim: c20sim mcp needs the MCP SDK, an optional extra: pip install 'c20sim[mcp]' "
        "(in a clone: pip install -e '.[mcp]')\n"
    )


# --- A new operation is a tool with no other edit (in this process: a subprocess cannot see the test's row).


def spin(sim: Any, address: int, turns: object) -> dict[str, Any]:
    return {"address": address, "turns": ops.integer("turns", turns, 1, 10), "t": sim.now()}


SPIN = routes.Route(
    "POST",
    "/drives/{address}/spin",
    "spin",
    '{"turns": 3} (a test\'s throwaway operation)',
    spin,
    (routes.Field("turns", {"type": "integer", "minimum": 1, "maximum": 10}, True),),
    changes=True,
    help="spin the drive's test operation",
)


@pytest.fixture
def with_spin() -> Iterator[routes.Table]:
    table = routes.table()
    table.add(SPIN)
    try:
        yield table
    finally:
        table.remove("spin")


async def test_a_new_row_is_a_tool(with_spin: routes.Table) -> None:
    with serving() as served:
        client = ControlClient(served.url)
        try:
            async with create_connected_server_and_client_session(build_server(Bench(client))) as session:
                tools = {t.name: t for t in (await session.list_tools()).tools}
                assert list(tools) == [*TOOLS, "spin"]
                assert tools["spin"].inputSchema == {
                    "type": "object",
                    "properties": {"address": ADDRESS, "turns": {"type": "integer", "minimum": 1, "maximum": 10}},
                    "additionalProperties": False,
                    "required": ["turns"],
                }
                assert tools["spin"].description == (
                    "spin the drive's test operation\n\nPOST /drives/{address}/spin: "
                    '{"turns": 3} (a test\'s throwaway operation)'
                )
                assert answer(await session.call_tool("spin", {"turns": 3})) == {"address": 1, "turns": 3, "t": 0.0}
                assert error(await session.call_tool("spin", {"turns": 11})) == "turns: 11 is outside 1-10"
                with_spin.remove("spin")
                try:
                    assert [t.name for t in (await session.list_tools()).tools] == TOOLS
                finally:
                    with_spin.add(SPIN)
        finally:
            client.close()

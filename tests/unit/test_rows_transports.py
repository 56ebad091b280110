"""A transport is one row (c20sim.transport.rows), and the bus tells of a line change: nobody polls.

A throwaway transport (RTU frames on a TCP listener of this file's own, with
no code of c20sim's beyond the line and the endpoint every stream uses) is
registered by a fixture and removed after: with no other edit it reaches
serve's options and ``--help``, the ready file, the test handle and the
pytest plugin, the plant's manifests, the dashboard's session and the
drill's ``--transport`` (tests/drill/test_rows.py plays a drill over it); once
removed, it is gone from each. The line change is followed through real
ports by pymodbus, with every read of the bus's baud counted.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any, cast

import kubernetes_validate
import pytest
import yaml
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient

from c20sim import cli
from c20sim.control import liveaudit
from c20sim.core.bus import Bus, LineSettings
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drill import INCIDENTS
from c20sim.drillrun import carries, drill_transports, standard_for
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.testing import C20Sim, transports
from c20sim.transport.endpoint import RtuEndpoint, stream_framer
from c20sim.transport.line import Line
from c20sim.transport.rows import Endpoint, Opening, Option, PlantPort, Transport, register, rows
from c20sim.tui import session
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import with_crc
from tests.conftest import Line as Master

pytest_plugins = ["pytester"]


class _LoopConnection(asyncio.Protocol):
    """One master's connection: its bytes framed for the shared line, its replies written back."""

    def __init__(self, line: Line) -> None:
        self.line = line
        self.endpoint: RtuEndpoint | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        stream = cast(asyncio.Transport, transport)
        self.endpoint = RtuEndpoint(
            self.line,
            stream_framer(self.line.sim.bus.line_baud),
            lambda data, _baud: stream.write(data),
            name="loop",
            pause=stream.pause_reading,
            resume=stream.resume_reading,
        )

    def data_received(self, data: bytes) -> None:
        assert self.endpoint is not None
        self.endpoint.feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.endpoint is not None:
            self.endpoint.close()


class LoopListener:
    """The throwaway transport: RTU frames on a plain asyncio TCP listener."""

    def __init__(self, line: Line, address: str) -> None:
        self.line = line
        host, _, port = address.rpartition(":")
        self.host, self.port = host, int(port)
        self._server: asyncio.Server | None = None

    @property
    def name(self) -> str:
        return f"{self.host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.get_running_loop().create_server(
            lambda: _LoopConnection(self.line), self.host, self.port
        )
        self.host, self.port = self._server.sockets[0].getsockname()[:2]

    def close(self) -> None:
        if self._server is not None:
            self._server.close()

    async def wait_closed(self) -> None:
        if self._server is not None:
            await self._server.wait_closed()


def _open_loop(opening: Opening) -> Endpoint:
    return LoopListener(opening.line, opening.values["loop_tcp"])


LOOP = Transport(
    name="loop-tcp",
    key="loop_tcp",
    options=(Option("--loop-tcp", "RTU frames on a throwaway listener (a test's own)", "HOST:PORT"),),
    opener=_open_loop,
    model="rtu",
    help="a test's throwaway transport",
    network=True,
    fixture="127.0.0.1:0",
    plant=PlantPort("loop-tcp", 5040, 5041, "--loop-port-base", "loop RTU"),
)


@pytest.fixture
def loop_row() -> Iterator[Transport]:
    remove = register(LOOP)
    try:
        yield LOOP
    finally:
        remove()


def _help(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        cli.main([*words, "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


def _read_write(host: str, port: int) -> list[int]:
    """An independent master (pymodbus, RTU framing over TCP): write 2001H, read it back."""
    client = ModbusTcpClient(host, port=port, framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    try:
        assert not client.write_register(0x2001, 1234, device_id=1).isError()
        return list(client.read_holding_registers(0x2001, count=1, device_id=1).registers)
    finally:
        client.close()


# --- one row reaches every front end


def test_the_row_reaches_serves_options_and_help(loop_row: Transport, capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("serve", "dashboard", "web", "mcp"):
        text = " ".join(_help(capsys, command).split())
        assert "--loop-tcp HOST:PORT RTU frames on a throwaway listener (a test's own)" in text, command
        assert "; --loop-tcp, a test's throwaway transport." in text, command  # its help line
    assert ServeOptions(loop_tcp="127.0.0.1:0").asked() == [loop_row]


async def test_serve_opens_the_row_and_the_ready_file_names_it(loop_row: Transport, tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    args = cli.build_parser().parse_args(
        ["serve", "--loop-tcp", "127.0.0.1:0", "--ready-file", str(ready), "--clock", "virtual"]
    )
    server = Server(cli.build_simulator(args), cli.serve_options(args))
    await server.start()
    try:
        listener = server.endpoints.get("loop_tcp")
        assert isinstance(listener, LoopListener)
        assert listener.port != 0
        assert json.loads(ready.read_text()) == {"loop_tcp": f"127.0.0.1:{listener.port}"}
        assert f"; loop_tcp 127.0.0.1:{listener.port}" in server.ready_line()
        assert await asyncio.to_thread(_read_write, "127.0.0.1", listener.port) == [1234]
        assert [r.text for r in server.sim.bus.records][-1] == "2001H = 04D2: 1234 rpm"  # its reply, on the line
    finally:
        await server.aclose()
    assert not ready.exists()


def test_the_test_handle_opens_the_row(loop_row: Transport) -> None:
    assert transports() == ("tcp", "pty", "modbus-tcp", "loop-tcp")
    with C20Sim.start(transport="loop-tcp") as sim:
        assert sim.port is not None and sim.host == "127.0.0.1"
        assert sim.endpoints == {"loop_tcp": f"127.0.0.1:{sim.port}"}
        assert sim.tcp_port is None and sim.modbus_tcp_port is None and sim.pty is None
        assert _read_write(sim.host, sim.port) == [1234]
        sim.assert_written("2001H", 1234)


def test_the_pytest_plugin_serves_the_row(loop_row: Transport, pytester: pytest.Pytester) -> None:
    pytester.makepyfile(
        test_user="""
        import pytest
        from pymodbus import FramerType
        from pymodbus.client import ModbusTcpClient

        @pytest.mark.c20sim(transport="loop-tcp")
        def test_loop(c20sim):
            assert list(c20sim.endpoints) == ["loop_tcp"]
            client = ModbusTcpClient(c20sim.host, port=c20sim.port, framer=FramerType.RTU, timeout=2, retries=0)
            assert client.connect()
            assert not client.write_register(0x2001, 777, device_id=1).isError()
            client.close()
            c20sim.assert_written("2001H", 777)
        """
    )
    quiet = ("-p", "no:cacheprovider", "-p", "no:textual-snapshot", "-p", "no:syrupy")
    result = pytester.runpytest(*quiet, "-o", "asyncio_default_fixture_loop_scope=function")
    result.assert_outcomes(passed=1)
    markers = pytester.runpytest("--markers", *quiet, "-o", "asyncio_default_fixture_loop_scope=function").stdout.str()
    assert "(transport: tcp, pty, modbus-tcp, loop-tcp, or several)" in markers


def test_the_plant_publishes_the_row(loop_row: Transport, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["plant", "--buses", "2", "--drives", "1-4", "--loop-port-base", "16000"]) == 0
    text = capsys.readouterr().out
    assert "Services c20sim-bus-N: RTU over TCP :5020, Modbus TCP :502, loop RTU :5041)" in text
    assert "--image localhost/c20sim:0.1.0 --loop-port-base 16000\n" in text
    docs = [doc for doc in yaml.safe_load_all(text) if doc is not None]
    deployment, service = docs[3], docs[4]
    [container] = deployment["spec"]["template"]["spec"]["containers"]
    assert container["args"][:6] == [
        "--tcp",
        "0.0.0.0:5020",
        "--modbus-tcp",
        "0.0.0.0:1502",
        "--loop-tcp",
        "0.0.0.0:5040",
    ]
    assert {"name": "loop-tcp", "containerPort": 5040, "hostPort": 16001, "protocol": "TCP"} in container["ports"]
    assert service["spec"]["ports"][-1] == {
        "name": "loop-tcp",
        "port": 5041,
        "targetPort": "loop-tcp",
        "protocol": "TCP",
    }
    version = kubernetes_validate.latest_version()
    for doc in docs:
        kubernetes_validate.validate(doc, version, strict=True)
    assert "--loop-port-base" in _help(capsys, "plant")


def test_the_dashboard_session_passes_the_row_on(loop_row: Transport) -> None:
    args = cli.build_parser().parse_args(["dashboard", "--loop-tcp", "127.0.0.1:0"])
    argv = session.serve_argv(args, "READY")
    at = argv.index("--loop-tcp")
    assert argv[at + 1] == "127.0.0.1:0"
    attach = cli.build_parser().parse_args(["dashboard", "--attach", "http://127.0.0.1:1", "--loop-tcp", "h:1"])
    with pytest.raises(C20SimError, match=r"^--attach: --loop-tcp is the server's option;"):
        session.check_attach_options(attach, attach.serve_defaults)


def test_the_row_is_a_drill_transport(loop_row: Transport, capsys: pytest.CaptureFixture[str]) -> None:
    """``c20sim drill --transport`` takes it (the test handle opens it), and the standard plan over it is what RTU
    over TCP carries (its line model is RTU); serve's drill runner over it refuses nothing RTU over TCP takes.
    tests/drill/test_rows.py plays a drill over it against a real master."""
    assert drill_transports() == ("pty", "tcp", "modbus-tcp", "loop-tcp")
    assert "--transport {pty,tcp,modbus-tcp,loop-tcp}" in _help(capsys, "drill")
    over_loop = [d.name for d in standard_for(1, "loop-tcp").drills]
    assert over_loop == [d.name for d in standard_for(1, "tcp").drills]
    assert "crc" in over_loop and "crc" not in [d.name for d in standard_for(1, "modbus-tcp").drills]
    assert carries(INCIDENTS["crc"], "loop-tcp") and not carries(INCIDENTS["crc"], "modbus-tcp")


def test_a_removed_row_is_gone_from_every_front_end(capsys: pytest.CaptureFixture[str]) -> None:
    remove = register(LOOP)
    remove()
    assert LOOP not in rows()
    assert "--loop-tcp" not in _help(capsys, "serve")
    assert "--loop-port-base" not in _help(capsys, "plant")
    assert "loop-tcp" not in transports()
    assert "loop-tcp" not in drill_transports() and "loop-tcp" not in _help(capsys, "drill")
    assert not carries(INCIDENTS["crc"], "loop-tcp")
    assert "loop_tcp" not in session.serve_options()
    with pytest.raises(TypeError, match="no transport has the option 'loop_tcp'"):
        ServeOptions(loop_tcp="127.0.0.1:0")


def test_a_row_may_not_take_another_rows_name_key_or_option() -> None:
    with pytest.raises(ValueError, match="the name or the key is taken"):
        register(Transport("tcp", "other", (), _open_loop, "rtu", "x"))
    with pytest.raises(ValueError, match="option --tcp belongs to another transport"):
        register(Transport("other", "other", (Option("--tcp", "x", "H:P"),), _open_loop, "rtu", "x"))


# --- the bus tells of a line change; nobody polls


def test_the_bus_tells_its_listeners_once_the_change_is_recorded() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    bus = sim.bus
    told: list[tuple[LineSettings, str]] = []
    unsubscribe = bus.on_line(lambda line: told.append((line, str(bus.records[-1].direction))))
    failing = bus.on_line(lambda line: 1 / 0)  # a broken listener is logged, and costs the others nothing
    master = Master(bus)
    assert master.send(with_crc(bytes.fromhex("01 03 20 09 00 01"))) is not None  # a read: no change, none told
    assert told == []
    write = with_crc(bytes.fromhex("01 06 20 09 00 03"))  # F08.01 = 3: 9600 baud
    assert master.send(write) == write  # acknowledged, at 19200
    assert told == [(LineSettings(9600, 10), "tx")]  # told after the reply at the old baud was recorded
    bus.char_bits = 11  # serve's --parity E
    bus.char_bits = 11  # no change: not told again
    sim.reset()  # the set-up's baud again
    assert [t[0] for t in told] == [LineSettings(9600, 10), LineSettings(9600, 11), LineSettings(19200, 11)]
    unsubscribe()
    failing()
    bus.char_bits = 10
    assert len(told) == 3


@pytest.fixture
def baud_reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Every read of ``Bus.line_baud`` from now on (its value), by anyone."""
    reads: list[int] = []
    prop = cast(Any, Bus).line_baud

    def counted(self: Bus) -> int:
        value = int(prop.fget(self))
        reads.append(value)
        return value

    monkeypatch.setattr(Bus, "line_baud", property(counted, prop.fset))
    return reads


async def wait_for(condition: Any, timeout: float = 5.0) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not condition():
        assert loop.time() < deadline, "condition not met in time"
        await asyncio.sleep(0.005)


@pytest.mark.sources_only  # it counts reads of Bus.line_baud by patching the property
async def test_a_baud_change_reaches_every_listener_without_a_poll(baud_reads: list[int]) -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    server = Server(sim, ServeOptions(tcp="127.0.0.1:0", modbus_tcp="127.0.0.1:0", bus_timing=True))
    await server.start()
    told: list[int] = []
    server.line.on_baud(told.append)
    rtu = server.endpoints.tcp
    assert rtu is not None and server.endpoints.modbus_tcp is not None
    client = AsyncModbusTcpClient("127.0.0.1", port=rtu.port, framer=FramerType.RTU, timeout=2, retries=0)
    gateway = AsyncModbusTcpClient("127.0.0.1", port=server.endpoints.modbus_tcp.port, timeout=2, retries=0)
    try:
        assert await client.connect() and await gateway.connect()
        await wait_for(lambda: len(rtu.connections) == 1)
        baud_reads.clear()  # a connection's framer starts at the line's baud: read once, when it is made
        for _ in range(20):
            assert (await client.read_holding_registers(0x2100, count=1, device_id=1)).registers is not None
            assert not (await gateway.read_holding_registers(0x2100, count=1, device_id=1)).isError()
        assert not (await client.write_register(0x2009, 3, device_id=1)).isError()  # 9600 baud, acknowledged at 19200
        await wait_for(lambda: told == [9600])
        [connection] = rtu.connections
        endpoint = cast(Any, connection).endpoint
        assert endpoint.framer.baud == 9600  # the RTU-over-TCP stream's framer was told
        audit = liveaudit.of(sim)
        assert audit is not None
        audit.drain()
        assert audit.auditor.baud == 9600  # and the live audit
        assert baud_reads == []  # 41 transactions, a baud change, its telling: nobody read the bus's baud
    finally:
        client.close()
        gateway.close()
        await server.aclose()

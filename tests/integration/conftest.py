"""A simulator served on real ports in the test's event loop, and pymodbus masters for it."""

from __future__ import annotations

import asyncio
import json
import shutil
import signal
import struct
import subprocess
import sys
import urllib.request
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import Profile, load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.wire.registers import parse_fcode

#: a drive served over Modbus TCP in the test's process, in virtual time, and a pymodbus master on it
Link = tuple[Simulator, AsyncModbusTcpClient]


@asynccontextmanager
async def modbus_tcp_link(profile: Profile) -> AsyncIterator[Link]:
    """Drive 1 of ``profile`` served over Modbus TCP here (the test moves its virtual time) and a master on it."""
    sim = Simulator(profile, (1,), clock=VirtualClock())
    server = Server(sim, ServeOptions(modbus_tcp="127.0.0.1:0"))
    await server.start()
    assert server.endpoints.modbus_tcp is not None
    client = AsyncModbusTcpClient("127.0.0.1", port=server.endpoints.modbus_tcp.port, timeout=2.0, retries=0)
    assert await client.connect()
    try:
        yield sim, client
    finally:
        client.close()
        await server.aclose()


async def write_register(client: AsyncModbusTcpClient, register: int | str, value: int) -> None:
    """Write one register of drive 1 (an address, or a function code such as ``"F08.28"``); it must be taken."""
    address = parse_fcode(register) if isinstance(register, str) else register
    reply = await client.write_register(address, value, device_id=1)
    assert not reply.isError(), (register, reply)


async def read_register(client: AsyncModbusTcpClient, register: int) -> int:
    """One register of drive 1; it must answer."""
    reply = await client.read_holding_registers(register, count=1, device_id=1)
    assert not reply.isError(), reply
    return int(reply.registers[0])


def mbap_read(transaction: int, register: int) -> bytes:
    """A Modbus TCP request (MBAP header, unit 1) reading one register."""
    pdu = struct.pack(">BHH", 3, register, 1)
    return struct.pack(">HHHB", transaction & 0xFFFF, 0, len(pdu) + 1, 1) + pdu


@dataclass
class Served:
    sim: Simulator
    server: Server

    @property
    def pty(self) -> str:
        assert self.server.endpoints.pty is not None
        return self.server.endpoints.pty.path

    @property
    def tcp_port(self) -> int:
        assert self.server.endpoints.tcp is not None
        return self.server.endpoints.tcp.port

    @property
    def modbus_tcp_port(self) -> int:
        assert self.server.endpoints.modbus_tcp is not None
        return self.server.endpoints.modbus_tcp.port

    async def serial_client(self, timeout: float = 1.0, **kwargs: object) -> AsyncModbusSerialClient:
        client = AsyncModbusSerialClient(self.pty, framer=FramerType.RTU, timeout=timeout, retries=0, **kwargs)  # type: ignore[arg-type]
        assert await client.connect()
        return client

    async def rtu_tcp_client(self, timeout: float = 1.0, **kwargs: object) -> AsyncModbusTcpClient:
        client = AsyncModbusTcpClient(
            "127.0.0.1",
            port=self.tcp_port,
            framer=FramerType.RTU,
            timeout=timeout,
            retries=0,
            **kwargs,  # type: ignore[arg-type]
        )
        assert await client.connect()
        return client


ServeFactory = Callable[..., Awaitable[Served]]


@pytest.fixture
async def serve() -> AsyncIterator[ServeFactory]:
    """Start a simulator on a pty, RTU-over-TCP and Modbus TCP (port 0); closed after the test."""
    started: list[Server] = []

    async def start(
        addresses: tuple[int, ...] = (1,), profile: Profile | None = None, seed: int = 1, **options: object
    ) -> Served:
        sim = Simulator(profile or load_profile(), addresses, clock=VirtualClock(), seed=seed)
        settings: dict[str, object] = {"pty": True, "tcp": "127.0.0.1:0", "modbus_tcp": "127.0.0.1:0", **options}
        opts = ServeOptions(**settings)  # type: ignore[arg-type]
        server = Server(sim, opts)
        await server.start()
        started.append(server)
        return Served(sim, server)

    yield start
    for server in started:
        await server.aclose()
    await asyncio.sleep(0)


def need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        pytest.skip(f"{tool} is not installed (apt-get install {tool}); .ci/run installs it")
    return path


# --- c20sim as a user runs it: a command in a child process.


def c20sim_command(*args: str) -> list[str]:
    """The command line of ``c20sim ARGS`` with this interpreter."""
    return [sys.executable, "-m", "c20sim", *args]


def c20sim_run(*args: str, cwd: Path, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    """``c20sim ARGS`` run to its end in ``cwd``, its output captured."""
    return subprocess.run(c20sim_command(*args), capture_output=True, text=True, timeout=timeout, check=False, cwd=cwd)


def one_line(done: subprocess.CompletedProcess[str], code: int = 2) -> str:
    """The one line a refused command says on stderr (exit ``code``, 2 for a bad input), with no traceback."""
    assert done.returncode == code, (done.returncode, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    return lines[0]


@pytest.fixture
def procs() -> Iterator[list[subprocess.Popen[str]]]:
    """The child processes a test starts: killed (if still running) and waited for after it."""
    started: list[subprocess.Popen[str]] = []
    yield started
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


def stop(proc: subprocess.Popen[str]) -> tuple[str, str]:
    """SIGTERM, as a service manager stops it: it must exit 0; its stdout and stderr."""
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    return out, err


def get(url: str) -> dict[str, object]:
    """A GET of the control API, as JSON."""
    with urllib.request.urlopen(url, timeout=10) as response:
        data: dict[str, object] = json.load(response)
    return data

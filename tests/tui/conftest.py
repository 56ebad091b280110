"""The dashboard in a headless Textual pilot, attached to a simulator served on a background thread.

The simulator is served as ``c20sim serve`` serves it (RTU over TCP on port 0,
the control API on loopback port 0), on an event loop of its own; the
dashboard attaches to its control API, as it does to a serve in its own
process, and a pymodbus master talks to its TCP port.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable, Iterator
from contextlib import asynccontextmanager, contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient
from textual.pilot import Pilot

from c20sim.control.client import ControlClient, RemoteOps
from c20sim.core.clock import Clock, VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.testing import _LoopThread
from c20sim.tui import Dashboard

T = TypeVar("T")


@dataclass
class Served:
    """A simulator served on a background thread: its TCP port, its control API, and calls on its thread."""

    server: Server
    thread: _LoopThread

    @property
    def sim(self) -> Simulator:
        return self.server.sim

    @property
    def port(self) -> int:
        assert self.server.endpoints.tcp is not None
        return self.server.endpoints.tcp.port

    @property
    def url(self) -> str:
        assert self.server.control is not None
        return self.server.control.url

    def call(self, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn(*args)`` on the server's thread, between frames."""

        async def run() -> T:
            return fn(*args)

        return self.thread.run(run())

    def remote(self, token: str | None = None) -> RemoteOps:
        return RemoteOps(ControlClient(self.url, token))


@contextmanager
def serving(
    drives: tuple[int, ...] = (1,),
    *,
    tcp: bool = True,
    control: str = "127.0.0.1:0",
    token: str | None = None,
    clock: Clock | None = None,
    modbus_tcp: bool = False,
) -> Iterator[Served]:
    sim = Simulator(load_profile(), drives, clock=clock if clock is not None else VirtualClock(), seed=1)
    options = ServeOptions(
        tcp="127.0.0.1:0" if tcp else None,
        modbus_tcp="127.0.0.1:0" if modbus_tcp else None,
        control=control,
        control_token=token,
    )
    thread = _LoopThread()

    async def start() -> Server:
        server = Server(sim, options)
        await server.start()
        return server

    try:
        server = thread.run(start())
    except BaseException:
        thread.stop()
        raise
    try:
        yield Served(server, thread)
    finally:
        try:
            thread.run(server.aclose())
        finally:
            thread.stop()


async def until(check: Callable[[], bool], what: str, timeout: float = 10.0) -> None:
    """Wait (the dashboard's loop running) until ``check`` holds; fail saying what was awaited."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not check():
        assert loop.time() < deadline, f"timed out after {timeout:g} s waiting for {what}"
        await asyncio.sleep(0.02)


@dataclass
class Bench:
    """A running dashboard, its pilot, the served simulator, and a Modbus master on its TCP port."""

    app: Dashboard
    pilot: Pilot[int]
    client: AsyncModbusTcpClient
    served: Served

    async def read(self, address: int, device: int = 1) -> int:
        response = await self.client.read_holding_registers(address, count=1, device_id=device)
        assert not response.isError(), response
        return int(response.registers[0])

    async def write(self, address: int, value: int, device: int = 1) -> None:
        response = await self.client.write_register(address, value, device_id=device)
        assert not response.isError(), response

    async def press(self, *keys: str) -> None:
        await self.pilot.press(*keys)
        await self.pilot.pause()

    def screen_text(self) -> str:
        """The text of the drive's status (what a user reads)."""
        from c20sim.tui.status import DriveStatus

        status = self.app.get_screen_main().query_one(DriveStatus)
        return str(status.render())

    async def shows(self, text: str) -> None:
        """Wait until the drive's status shows ``text`` (telemetry comes over the stream)."""
        await until(lambda: text in self.screen_text(), f"{text!r} on the screen; it shows:\n{self.screen_text()}")


@asynccontextmanager
async def attached(served: Served, size: tuple[int, int] = (100, 30)) -> AsyncIterator[tuple[Dashboard, Pilot[int]]]:
    app = Dashboard(served.remote())
    async with app.run_test(size=size) as pilot:
        await until(lambda: app.streaming and app.received > 0, "the dashboard's stream")
        yield app, pilot


@asynccontextmanager
async def running(drives: tuple[int, ...] = (1,), size: tuple[int, int] = (100, 30)) -> AsyncIterator[Bench]:
    with serving(drives) as served:
        async with attached(served, size) as (app, pilot):
            # a generous timeout: the dashboard shares this loop, and a loaded machine slows its redraws, never
            # the answer a test waits for (a timeout here only bounds a failure)
            client = AsyncModbusTcpClient("127.0.0.1", port=served.port, framer=FramerType.RTU, timeout=5, retries=0)
            assert await client.connect()
            try:
                yield Bench(app, pilot, client, served)
            finally:
                client.close()


@pytest.fixture
async def bench() -> AsyncIterator[Bench]:
    async with running() as b:
        yield b

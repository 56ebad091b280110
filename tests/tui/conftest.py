"""The dashboard in a headless Textual pilot, serving RTU over TCP on port 0, and a pymodbus master for it."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient
from textual.pilot import Pilot

from c20sim.clock import VirtualClock
from c20sim.profile import load_profile
from c20sim.serve import ServeOptions
from c20sim.simulator import Simulator
from c20sim.tui import Dashboard


@dataclass
class Bench:
    """A running dashboard, its pilot, and a Modbus master on its TCP port."""

    app: Dashboard
    pilot: Pilot[int]
    client: AsyncModbusTcpClient

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
        """The text of every widget on the main screen (what a user reads)."""
        from c20sim.tui.widgets import DriveStatus

        status = self.app.get_screen_main().query_one(DriveStatus)
        return str(status.render())


Start = Callable[..., Awaitable[Bench]]


@asynccontextmanager
async def running(drives: tuple[int, ...] = (1,), size: tuple[int, int] = (100, 30)) -> AsyncIterator[Bench]:
    sim = Simulator(load_profile(), drives, clock=VirtualClock(), seed=1)
    app = Dashboard(sim, ServeOptions(tcp="127.0.0.1:0"))
    async with app.run_test(size=size) as pilot:
        await pilot.pause()
        assert app.server.endpoints.tcp is not None
        client = AsyncModbusTcpClient(
            "127.0.0.1", port=app.server.endpoints.tcp.port, framer=FramerType.RTU, timeout=0.5, retries=0
        )
        assert await client.connect()
        try:
            yield Bench(app, pilot, client)
        finally:
            client.close()


@pytest.fixture
async def bench() -> AsyncIterator[Bench]:
    async with running() as b:
        yield b

"""``c20sim dashboard --attach``: two dashboards on one running serve, each sees what the other does; closing one
leaves the server serving (and the other attached)."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.control.client import ControlClient, RemoteOps, attach_target
from c20sim.tui import Dashboard
from tests.conftest import wait_for_ready_file
from tests.terminal import NEEDS_TMUX, TMUX, Terminal, terminal_running
from tests.tui.conftest import until

pytestmark = pytest.mark.skipif(TMUX is None, reason=NEEDS_TMUX)


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[tuple[Path, dict[str, str]]]:
    ready = tmp_path / "ready.json"
    argv = [sys.executable, "-m", "c20sim", "serve", "--clock", "virtual", "--tcp", "127.0.0.1:0"]
    argv += ["--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        yield ready, wait_for_ready_file(ready, proc)
        assert proc.poll() is None, "the server ended while dashboards were attached"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.fixture
def terminal(serve: tuple[Path, dict[str, str]]) -> Iterator[Terminal]:
    ready, _ = serve
    command = f"{sys.executable} -m c20sim dashboard --attach {ready}"
    with terminal_running(ready.with_name("status"), command) as terminal:
        yield terminal


def read(info: dict[str, str], register: int) -> int:
    host, port = info["tcp"].rsplit(":", 1)
    client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    try:
        response = client.read_holding_registers(register, count=1, device_id=1)
        assert not response.isError(), response
        return int(response.registers[0])
    finally:
        client.close()


async def test_two_dashboards_attached_and_one_closed(serve: tuple[Path, dict[str, str]], terminal: Terminal) -> None:
    ready, info = serve
    app = Dashboard(RemoteOps(ControlClient(*attach_target(str(ready)))))
    async with app.run_test(size=(100, 30)) as pilot:
        await until(lambda: app.streaming and app.received > 0, "the dashboard's stream")
        await asyncio.to_thread(terminal.wait_for_text, "STOPPED")
        # one acts, the other shows it
        await pilot.press("f4", "u")
        await asyncio.to_thread(terminal.wait_for_text, "supply 10 V")
        await pilot.press("t", "t")  # +2 s: the bus bleeds below the 20 V level while stopped: off
        assert await asyncio.to_thread(read, info, 0x2100) == 5
        await asyncio.to_thread(terminal.keys, "F4")
        await asyncio.to_thread(terminal.wait_for_text, "u undervoltage")
        await asyncio.to_thread(terminal.keys, "u")
        await until(lambda: app.bench.conditions(1).supply_v == 48.0, "the supply the other dashboard restored")
        # the terminal's dashboard closes; the server serves on, and this one stays attached
        await asyncio.to_thread(terminal.keys, "q")
        assert await asyncio.to_thread(terminal.exit_status) == "status 0"
        before = app.received
        await until(lambda: app.received > before + 2, "telemetry after the other dashboard closed")
        assert app.streaming
        await pilot.press("t")  # time moves on through this one's API call
        assert await asyncio.to_thread(read, info, 0x2100) == 3

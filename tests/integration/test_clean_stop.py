"""SIGTERM stops an idle ``c20sim serve`` cleanly: the ready file and the pty link go, the EEPROM state stays saved,
exit code 0 and nothing on stderr, with masters and a dashboard's /stream reader still connected. How long the stop
takes is a bench figure (bench/stop_time.py, bench/RESULTS.md), not asserted here."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import aiohttp
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient

from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file


def serve(*args: str) -> list[str]:
    return [sys.executable, "-m", "c20sim", "serve", *args]


async def test_sigterm_on_an_idle_server_stops_it_cleanly(tmp_path: Path) -> None:
    ready, link, state = tmp_path / "ready.json", tmp_path / "ttyC20", tmp_path / "drive.json"
    options = ["--link", str(link), "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"]
    options += ["--control", "127.0.0.1:0", "--state", str(state), "--ready-file", str(ready)]
    proc = subprocess.Popen(serve(*options), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        info = wait_for_ready_file(ready, proc)
        assert link.is_symlink() and info["pty"] == str(link)
        host, port = info["tcp"].rsplit(":", 1)
        master = AsyncModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
        assert await master.connect()
        assert not (await master.write_register(Reg.ACCEL_TIME, 4321, device_id=1)).isError()
        pty_master = os.open(link, os.O_RDWR | os.O_NOCTTY)  # a master holding the pty open, idle
        async with aiohttp.ClientSession() as session, session.ws_connect(info["control"] + "/stream") as ws:
            first = await ws.receive_json(timeout=10)  # a dashboard's reader, attached
            assert first["type"] == "telemetry"
            proc.send_signal(signal.SIGTERM)
            out, err = await asyncio.to_thread(proc.communicate, timeout=20)
        os.close(pty_master)
        master.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert (proc.returncode, err) == (0, "")
    assert out.startswith("c20sim ready: ")
    assert not ready.exists()
    assert not os.path.lexists(link)
    assert json.loads(state.read_text())["parameters"]["F00.11"] == 4321
    # and the next start finds the drive as it was left
    again = subprocess.Popen(
        serve("--tcp", "127.0.0.1:0", "--state", str(state), "--ready-file", str(ready)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        host, port = wait_for_ready_file(ready, again)["tcp"].rsplit(":", 1)
        client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=2, retries=0)
        assert client.connect()
        try:
            assert client.read_holding_registers(Reg.ACCEL_TIME, count=1, device_id=1).registers == [4321]
        finally:
            client.close()
    finally:
        again.send_signal(signal.SIGTERM)
        _, err = again.communicate(timeout=20)
    assert (again.returncode, err) == (0, "")

"""CPU of the dashboard while the motor runs, against the same simulator without a UI.

Three runs of N wall seconds each, the drive running at 1500 rpm under load on
a realtime clock:

- reference: the same Simulator in this process, brought to the clock's time
  5 times a second (what the dashboard's timer asks of the model), no UI;
- headless: the Dashboard under ``App.run_test`` in this process (Textual
  lays out and renders every frame, without a terminal);
- terminal: ``python -m c20sim dashboard`` in a real terminal (tmux, 120x40),
  CPU read from /proc; skipped without tmux.

Prints CPU seconds per wall second for each (1.0 = one core busy).

    .venv/bin/python bench/bench_dashboard.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from c20sim.clock import RealtimeClock
from c20sim.profile import load_profile
from c20sim.registers import Reg
from c20sim.serve import ServeOptions
from c20sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[1]


def running_sim() -> Simulator:
    sim = Simulator(load_profile(), (1,), clock=RealtimeClock())
    drive = sim.drive(1)
    drive.write(Reg.SPEED_SETPOINT, 1500)
    drive.write(Reg.COMMAND, 1)
    return sim


def cpu_per_wall(start_cpu: float, start_wall: float) -> float:
    return (time.process_time() - start_cpu) / (time.monotonic() - start_wall)


async def reference(seconds: float) -> float:
    sim = running_sim()
    from c20sim.drive.model import Drive

    drive = sim.drive(1)
    assert isinstance(drive, Drive)
    drive.set_load_torque(0.8)
    cpu, wall = time.process_time(), time.monotonic()
    end = wall + seconds
    while time.monotonic() < end:
        sim.sync()
        drive.telemetry()
        await asyncio.sleep(0.2)
    return cpu_per_wall(cpu, wall)


async def headless(seconds: float) -> float:
    from c20sim.tui import Dashboard

    sim = running_sim()
    app = Dashboard(sim, ServeOptions())
    async with app.run_test(size=(120, 40)) as pilot:
        app.bench.set_load(1, 0.8)
        await pilot.pause()
        cpu, wall = time.process_time(), time.monotonic()
        await asyncio.sleep(seconds)
        figure = cpu_per_wall(cpu, wall)
        assert app.views[1].telemetry.status == 1, "the motor should still be running"
    return figure


def proc_cpu(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def terminal(seconds: float) -> float | None:
    tmux = shutil.which("tmux")
    if tmux is None:
        return None
    from pymodbus import FramerType
    from pymodbus.client import ModbusTcpClient

    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / "ready.json"
        session = f"c20bench-{uuid.uuid4().hex[:6]}"
        command = f"exec {sys.executable} -m c20sim dashboard --tcp 127.0.0.1:0 --ready-file {ready}"
        subprocess.run(
            [tmux, "new-session", "-d", "-s", session, "-x", "120", "-y", "40", command], check=True, cwd=ROOT
        )
        try:
            deadline = time.monotonic() + 20
            while not ready.exists():
                assert time.monotonic() < deadline, "the dashboard did not start"
                time.sleep(0.05)
            pid = int(
                subprocess.run(
                    [tmux, "list-panes", "-t", session, "-F", "#{pane_pid}"], capture_output=True, text=True, check=True
                ).stdout.split()[0]
            )
            host, port = json.loads(ready.read_text())["tcp"].rsplit(":", 1)
            client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=1, retries=0)
            assert client.connect()
            client.write_register(0x2001, 1500, device_id=1)
            client.write_register(0x2000, 1, device_id=1)
            client.close()
            time.sleep(1.0)  # settle: the first frames and the layout
            cpu, wall = proc_cpu(pid), time.monotonic()
            time.sleep(seconds)
            return (proc_cpu(pid) - cpu) / (time.monotonic() - wall)
        finally:
            subprocess.run([tmux, "kill-session", "-t", session], check=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()
    ref = asyncio.run(reference(args.seconds))
    head = asyncio.run(headless(args.seconds))
    real = terminal(args.seconds)
    print(f"motor running at 1500 rpm, 0.8 N m, realtime clock, {args.seconds:g} s each")
    print(f"{'run':<48} {'CPU s / wall s':>14}")
    print(f"{'reference: simulator synced at 5 Hz, no UI':<48} {ref:>14.4f}")
    print(f"{'dashboard headless (App.run_test, 120x40)':<48} {head:>14.4f}")
    if real is None:
        print(f"{'dashboard in tmux (120x40)':<48} {'skipped: no tmux':>14}")
    else:
        print(f"{'dashboard in tmux (120x40), whole process':<48} {real:>14.4f}")
    print(f"UI cost beyond the model (headless - reference): {head - ref:.4f} CPU s per wall s")


if __name__ == "__main__":
    main()

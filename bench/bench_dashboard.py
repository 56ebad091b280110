"""Reply latency over RTU-over-TCP with nobody watching, and with the dashboard open in a terminal, in one run.

The simulator runs in its own process (``c20sim serve``), and the dashboard is
a client of its control API, so a redraw should hold no reply. This measures
that, the motor running (1500 rpm, 0.8 N m, realtime clock) and a lean master
(bench/_common.py's RawRtuClient, one request at a time, every reply checked)
polling as fast as it can:

- headless: ``c20sim serve --tcp ... --control ...``, no viewer;
- stream: the same serve with one reader of its ``/stream`` (aiohttp, in a
  process of its own) asking what the dashboard asks, and drawing nothing:
  the server's own cost of a viewer, without a UI's CPU beside it;
- dashboard: ``c20sim dashboard --tcp ...`` in tmux (120x40), which starts the
  same serve as a child and attaches to it: telemetry at 5 Hz over the stream,
  the plot moving, every frame offered to its frame log.

The three take turns for ``--rounds`` rounds, each first in some round, so
the machine's noise falls on all; the profile is c20-400hr with turnaround 0 (a copy of its TOML), so the
latency is the server's, not a deliberate delay. Prints req/s, p50, p99 and the
worst reply of each run, CPU of the processes during the dashboard runs, and
the goals: p99 with the dashboard <= 2 x headless p99, worst < 20 ms.

    .venv/bin/python bench/bench_dashboard.py [--requests 30000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

from _common import ROOT, RawRtuClient, machine, percentile

from c20sim.control.client import ControlClient
from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg

TMUX = shutil.which("tmux")


def profile_copy(tmp: Path) -> Path:
    """c20-400hr with turnaround 0: the only change."""
    text = Path(load_profile().path or "").read_text()
    lines = [
        "turnaround_ms = 0.0               # the benchmark's copy: no deliberate delay" if line.startswith("turnaround_ms")
        else line
        for line in text.splitlines()
    ]  # fmt: skip
    path = tmp / "c20-400hr-t0.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def wait_for(what: str, check: object, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise SystemExit(f"bench_dashboard: timed out waiting for {what}")
        time.sleep(0.05)


def start_motor(info: dict[str, str]) -> None:
    host, port = info["tcp"].rsplit(":", 1)
    client = RawRtuClient(host, int(port))
    for frame in (WriteSingleRequest(1, Reg.SPEED_SETPOINT, 1500), WriteSingleRequest(1, Reg.COMMAND, 1)):
        client.transact(encode(frame))
    client.close()
    api = ControlClient(info["control"], info.get("token"))
    api.call("PATCH", "/drives/1/conditions", {"load_torque_nm": 0.8})
    wait_for("the motor at speed", lambda: api.call("GET", "/drives/1")["speed_rpm"] > 1400)
    api.close()


def poll(info: dict[str, str], count: int) -> tuple[list[float], float]:
    """``count`` sequential reads of the motor speed (3006H); latencies (s) and wall time."""
    host, port = info["tcp"].rsplit(":", 1)
    client = RawRtuClient(host, int(port), timeout=5.0)
    read = encode(ReadRequest(1, Reg.MOTOR_SPEED, 1))
    latencies = []
    perf = time.perf_counter
    start = perf()
    try:
        for _ in range(count):
            t = perf()
            reply = client.transact(read)
            latencies.append(perf() - t)
            if reply[:3] != b"\x01\x03\x02" or int.from_bytes(reply[3:5], "big") < 1400:
                raise AssertionError(f"read 3006H: reply {reply.hex(' ')}: the motor should be running")
    finally:
        client.close()
    return latencies, perf() - start


#: A stream reader that takes what the dashboard takes and draws nothing.
READER = """
import asyncio, sys, aiohttp
async def main(url):
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(url) as ws:
            async for _ in ws:
                pass
asyncio.run(main(sys.argv[1]))
"""


@contextlib.contextmanager
def with_stream(profile: Path, tmp: Path) -> Iterator[tuple[dict[str, str], list[int]]]:
    from c20sim.tui.app import FRAME_HZ, STREAM_BUFFER

    with headless(profile, tmp) as (info, pids):
        url = f"{info['control']}/stream?hz=5&frame_hz={FRAME_HZ}&buffer={STREAM_BUFFER}"
        reader = subprocess.Popen([sys.executable, "-c", READER, url], cwd=ROOT)
        try:
            yield info, [reader.pid, *pids]
        finally:
            reader.terminate()
            reader.wait(10)


@contextlib.contextmanager
def headless(profile: Path, tmp: Path) -> Iterator[tuple[dict[str, str], list[int]]]:
    ready = tmp / f"ready-{uuid.uuid4().hex[:6]}.json"
    argv = [sys.executable, "-m", "c20sim", "serve", "--profile", str(profile), "--tcp", "127.0.0.1:0"]
    argv.append("--no-bus-timing")  # the traffic as recorded before bus timing (issue 27)
    argv += ["--control", "127.0.0.1:0", "--ready-file", str(ready)]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, cwd=ROOT)
    try:
        wait_for("the ready file", ready.exists)
        yield json.loads(ready.read_text()), [proc.pid]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)


def children(pid: int) -> list[int]:
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError):
                stat = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                if int(stat[1]) == pid:
                    out.append(int(entry.name))
    return out


def proc_cpu(pid: int) -> float:
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextlib.contextmanager
def with_dashboard(profile: Path, tmp: Path) -> Iterator[tuple[dict[str, str], list[int]]]:
    assert TMUX is not None
    ready = tmp / f"ready-{uuid.uuid4().hex[:6]}.json"
    session = f"c20bench-{uuid.uuid4().hex[:6]}"
    # --no-bus-timing as for the headless serve: bus timing became the default (issue 27), and with it every read
    # waits out its RS485 time (about 80 reads/s), which is the line, not the dashboard
    command = (
        f"{sys.executable} -m c20sim dashboard --profile {profile} --tcp 127.0.0.1:0 --no-bus-timing"
        f" --ready-file {ready}"
    )
    subprocess.run([TMUX, "new-session", "-d", "-s", session, "-x", "120", "-y", "40"], check=True, cwd=ROOT)
    subprocess.run([TMUX, "set-option", "-w", "-t", session, "remain-on-exit", "on"], check=True)
    subprocess.run([TMUX, "respawn-pane", "-k", "-t", session, "-c", str(ROOT), command], check=True)

    def screen() -> str:
        argv = [TMUX, "capture-pane", "-p", "-S", "-40", "-t", session]
        return subprocess.run(argv, capture_output=True, text=True).stdout

    try:
        wait_for("the ready file", ready.exists)
        wait_for("the dashboard on screen", lambda: "STOPPED" in screen() or "FORWARD" in screen())
        pane = int(
            subprocess.run(
                [TMUX, "list-panes", "-t", session, "-F", "#{pane_pid}"], capture_output=True, text=True, check=True
            ).stdout.split()[0]
        )
        yield json.loads(ready.read_text()), [pane, *children(pane)]
        if "FORWARD RUNNING" not in screen():
            raise SystemExit(f"bench_dashboard: the dashboard did not show the motor running:\n{screen()}")
    finally:
        subprocess.run([TMUX, "send-keys", "-t", session, "q"], check=False)
        with contextlib.suppress(SystemExit):
            wait_for("the dashboard to close", lambda: not ready.exists(), timeout=15)
        subprocess.run([TMUX, "kill-session", "-t", session], check=False, stderr=subprocess.DEVNULL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=30_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    if TMUX is None:
        raise SystemExit("bench_dashboard: needs tmux (apt-get install tmux)")
    results: dict[str, list[float]] = {"headless": [], "stream": [], "dashboard": []}
    rows = []
    cpu_rows = []
    with tempfile.TemporaryDirectory(prefix="c20bench-") as name:
        tmp = Path(name)
        profile = profile_copy(tmp)
        for round_ in range(1, args.rounds + 1):
            runs = [("headless", headless), ("stream", with_stream), ("dashboard", with_dashboard)]
            for kind, start in runs[round_ % 3 :] + runs[: round_ % 3]:  # each goes first in some round
                with start(profile, tmp) as (info, pids):
                    start_motor(info)
                    time.sleep(1.0)  # the plot has samples and keeps moving
                    cpu = {pid: proc_cpu(pid) for pid in pids}
                    latencies, wall = poll(info, args.requests)
                    cpu_used = {pid: proc_cpu(pid) - cpu[pid] for pid in pids}
                latencies.sort()
                results[kind] += latencies
                rows.append(
                    (round_, kind, len(latencies) / wall, percentile(latencies, 50), percentile(latencies, 99),
                     latencies[-1])
                )  # fmt: skip
                cpu_rows.append((round_, kind, [cpu_used[pid] / wall for pid in pids]))
    print(f"{machine()}; {args.requests} reads of 3006H per run, motor at 1500 rpm, 0.8 N m, realtime clock")
    print(f"{'round':>5} {'run':<10} {'req/s':>8} {'p50 us':>8} {'p99 us':>8} {'worst ms':>9}")
    for round_, kind, rate, p50, p99, worst in rows:
        print(f"{round_:>5} {kind:<10} {rate:>8.0f} {p50 * 1e6:>8.0f} {p99 * 1e6:>8.0f} {worst * 1e3:>9.2f}")
    print("CPU s per wall s: the viewer's process (stream reader or dashboard), then the serve")
    for round_, kind, shares in cpu_rows:
        print(f"{round_:>5} {kind:<10} " + "  ".join(f"{share:.3f}" for share in shares))
    head, stream, dash = (sorted(results[k]) for k in ("headless", "stream", "dashboard"))
    p99_head, p99_stream, p99_dash = percentile(head, 99), percentile(stream, 99), percentile(dash, 99)
    print(
        f"all runs: p99 headless {p99_head * 1e6:.0f} us, stream reader {p99_stream * 1e6:.0f} us "
        f"(x{p99_stream / p99_head:.2f}), dashboard {p99_dash * 1e6:.0f} us (x{p99_dash / p99_head:.2f}); "
        f"worst {head[-1] * 1e3:.2f} / {stream[-1] * 1e3:.2f} / {dash[-1] * 1e3:.2f} ms"
    )
    print(f"goal p99 with the dashboard <= 2 x headless: {'met' if p99_dash <= 2 * p99_head else 'NOT met'}")
    print(f"goal worst reply < 20 ms with the dashboard: {'met' if dash[-1] < 0.020 else 'NOT met'}")


if __name__ == "__main__":
    main()

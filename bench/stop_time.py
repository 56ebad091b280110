"""Stop: time from SIGTERM to the exit of an idle ``c20sim serve``, over several runs and endpoint sets.

Each run starts ``python -m c20sim serve ... --ready-file F`` as a fresh process, waits for the ready file,
sets up what the case names (a master that has talked to the drive and keeps its connection or the pty open,
a dashboard's /stream reader), lets the server sit idle for half a second, sends SIGTERM and times until the
process has exited. Every run also checks that the stop was clean: exit code 0, nothing on stderr, the ready
file and the pty link gone. Prints median, min and max in milliseconds.

    .venv/bin/python bench/stop_time.py [--runs 10]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from _common import machine

#: What a case holds open while the server idles; returns what closes it.
Hold = Callable[[dict[str, str]], Callable[[], None]]

READ_2100 = bytes.fromhex("01 03 21 00 00 01 8E 36")
SPEED_1500 = bytes.fromhex("01 06 20 01 05 DC D1 03")
FORWARD_RUN = bytes.fromhex("01 06 20 00 00 01 43 CA")


def nothing(info: dict[str, str]) -> Callable[[], None]:
    return lambda: None


def rtu_masters(info: dict[str, str]) -> Callable[[], None]:
    """An RTU master on the pty and one on RTU over TCP, both still open; the TCP one has set the motor running
    (1500 rpm, forward run), as the README's first minutes do."""
    fd = os.open(info["pty"], os.O_RDWR | os.O_NOCTTY)
    os.write(fd, READ_2100)
    got = b""
    deadline = time.monotonic() + 5
    while len(got) < 7 and time.monotonic() < deadline:
        got += os.read(fd, 64)
    host, port = info["tcp"].rsplit(":", 1)
    sock = socket.create_connection((host, int(port)), timeout=5)
    for request in (READ_2100, SPEED_1500, FORWARD_RUN):
        sock.sendall(request)
        sock.recv(64)

    def close() -> None:
        sock.close()
        os.close(fd)

    return close


def stream_reader(info: dict[str, str]) -> Callable[[], None]:
    """A dashboard's view: a /stream WebSocket reading telemetry and frames."""
    import aiohttp

    done = threading.Event()
    connected = threading.Event()

    def run() -> None:
        async def read() -> None:
            async with aiohttp.ClientSession() as session, session.ws_connect(info["control"] + "/stream") as ws:
                connected.set()
                async for _ in ws:
                    if done.is_set():
                        break

        with contextlib.suppress(aiohttp.ClientError, OSError):
            asyncio.run(read())

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    connected.wait(5)

    def close() -> None:
        done.set()
        thread.join(5)

    return close


CONTROL = ["--control", "127.0.0.1:0"]
CASES: dict[str, tuple[list[str], Hold]] = {
    "pty, RTU/TCP, Modbus TCP (the defaults' set)": (
        ["--pty", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"],
        nothing,
    ),
    "... + control, state, frame log, link": (
        [
            "--tcp",
            "127.0.0.1:0",
            "--modbus-tcp",
            "127.0.0.1:0",
            *CONTROL,
            "--state",
            "{dir}/state.toml",
            "--log-frames",
            "{dir}/frames.jsonl",
            "--link",
            "{dir}/ttyC20",
        ],
        nothing,
    ),
    "... + RTU masters on the pty and TCP, motor running": (
        ["--link", "{dir}/ttyC20", "--tcp", "127.0.0.1:0", *CONTROL, "--state", "{dir}/state.toml"],
        rtu_masters,
    ),
    "... + a dashboard's /stream reader": (
        ["--link", "{dir}/ttyC20", "--tcp", "127.0.0.1:0", *CONTROL],
        stream_reader,
    ),
    "pty --line-timing": (["--link", "{dir}/ttyC20", "--line-timing"], nothing),
}


def time_stop(options: list[str], hold: Hold, folder: Path) -> float:
    ready = folder / "ready.json"
    ready.unlink(missing_ok=True)
    argv = [sys.executable, "-m", "c20sim", "serve", *(o.format(dir=folder) for o in options), "--ready-file"]
    proc = subprocess.Popen([*argv, str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise SystemExit(f"serve did not start: {proc.communicate()[1]}")
        time.sleep(0.01)
    info: dict[str, Any] = json.loads(ready.read_text())
    release = hold(info)
    time.sleep(0.5)  # idle
    start = time.perf_counter()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    took = time.perf_counter() - start
    release()
    link = folder / "ttyC20"
    if proc.returncode != 0 or err or ready.exists() or link.exists():
        raise SystemExit(
            f"unclean stop: exit {proc.returncode}, stderr {err!r}, ready file left: {ready.exists()}, "
            f"link left: {link.exists()}"
        )
    return took


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    print(f"stop on SIGTERM, idle: {machine()}, {args.runs} runs a case, interleaved")
    times: dict[str, list[float]] = {name: [] for name in CASES}
    with tempfile.TemporaryDirectory(prefix="c20sim-stop-") as tmp:
        for _ in range(args.runs):
            for name, (options, hold) in CASES.items():
                times[name].append(time_stop(options, hold, Path(tmp)))
    print(f"{'case':<48} {'median':>7} {'min':>6} {'max':>6}  (ms)")
    for name, values in times.items():
        ms = [v * 1000 for v in values]
        print(f"{name:<48} {statistics.median(ms):7.0f} {min(ms):6.0f} {max(ms):6.0f}")
    worst = max(max(v) for v in times.values())
    print(f"worst {worst * 1000:.0f} ms: {'PASS' if worst <= 0.3 else 'FAIL'} (0.3 s asked for); every stop clean")
    return 0 if worst <= 0.3 else 1


if __name__ == "__main__":
    sys.exit(main())

"""Bus timing (issue 27): the rate a master over TCP gets, against the RS485 line's capacity.

``c20sim serve --tcp`` runs as a child process (the real CLI: bus timing is its default) at each baud; a
lean blocking RTU-over-TCP master (bench/_common.py) reads 2100H one register at a time, as fast as the
replies come, for ``--seconds``; then two such masters at once (they share the line, as behind a serial
device server); then the same single master with ``--no-bus-timing`` for contrast. The line's capacity is
1 / transaction_time(8, 7, baud, 10 bits, turnaround) with the profile's 2 ms turnaround, and without it
(the bare line: request, reply, a t3.5 before each). The measured rate must stay below the capacity with
the turnaround (a lower bound on time is all bus timing promises; the loop's timers add to it).

Run it alone, on an idle machine:

    .venv/bin/python bench/bench_bus_timing.py --seconds 5
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import RawRtuClient, machine

from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import ReadRequest, encode, transaction_time
from c20sim.wire.registers import Reg

BAUDS = (9600, 19200, 38400)


def start(baud: int, *extra: str) -> tuple[subprocess.Popen[bytes], int, Path]:
    tmp = Path(tempfile.mkdtemp(prefix="c20sim-bench-"))
    ready = tmp / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--baud", str(baud)]
    proc = subprocess.Popen([*command, *extra, "--ready-file", str(ready)], stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 30.0
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("c20sim serve did not start")
        time.sleep(0.05)
    port = int(json.loads(ready.read_text())["tcp"].rsplit(":", 1)[1])
    return proc, port, tmp


def poll(port: int, seconds: float, counts: list[int], slot: int) -> None:
    client = RawRtuClient("127.0.0.1", port, timeout=2.0)
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    end = time.monotonic() + seconds
    try:
        while time.monotonic() < end:
            client.transact(frame)
            counts[slot] += 1
    finally:
        client.close()


def rate(port: int, seconds: float, masters: int) -> float:
    counts = [0] * masters
    threads = [threading.Thread(target=poll, args=(port, seconds, counts, i)) for i in range(masters)]
    began = time.monotonic()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return sum(counts) / (time.monotonic() - began)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="polling time per measurement")
    args = parser.parse_args()
    turnaround = load_profile("c20-400hr").protocol.turnaround_ms / 1000.0
    print(f"{machine()}; {args.seconds:g} s per figure; one-register reads of 2100H, 8N1\n")
    print("| baud | line capacity (with 2 ms turnaround / bare) | 1 master | 2 masters together | --no-bus-timing |")
    print("|---|---|---|---|---|")
    for baud in BAUDS:
        capacity = 1.0 / transaction_time(8, 7, baud, 10, turnaround)
        bare = 1.0 / transaction_time(8, 7, baud, 10)
        proc, port, _ = start(baud)
        try:
            one = rate(port, args.seconds, 1)
            two = rate(port, args.seconds, 2)
        finally:
            proc.terminate()
            proc.wait(10)
        proc, port, _ = start(baud, "--no-bus-timing")
        try:
            free = rate(port, args.seconds, 1)
        finally:
            proc.terminate()
            proc.wait(10)
        print(f"| {baud} | {capacity:.1f} / {bare:.1f} /s | {one:.1f} /s | {two:.1f} /s | {free:.1f} /s |")


if __name__ == "__main__":
    main()

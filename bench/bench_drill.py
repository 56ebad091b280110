"""What a drill costs the wire outside its incidents: a polite master's p99 with a drill running, and idle.

    .venv/bin/python bench/bench_drill.py [--requests N] [--rate R] [--rounds K]

One simulator (realtime clock, bus timing on, RTU over TCP, as ``c20sim drill`` serves it) in this process's
background thread; a polite master (one read of 3006H at a time, paced at R a second, each reply checked) in a
child process measures each round trip. Rounds alternate: idle (nothing but the master), and a drill running
between incidents: the drill's frame recorder subscribed to the bus, and its runner polling the simulator's
thread every 5 ms, as it does while a reply fault is armed (the most it ever asks of the loop). Prints p50 and
p99 of each, and the p99 ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine, percentile

from c20sim.drillrun import _Recorder
from c20sim.testing import C20Sim

MASTER = r"""
import socket, struct, sys, time
host, port, count, rate = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc
body = struct.pack(">BBHH", 1, 3, 0x3006, 1)
frame = body + crc16(body).to_bytes(2, "little")
s = socket.create_connection((host, port))
s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
out = []
due = time.perf_counter()
for _ in range(count):
    due += 1.0 / rate
    t0 = time.perf_counter()
    s.sendall(frame)
    buf = b""
    while len(buf) < 7:
        buf += s.recv(64)
    assert crc16(buf) == 0, buf.hex()
    out.append(time.perf_counter() - t0)
    pause = due - time.perf_counter()
    if pause > 0:
        time.sleep(pause)
print(" ".join(f"{x:.7f}" for x in out))
"""


def round_trips(sim: C20Sim, requests: int, rate: float) -> list[float]:
    done = subprocess.run(
        [sys.executable, "-c", MASTER, str(sim.host), str(sim.port), str(requests), str(rate)],
        capture_output=True,
        text=True,
        check=True,
    )
    return [float(x) for x in done.stdout.split()]


def drilling(sim: C20Sim, requests: int, rate: float) -> list[float]:
    recorder = _Recorder()
    unsubscribe = sim.call(lambda: sim.sim.bus.subscribe(recorder))
    stop = threading.Event()

    def poll() -> None:
        while not stop.is_set():
            sim.call(lambda: sim.sim.link_faults(None).replies)
            time.sleep(0.005)

    poller = threading.Thread(target=poll, daemon=True)
    poller.start()
    try:
        return round_trips(sim, requests, rate)
    finally:
        stop.set()
        poller.join()
        sim.call(unsubscribe)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=1000)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    idle: list[float] = []
    drill: list[float] = []
    with C20Sim.start(transport="tcp", clock="realtime", bus_timing=True) as sim:
        round_trips(sim, 50, args.rate)  # warm the path
        for _ in range(args.rounds):
            idle += round_trips(sim, args.requests, args.rate)
            drill += drilling(sim, args.requests, args.rate)
    idle.sort()
    drill.sort()
    print(f"{machine()}; {args.rounds} alternating rounds of {args.requests} reads at {args.rate:g}/s each")
    for name, values in (("idle", idle), ("drill", drill)):
        print(f"  {name:<6} p50 {percentile(values, 50) * 1000:.3f} ms  p99 {percentile(values, 99) * 1000:.3f} ms")
    print(f"  p99 ratio drill/idle {percentile(drill, 99) / percentile(idle, 99):.3f}")


if __name__ == "__main__":
    main()

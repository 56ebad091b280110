"""How fast ``c20sim audit`` reads a frame log, and that its memory stays bounded.

Writes a frame log of N frames (default 1,000,000) as ``serve --log-frames`` writes it: a
master polling four drives (status, speed, current of each, every 100 ms), writing a speed
reference now and then, reading an absent register, and each request's reply. Then audits it
in this process, as ``c20sim audit`` does (the same reader and engine), and prints the CPU and
wall time, the frames a second, and the resident memory before and after. A reference loop
gives the ratio, for noisy machines.

    .venv/bin/python bench/bench_audit.py [--frames 1000000]

With ``--live``, it measures what the live audit costs the wire instead: two c20sim servers in child
processes (turnaround 0), one with the audit on (serve's default) and one with ``--no-audit``, taking
turns in rounds under one sequential RTU-over-TCP client (bench_tcp.py's write/read pairs) at a low
load (``--rate``, 200 requests a second by default; 0: back to back, the wire saturated); run it alone on
the machine. It prints p50 and p99 of each and the ratio of the p99s (target: within 1.1).

    .venv/bin/python bench/bench_audit.py --live [--requests 10000 --rounds 5 --rate 200]

``--bus`` measures the audit's own cost, in this process and free of the network's noise: the bus
serving write/read pairs with and without the live audit, best of alternating rounds.

    .venv/bin/python bench/bench_audit.py --bus [--requests 20000 --rounds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import ChildServer, RawRtuClient, ServerSpec, cpu_seconds, machine, percentile, rss_kib

try:
    from bench_tcp import run as transact_pairs
except ImportError:  # bench_tcp.py has no run() since its loadgen rewrite: --live cannot measure; the rest can
    transact_pairs = None

from c20sim.audit import Auditor
from c20sim.drive.profile import load_profile
from c20sim.traffic.auditlog import audit_log
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    encode,
)


def reference_loop() -> float:
    x = 0.0
    for i in range(1_000_000):
        x = x * 0.999 + i
    return x


def write_log(path: Path, frames: int) -> None:
    cycle: list[tuple[bytes, bytes, str]] = []
    for slave in (1, 2, 3, 4):
        for register in (0x2100, 0x3006, 0x3004):
            cycle.append((encode(ReadRequest(slave, register, 1)), encode(ReadResponse(slave, (5,))), "reply"))
    cycle.append((encode(WriteSingleRequest(1, 0x2001, 1500)), encode(WriteSingleResponse(1, 0x2001, 1500)), "reply"))
    absent = encode(ExceptionResponse(2, 3, ExceptionCode.ILLEGAL_ADDRESS))
    cycle.append((encode(ReadRequest(2, 0x0032, 1)), absent, "exception"))
    step = 0.1 / len(cycle)
    t = 0.0
    written = 0
    with path.open("w") as out:
        while written < frames:
            for request, reply, kind in cycle:
                for direction, data, what, at in (("rx", request, "request", t), ("tx", reply, kind, t + 0.002)):
                    record = {
                        "t": round(at, 6),
                        "wall": round(1.7e9 + at, 3),
                        "model_t": round(t, 6),
                        "dir": direction,
                        "hex": data.hex(" ").upper(),
                        "kind": what,
                        "slave": data[0],
                        "text": "2100H = 0005h (status word 1: stopped)",
                        "note": "",
                    }
                    out.write(json.dumps(record) + "\n")
                    written += 1
                t += step
                if written >= frames:
                    break


def paced(client: RawRtuClient, count: int, first: int, rate: float) -> list[float]:
    """``count`` write/read pairs' latencies, a request every ``1 / rate`` s (0: back to back)."""
    if transact_pairs is None:
        raise SystemExit("bench_audit --live: bench_tcp.py no longer has run(), the sequential client it drives")
    if rate <= 0:
        return transact_pairs(client, count, first)
    latencies: list[float] = []
    period = 1.0 / rate
    due = time.perf_counter()
    for i in range(count // 2):
        due += 2 * period
        latencies += transact_pairs(client, 2, first + i)
        pause = due - time.perf_counter()
        if pause > 0:
            time.sleep(pause)
    return latencies


def live(requests: int, rounds: int, rate: float) -> None:
    servers = {
        "audit on": ChildServer(ServerSpec("c20sim", turnaround_ms=0.0, audit=True)),
        "audit off (--no-audit)": ChildServer(ServerSpec("c20sim", turnaround_ms=0.0, audit=False)),
    }
    latencies: dict[str, list[float]] = {name: [] for name in servers}
    try:
        clients = {name: RawRtuClient("127.0.0.1", server.port) for name, server in servers.items()}
        for client in clients.values():
            transact_pairs(client, 1000, 0)  # warm up
        for r in range(rounds):
            for name, client in clients.items() if r % 2 == 0 else reversed(clients.items()):
                latencies[name] += paced(client, requests // rounds, r * requests, rate)
        for client in clients.values():
            client.close()
    finally:
        for server in servers.values():
            server.stop()
    print(machine())
    pace = f"{rate:g} requests/s" if rate > 0 else "back to back"
    print(f"{requests:,} sequential requests per server, {pace}, in {rounds} alternating rounds (write/read 2001H)")
    p99 = {}
    for name, values in latencies.items():
        values.sort()
        p99[name] = percentile(values, 99)
        print(f"  {name:<24} p50 {percentile(values, 50) * 1e3:.3f} ms  p99 {p99[name] * 1e3:.3f} ms")
    print(f"p99 audit on / off: {p99['audit on'] / p99['audit off (--no-audit)']:.3f} (target: <= 1.1)")


def on_the_bus(requests: int, rounds: int) -> None:
    """The audit's cost a request in this process: the bus serving write/read pairs with and without it."""
    import dataclasses

    from c20sim.control import liveaudit
    from c20sim.core.clock import VirtualClock
    from c20sim.core.simulator import Simulator
    from c20sim.wire.protocol import FrameEvent, FrameKind

    base = load_profile("c20-400hr")
    profile = dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, turnaround_ms=0.0))
    frames = [encode(WriteSingleRequest(1, 0x2001, v % 3000)) for v in range(1000)]
    frames += [encode(ReadRequest(1, 0x2001, 1))] * 1000

    def serve(audited: bool) -> float:
        sim = Simulator(profile, (1,), clock=VirtualClock())
        audit = liveaudit.start(sim) if audited else None
        start, t0 = time.perf_counter(), time.monotonic()
        for k in range(requests):
            sim.bus.handle(FrameEvent(FrameKind.FRAME, frames[k % len(frames)], t0 + k * 1e-4), sim.now())
        elapsed = time.perf_counter() - start
        if audit is not None:
            audit.close()
        return elapsed / requests

    best = {True: float("inf"), False: float("inf")}
    for _ in range(rounds):
        for audited in (False, True):
            best[audited] = min(best[audited], serve(audited))
    print(machine())
    print(f"the bus serving {requests:,} requests (write/read 2001H), best of {rounds} alternating rounds")
    print(f"  audit off  {best[False] * 1e6:.2f} us a request")
    print(f"  audit on   {best[True] * 1e6:.2f} us a request (+{(best[True] - best[False]) * 1e6:.2f} us)")
    print(f"ratio on / off: {best[True] / best[False]:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1_000_000)
    parser.add_argument("--live", action="store_true", help="the live audit's cost to the wire's p99 instead")
    parser.add_argument("--bus", action="store_true", help="the live audit's cost a request on the bus, in process")
    parser.add_argument("--requests", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--rate", type=float, default=200.0, help="--live: requests a second (0: back to back)")
    args = parser.parse_args()
    if args.live:
        live(args.requests, args.rounds, args.rate)
        return
    if args.bus:
        on_the_bus(args.requests, args.rounds)
        return
    profile = load_profile("c20-400hr")
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "frames.jsonl"
        write_log(log, args.frames)
        size = os.path.getsize(log)
        start = time.process_time()
        reference_loop()
        reference = time.process_time() - start
        rss_before = rss_kib()
        wall, cpu = time.perf_counter(), cpu_seconds()
        auditor = audit_log(str(log), Auditor(profile))
        wall, cpu = time.perf_counter() - wall, cpu_seconds() - cpu
        rss_after = rss_kib()
    print(machine())
    print(f"log: {args.frames:,} frames, {size / 1e6:.0f} MB")
    print(f"reference loop (1e6 float multiply-adds): {reference * 1e3:.1f} ms CPU")
    print(
        f"audit: {wall:.2f} s wall, {cpu:.2f} s CPU ({cpu / reference:.0f} x reference), "
        f"{args.frames / wall:,.0f} frames/s"
    )
    print(f"RSS before {rss_before / 1024:.1f} MiB, after {rss_after / 1024:.1f} MiB")
    for finding in auditor.findings():
        print("  " + finding.line())
    print(f"line demand peak {auditor.line_demand().peak:.0f} %")


if __name__ == "__main__":
    main()

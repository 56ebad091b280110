"""Throughput and latency over RTU over TCP: c20sim beside pymodbus's own server and the Python floor, in one run.

Each server runs in a child process of its own, pinned to core 0; the load comes from the C client
(bench/loadgen.c), which costs the measurement about 2 us a request where a Python client costs 20-30,
and checks every reply (length, CRC, address, function). ``--placement`` puts the client on core 1
("split", the default: client and server never compete for a core, but every request and reply wakes
the other core, which on a VM costs tens of microseconds a round trip), on core 0 beside the server
("same": a round trip is the two processes' CPU alone), or runs both. Two loads: single-register reads of
2001H (a master polling: the issue's measurement), and write 2001H = v then read 2001H, v changing every
write (the drive derives its settings anew at each write). The servers take turns in rounds, so that the
machine's noise falls on all of them alike: the ratios are the figures.

Servers:
- c20sim as ``c20sim serve`` runs it (the live audit on) with its bus timing off and a turnaround of 0
  (a profile copy): the server's own speed, not the RS485 line's, which bus timing would impose;
- the same with ``--no-audit``;
- pymodbus 3.16's ``ModbusTcpServer`` with ``FramerType.RTU`` over a ``ModbusSequentialDataBlock``;
- the floor: an asyncio protocol on uvloop that answers a canned reply and parses nothing (the fastest a
  Python server on this loop can be).

Sequential: one connection, one request at a time (a master's rhythm): requests/s, latency p50/p99, and
the server's CPU per request. Saturated: ``--clients`` connections at once: requests/s and CPU per
request, and the fewest and most requests any connection got through.

    .venv/bin/python bench/bench_tcp.py --seconds 2 --rounds 5 --clients 4 [--mix reads|write-read|both]
        [--placement split|same|both]
"""

from __future__ import annotations

import argparse
import sys
import time
from statistics import median

import pymodbus
from _common import ChildServer, ServerSpec, loadgen, machine, pin_process

from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg

C20SIM = "c20sim (serve's default, bus timing off, turnaround 0)"
NO_AUDIT = "c20sim --no-audit (bus timing off, turnaround 0)"
PYMODBUS = f"pymodbus {pymodbus.__version__} ModbusTcpServer (RTU framer)"
FLOOR = "floor (uvloop protocol, canned reply)"

SERVERS = {
    C20SIM: ServerSpec("c20sim", turnaround_ms=0.0),
    NO_AUDIT: ServerSpec("c20sim", turnaround_ms=0.0, audit=False),
    PYMODBUS: ServerSpec("pymodbus"),
    FLOOR: ServerSpec("floor"),
}

#: the loads: single-register reads of 2001H (the issue's measurement, a master polling), and write 2001H = v
#: then read 2001H for eight values of v (every write changes the set speed, so the drive derives its
#: settings anew each time: the dearer request)
MIXES = {
    "reads": [encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))],
    "write-read": [
        frame
        for v in range(100, 900, 100)
        for frame in (
            encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, v)),
            encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1)),
        )
    ],
}

SERVER_CPU = {0}
#: where the C client runs: beside the servers' core, or on it
PLACEMENTS = {"split": {1}, "same": {0}}


def measure(
    server: ChildServer, frames: list[bytes], conns: int, seconds: float, client_cpus: set[int]
) -> dict[str, float]:
    cpu0 = server.cpu_rss()[0]
    figures = loadgen([server.port], frames, conns=conns, seconds=seconds, warmup=0.3, cpus=client_cpus)
    cpu = server.cpu_rss()[0] - cpu0
    # the server's CPU over warm-up and run, per request answered in both (at the measured rate)
    figures["cpu_us"] = cpu / (figures["req_s"] * (seconds + 0.3)) * 1e6
    return figures


def table(rows: dict[str, dict[str, float]], columns: list[tuple[str, str, str]]) -> None:
    header = f"| {'server':<58} |" + "".join(f" {title:>{len(title)}} |" for title, _, _ in columns)
    print(header)
    print("|" + "|".join("-" * len(cell) for cell in header.split("|")[1:-1]) + "|")
    for name, figures in rows.items():
        print(f"| {name:<58} |" + "".join(f" {figures[key]:>{len(title)}{fmt}} |" for title, key, fmt in columns))


def ratios(figures: dict[str, dict[str, float]], *, latency: bool) -> None:
    """The issue's targets for one mode: requests/s against the floor and pymodbus (and the p99 sequentially)."""

    def rate(a: str, b: str) -> float:
        return figures[a]["req_s"] / figures[b]["req_s"]

    print(f"c20sim / floor: {rate(C20SIM, FLOOR):.2f}x requests/s (target >= 0.6x)")
    print(f"c20sim / pymodbus: {rate(C20SIM, PYMODBUS):.2f}x requests/s (target >= 1.5x)")
    if latency:
        c20sim_p99, pymodbus_p50 = figures[C20SIM]["p99_us"], figures[PYMODBUS]["p50_us"]
        print(f"c20sim p99 {c20sim_p99:.1f} us, pymodbus p50 {pymodbus_p50:.1f} us (target: below)")
    print(f"--no-audit / floor: {rate(NO_AUDIT, FLOOR):.2f}x; / pymodbus: {rate(NO_AUDIT, PYMODBUS):.2f}x")
    print()


def report(mix: str, seq: dict[str, dict[str, float]], sat: dict[str, dict[str, float]], clients: int) -> None:
    print(f"### {mix}: " + ("single-register reads of 2001H" if mix == "reads" else "write 2001H = v, read 2001H"))
    print()
    print("Sequential: one connection, one request at a time")
    print()
    table(
        seq,
        [
            ("req/s", "req_s", ".0f"),
            ("p50 us", "p50_us", ".1f"),
            ("p99 us", "p99_us", ".1f"),
            ("CPU us/req", "cpu_us", ".1f"),
        ],
    )
    print()
    ratios(seq, latency=True)
    print(f"Saturated: {clients} connections at once")
    print()
    table(
        sat,
        [
            ("req/s", "req_s", ".0f"),
            ("CPU us/req", "cpu_us", ".1f"),
            ("fewest", "fewest", ".0f"),
            ("most", "most", ".0f"),
        ],
    )
    print()
    ratios(sat, latency=False)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=2.0, help="seconds of load per server, load and round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--clients", type=int, default=4, help="connections at once, for the saturated run")
    parser.add_argument("--mix", choices=[*MIXES, "both"], default="both", help="the requests (default: both loads)")
    parser.add_argument(
        "--placement",
        choices=[*PLACEMENTS, "both"],
        default="split",
        help="the client on core 1 (split, the default), on the servers' core 0 (same), or both",
    )
    args = parser.parse_args()
    mixes = list(MIXES) if args.mix == "both" else [args.mix]
    placements = list(PLACEMENTS) if args.placement == "both" else [args.placement]

    servers = {name: ChildServer(spec) for name, spec in SERVERS.items()}
    Runs = dict[str, list[dict[str, float]]]
    runs: dict[tuple[str, str, str], Runs] = {
        (place, mix, mode): {name: [] for name in servers}
        for place in placements
        for mix in mixes
        for mode in ("seq", "sat")
    }
    try:
        for server in servers.values():
            assert server.process.pid is not None  # started
            pin_process(server.process.pid, SERVER_CPU)
        for _ in range(args.rounds):
            for place in placements:
                for mix in mixes:
                    for mode, conns in (("seq", 1), ("sat", args.clients)):
                        for name, server in servers.items():
                            figures = measure(server, MIXES[mix], conns, args.seconds, PLACEMENTS[place])
                            runs[place, mix, mode][name].append(figures)
    finally:
        for server in servers.values():
            server.stop()

    def medians(found: Runs) -> dict[str, dict[str, float]]:
        return {name: {key: median(r[key] for r in rs) for key in rs[0]} for name, rs in found.items()}

    print(f"RTU over TCP, {time.strftime('%Y-%m-%d')}, {machine()}")
    print(f"{args.rounds} alternating rounds of {args.seconds:g} s per server, load and mode (medians of the rounds)")
    print()
    for place in placements:
        where = "core 1" if place == "split" else "core 0, beside them"
        print(f"## placement {place}: the servers on core 0, the C client on {where}")
        print()
        for mix in mixes:
            report(mix, medians(runs[place, mix, "seq"]), medians(runs[place, mix, "sat"]), args.clients)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Throughput and latency over RTU-over-TCP: c20sim beside pymodbus's own server, in the same run.

Each server runs in a child process of its own; one lean blocking client
(bench/_common.py, the same for every server) sends sequential requests,
alternately ``write 2001H = v`` and ``read 2001H`` to drive 1, and checks every
reply. The servers take turns in rounds so that the machine's noise falls on
all of them alike; the ratio is the figure.

Servers: c20sim with turnaround 0 (a profile copy, ``dataclasses.replace`` of
``profile.protocol``), c20sim with the default profile (turnaround 2 ms, a
deliberate delay per reply), and pymodbus 3.16's ``ModbusTcpServer`` with
``FramerType.RTU`` and a ``ModbusSequentialDataBlock`` holding the registers.

    .venv/bin/python bench/bench_tcp.py --requests 20000 --rounds 5
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from typing import Any

import pymodbus
from _common import ChildServer, RawRtuClient, ServerSpec, machine, percentile

from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg

SERVERS = {
    "c20sim (turnaround 0)": ServerSpec("c20sim", turnaround_ms=0.0),
    "c20sim (default profile, turnaround 2 ms)": ServerSpec("c20sim", turnaround_ms=None),
    f"pymodbus {pymodbus.__version__} ModbusTcpServer": ServerSpec("pymodbus"),
}


def run(client: RawRtuClient, count: int, first: int) -> list[float]:
    """``count`` sequential requests; their latencies in seconds."""
    latencies: list[float] = []
    perf = time.perf_counter
    for i in range(count // 2):
        value = (first + i) % 3001
        write = encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, value))
        read = encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))
        t = perf()
        reply = client.transact(write)
        t1 = perf()
        if reply != write:
            raise AssertionError(f"write {value}: reply {reply.hex(' ')}")
        reply = client.transact(read)
        t2 = perf()
        if int.from_bytes(reply[3:5], "big") != value:
            raise AssertionError(f"read after write {value}: reply {reply.hex(' ')}")
        latencies += (t1 - t, t2 - t1)
    return latencies


def _client_process(port: int, count: int, out: Any) -> None:
    """Sequential reads of 2001H (the clients share the drive, so each checks the reply's form only)."""
    client = RawRtuClient("127.0.0.1", port, timeout=5.0)
    read = encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))
    try:
        for _ in range(count):
            reply = client.transact(read)
            if reply[:3] != b"\x01\x03\x02":
                raise AssertionError(f"read 2001H: reply {reply.hex(' ')}")
    finally:
        client.close()
    out.send(count)


def saturate(servers: dict[str, ChildServer], clients: int, count: int, rounds: int) -> dict[str, tuple[float, float]]:
    """``clients`` client processes at once against each server in turn: (req/s, server CPU us/req)."""
    ctx = multiprocessing.get_context("fork")
    totals: dict[str, list[float]] = {name: [0.0, 0.0, 0.0] for name in servers}  # requests, wall, cpu
    for _ in range(rounds):
        for name, server in servers.items():
            pipes = [ctx.Pipe() for _ in range(clients)]
            procs = [ctx.Process(target=_client_process, args=(server.port, count, child)) for _, child in pipes]
            cpu0 = server.cpu_rss()[0]
            t0 = time.perf_counter()
            for proc in procs:
                proc.start()
            done = sum(parent.recv() for parent, _ in pipes)
            wall = time.perf_counter() - t0
            for proc in procs:
                proc.join()
            totals[name][0] += done
            totals[name][1] += wall
            totals[name][2] += server.cpu_rss()[0] - cpu0
    return {name: (n / wall, cpu / n * 1e6) for name, (n, wall, cpu) in totals.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=20000, help="requests per server, over all rounds")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=500)
    parser.add_argument("--clients", type=int, default=4, help="client processes at once, for the saturated run")
    args = parser.parse_args()

    servers = {name: ChildServer(spec) for name, spec in SERVERS.items()}
    clients = {name: RawRtuClient("127.0.0.1", server.port, timeout=5.0) for name, server in servers.items()}
    latencies: dict[str, list[float]] = {name: [] for name in servers}
    wall: dict[str, float] = dict.fromkeys(servers, 0.0)
    cpu: dict[str, float] = dict.fromkeys(servers, 0.0)
    per_round = args.requests // args.rounds
    saturated: dict[str, tuple[float, float]] = {}
    try:
        for client in clients.values():
            run(client, args.warmup, 0)
        for r in range(args.rounds):
            for name, client in clients.items():
                cpu0 = servers[name].cpu_rss()[0]
                t0 = time.perf_counter()
                latencies[name] += run(client, per_round, r * per_round)
                wall[name] += time.perf_counter() - t0
                cpu[name] += servers[name].cpu_rss()[0] - cpu0
        fast_servers = {n: s for n, s in servers.items() if "default profile" not in n}
        saturated = saturate(fast_servers, args.clients, args.requests // args.rounds // args.clients, args.rounds)
    finally:
        for client in clients.values():
            client.close()
        for server in servers.values():
            server.stop()

    print(f"RTU over TCP, sequential requests, {time.strftime('%Y-%m-%d')}, {machine()}")
    print(f"{args.requests} requests per server in {args.rounds} alternating rounds (write 2001H / read 2001H)")
    print()
    header = f"| {'server':<42} | {'req/s':>7} | {'p50 ms':>7} | {'p99 ms':>7} | {'server CPU us/req':>17} |"
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|")
    rates = {}
    p = {}
    for name in servers:
        lat = sorted(latencies[name])
        rates[name] = len(lat) / wall[name]
        p[name] = (percentile(lat, 50) * 1000, percentile(lat, 99) * 1000)
        per_req = cpu[name] / len(lat) * 1e6
        print(f"| {name:<42} | {rates[name]:>7.0f} | {p[name][0]:>7.3f} | {p[name][1]:>7.3f} | {per_req:>17.1f} |")
    fast, default, pym = list(servers)
    print()
    print(f"throughput ratio c20sim (turnaround 0) / pymodbus: {rates[fast] / rates[pym]:.2f}x (target >= 1.5x)")
    print(f"c20sim p99 {p[fast][1]:.3f} ms vs pymodbus p50 {p[pym][0]:.3f} ms (target: below)")
    print(f"default profile / pymodbus: {rates[default] / rates[pym]:.2f}x (the 2 ms turnaround is deliberate)")
    print()
    print(f"saturated: {args.clients} client processes at once, each reading 2001H sequentially, same totals")
    print()
    header = f"| {'server':<42} | {'req/s':>7} | {'server CPU us/req':>17} |"
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|")
    for name, (rate, per_req) in saturated.items():
        print(f"| {name:<42} | {rate:>7.0f} | {per_req:>17.1f} |")
    sat_fast, sat_pym = (saturated[n][0] for n in saturated)
    print()
    print(f"saturated throughput ratio c20sim (turnaround 0) / pymodbus: {sat_fast / sat_pym:.2f}x (target >= 1.5x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

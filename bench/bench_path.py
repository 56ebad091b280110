"""The request path's own cost, in one process: a request's bytes handed to the connection, to its reply written.

No socket and no second process: the real RTU-over-TCP connection, endpoint, line, bus, slave and drive of
``c20sim serve``, on uvloop, with a transport that only counts what it is given. Each request is one loop
turn (``data_received``, then ``await asyncio.sleep(0)``, which runs what the request scheduled: the
endpoint's next read, the live audit); a loop of bare turns is timed first and taken off, so the figure is
the microseconds of Python a request costs. The same for the floor (a protocol that writes a canned reply)
and for pymodbus 3.16's own server protocol fed the same frame.

    .venv/bin/python bench/bench_path.py --requests 50000 --rounds 5 [--profile]

``--profile`` prints cProfile's view of the path (its own overhead inflates every figure about 3x; read the
shares, not the microseconds). ``--split`` times each request to the moment its reply is written and to the
end of ``data_received``: what a master waits for, and what comes after its reply.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import cProfile
import dataclasses
import logging
import pstats
import statistics
import sys
import time
from collections.abc import AsyncIterator
from typing import Any

from _common import Floor, machine

from c20sim.core.clock import RealtimeClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server, run
from c20sim.transport.tcp import RtuOverTcpServer, _RtuConnection
from c20sim.wire.protocol import ReadRequest, WriteSingleRequest, encode
from c20sim.wire.registers import Reg


class CountingTransport:
    """What a connection writes to, counted and dropped."""

    def __init__(self) -> None:
        self.writes = 0
        self.last = b""
        self.written_at = 0.0  #: time.perf_counter() at the last write

    def write(self, data: bytes) -> None:
        self.writes += 1
        self.last = data
        self.written_at = time.perf_counter()

    def set_write_buffer_limits(self, high: int | None = None, low: int | None = None) -> None:
        pass

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return ("127.0.0.1", 40000) if name == "peername" else default

    def is_closing(self) -> bool:
        return False

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass

    def close(self) -> None:
        pass


async def bare_turns(n: int) -> float:
    sleep = asyncio.sleep
    t0 = time.perf_counter()
    for _ in range(n):
        await sleep(0)
    return time.perf_counter() - t0


async def drive_protocol(protocol: Any, frames: list[bytes], n: int, profile: cProfile.Profile | None) -> float:
    """``n`` requests through ``protocol``, one a loop turn; seconds taken."""
    sleep = asyncio.sleep
    count = len(frames)
    if profile is not None:
        profile.enable()
    t0 = time.perf_counter()
    for i in range(n):
        protocol.data_received(frames[i % count])
        await sleep(0)
    seconds = time.perf_counter() - t0
    if profile is not None:
        profile.disable()
    return seconds


@contextlib.asynccontextmanager
async def served_connection(audit: bool) -> AsyncIterator[tuple[_RtuConnection, CountingTransport]]:
    """A ``c20sim serve`` server (turnaround 0, bus timing off) and one RTU-over-TCP connection of it, on a
    transport that only counts."""
    base = load_profile()
    base = dataclasses.replace(base, protocol=dataclasses.replace(base.protocol, turnaround_ms=0.0))
    sim = Simulator(base, (1,), clock=RealtimeClock(), seed=1)
    server = Server(sim, ServeOptions(tcp="127.0.0.1:0", audit=audit))
    await server.start()
    try:
        tcp = server.endpoints.tcp
        assert isinstance(tcp, RtuOverTcpServer)
        connection = _RtuConnection(tcp)
        transport = CountingTransport()
        connection.connection_made(transport)  # type: ignore[arg-type]
        yield connection, transport
        connection.connection_lost(None)
    finally:
        await server.aclose()


async def split_case(audit: bool, mix: str, n: int) -> tuple[float, float]:
    """Medians over ``n`` requests (after a warm-up that fills the live audit's window): seconds from a request's
    bytes handed over to its reply written, and from there to ``data_received``'s return."""
    frames = [encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))]
    if mix == "write-read":
        frames.append(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 0)))
    async with served_connection(audit) as (connection, transport):
        await drive_protocol(connection, frames, 20000, None)  # warm
        before: list[float] = []
        after: list[float] = []
        sleep = asyncio.sleep
        for i in range(n):
            t0 = time.perf_counter()
            connection.data_received(frames[i % len(frames)])
            t1 = time.perf_counter()
            before.append(transport.written_at - t0)
            after.append(t1 - transport.written_at)
            await sleep(0)
    return statistics.median(before), statistics.median(after)


async def c20sim_case(audit: bool, n: int, profile: cProfile.Profile | None) -> float:
    frames = [encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1)), encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 0))]
    async with served_connection(audit) as (connection, transport):
        await drive_protocol(connection, frames, 2000, None)  # warm
        before = transport.writes
        seconds = await drive_protocol(connection, frames, n, profile)
        if transport.writes - before != n:
            raise AssertionError(f"{n} requests, {transport.writes - before} replies")
    return seconds


async def floor_case(n: int) -> float:
    floor = Floor()
    transport = CountingTransport()
    floor.connection_made(transport)
    frames = [encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))]
    await drive_protocol(floor, frames, 2000, None)
    return await drive_protocol(floor, frames, n, None)


async def pymodbus_case(n: int) -> float | None:
    """pymodbus's server connection fed the same frames (its request handling runs as a task)."""
    try:
        from pymodbus import FramerType
        from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
        from pymodbus.server import ModbusTcpServer
    except ImportError:
        return None
    logging.getLogger("pymodbus").setLevel(logging.ERROR)  # its datastore's v4 deprecation notices
    block: Any = ModbusSequentialDataBlock
    context = ModbusServerContext(devices={1: ModbusDeviceContext(hr=block(0x1F00, [3] * 0x400))}, single=False)
    server = ModbusTcpServer(context, framer=FramerType.RTU, address=("127.0.0.1", 0))
    connection: Any = server.callback_new_connection()
    transport = CountingTransport()
    connection.connection_made(transport)
    frames = [encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1)), encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 0))]
    sleep = asyncio.sleep

    async def feed(count: int) -> float:
        t0 = time.perf_counter()
        for i in range(count):
            before = transport.writes
            connection.data_received(frames[i % 2])
            while transport.writes == before:  # its handler answers from a task: turn the loop until it has
                await sleep(0)
        return time.perf_counter() - t0

    await feed(2000)
    seconds = await feed(n)
    connection.connection_lost(None)
    return seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--requests", type=int, default=50000, help="requests per case and round")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--profile", action="store_true", help="cProfile the path, and print it")
    parser.add_argument("--no-audit", action="store_true", help="with --profile: the live audit off")
    parser.add_argument("--split", action="store_true", help="time each request to its reply's write, and after")
    args = parser.parse_args()
    n = args.requests

    if args.split:
        print(f"The request path in one process, {time.strftime('%Y-%m-%d')}, {machine()}: medians of {n} requests")
        print()
        print("| case | load | to the reply's write, us | after it, in data_received, us |")
        print("|---|---|---|---|")
        for audit in (True, False):
            for mix in ("reads", "write-read"):
                to_write, after = run(split_case(audit, mix, n))
                name = "c20sim, live audit on" if audit else "c20sim, --no-audit"
                print(f"| {name} | {mix} | {to_write * 1e6:.2f} | {after * 1e6:.2f} |")
        return 0

    if args.profile:
        profile = cProfile.Profile()
        run(c20sim_case(not args.no_audit, n, profile))
        pstats.Stats(profile).sort_stats("tottime").print_stats(30)
        calls = sum(stat[1] for stat in pstats.Stats(profile).stats.values())  # type: ignore[attr-defined]
        print(f"function calls a request: {calls / n:.0f}")
        return 0

    cases = {
        "c20sim, live audit on (serve's default)": lambda: c20sim_case(True, n, None),
        "c20sim, --no-audit": lambda: c20sim_case(False, n, None),
        "floor (canned reply)": lambda: floor_case(n),
        "pymodbus 3.16 server protocol": lambda: pymodbus_case(n),
    }
    best: dict[str, float] = {}
    for _ in range(args.rounds):
        turns = run(bare_turns(n))
        for name, case in cases.items():
            seconds = run(case())
            if seconds is None:
                continue
            per = (seconds - turns) / n * 1e6
            best[name] = min(best.get(name, per), per)
    print(f"The request path in one process, {time.strftime('%Y-%m-%d')}, {machine()}")
    print(f"{n} requests a case, best of {args.rounds} rounds; microseconds of Python a request, the loop's bare turn")
    print("taken off (a read and a write of 2001H, alternately; turnaround 0, bus timing off)")
    print()
    print(f"| {'case':<42} | {'us/request':>10} |")
    print(f"|{'-' * 44}|{'-' * 12}|")
    for name, per in best.items():
        print(f"| {name:<42} | {per:>10.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

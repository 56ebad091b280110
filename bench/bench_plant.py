"""The plant: how many RS485 buses one serving process holds, on one core, and how fairly it serves them.

Each bus is a c20sim simulator behind its own RTU-over-TCP port, all in ONE serving process (bench/_common.py's
``ChildServer``, on uvloop as ``c20sim serve``), pinned to one core; the C load client (bench/loadgen.c) runs
pinned to another. The frame is a one-register read of 2100H (status 1). The line's figures are the code's,
not assumed: the drive's baud (the simulator's line), the character size serve gives the line (8N1: 10 bits)
and the default profile's turnaround; a transaction's RS485 time is ``transaction_time(8, 7, baud, bits,
turnaround)`` (13.458 ms at 19200 8N1 with 2 ms: 74.3 transactions/s per bus).

0. The timer alone: ``loop.call_later(hold)`` on uvloop and on asyncio's loop, on an idle loop and on a busy
   one, against the hold asked for. The line (c20sim/transport/line.py) releases each reply with that call.
1. Buses per core. N buses, one drive each, serve's defaults (bus timing on, the profile's turnaround, the
   live audit on); one connection per bus sends its next request as soon as the reply comes (a master polling
   as fast as the line allows). Each reply is due one transaction time after its request; lateness = latency
   - due. Per N: transactions/s, the server's CPU (% of its core, while polled and idle), CPU us per request,
   lateness percentiles and the share within 1 ms of due, then the lateness histogram. N steps up until the
   core no longer keeps up (transactions/s below ``--keep-up`` of the line's aggregate) or ``--max-buses``.
   Then bus timing off, each connection paced at the line's rate (``loadgen --rate``: a master's fixed poll
   cycle), turnaround ``--paced-turnaround-ms`` (0: the reply is due at once, lateness = latency).
2. Concurrency on one bus: 4 and 64 connections, bus timing off with turnaround 0 (CPU-bound) and bus timing on
   (line-bound): requests/s, CPU us per request, latency, and the fewest and most requests any connection got.
3. 8 buses x 32 drives polled at once (a read of each of the 32 addresses, round robin, ``--conns-per-bus`` per
   bus), bus timing on and off (turnaround 0).
4. Collections of a long-running plant, in this process, no sockets: N simulators (one drive each, the default
   ring of 2000 frame records) served a read of 2100H until every ring is full, start-up frozen as serve
   freezes it (``gc.freeze``), then a fixed number of further requests per bus: the objects the collector
   tracks (``gc.get_objects``: start-up frozen, and what the serving added), the collections of each
   generation those requests caused and their longest pause (``gc.callbacks``), and one full collection
   timed. This is the part a collection costs every bus at once, without the machine's noise of parts 1-3.
5. The same over the wire: N buses served by ``Server`` in this process (serve's defaults: bus timing, the live
   audit), polled by loadgen (pinned to the other core) for ``--seconds``; the collections in that time and their
   longest pause in CPU time (``time.thread_time``: not the time another process held the core), and the tracked
   objects beside the frozen start-up at the end, by type (the five commonest).

Beside each figure, what else held the server: "core taken" is the time it was ready to run but its core ran
another process (run queue wait, /proc/PID/task/*/schedstat) or the hypervisor ran something else (steal,
/proc/stat), as % of the run; "GC" is the garbage collector's pauses within the run (gc.callbacks in the
server child), whose full collections stop every bus at once. On a shared machine the first is not zero,
and the figures are not the server's alone.

Run it alone, on an idle machine with 2 cores or more (about 3-4 minutes at the defaults):

    cd /path/to/c20sim && .venv/bin/python bench/bench_plant.py [--seconds 3] [--max-buses 1024]

``--parts 1,2`` runs only some parts; ``--steps 1,8,64`` gives the N of part 1.
"""

from __future__ import annotations

import argparse
import asyncio
import gc
import os
import sys
import tempfile
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import ChildServer, ServerSpec, loadgen, loadgen_binary, machine, percentile, pin_process

from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions
from c20sim.wire.protocol import ReadRequest, char_bits, encode, transaction_time
from c20sim.wire.registers import Reg

STEPS = (1, 8, 16, 32, 64, 128, 192, 256, 384, 512, 768, 1024)
#: lateness histogram: upper bounds in us (the last bin is everything above)
BINS = (-1000.0, -500.0, 0.0, 500.0, 1000.0, 2000.0)
BIN_NAMES = ("< -1 ms", "-1..-0.5", "-0.5..0", "0..0.5", "0.5..1", "1..2 ms", "> 2 ms")


@dataclass(frozen=True)
class LineFigures:
    """The line every bus stands for, from the code."""

    baud: int
    bits: int
    turnaround: float  #: seconds, the default profile's
    request: int = 8  #: bytes of a one-register read
    reply: int = 7

    @property
    def transaction(self) -> float:
        return transaction_time(self.request, self.reply, self.baud, self.bits, self.turnaround)

    @property
    def rate(self) -> float:
        return 1.0 / self.transaction


def line_figures() -> LineFigures:
    profile = load_profile()
    sim = Simulator(profile, (1,))
    options = ServeOptions()  # the character serve gives the line: 8, its parity, its stop bits
    return LineFigures(
        sim.bus.line_baud, char_bits(8, options.parity, options.stopbits), profile.protocol.turnaround_ms / 1e3
    )


@dataclass
class Measured:
    """One load run against one server."""

    figures: dict[str, float]
    latencies: list[float]  #: us, ascending
    cpu_s: float  #: the server's CPU over the run
    wall_s: float
    idle_pct: float | None = None  #: the server's CPU with no traffic, % of a core
    waited_s: float = 0.0  #: seconds the server was ready to run but its core ran something else
    steal_s: float = 0.0  #: seconds the hypervisor took the server's core from this machine
    #: the server's garbage collector pauses within the run: (generation, seconds)
    gc_pauses: list[tuple[int, float]] = field(default_factory=list)
    due_us: float = 0.0
    lateness: list[float] = field(init=False)

    def __post_init__(self) -> None:
        self.lateness = [v - self.due_us for v in self.latencies]

    @property
    def req_s(self) -> float:
        return self.figures["req_s"]

    @property
    def cpu_pct(self) -> float:
        return 100.0 * self.cpu_s / self.wall_s

    @property
    def waited_pct(self) -> float:
        """Time the server was runnable but not running (its core taken by another process), % of the run."""
        return 100.0 * self.waited_s / self.wall_s

    @property
    def steal_pct(self) -> float:
        return 100.0 * self.steal_s / self.wall_s

    @property
    def us_per_req(self) -> float:
        """The server's CPU per request: its CPU per second over the requests per second."""
        return 1e6 * self.cpu_s / self.wall_s / self.req_s if self.req_s else float("nan")

    @property
    def gc(self) -> str:
        """The server's longest GC pause in the run, and its full collections (count, longest), in ms."""
        longest = max((s for _, s in self.gc_pauses), default=0.0)
        full = [s for g, s in self.gc_pauses if g == 2]
        return f"{longest * 1e3:.1f} ({len(full)}: {max(full, default=0.0) * 1e3:.1f})"

    def late(self, p: float) -> float:
        return percentile(self.lateness, p)

    @property
    def within_1ms(self) -> float:
        """Share of replies within 1 ms of due, either side."""
        if not self.lateness:
            return float("nan")
        return sum(1 for v in self.lateness if -1000.0 <= v <= 1000.0) / len(self.lateness)

    @property
    def all_within_1ms(self) -> bool:
        return bool(self.lateness) and self.lateness[0] >= -1000.0 and self.lateness[-1] <= 1000.0

    @property
    def p999_within_1ms(self) -> bool:
        """p0.1 and p99.9 of the lateness within 1 ms of due."""
        return bool(self.lateness) and self.late(0.1) >= -1000.0 and self.late(99.9) <= 1000.0

    def histogram(self) -> list[float]:
        counts = [0] * (len(BINS) + 1)
        for v in self.lateness:
            i = 0
            while i < len(BINS) and v >= BINS[i]:
                i += 1
            counts[i] += 1
        total = len(self.lateness) or 1
        return [c / total for c in counts]

    @property
    def fairness(self) -> str:
        fewest, most = self.figures["fewest"], self.figures["most"]
        return f"{most / fewest:.2f}" if fewest else "inf (starved)"


@dataclass
class Bench:
    seconds: float
    warmup: float
    idle: float
    server_cores: set[int]
    client_cores: set[int] | None
    tmp: Path

    def start(self, spec: ServerSpec) -> ChildServer:
        server = ChildServer(spec)
        assert server.process.pid is not None
        pin_process(server.process.pid, self.server_cores)
        return server

    def run(
        self,
        spec: ServerSpec,
        frames: Sequence[bytes],
        *,
        conns: int,
        due_us: float = 0.0,
        rate: float | None = None,
        seconds: float | None = None,
        idle: bool = False,
    ) -> Measured:
        server = self.start(spec)
        pid = server.process.pid
        assert pid is not None
        try:
            idle_pct = None
            if idle and self.idle > 0:
                cpu, wall = server.measure_idle(self.idle)
                idle_pct = 100.0 * cpu / wall
            dump = self.tmp / "latencies.txt"
            cpu0, _ = server.cpu_rss()
            waited0, steal0 = run_delay(pid), steal(self.server_cores)
            t0 = time.monotonic()
            measured_from = t0 + self.warmup
            figures = loadgen(
                server.ports,
                frames,
                conns=conns,
                seconds=seconds or self.seconds,
                warmup=self.warmup,
                rate=rate,
                due_us=due_us,
                cpus=self.client_cores,
                dump=dump,
            )
            cpu1, _ = server.cpu_rss()
            wall = time.monotonic() - t0
            waited, stolen = run_delay(pid) - waited0, steal(self.server_cores) - steal0
            latencies = sorted(float(line) for line in dump.read_text().split())
        finally:
            report = server.stop()
        pauses = [(g, s) for t, g, s in report.gc_pauses if t + s >= measured_from and t < t0 + wall]
        if report.errors_logged:
            print(f"  (the server logged {report.errors_logged} errors)", file=sys.stderr)
        return Measured(figures, latencies, cpu1 - cpu0, wall, idle_pct, waited, stolen, pauses, due_us)


def run_delay(pid: int) -> float:
    """Seconds the threads of ``pid`` have waited on a run queue (/proc/PID/task/*/schedstat, field 2): ready
    to run, their core busy with something else. 0 where the kernel keeps no schedstat."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            total += int((task / "schedstat").read_text().split()[1])
        except (OSError, IndexError, ValueError):
            continue
    return total / 1e9


def steal(cores: Collection[int]) -> float:
    """Seconds of steal (/proc/stat: a virtual machine's core running something else on its host) on ``cores``."""
    hz = os.sysconf("SC_CLK_TCK")
    total = 0
    for line in Path("/proc/stat").read_text().splitlines():
        name, *fields = line.split()
        if name.startswith("cpu") and name[3:].isdigit() and int(name[3:]) in cores and len(fields) > 7:
            total += int(fields[7])
    return total / hz


def us(v: float) -> str:
    return f"{v:+.0f}" if v == v else "-"


def pct(v: float) -> str:
    return f"{100 * v:.1f} %"


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    print()


# --- part 0: the timer alone


def _stamp(fired: asyncio.Future[float]) -> None:
    fired.set_result(time.perf_counter())


def timer_probe(hold: float, samples: int, loop_name: str, busy: bool) -> list[float]:
    """Microseconds from ``call_later(hold)`` to its callback, less ``hold``, ``samples`` times; each call made
    at a random phase of the millisecond. ``busy``: a neighbour keeps the loop turning (as many buses do)."""
    import random

    async def probe() -> list[float]:
        loop = asyncio.get_running_loop()
        running = True

        def spin() -> None:
            if running:
                loop.call_soon(spin)

        if busy:
            spin()
        rng = random.Random(1)
        out: list[float] = []
        for _ in range(samples):
            until = time.perf_counter() + rng.random() * 0.001
            while time.perf_counter() < until:  # a random phase of the loop's millisecond clock
                pass
            fired: asyncio.Future[float] = loop.create_future()
            t0 = time.perf_counter()
            loop.call_later(hold, _stamp, fired)
            out.append((await fired - t0 - hold) * 1e6)
        running = False
        return out

    if loop_name == "uvloop":
        import uvloop

        return sorted(uvloop.run(probe()))
    return sorted(asyncio.run(probe()))


def part0(line: LineFigures, samples: int) -> None:
    hold = line.transaction
    print(f"## 0. The timer alone: call_later({hold * 1e3:.3f} ms), {samples} calls at random phases\n")
    rows = []
    for loop_name in ("uvloop", "asyncio"):
        for busy in (False, True):
            try:
                errors = timer_probe(hold, samples, loop_name, busy)
            except ImportError:
                continue
            early = sum(1 for e in errors if e < 0) / len(errors)
            rows.append(
                [
                    loop_name,
                    "busy" if busy else "idle",
                    us(errors[0]),
                    us(percentile(errors, 50)),
                    us(errors[-1]),
                    pct(early),
                ]
            )
    table(["loop", "loop otherwise", "fired - hold: min us", "p50 us", "max us", "early"], rows)
    print(
        f"uvloop takes the delay in whole ms (round({hold * 1e3:.3f}) = {round(hold * 1e3)} ms) from its ms clock "
        "(truncated), so a timer fires at the first loop turn at or past that ms boundary: between "
        f"{(round(hold * 1e3) - 1 - hold * 1e3) * 1e3:+.0f} and {(round(hold * 1e3) - hold * 1e3) * 1e3:+.0f} us off "
        "on a loop that turns often, before the wake-up's own delay.\n"
    )


# --- part 1: buses per core


def part1(bench: Bench, line: LineFigures, steps: Sequence[int], keep_up: float, paced_turnaround: float) -> None:
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    due = line.transaction * 1e6
    print(
        f"## 1. Buses per core: one drive per bus, one master per bus polling as fast as the line allows\n\n"
        f"Line: {line.baud} baud, {line.bits} bits a character, turnaround {line.turnaround * 1e3:g} ms: a "
        f"one-register read holds it {due / 1e3:.3f} ms, {line.rate:.1f} transactions/s per bus. Each reply is "
        f"due {due / 1e3:.3f} ms after its request; lateness = latency - due (negative: early). Server on core(s) "
        f"{sorted(bench.server_cores)}, client on {sorted(bench.client_cores or [])}.\n"
    )
    runs: list[tuple[int, Measured]] = []
    for n in steps:
        spec = ServerSpec(buses=n, turnaround_ms=None, bus_timing=True, audit=True)
        m = bench.run(spec, [frame], conns=n, due_us=due, idle=True)
        runs.append((n, m))
        print(
            f"  N={n}: {m.req_s:.0f} tr/s, CPU {m.cpu_pct:.0f} %, {m.us_per_req:.0f} us/req, "
            f"late p99.9 {m.late(99.9):+.0f} us",
            file=sys.stderr,
        )
        if m.req_s < keep_up * n * line.rate:
            break
    base = runs[0][1].us_per_req
    rows = []
    for n, m in runs:
        rows.append(
            [
                str(n),
                f"{n * line.rate:.0f}",
                f"{m.req_s:.0f}",
                pct(m.req_s / (n * line.rate)),
                f"{m.cpu_pct:.0f} %",
                f"{m.idle_pct:.1f} %" if m.idle_pct is not None else "-",
                *_lateness_cells(m, base),
                us(m.lateness[0] if m.lateness else float("nan")),
                pct(m.within_1ms),
            ]
        )
    table(
        [
            "buses",
            "line's tr/s",
            "tr/s",
            "of line",
            "server CPU",
            "idle CPU",
            "core taken: runq / steal",
            "GC in run, ms: longest (full: n, longest)",
            "CPU us/req",
            "vs 1st",
            "late p50 us",
            "p99",
            "p99.9",
            "max",
            "min",
            "within 1 ms",
        ],
        rows,
    )
    print("Lateness histogram (share of replies; negative = early):\n")
    table(["buses", *BIN_NAMES], [[str(n), *(pct(s) for s in m.histogram())] for n, m in runs])
    kept, every, p999 = _passing(runs, line, keep_up)
    print(
        f"- the core keeps up (>= {keep_up:.0%} of the line's rate) up to {max(kept) if kept else 'no'} buses "
        f"of those tried\n"
        f"- every reply within 1 ms of due (either side): {_largest(every)}\n"
        f"- p0.1 .. p99.9 of lateness within 1 ms of due: {_largest(p999)}\n"
    )

    # Bus timing off, each master paced at the line's rate.
    due_paced = paced_turnaround * 1e6
    print(
        f"### Bus timing off, each master paced at {line.rate:.1f}/s (the line's rate), turnaround "
        f"{paced_turnaround * 1e3:g} ms: each reply due {due_paced / 1e3:g} ms after its request\n"
    )
    paced: list[tuple[int, Measured]] = []
    for n in steps:
        spec = ServerSpec(buses=n, turnaround_ms=paced_turnaround * 1e3, bus_timing=False, audit=True)
        m = bench.run(spec, [frame], conns=n, due_us=due_paced, rate=line.rate)
        paced.append((n, m))
        print(f"  paced N={n}: {m.req_s:.0f} req/s, CPU {m.cpu_pct:.0f} %, {m.us_per_req:.0f} us/req", file=sys.stderr)
        if m.req_s < keep_up * n * line.rate:
            break
    base = paced[0][1].us_per_req
    table(
        [
            "buses",
            "asked req/s",
            "req/s",
            "server CPU",
            "core taken: runq / steal",
            "GC in run, ms: longest (full: n, longest)",
            "CPU us/req",
            "vs 1st",
            "late p50 us",
            "p99",
            "p99.9",
            "max",
            "within 1 ms",
        ],
        [
            [
                str(n),
                f"{n * line.rate:.0f}",
                f"{m.req_s:.0f}",
                f"{m.cpu_pct:.0f} %",
                *_lateness_cells(m, base),
                pct(m.within_1ms),
            ]
            for n, m in paced
        ],
    )
    kept, every, p999 = _passing(paced, line, keep_up)
    print(
        f"- the core keeps up up to {max(kept) if kept else 'no'} buses of those tried; every reply within 1 ms: "
        f"{_largest(every)}; p99.9 within 1 ms: {_largest(p999)}\n"
    )


def _lateness_cells(m: Measured, base: float) -> list[str]:
    """The cells both tables of part 1 give a run: core taken, GC, CPU a request (and against the first run's),
    lateness p50, p99, p99.9 and max."""
    return [
        f"{m.waited_pct:.1f} / {m.steal_pct:.1f} %",
        m.gc,
        f"{m.us_per_req:.0f}",
        f"{m.us_per_req / base:.2f}",
        us(m.late(50)),
        us(m.late(99)),
        us(m.late(99.9)),
        us(m.lateness[-1] if m.lateness else float("nan")),
    ]


def _passing(runs: Sequence[tuple[int, Measured]], line: LineFigures, keep_up: float) -> tuple[list[int], ...]:
    """The bus counts whose core kept up, and of those, the ones with every reply, and with p0.1-p99.9 of
    them, within 1 ms of due."""
    kept = [(n, m) for n, m in runs if m.req_s >= keep_up * n * line.rate]
    return (
        [n for n, _ in kept],
        [n for n, m in kept if m.all_within_1ms],
        [n for n, m in kept if m.p999_within_1ms],
    )


def _largest(ns: Collection[int]) -> str:
    return f"up to {max(ns)} buses (passing: {', '.join(map(str, sorted(ns)))})" if ns else "none of those tried"


# --- part 2: concurrency on one bus

#: the columns parts 2 and 3 give each run (:func:`load_cells`)
LOAD_HEADER = (
    "req/s",
    "server CPU",
    "core taken: runq / steal",
    "CPU us/req",
    "p50 ms",
    "p99 ms",
    "fewest",
    "most",
    "most/fewest",
)


def load_cells(m: Measured) -> list[str]:
    """A run of parts 2 and 3 under :data:`LOAD_HEADER`: throughput, CPU, latency and fairness."""
    return [
        f"{m.req_s:.0f}",
        f"{m.cpu_pct:.0f} %",
        f"{m.waited_pct:.1f} / {m.steal_pct:.1f} %",
        f"{m.us_per_req:.0f}",
        f"{m.figures['p50_us'] / 1e3:.2f}",
        f"{m.figures['p99_us'] / 1e3:.2f}",
        f"{m.figures['fewest']:.0f}",
        f"{m.figures['most']:.0f}",
        m.fairness,
    ]


def part2(bench: Bench, line_seconds: float) -> None:
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    print("## 2. Concurrency on one bus\n")
    rows = []
    for timed in (False, True):
        for conns in (4, 64):
            spec = ServerSpec(buses=1, turnaround_ms=None if timed else 0.0, bus_timing=timed, audit=True)
            m = bench.run(spec, [frame], conns=conns, seconds=line_seconds if timed else None)
            rows.append(
                [
                    "on (line-bound)" if timed else "off, turnaround 0 (CPU-bound)",
                    str(conns),
                    *load_cells(m),
                ]
            )
    table(
        [
            "bus timing",
            "conns",
            *LOAD_HEADER,
        ],
        rows,
    )


# --- part 3: 8 buses x 32 drives


def part3(bench: Bench, line: LineFigures, conns_per_bus: int) -> None:
    buses, drives = 8, 32
    addresses = tuple(range(1, drives + 1))
    frames = [encode(ReadRequest(a, Reg.STATUS1, 1)) for a in addresses]
    conns = buses * conns_per_bus
    print(
        f"## 3. {buses} buses x {drives} drives polled at once: a read of 2100H of each address in turn, "
        f"{conns_per_bus} connections per bus\n"
    )
    rows = []
    for timed in (True, False):
        spec = ServerSpec(buses=buses, addresses=addresses, turnaround_ms=None if timed else 0.0, bus_timing=timed)
        m = bench.run(spec, frames, conns=conns)
        rows.append(
            [
                "on" if timed else "off, turnaround 0",
                str(conns),
                f"{buses * line.rate:.0f}" if timed else "-",
                *load_cells(m),
            ]
        )
    table(
        [
            "bus timing",
            "conns",
            "line's tr/s",
            *LOAD_HEADER,
        ],
        rows,
    )


# --- part 4: collections of a long-running plant


@dataclass
class Collections:
    """What the collector did while ``requests`` requests were served (:func:`plant_collections`)."""

    buses: int
    tracked_frozen: int  #: objects tracked at the end of start-up, frozen
    tracked_serving: int  #: tracked objects not frozen, with every ring full
    requests: int
    counts: tuple[int, int, int]  #: collections of generations 0, 1, 2
    longest: tuple[float, float, float]  #: the longest pause of each generation, seconds
    full: float  #: one gc.collect() with every ring full, seconds


def plant_collections(buses: int, per_bus: int, log_size: int = 2000) -> Collections:
    """N simulators served in this process (no I/O): start-up frozen, the rings filled, then ``per_bus``
    requests a bus, timed by the collector's own callbacks."""
    from c20sim.wire.protocol import FrameEvent, FrameKind

    profile = load_profile()
    gc.collect()
    sims = [Simulator(profile, (1,), seed=i, log_size=log_size) for i in range(buses)]
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    gc.collect()
    gc.freeze()  # as serve does at the end of its start-up
    frozen = gc.get_freeze_count()
    t = 0.0

    def serve(rounds: int) -> None:
        nonlocal t
        for _ in range(rounds):
            t += 0.0135
            for sim in sims:
                sim.bus.handle(FrameEvent(FrameKind.FRAME, frame, t), t)

    try:
        serve(log_size // 2 + 1)  # two records a request: every ring full
        gc.collect()
        serving = len(gc.get_objects())
        began: list[float] = [0.0]
        counts = [0, 0, 0]
        longest = [0.0, 0.0, 0.0]

        def timed(phase: str, info: dict[str, int]) -> None:
            if phase == "start":
                began[0] = time.perf_counter()
                return
            g = info["generation"]
            counts[g] += 1
            longest[g] = max(longest[g], time.perf_counter() - began[0])

        gc.callbacks.append(timed)
        try:
            serve(per_bus)
        finally:
            gc.callbacks.remove(timed)
        t0 = time.perf_counter()
        gc.collect()
        full = time.perf_counter() - t0
    finally:
        sims.clear()
        gc.unfreeze()
        gc.collect()
    return Collections(
        buses,
        frozen,
        serving,
        buses * per_bus,
        (counts[0], counts[1], counts[2]),
        tuple(longest),
        full,  # type: ignore[arg-type]
    )


def part4(steps: Sequence[int], per_bus: int) -> None:
    print(
        f"## 4. Collections of a long-running plant: N buses, every frame-log ring full (2000 records), then "
        f"{per_bus} reads a bus, in this process\n"
    )
    rows = []
    for n in steps:
        c = plant_collections(n, per_bus)
        print(f"  part 4 N={n}: {c.tracked_serving} tracked, full collection {c.full * 1e3:.1f} ms", file=sys.stderr)
        rows.append(
            [
                str(n),
                f"{c.tracked_frozen}",
                f"{c.tracked_serving}",
                f"{c.requests}",
                " / ".join(str(x) for x in c.counts),
                " / ".join(f"{x * 1e3:.2f}" for x in c.longest),
                f"{c.full * 1e3:.2f}",
            ]
        )
    table(
        [
            "buses",
            "tracked, frozen at start-up",
            "tracked while serving (rings full)",
            "requests",
            "collections gen 0 / 1 / 2",
            "longest pause ms gen 0 / 1 / 2",
            "one full collection ms",
        ],
        rows,
    )


# --- part 5: collections while serving over TCP


class _Collections:
    """gc.callbacks: collections per generation and the longest of each, in this thread's CPU time."""

    def __init__(self) -> None:
        self.counts = [0, 0, 0]
        self.longest = [0.0, 0.0, 0.0]
        self._began = 0.0

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._began = time.thread_time()
            return
        g = info["generation"]
        self.counts[g] += 1
        self.longest[g] = max(self.longest[g], time.thread_time() - self._began)


async def serving_collections(buses: int, seconds: float, client_cores: set[int] | None) -> tuple[Any, ...]:
    """Serve ``buses`` buses over TCP in this process while loadgen polls each; what the collector did."""
    import collections

    from c20sim.core.clock import RealtimeClock
    from c20sim.serve import Server

    profile = load_profile()
    servers = []
    try:
        for i in range(buses):
            sim = Simulator(profile, (1,), clock=RealtimeClock(), seed=i)
            server = Server(sim, ServeOptions(tcp="127.0.0.1:0"))
            await server.start()
            servers.append(server)
        gc.collect()
        gc.freeze()  # as serve does at the end of its start-up
        args = [str(loadgen_binary()), "--conns", str(buses), "--seconds", str(seconds), "--warmup", "0.5"]
        args += ["--frame", encode(ReadRequest(1, Reg.STATUS1, 1)).hex()]
        for server in servers:
            args += ["--port", str(server.endpoints.tcp.port)]  # type: ignore[union-attr]
        if client_cores:
            args = ["taskset", "-c", ",".join(map(str, sorted(client_cores))), *args]
        watch = _Collections()
        client = await asyncio.create_subprocess_exec(*args, stdout=asyncio.subprocess.PIPE)
        await asyncio.sleep(0.5)  # its warm-up
        gc.callbacks.append(watch)
        try:
            await asyncio.sleep(seconds)
        finally:
            gc.callbacks.remove(watch)
        tracked = gc.get_objects()
        kinds = collections.Counter(type(o).__qualname__ for o in tracked).most_common(5)
        count = len(tracked)
        del tracked
        await client.communicate()
        return watch.counts, watch.longest, count, kinds
    finally:
        for server in servers:
            await server.aclose()
        gc.unfreeze()


def part5(steps: Sequence[int], seconds: float, server_cores: set[int], client_cores: set[int] | None) -> None:
    import uvloop

    print(f"## 5. Collections while serving over TCP: N buses in this process, loadgen polling each, {seconds:g} s\n")
    rows = []
    allowed = os.sched_getaffinity(0)
    for n in steps:
        os.sched_setaffinity(0, server_cores)  # this process serves: on the server's core, as parts 1-3's child
        try:
            counts, longest, count, kinds = uvloop.run(serving_collections(n, seconds, client_cores))
        finally:
            os.sched_setaffinity(0, allowed)
        rows.append(
            [
                str(n),
                " / ".join(map(str, counts)),
                " / ".join(f"{x * 1e3:.2f}" for x in longest),
                str(count),
                ", ".join(f"{name} {k}" for name, k in kinds),
            ]
        )
    table(
        [
            "buses",
            "collections gen 0 / 1 / 2",
            "longest, ms of CPU, gen 0 / 1 / 2",
            "tracked beside the frozen start-up",
            "commonest tracked",
        ],
        rows,
    )


def cores() -> tuple[set[int], set[int] | None]:
    """The server's core and the client's: the first two this process may use; one core: both on it."""
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < 2:
        print("only one core: the server and the client share it, the figures mean little", file=sys.stderr)
        return {allowed[0]}, None
    return {allowed[0]}, {allowed[1]}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measured time per run (default 3)")
    parser.add_argument("--warmup", type=float, default=0.5, help="unmeasured time before each run (default 0.5)")
    parser.add_argument("--idle", type=float, default=0.5, help="idle CPU measured per N in part 1 (0: skip)")
    parser.add_argument("--max-buses", type=int, default=1024, help="largest N of part 1 (loadgen takes 1024 ports)")
    parser.add_argument("--steps", type=_ints, default=STEPS, help="the N of part 1, comma-separated")
    parser.add_argument(
        "--keep-up", type=float, default=0.95, help="part 1 stops once tr/s falls below this share of the line's"
    )
    parser.add_argument(
        "--paced-turnaround-ms", type=float, default=0.0, help="turnaround of part 1's paced run (default 0)"
    )
    parser.add_argument(
        "--line-seconds", type=float, default=6.0, help="measured time of part 2's line-bound runs (default 6)"
    )
    parser.add_argument("--conns-per-bus", type=int, default=4, help="part 3's connections per bus (default 4)")
    parser.add_argument("--timer-samples", type=int, default=60, help="calls per case of part 0 (default 60)")
    parser.add_argument(
        "--plant-requests", type=int, default=2000, help="part 4's reads a bus after the rings are full (default 2000)"
    )
    parser.add_argument("--parts", type=_ints, default=(0, 1, 2, 3, 4, 5), help="which parts, comma-separated")
    args = parser.parse_args()
    server_cores, client_cores = cores()
    line = line_figures()
    steps = [n for n in args.steps if n <= args.max_buses]
    print(f"{machine()}; {args.seconds:g} s per run after {args.warmup:g} s of warm-up\n")
    with tempfile.TemporaryDirectory(prefix="c20sim-plant-") as tmp:
        bench = Bench(args.seconds, args.warmup, args.idle, server_cores, client_cores, Path(tmp))
        parts: dict[int, Callable[[], None]] = {
            0: lambda: part0(line, args.timer_samples),
            1: lambda: part1(bench, line, steps, args.keep_up, args.paced_turnaround_ms / 1e3),
            2: lambda: part2(bench, args.line_seconds),
            3: lambda: part3(bench, line, args.conns_per_bus),
            4: lambda: part4(steps, args.plant_requests),
            5: lambda: part5(steps, args.seconds, server_cores, client_cores),
        }
        began = time.monotonic()
        for part in args.parts:
            parts[part]()
        print(f"({time.monotonic() - began:.0f} s in all)")


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(x) for x in text.split(","))


if __name__ == "__main__":
    main()

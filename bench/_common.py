"""Shared pieces of the benchmarks: a lean RTU-over-TCP client, servers in child processes, CPU and RSS.

The benchmarks measure servers, so the servers run in processes of their own
(multiprocessing, spawn) and the clients in others: a client never competes
with the server it measures for the same interpreter lock. A server child
reports its CPU time and RSS when told to stop.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import dataclasses
import functools
import gc
import json
import logging
import multiprocessing as mp
import os
import platform
import random
import resource
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from c20sim.wire.protocol import crc_ok, expected_length  # noqa: E402

CTX = mp.get_context("spawn")


# --- measuring a process


def rss_kib(pid: int | str = "self") -> int:
    """Resident set size in KiB, from /proc (psutil is not installed)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def cpu_seconds() -> float:
    """User + system CPU time of this process."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def percentile(sorted_values: Sequence[float], p: float) -> float:
    if not sorted_values:
        return float("nan")
    k = min(len(sorted_values) - 1, max(0, round(p / 100 * (len(sorted_values) - 1))))
    return sorted_values[k]


# --- a lean RTU-over-TCP client


class ReplyError(Exception):
    """A reply that is not a good frame: bad CRC, cut short, or garbage."""


class RawRtuClient:
    """Blocking RTU-over-TCP master: one request, then its reply read by its length."""

    def __init__(self, host: str, port: int, timeout: float = 1.0) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self.sock = self._connect()

    def _connect(self) -> socket.socket:
        sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return sock

    def reconnect(self) -> None:
        """A fresh connection: whatever the old one still carries is left behind."""
        with contextlib.suppress(OSError):
            self.sock.close()
        self.sock = self._connect()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()

    def transact(self, frame: bytes) -> bytes:
        """Send ``frame``; return the reply frame. Raises TimeoutError or ReplyError."""
        self.sock.sendall(frame)
        buf = b""
        want: int | None = None
        while want is None or len(buf) < want:
            chunk = self.sock.recv(512)
            if not chunk:
                raise ConnectionError("server closed the connection")
            buf += chunk
            if want is None and len(buf) >= 3:
                want = expected_length(buf, "response")
                if want is None:
                    raise ReplyError(f"not a C20 reply: {buf.hex(' ')}")
        if len(buf) != want or not crc_ok(buf):
            raise ReplyError(f"bad reply: {buf.hex(' ')}")
        return buf


# --- servers in child processes


@dataclass
class ServerSpec:
    """What to serve in the child: ``kind`` is "c20sim", "pymodbus" or "floor".

    "floor" is the Python floor: an asyncio protocol on uvloop that answers every read with a canned reply,
    parsing nothing. No Python server of RTU over TCP can be faster; the ratio to it is the figure."""

    kind: str = "c20sim"
    addresses: tuple[int, ...] = (1,)
    turnaround_ms: float | None = 0.0  #: None keeps the profile's default
    seed: int = 1
    buses: int = 1  #: c20sim: this many simulators, each on its own port
    #: c20sim: "random" flips link faults from a timer; "random+wrong" adds replies from a wrong
    #: address, which a client must catch (the soak's self-check)
    faults: str | None = None
    fault_period: float = 0.5
    log_size: int = 2000
    audit: bool = True  #: c20sim: the live audit (serve's default; --no-audit: False)
    bus_timing: bool = False  #: c20sim: hold the line for each transaction's RS485 time (serve's default: on)


@dataclass
class ServerReport:
    cpu_s: float
    rss_start_kib: int
    rss_end_kib: int
    faults_switched: int = 0
    errors_logged: int = 0  #: log records at ERROR or above: a bug in serving
    #: the garbage collector's pauses (a stop-the-world pause holds every reply): (time.monotonic() at its start,
    #: generation, seconds), the last 100000 of them
    gc_pauses: list[tuple[float, int, float]] = dataclasses.field(default_factory=list)


class _GcPauses:
    """Times the garbage collector's pauses (gc.callbacks)."""

    def __init__(self) -> None:
        self.started = 0.0
        self.pauses: collections.deque[tuple[float, int, float]] = collections.deque(maxlen=100_000)
        gc.callbacks.append(self)

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self.started = time.monotonic()
        else:
            self.pauses.append((self.started, info.get("generation", -1), time.monotonic() - self.started))


class Floor(asyncio.Protocol):
    """The Python floor: answers a canned reply and parses nothing (a write's echo, or a one-register read's
    reply, 2001H = 0). No Python server of RTU over TCP can be faster."""

    CANNED = bytes.fromhex("01 03 02 00 00 B8 44")

    def connection_made(self, transport: Any) -> None:
        self.transport = transport

    def data_received(self, data: bytes) -> None:
        self.transport.write(data if data[1] == 0x06 else self.CANNED)


class ChildServer:
    """A server in a child process; ``ports`` once started, :meth:`stop` returns its report."""

    def __init__(self, spec: ServerSpec) -> None:
        self.spec = spec
        parent, child = CTX.Pipe()
        self._conn = parent
        self.process = CTX.Process(target=_server_main, args=(spec, child), daemon=True)
        self.process.start()
        message = parent.recv()
        if message[0] != "ready":
            raise RuntimeError(f"server child failed: {message}")
        self.ports: list[int] = message[1]

    @property
    def port(self) -> int:
        return self.ports[0]

    def measure_idle(self, seconds: float) -> tuple[float, float]:
        """CPU seconds the server spends over ``seconds`` of wall time with no traffic."""
        self._conn.send(("idle", seconds))
        cpu, wall = self._conn.recv()
        return float(cpu), float(wall)

    def cpu_rss(self) -> tuple[float, int]:
        """(CPU seconds, RSS KiB) of the server so far."""
        self._conn.send(("cpu",))
        cpu, rss = self._conn.recv()
        return float(cpu), int(rss)

    def stop(self) -> ServerReport:
        self._conn.send(("stop",))
        report: ServerReport = self._conn.recv()
        self.process.join(10)
        return report


def _server_main(spec: ServerSpec, conn: Connection) -> None:
    try:
        if spec.kind in ("c20sim", "floor"):
            from c20sim.serve import run  # the loop `c20sim serve` runs on (uvloop where installed)

            run(_serve(spec, conn))
        else:
            asyncio.run(_serve(spec, conn))
    except BaseException as exc:  # report, so that the parent does not hang
        conn.send(("error", repr(exc)))
        raise


def _profile(turnaround_ms: float | None) -> Any:
    from c20sim.drive.profile import load_profile

    profile = load_profile()
    if turnaround_ms is not None:
        profile = dataclasses.replace(
            profile, protocol=dataclasses.replace(profile.protocol, turnaround_ms=turnaround_ms)
        )
    return profile


class _ErrorCounter(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.count = 0

    def emit(self, record: logging.LogRecord) -> None:
        self.count += 1
        sys.stderr.write(self.format(record) + "\n")


async def _serve(spec: ServerSpec, conn: Connection) -> None:
    loop = asyncio.get_running_loop()
    errors = _ErrorCounter()
    logging.getLogger().addHandler(errors)
    pauses = _GcPauses()
    rss_start = rss_kib()
    closers: list[Callable[[], Any]] = []
    switched = 0
    if spec.kind == "c20sim":
        from c20sim.core.clock import RealtimeClock
        from c20sim.core.simulator import Simulator
        from c20sim.serve import ServeOptions, Server

        profile = _profile(spec.turnaround_ms)
        sims = []
        ports = []
        for i in range(spec.buses):
            sim = Simulator(profile, spec.addresses, clock=RealtimeClock(), seed=spec.seed + i, log_size=spec.log_size)
            server = Server(sim, ServeOptions(tcp="127.0.0.1:0", audit=spec.audit, bus_timing=spec.bus_timing))
            await server.start()
            assert server.endpoints.tcp is not None
            ports.append(server.endpoints.tcp.port)
            sims.append(sim)
            closers.append(server.aclose)
        if spec.faults in ("random", "random+wrong"):
            wrong = spec.faults == "random+wrong"
            rng = random.Random(spec.seed)

            def flip() -> None:
                nonlocal switched
                for sim in sims:
                    _random_faults(sim.link_faults(), rng, wrong=wrong)
                switched += 1
                loop.call_later(spec.fault_period, flip)

            loop.call_later(spec.fault_period, flip)
    elif spec.kind == "floor":
        server = await loop.create_server(Floor, "127.0.0.1", 0)
        ports = [server.sockets[0].getsockname()[1]]
        closers.append(server.close)
    elif spec.kind == "pymodbus":
        from pymodbus import FramerType
        from pymodbus.datastore import ModbusDeviceContext, ModbusSequentialDataBlock, ModbusServerContext
        from pymodbus.server import ModbusTcpServer

        port = free_port()
        # The registers the benchmarks touch (2000H-2110H) and more, whatever pymodbus's address offset.
        block: Any = ModbusSequentialDataBlock  # untyped in pymodbus
        devices: dict[int, Any] = {a: ModbusDeviceContext(hr=block(0x1F00, [3] * 0x400)) for a in spec.addresses}
        context = ModbusServerContext(devices=devices, single=False)
        pyserver = ModbusTcpServer(context, framer=FramerType.RTU, address=("127.0.0.1", port))
        task = asyncio.create_task(pyserver.serve_forever())
        for _ in range(200):  # until it listens
            with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.2):
                break
            await asyncio.sleep(0.02)
        ports = [port]
        closers.append(pyserver.shutdown)
        closers.append(lambda: task)
    else:
        raise ValueError(spec.kind)
    if spec.kind == "c20sim":
        gc.collect()  # as c20sim serve does once it has started (serve.run_server)
        gc.freeze()
    conn.send(("ready", ports))
    while True:
        message = await loop.run_in_executor(None, conn.recv)
        if message[0] == "cpu":
            conn.send((cpu_seconds(), rss_kib()))
        elif message[0] == "idle":
            wall0, cpu0 = time.monotonic(), _main_thread_cpu()
            await asyncio.sleep(message[1])
            conn.send((_main_thread_cpu() - cpu0, time.monotonic() - wall0))
        else:
            break
    report = ServerReport(
        cpu_seconds(),
        rss_start,
        rss_kib(),
        switched,
        errors.count,
        list(pauses.pauses),
    )
    for close in closers:
        with contextlib.suppress(Exception):
            result = close()
            if asyncio.iscoroutine(result) or isinstance(result, asyncio.Future):
                await asyncio.wait_for(result, 5)
    conn.send(report)


def _main_thread_cpu() -> float:
    """CPU time of the whole process (the executor thread waiting on the pipe sleeps in recv)."""
    return cpu_seconds()


def _random_faults(link: Any, rng: random.Random, *, wrong: bool = False) -> None:
    """One random link-fault setting: half the time none, else one of the reply faults."""
    link.clear()
    choices = ["none"] * 5 + ["drop", "corrupt", "delay", "truncate", "garbage", "drop_next"]
    choice = rng.choice([*choices, "wrong_address"] if wrong else choices)
    if choice == "wrong_address":
        link.wrong_address = 99  # a good CRC from an address no client owns
    if choice == "drop":
        link.drop_percent = rng.choice([1.0, 5.0, 20.0])
    elif choice == "corrupt":
        link.corrupt_crc = True
    elif choice == "delay":
        link.delay = 0.001
        link.delay_jitter = 0.01
    elif choice == "truncate":
        link.truncate = True
    elif choice == "garbage":
        # starts with 00 00: function 0x00 is no reply's, so it can never pass for a good frame
        link.garbage_before = b"\x00\x00" + bytes(rng.randrange(256) for _ in range(rng.randint(0, 3)))
    elif choice == "drop_next":
        link.drop_next = rng.randint(1, 3)


def pin_process(pid: int, cpus: Collection[int]) -> None:
    """Pin every thread of process ``pid`` to ``cpus`` (sched_setaffinity on a pid pins that thread alone)."""
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(ProcessLookupError):
            os.sched_setaffinity(int(task.name), set(cpus))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


# --- the C load client (bench/loadgen.c)

LOADGEN_SOURCE = Path(__file__).with_name("loadgen.c")


def loadgen_binary() -> Path:
    """bench/loadgen.c, built with the machine's C compiler into the user's cache on first use (and anew when
    the source changes)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "c20sim-bench"
    binary = cache / f"loadgen-{int(LOADGEN_SOURCE.stat().st_mtime)}"
    if not binary.exists():
        cache.mkdir(parents=True, exist_ok=True)
        compiler = os.environ.get("CC", "cc")
        result = subprocess.run(
            [compiler, "-O2", "-o", str(binary), str(LOADGEN_SOURCE)], capture_output=True, text=True
        )
        if result.returncode:
            raise SystemExit(f"cannot build {LOADGEN_SOURCE} with {compiler}: {result.stderr.strip()}")
    return binary


def loadgen(
    ports: Sequence[int],
    frames: Sequence[bytes],
    *,
    conns: int = 1,
    seconds: float | None = None,
    requests: int | None = None,
    warmup: float = 0.0,
    rate: float | None = None,
    due_us: float | None = None,
    cpus: Collection[int] | None = None,
    dump: Path | None = None,
) -> dict[str, float]:
    """Run the C load client to its end; its JSON figures (see bench/loadgen.c).

    ``cpus``: the cores the client may run on (so that it does not share the server's); ``dump``: a file to
    which the client writes every measured latency (us, one a line, in the order the replies came)."""
    args = [str(loadgen_binary()), "--conns", str(conns), "--warmup", str(warmup)]
    for port in ports:
        args += ["--port", str(port)]
    for frame in frames:
        args += ["--frame", frame.hex()]
    if seconds is not None:
        args += ["--seconds", str(seconds)]
    if requests is not None:
        args += ["--requests", str(requests)]
    if rate is not None:
        args += ["--rate", str(rate)]
    if due_us is not None:
        args += ["--due-us", str(due_us)]
    if dump is not None:
        args += ["--dump", str(dump)]
    pin = None if cpus is None else functools.partial(os.sched_setaffinity, 0, set(cpus))
    result = subprocess.run(args, capture_output=True, text=True, preexec_fn=pin)
    if result.returncode:
        raise RuntimeError(f"loadgen failed: {result.stderr.strip()}")
    figures: dict[str, float] = json.loads(result.stdout)
    return figures

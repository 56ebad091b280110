"""``c20sim serve``: a simulator on every endpoint asked for, until SIGINT or SIGTERM.

Endpoints start in order; if one fails (busy port, missing device, bad
address) the ones already started are closed before the error is reported,
so nothing is left half-started. When all are up, one ready line lists every
endpoint, and ``--ready-file`` gets the same as JSON with the real addresses
(port 0 is resolved), for scripts and CI to read.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import gc
import json
import os
import signal
import sys
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol, TypeVar

from .core.simulator import Simulator
from .transport.framelog import FrameLog
from .transport.line import Line
from .transport.modbustcp import ModbusTcpServer
from .transport.tcp import RtuOverTcpServer, parse_host_port
from .wire.errors import C20SimError
from .wire.protocol import char_bits

if TYPE_CHECKING:
    # Imported where used: pty needs tty/termios and pyserial needs them on POSIX, which Windows lacks.
    from .control.http import ControlApi
    from .scenario.timeline import Report, Scenario
    from .transport.pty import PtyPort
    from .transport.serial import SerialPort

T = TypeVar("T")

__all__ = ["NEEDS_POSIX", "Endpoints", "ServeOptions", "Server", "pty_supported", "run", "run_server"]


#: ``--log-frames``' bound without ``--log-frames-max-mb`` (MiB): the file is rotated at this size, keeping KEEP old
#: ones, so the log takes at most 400 MiB of disk; ``--log-frames-max-mb 0`` for no bound.
LOG_FRAMES_MAX_MB = 100.0

#: What ``--pty`` says where there are no ptys (Windows): tty and termios are POSIX-only.
NEEDS_POSIX = (
    "--pty needs a POSIX system (Linux, macOS, BSD); on Windows use a com0com pair with --serial COMn, "
    "or --tcp HOST:PORT (RTU over TCP) or --modbus-tcp HOST:PORT"
)


def pty_supported() -> bool:
    """True where a pty can be made (POSIX: the tty module loads); False on Windows."""
    try:
        import tty  # noqa: F401
    except ImportError:
        return False
    return True


class Endpoint(Protocol):
    @property
    def name(self) -> str: ...

    async def start(self) -> None: ...

    def close(self) -> None: ...


@dataclass
class ServeOptions:
    """The endpoint options of ``serve`` and ``dashboard``."""

    pty: bool = False
    link: str | None = None
    serial: str | None = None
    parity: str = "N"
    stopbits: int = 1
    tcp: str | None = None
    modbus_tcp: str | None = None
    line_timing: bool = False
    #: hold the shared line for each transaction's RS485 time at the drive's serial settings, whatever the
    #: transport (the command line's default is on: see docs/line-timing.md); off here for the building block
    bus_timing: bool = False
    #: connections each TCP port takes at once (None: the port's default, transport.tcp.MAX_CONNECTIONS)
    max_connections: int | None = None
    #: seconds a TCP request may wait for the line, or for a reply on it (transport.tcp.GATEWAY_TIMEOUT)
    gateway_timeout: float = 1.0
    log_frames: str | None = None
    #: rotate the frame log when it reaches this many MiB (None: no limit)
    log_frames_max_mb: float | None = None
    ready_file: str | None = None
    #: HOST:PORT of the HTTP control API (c20sim.control), or None
    control: str | None = None
    #: the token the control API asks for; None: none on loopback, a generated one beyond it
    control_token: str | None = None
    #: HOST:PORT of a read-only listener serving GET /metrics alone (Prometheus), or None
    metrics: str | None = None
    #: a scenario file (c20sim.scenario.timeline) to play against the served simulator once ready
    scenario: str | None = None
    #: the live audit (c20sim.control.liveaudit, docs/audit.md): on unless --no-audit
    audit: bool = True
    #: after the scenario: "exit" (serve ends with the scenario's exit code) or "serve" (until a stop signal)
    then: str = "exit"
    extra_ready: dict[str, str] = field(default_factory=dict)

    @property
    def any_endpoint(self) -> bool:
        return bool(self.pty or self.link or self.serial or self.tcp or self.modbus_tcp)


@dataclass
class Endpoints:
    pty: PtyPort | None = None
    serial: SerialPort | None = None
    tcp: RtuOverTcpServer | None = None
    modbus_tcp: ModbusTcpServer | None = None

    def all(self) -> list[Endpoint]:
        return [e for e in (self.pty, self.serial, self.tcp, self.modbus_tcp) if e is not None]

    def addresses(self) -> dict[str, str]:
        """The ready file's keys: ``tcp``/``modbus_tcp`` as HOST:PORT, ``pty``/``serial`` as paths."""
        out: dict[str, str] = {}
        if self.pty is not None:
            out["pty"] = self.pty.name
        if self.serial is not None:
            out["serial"] = self.serial.name
        if self.tcp is not None:
            out["tcp"] = self.tcp.name
        if self.modbus_tcp is not None:
            out["modbus_tcp"] = self.modbus_tcp.name
        return out


class Server:
    """A simulator behind the endpoints of ``options``; start, then close."""

    def __init__(self, sim: Simulator, options: ServeOptions) -> None:
        self.sim = sim
        self.options = options
        self.line = Line(sim, bus_timing=options.bus_timing)
        # The line's character: the serial settings (the serial port's, or those a serial device server in
        # front of the TCP endpoints would have).
        sim.bus.char_bits = char_bits(8, options.parity, options.stopbits)
        self.endpoints = Endpoints()
        self.frame_log: FrameLog | None = None
        self._unsubscribe: list[Callable[[], None]] = []
        self.control: ControlApi | None = None
        self.metrics: ControlApi | None = None  #: the --metrics listener: GET /metrics alone, no token
        self._ready: tuple[Path, str] | None = None  #: the ready file written, and what it says
        self.scenario_task: asyncio.Task[Report] | None = None

    async def start(self) -> None:
        """Start every endpoint, or none: on error, close what started and raise C20SimError."""
        opts, sim, line = self.options, self.sim, self.line
        max_mb = opts.log_frames_max_mb
        if max_mb is not None and max_mb != 0 and not 0.01 <= max_mb <= 1e6:  # refuses nan; inf is above the range
            raise C20SimError(
                f"--log-frames-max-mb {max_mb:g}: give a size in MiB from 0.01 to 1000000, or 0 for no bound"
            )
        scenario = None
        if opts.scenario:
            from .scenario.timeline import check, load_scenario

            scenario = load_scenario(opts.scenario)
            for warning in _scenario_differences(scenario, sim):
                print(f"c20sim: warning: {warning}", file=sys.stderr, flush=True)
            check(scenario, sim)
        try:
            if opts.audit:
                from .control import liveaudit

                self._unsubscribe.append(liveaudit.start(sim).close)
            from .control import drills
            from .drillrun import serve_runner

            rtu = opts.pty or opts.link or opts.serial or opts.tcp
            drills.attach(sim, serve_runner(sim, asyncio.get_running_loop(), "tcp" if rtu else "modbus-tcp"))
            # at close: a running drill stops (its thread calls on this loop no more) and the service goes
            self._unsubscribe.append(lambda: drills.detach(sim))
            if opts.log_frames:
                self._open_frame_log(opts.log_frames)
            if opts.pty or opts.link:
                if not pty_supported():
                    raise C20SimError(NEEDS_POSIX)
                from .transport.pty import PtyPort

                self.endpoints.pty = PtyPort(line, link=opts.link, line_timing=opts.line_timing)
                await self.endpoints.pty.start()
            if opts.serial:
                try:
                    from .transport.serial import SerialPort
                except ImportError as exc:
                    raise C20SimError(
                        f"--serial: pyserial cannot be loaded here ({exc}); use --tcp or --modbus-tcp"
                    ) from None
                self.endpoints.serial = SerialPort(
                    line,
                    opts.serial,
                    parity=opts.parity,
                    stopbits=opts.stopbits,
                    line_timing=opts.line_timing,
                )
                await self.endpoints.serial.start()
            if (opts.tcp or opts.modbus_tcp) and not 0.01 <= opts.gateway_timeout <= 120.0:  # refuses nan
                raise C20SimError(
                    f"--gateway-timeout {opts.gateway_timeout:g}: give seconds from 0.01 to 120 (an MGate's range)"
                )
            if opts.max_connections is not None and not 1 <= opts.max_connections <= 10000:
                raise C20SimError(f"--max-connections {opts.max_connections}: give 1 to 10000 connections per port")
            if opts.tcp:
                host, port = parse_host_port(opts.tcp, "--tcp")
                self.endpoints.tcp = RtuOverTcpServer(
                    line, host, port, max_connections=opts.max_connections, timeout=opts.gateway_timeout
                )
                await self.endpoints.tcp.start()
            if opts.modbus_tcp:
                host, port = parse_host_port(opts.modbus_tcp, "--modbus-tcp")
                self.endpoints.modbus_tcp = ModbusTcpServer(
                    line, host, port, max_connections=opts.max_connections, timeout=opts.gateway_timeout
                )
                await self.endpoints.modbus_tcp.start()
            if self.endpoints.tcp is not None and self.endpoints.modbus_tcp is not None:
                self.endpoints.tcp.modbus_tcp = functools.partial(str, self.endpoints.modbus_tcp.name)
                self.endpoints.modbus_tcp.rtu_tcp = functools.partial(str, self.endpoints.tcp.name)
            if opts.control:
                from .control.http import ControlApi, is_loopback, new_token  # imports aiohttp: only when asked for

                host, port = parse_host_port(opts.control, "--control")
                token = opts.control_token
                if token is not None and not token.strip():
                    raise C20SimError("--control-token: empty; give a token, or leave the option out")
                if token is None and not is_loopback(host):
                    token = new_token()  # beyond loopback, never without one
                self.control = ControlApi(sim, token=token, endpoints=self.endpoints.addresses)
                self.control.frame_log = self.frame_log
                self.control.line = line
                await self.control.start(host, port)
            if opts.metrics:
                from .control import routes
                from .control.http import ControlApi

                host, port = parse_host_port(opts.metrics, "--metrics")
                self.metrics = ControlApi(sim, endpoints=self.endpoints.addresses)
                self.metrics.line = line
                only = routes.Table([routes.table().named("metrics")])
                await self.metrics.start(host, port, table=only, option="--metrics")
            if opts.ready_file:
                self.write_ready_file(opts.ready_file)
            if self.control is not None:
                self.control.serving = True
            if scenario is not None:
                from .scenario.timeline import play

                self.scenario_task = asyncio.create_task(play(scenario, sim, line=line, out=sys.stdout))
                self.scenario_task.add_done_callback(_report_scenario_error)
        except BaseException:
            self.close()
            await self._close_control()
            raise

    def addresses(self) -> dict[str, str]:
        """The ready file's keys: the endpoints, ``control`` as http://HOST:PORT, and ``extra_ready``."""
        control = {"control": self.control.url} if self.control is not None and self.control.url else {}
        if self.control is not None and self.control.token is not None:
            control["token"] = self.control.token
        if self.metrics is not None and self.metrics.url:
            control["metrics"] = f"{self.metrics.url}/metrics"
        return {**self.endpoints.addresses(), **control, **self.options.extra_ready}

    async def _close_control(self) -> None:
        if self.control is not None:
            await self.control.close()
            self.control = None
        if self.metrics is not None:
            await self.metrics.close()
            self.metrics = None

    def ready_line(self) -> str:
        parts = [f"{key} {value}" for key, value in self.addresses().items() if key != "token"]
        if self.control is not None and self.control.token is not None:
            # the token is a secret: shown only where there is no ready file to read it from
            parts.append("token in the ready file" if self.options.ready_file else f"token {self.control.token}")
        drives = ",".join(map(str, self.sim.drives))
        clock = "virtual" if self.sim.virtual else "realtime"
        return f"c20sim ready: {self.sim.profile.name}, drives {drives}, {clock} clock; " + "; ".join(parts)

    def write_ready_file(self, path: str) -> None:
        data = self.addresses()
        target = Path(path)
        tmp = target.with_name(f".{target.name}.tmp")
        text = json.dumps(data, indent=2) + "\n"
        try:
            tmp.unlink(missing_ok=True)
            mode = 0o600 if "token" in data else 0o644  # a token is for the one who started the server
            with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode), "w") as out:
                out.write(text)
            os.replace(tmp, target)
        except OSError as exc:
            raise C20SimError(f"--ready-file {path}: cannot write: {exc.strerror}") from None
        self._ready = (target, text)

    def _remove_ready_file(self) -> None:
        """A ready file says 'serving here': it goes when the server does (unless another wrote over it)."""
        if self._ready is None:
            return
        target, text = self._ready
        self._ready = None
        with contextlib.suppress(OSError):
            if target.read_text() == text:
                target.unlink()

    def _open_frame_log(self, path: str) -> None:
        max_mb = self.options.log_frames_max_mb
        if max_mb is None:
            max_mb = LOG_FRAMES_MAX_MB  # bounded unless asked: a busy line writes about 10 MB a minute
        self.frame_log = FrameLog(path, max_bytes=None if max_mb == 0 else int(max_mb * 1024 * 1024))
        self.frame_log.start()
        self._unsubscribe.append(self.sim.bus.subscribe(self.frame_log.put))

    async def aclose(self) -> None:
        """Close, and wait until every TCP connection has ended and the scenario has stopped."""
        self.close()
        if self.scenario_task is not None:
            await asyncio.wait([self.scenario_task])  # cancelled by close(); an error was reported as it ended
        await self._close_control()
        for server in (self.endpoints.tcp, self.endpoints.modbus_tcp):
            if server is not None:
                await server.wait_closed()

    def close(self) -> None:
        self._remove_ready_file()
        if self.scenario_task is not None:
            self.scenario_task.cancel()
        for endpoint in self.endpoints.all():
            endpoint.close()
        self.line.close()
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()
        if self.frame_log is not None:
            self.frame_log.close()
            self.frame_log = None


def _profile_name(name_or_path: str) -> str:
    from .drive.profile import load_profile

    try:
        return load_profile(name_or_path).name
    except C20SimError:
        return name_or_path


def _scenario_differences(scenario: Scenario, sim: Simulator) -> list[str]:
    """What the scenario asks for that serve does not take from it: the profile and the drives come from
    the command line."""
    out = []
    if scenario.profile is not None and _profile_name(scenario.profile) != sim.profile.name:
        out.append(
            f"{scenario.path}: the scenario names profile {scenario.profile}, but {sim.profile.name} is served; "
            "serve takes the profile from --profile"
        )
    if scenario.drives is not None and tuple(scenario.drives) != tuple(sim.drives):
        out.append(
            f"{scenario.path}: the scenario names drives {','.join(map(str, scenario.drives))}, "
            f"but {','.join(map(str, sim.drives))} are served; serve takes the drives from --drives"
        )
    return out


def _report_scenario_error(task: asyncio.Task[Report]) -> None:
    if not task.cancelled() and task.exception() is not None:
        print(f"c20sim: scenario stopped: {task.exception()}", file=sys.stderr, flush=True)


def run(main: Coroutine[Any, Any, T]) -> T:
    """Run a serving coroutine on uvloop where it is installed (the cheaper loop), else asyncio's."""
    try:
        import uvloop
    except ImportError:
        return asyncio.run(main)
    return uvloop.run(main)


#: Signals that end serving cleanly: Ctrl-C, a service manager's stop, a closed terminal window.
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


async def run_server(sim: Simulator, options: ServeOptions, *, out: IO[str] = sys.stdout) -> int:
    """Serve until SIGINT, SIGTERM or SIGHUP, or until a played scenario ends (unless ``then`` is "serve");
    the exit code: 1 if a played scenario failed or stopped, else 0."""
    server = Server(sim, options)
    stop = asyncio.Event()
    # Handlers first: a signal that comes as soon as the ready file exists still closes everything.
    restore = _on_stop_signals(stop)
    try:
        await server.start()
        # What start-up made (modules, the profile, the drives, the listeners) lives as long as serving: keep
        # it out of every full garbage collection, which would otherwise walk it while the wire waits (its
        # garbage collected first, so that none is kept for good; thawed when serving ends).
        gc.collect()
        gc.freeze()
        print(server.ready_line(), file=out, flush=True)
        stopped = asyncio.ensure_future(stop.wait())
        ends: list[asyncio.Future[Any]] = [stopped]
        if server.scenario_task is not None and options.then == "exit":
            ends.append(server.scenario_task)  # a CI job's serve ends with its scenario
        try:
            await asyncio.wait(ends, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stopped.cancel()
    finally:
        restore()
        task = server.scenario_task
        await server.aclose()
        gc.unfreeze()
    if task is None or task.cancelled():
        return 0
    return 1 if task.exception() is not None or not task.result().ok else 0


def _on_stop_signals(stop: asyncio.Event) -> Callable[[], None]:
    """Set ``stop`` on SIGINT, SIGTERM or SIGHUP; returns what puts the old handlers back.

    The loop's own signal handlers where it has them (POSIX); where it has not (Windows, whose loops raise
    NotImplementedError) a plain ``signal.signal`` handler that hands the stop to the loop: Ctrl+C and
    Ctrl+Break still stop the server cleanly.
    """
    loop = asyncio.get_running_loop()
    signals = list(STOP_SIGNALS)

    def remove() -> None:
        for sig in signals:
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.remove_signal_handler(sig)

    try:
        for sig in signals:
            loop.add_signal_handler(sig, stop.set)
        return remove
    except (NotImplementedError, RuntimeError):
        remove()
    if hasattr(signal, "SIGBREAK"):  # Windows: Ctrl+Break
        signals.append(signal.SIGBREAK)
    old = {sig: signal.getsignal(sig) for sig in signals}

    def handler(signum: int, frame: object) -> None:
        loop.call_soon_threadsafe(stop.set)

    for sig in signals:
        signal.signal(sig, handler)

    def restore() -> None:
        for sig, previous in old.items():
            signal.signal(sig, previous)

    return restore

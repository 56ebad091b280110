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
import gc
import json
import os
import signal
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TypeVar, cast

from .core.simulator import Simulator
from .transport.framelog import FrameLog
from .transport.line import Line
from .transport.rows import NEEDS_POSIX, Endpoint, NetworkEndpoint, Opening, Transport, rows
from .transport.rows import posix_supported as pty_supported
from .transport.tcp import parse_host_port
from .wire.errors import C20SimError
from .wire.protocol import char_bits

if TYPE_CHECKING:
    from .control.http import ControlApi
    from .scenario.timeline import Report, Scenario
    from .transport.modbustcp import ModbusTcpServer
    from .transport.pty import PtyPort
    from .transport.serial import SerialPort
    from .transport.tcp import RtuOverTcpServer

T = TypeVar("T")

__all__ = ["NEEDS_POSIX", "Endpoints", "ServeOptions", "Server", "pty_supported", "run", "run_server"]


#: ``--log-frames``' bound without ``--log-frames-max-mb`` (MiB): the file is rotated at this size, keeping KEEP old
#: ones, so the log takes at most 400 MiB of disk; ``--log-frames-max-mb 0`` for no bound.
LOG_FRAMES_MAX_MB = 100.0


def endpoint_dests() -> dict[str, Transport]:
    """Every transport option's name (its dest: ``modbus_tcp``) and the transport it belongs to."""
    return {option.dest: row for row in rows() for option in row.options}


class ServeOptions:
    """The endpoint options of ``serve`` and ``dashboard``: the transports' (one keyword per option of a
    :mod:`~c20sim.transport.rows` row, such as ``tcp="127.0.0.1:0"`` or ``pty=True``, kept in :attr:`endpoints`)
    and serve's own."""

    def __init__(
        self,
        *,
        parity: str = "N",
        stopbits: int = 1,
        line_timing: bool = False,
        bus_timing: bool = False,
        max_connections: int | None = None,
        gateway_timeout: float = 1.0,
        log_frames: str | None = None,
        log_frames_max_mb: float | None = None,
        ready_file: str | None = None,
        control: str | None = None,
        control_token: str | None = None,
        metrics: str | None = None,
        scenario: str | None = None,
        audit: bool = True,
        then: str = "exit",
        extra_ready: dict[str, str] | None = None,
        **endpoints: Any,
    ) -> None:
        dests = endpoint_dests()
        unknown = sorted(set(endpoints) - set(dests))
        if unknown:
            raise TypeError(f"ServeOptions: no transport has the option {unknown[0]!r}; they are {', '.join(dests)}")
        #: each transport option's value, by dest (None or False: not given)
        self.endpoints: dict[str, Any] = {dest: endpoints.get(dest) for dest in dests}
        self.parity = parity
        self.stopbits = stopbits
        self.line_timing = line_timing
        #: hold the shared line for each transaction's RS485 time at the drive's serial settings, whatever the
        #: transport (the command line's default is on: see docs/line-timing.md); off here for the building block
        self.bus_timing = bus_timing
        #: connections each TCP port takes at once (None: the port's default, transport.tcp.MAX_CONNECTIONS)
        self.max_connections = max_connections
        #: seconds a TCP request may wait for the line, or for a reply on it (transport.tcp.GATEWAY_TIMEOUT)
        self.gateway_timeout = gateway_timeout
        self.log_frames = log_frames
        #: rotate the frame log when it reaches this many MiB (None: no limit)
        self.log_frames_max_mb = log_frames_max_mb
        self.ready_file = ready_file
        #: HOST:PORT of the HTTP control API (c20sim.control), or None
        self.control = control
        #: the token the control API asks for; None: none on loopback, a generated one beyond it
        self.control_token = control_token
        #: HOST:PORT of a read-only listener serving GET /metrics alone (Prometheus), or None
        self.metrics = metrics
        #: a scenario file (c20sim.scenario.timeline) to play against the served simulator once ready
        self.scenario = scenario
        #: the live audit (c20sim.control.liveaudit, docs/audit.md): on unless --no-audit
        self.audit = audit
        #: after the scenario: "exit" (serve ends with the scenario's exit code) or "serve" (until a stop signal)
        self.then = then
        self.extra_ready: dict[str, str] = dict(extra_ready or {})

    def asked(self) -> list[Transport]:
        """The transports asked for, in the rows' order."""
        return [row for row in rows() if row.asked(self.endpoints)]

    @property
    def any_endpoint(self) -> bool:
        return bool(self.asked())

    def give_defaults(self) -> None:
        """A bare serve's endpoints: each row's default where it can run here (no pty on Windows: TCP alone)."""
        for row in rows():
            if row.default is not None and row.usable():
                self.endpoints[row.options[0].dest] = row.default


class Endpoints:
    """The started endpoints, by their transport's ready-file key, in the rows' order."""

    def __init__(self) -> None:
        self.by_key: dict[str, Endpoint] = {}
        self.rows: dict[str, Transport] = {}

    def add(self, row: Transport, endpoint: Endpoint) -> None:
        self.by_key[row.key] = endpoint
        self.rows[row.key] = row

    def get(self, key: str) -> Endpoint | None:
        return self.by_key.get(key)

    def all(self) -> list[Endpoint]:
        return list(self.by_key.values())

    def network(self) -> list[NetworkEndpoint]:
        """The listening ones (host, port, wait_closed), in order."""
        return [cast(NetworkEndpoint, e) for key, e in self.by_key.items() if self.rows[key].network]

    def addresses(self) -> dict[str, str]:
        """The ready file's keys: each transport's key with its address (HOST:PORT, or a path)."""
        return {key: endpoint.name for key, endpoint in self.by_key.items()}

    def address(self, key: str) -> str | None:
        found = self.by_key.get(key)
        return found.name if found is not None else None

    # The shipped transports, typed, for the code and tests that know which they asked for.
    @property
    def pty(self) -> PtyPort | None:
        return cast("PtyPort | None", self.by_key.get("pty"))

    @property
    def serial(self) -> SerialPort | None:
        return cast("SerialPort | None", self.by_key.get("serial"))

    @property
    def tcp(self) -> RtuOverTcpServer | None:
        return cast("RtuOverTcpServer | None", self.by_key.get("tcp"))

    @property
    def modbus_tcp(self) -> ModbusTcpServer | None:
        return cast("ModbusTcpServer | None", self.by_key.get("modbus_tcp"))


class Server:
    """A simulator behind the endpoints of ``options``; start, then close."""

    def __init__(self, sim: Simulator, options: ServeOptions) -> None:
        self.sim = sim
        self.options = options
        self.line = Line(sim, bus_timing=options.bus_timing)
        # The line's character: the serial settings (the serial port's, or those a serial device server in
        # front of the TCP endpoints would have); the bus tells whoever listens.
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
        opts = self.options
        _check_options(opts)
        scenario = self._load_scenario()
        try:
            self._start_watchers()
            await self._open_endpoints()
            if opts.control:
                await self._start_control(opts.control)
            if opts.metrics:
                await self._start_metrics(opts.metrics)
            if opts.ready_file:
                self.write_ready_file(opts.ready_file)
            if self.control is not None:
                self.control.serving = True
            if scenario is not None:
                from .scenario.timeline import play

                self.scenario_task = asyncio.create_task(play(scenario, self.sim, line=self.line, out=sys.stdout))
                self.scenario_task.add_done_callback(_report_scenario_error)
        except BaseException:
            self.close()
            await self._close_control()
            raise

    def _load_scenario(self) -> Scenario | None:
        if not self.options.scenario:
            return None
        from .scenario.timeline import check, load_scenario

        scenario = load_scenario(self.options.scenario)
        for warning in _scenario_differences(scenario, self.sim):
            print(f"c20sim: warning: {warning}", file=sys.stderr, flush=True)
        check(scenario, self.sim)
        return scenario

    def _start_watchers(self) -> None:
        """The live audit, the drill service, the frame log: each listens to the bus until close."""
        sim, opts = self.sim, self.options
        if opts.audit:
            from .control import liveaudit

            self._unsubscribe.append(liveaudit.start(sim).close)
        from .control import drills
        from .drillrun import serve_runner

        drills.attach(sim, serve_runner(sim, asyncio.get_running_loop(), opts.asked()))
        # at close: a running drill stops (its thread calls on this loop no more) and the service goes
        self._unsubscribe.append(lambda: drills.detach(sim))
        if opts.log_frames:
            self._open_frame_log(opts.log_frames)

    async def _open_endpoints(self) -> None:
        """Each transport asked for, in the rows' order; then each is told where the others are."""
        opts = self.options
        for row in opts.asked():
            if not row.usable():
                raise C20SimError(row.posix_only or f"{row.options[0].flag}: not available here")
            opening = Opening(
                self.line,
                {option.dest: opts.endpoints.get(option.dest) for option in row.options},
                parity=opts.parity,
                stopbits=opts.stopbits,
                line_timing=opts.line_timing,
                max_connections=opts.max_connections,
                gateway_timeout=opts.gateway_timeout,
            )
            endpoint = row.opener(opening)
            self.endpoints.add(row, endpoint)  # closed with the others if its start fails half-way
            await endpoint.start()
        for key, endpoint in self.endpoints.by_key.items():
            introduce = self.endpoints.rows[key].introduce
            if introduce is not None:
                introduce(endpoint, self.endpoints.address)

    async def _start_control(self, address: str) -> None:
        from .control.http import ControlApi, is_loopback, new_token  # imports aiohttp: only when asked for

        host, port = parse_host_port(address, "--control")
        token = self.options.control_token
        if token is not None and not token.strip():
            raise C20SimError("--control-token: empty; give a token, or leave the option out")
        if token is None and not is_loopback(host):
            token = new_token()  # beyond loopback, never without one
        self.control = ControlApi(self.sim, token=token, endpoints=self.endpoints.addresses)
        self.control.frame_log = self.frame_log
        self.control.line = self.line
        await self.control.start(host, port)

    async def _start_metrics(self, address: str) -> None:
        from .control import routes
        from .control.http import ControlApi

        host, port = parse_host_port(address, "--metrics")
        self.metrics = ControlApi(self.sim, endpoints=self.endpoints.addresses)
        self.metrics.line = self.line
        only = routes.Table([routes.table().named("metrics")])
        await self.metrics.start(host, port, table=only, option="--metrics")

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
        for server in self.endpoints.network():
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


def _check_options(opts: ServeOptions) -> None:
    """serve's own limits, said before anything opens."""
    max_mb = opts.log_frames_max_mb
    if max_mb is not None and max_mb != 0 and not 0.01 <= max_mb <= 1e6:  # refuses nan; inf is above the range
        raise C20SimError(f"--log-frames-max-mb {max_mb:g}: give a size in MiB from 0.01 to 1000000, or 0 for no bound")
    if any(row.network for row in opts.asked()) and not 0.01 <= opts.gateway_timeout <= 120.0:  # refuses nan
        raise C20SimError(
            f"--gateway-timeout {opts.gateway_timeout:g}: give seconds from 0.01 to 120 (an MGate's range)"
        )
    if opts.max_connections is not None and not 1 <= opts.max_connections <= 10000:
        raise C20SimError(f"--max-connections {opts.max_connections}: give 1 to 10000 connections per port")


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

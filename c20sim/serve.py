"""``c20sim serve``: a simulator on every endpoint asked for, until SIGINT or SIGTERM.

Endpoints start in order; if one fails (busy port, missing device, bad
address) the ones already started are closed before the error is reported,
so nothing is left half-started. When all are up, one ready line lists every
endpoint, and ``--ready-file`` gets the same as JSON with the real addresses
(port 0 is resolved), for scripts and CI to read.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
from collections.abc import Callable, Coroutine
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Protocol, TypeVar

from .bus import FrameRecord
from .errors import C20SimError
from .simulator import Simulator
from .transport.line import Line
from .transport.pty import PtyPort
from .transport.serial import SerialPort
from .transport.tcp import ModbusTcpServer, RtuOverTcpServer, parse_host_port

if TYPE_CHECKING:
    from .control.http import ControlApi
    from .scenario import Report, Scenario

T = TypeVar("T")

__all__ = ["Endpoints", "ServeOptions", "Server", "run", "run_server"]


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
    log_frames: str | None = None
    ready_file: str | None = None
    #: HOST:PORT of the HTTP control API (c20sim.control), or None
    control: str | None = None
    #: the token the control API asks for; None: none on loopback, a generated one beyond it
    control_token: str | None = None
    #: a scenario file (c20sim.scenario) to play against the served simulator once ready
    scenario: str | None = None
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
        self.line = Line(sim)
        self.endpoints = Endpoints()
        self._log_file: IO[str] | None = None
        self._unsubscribe: list[Callable[[], None]] = []
        self.control: ControlApi | None = None
        self.scenario_task: asyncio.Task[Report] | None = None

    async def start(self) -> None:
        """Start every endpoint, or none: on error, close what started and raise C20SimError."""
        opts, sim, line = self.options, self.sim, self.line
        scenario = None
        if opts.scenario:
            from .scenario import check, load_scenario

            scenario = load_scenario(opts.scenario)
            for warning in _scenario_differences(scenario, sim):
                print(f"c20sim: warning: {warning}", file=sys.stderr, flush=True)
            check(scenario, sim)
        try:
            if opts.log_frames:
                self._open_frame_log(opts.log_frames)
            if opts.pty or opts.link:
                self.endpoints.pty = PtyPort(line, link=opts.link, line_timing=opts.line_timing)
                await self.endpoints.pty.start()
            if opts.serial:
                self.endpoints.serial = SerialPort(
                    line,
                    opts.serial,
                    parity=opts.parity,
                    stopbits=opts.stopbits,
                    line_timing=opts.line_timing,
                )
                await self.endpoints.serial.start()
            if opts.tcp:
                host, port = parse_host_port(opts.tcp, "--tcp")
                self.endpoints.tcp = RtuOverTcpServer(line, host, port)
                await self.endpoints.tcp.start()
            if opts.modbus_tcp:
                host, port = parse_host_port(opts.modbus_tcp, "--modbus-tcp")
                self.endpoints.modbus_tcp = ModbusTcpServer(line, host, port)
                await self.endpoints.modbus_tcp.start()
            if opts.control:
                from .control.http import ControlApi, is_loopback, new_token  # imports aiohttp: only when asked for

                host, port = parse_host_port(opts.control, "--control")
                token = opts.control_token
                if token is not None and not token.strip():
                    raise C20SimError("--control-token: empty; give a token, or leave the option out")
                if token is None and not is_loopback(host):
                    token = new_token()  # beyond loopback, never without one
                self.control = ControlApi(sim, token=token, endpoints=self.endpoints.addresses)
                await self.control.start(host, port)
            if opts.ready_file:
                self.write_ready_file(opts.ready_file)
            if scenario is not None:
                from .scenario import play

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
        return {**self.endpoints.addresses(), **control, **self.options.extra_ready}

    async def _close_control(self) -> None:
        if self.control is not None:
            await self.control.close()
            self.control = None

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
        try:
            tmp.unlink(missing_ok=True)
            mode = 0o600 if "token" in data else 0o644  # a token is for the one who started the server
            with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode), "w") as out:
                out.write(json.dumps(data, indent=2) + "\n")
            os.replace(tmp, target)
        except OSError as exc:
            raise C20SimError(f"--ready-file {path}: cannot write: {exc.strerror}") from None

    def _open_frame_log(self, path: str) -> None:
        try:
            self._log_file = open(path, "a", encoding="utf-8", buffering=1)  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise C20SimError(f"--log-frames {path}: cannot open: {exc.strerror}") from None
        log_file = self._log_file

        def write(record: FrameRecord) -> None:
            log_file.write(json.dumps(record.as_dict()) + "\n")

        self._unsubscribe.append(self.sim.bus.subscribe(write))

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
        if self.scenario_task is not None:
            self.scenario_task.cancel()
        for endpoint in self.endpoints.all():
            endpoint.close()
        self.line.close()
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None


def _profile_name(name_or_path: str) -> str:
    from .profile import load_profile

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


async def run_server(sim: Simulator, options: ServeOptions, *, out: IO[str] = sys.stdout) -> None:
    """Serve until SIGINT or SIGTERM."""
    server = Server(sim, options)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    # Handlers first: a signal that comes as soon as the ready file exists still closes everything.
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        await server.start()
        print(server.ready_line(), file=out, flush=True)
        await stop.wait()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await server.aclose()

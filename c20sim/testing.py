"""The test handle: a running C20 on real ports, driven from a test, a script or a unittest, no pytest needed.

:class:`C20Sim` serves a :class:`~c20sim.core.simulator.Simulator` with
:class:`~c20sim.serve.Server` on an event loop of its own, in a background
thread: the test's client (sync or async, any library) talks to a real port,
and the test's own loop is never asked to run the server. Every call from
the test into the simulator (advance time, set conditions, trip, read) is an
operation of :mod:`c20sim.control` run on that loop's thread, between frames,
never half-way through one::

    with C20Sim.start(transport="tcp") as sim:
        ...  # point a Modbus client at sim.host, sim.port
        sim.advance(1.0)
        sim.trip("undervoltage")
        sim.assert_fault(0x0A)

The clock is virtual unless asked otherwise: time stands still until
:meth:`C20Sim.advance`. A client that waits on timers of its own (a poll
every 100 ms, a response timeout) sees time stand still too: advance the
model from the test while the client works, or start with ``clock="realtime"``.
The pytest fixture (:mod:`c20sim.pytest_plugin`) is this handle, one per test.
"""

from __future__ import annotations

import asyncio
import os
import threading
from collections.abc import Callable, Coroutine, Iterable, Mapping, Sequence
from typing import Any, TypeVar

from .audit import RULES, Finding, Severity
from .control import liveaudit, ops
from .core.bus import Direction, FrameRecord, RecordKind
from .core.simulator import Simulator, make_clock
from .drill import Judgement
from .drive.model import Telemetry
from .drive.profile import DEFAULT_PROFILE, Profile, load_profile
from .drivehandle import DriveHandle
from .serve import ServeOptions, Server
from .testsettings import DEFAULT_TRANSPORT, SETTINGS, Settings, check_settings, transports
from .transport.rows import find, rows
from .wire.errors import C20SimError
from .wire.protocol import ExceptionResponse, WriteMultipleRequest, WriteSingleRequest

__all__ = [
    "DEFAULT_TRANSPORT",
    "SETTINGS",
    "C20Sim",
    "DriveHandle",
    "Settings",
    "check_settings",
    "start",
    "transports",
]

T = TypeVar("T")


#: Frames shown in an assertion's message.
SHOWN_FRAMES = 20


class _LoopThread:
    """An asyncio loop running in a daemon thread; ``run`` executes a coroutine there and waits."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._main, name="c20sim", daemon=True)
        self._thread.start()

    def _main(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def run(self, coro: Coroutine[Any, Any, T], timeout: float = 30.0) -> T:
        if threading.current_thread() is self._thread:
            raise RuntimeError("c20sim: called from the simulator's own thread")
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the loop and close it; if its thread does not end within ``timeout``, say so and leave it."""
        if self.loop.is_closed():
            return
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise RuntimeError(
                f"c20sim: the simulator's event loop did not stop within {timeout:g} s "
                "(something running on it blocks); its thread is left running"
            )
        self.loop.close()


def format_frames(records: Sequence[FrameRecord], limit: int = SHOWN_FRAMES) -> str:
    """The last ``limit`` frames, one per line, for assertion messages."""
    if not records:
        return "no frames on the line"
    shown = list(records)[-limit:]
    head = (
        f"frames on the line (last {len(shown)} of {len(records)}):" if len(records) > limit else "frames on the line:"
    )
    lines = [head]
    t0 = shown[0].t  # frames carry the line's arrival times: show them from the first one shown
    for r in shown:
        note = f"  ({r.note})" if r.note else ""
        lines.append(f"  +{r.t - t0:8.4f} s {r.direction} {r.data.hex(' ').upper():<26} {r.text}{note}")
    return "\n".join(lines)


class C20Sim:
    """A running simulator: its ports, its clock, its drives, and assertions on its frame log.

    ``host``/``port`` are the endpoint of the network transport asked for: RTU over TCP for ``transport="tcp"``,
    Modbus TCP for ``transport="modbus-tcp"`` (with both, the first one listed). ``tcp_port`` is the RTU-over-TCP
    port, ``modbus_tcp_port`` the Modbus TCP port and ``pty`` the virtual serial port's path; each is None unless
    that transport was asked for. ``endpoints`` has every transport's address by its ready-file key, as
    ``serve --ready-file`` writes them. Methods that take ``drive`` act on the first drive when it is None.
    """

    def __init__(
        self,
        server: Server,
        thread: _LoopThread,
        stop: Callable[[], None] | None = None,
        transports: Sequence[str] = ("tcp",),
    ) -> None:
        self._server = server
        self._thread = thread
        self._stop = stop
        #: the simulator itself: touch it only through :meth:`call`
        self.sim: Simulator = server.sim
        self.profile: Profile = server.sim.profile
        self.addresses: tuple[int, ...] = tuple(server.sim.drives)
        ends = server.endpoints
        #: every transport's address by its ready-file key (a path, or HOST:PORT)
        self.endpoints: dict[str, str] = ends.addresses()
        self.pty: str | None = ends.pty.path if ends.pty is not None else None
        self.tcp_port: int | None = ends.tcp.port if ends.tcp is not None else None
        self.modbus_tcp_port: int | None = ends.modbus_tcp.port if ends.modbus_tcp is not None else None
        names = [row.name for row in ends.rows.values() if row.network]
        listening = dict(zip(names, ends.network(), strict=True))
        first = next((listening[t] for t in transports if t in listening), None)
        self.host: str | None = first.host if first is not None else None
        self.port: int | None = first.port if first is not None else None
        #: what the masters' connections carry: ``rtu`` where any transport asked for carries RTU frames, else
        #: ``mbap`` (what the drill's standard plan plays, as serve's)
        models = {row.model for t in transports if (row := find(t)) is not None}
        self.model = "rtu" if "rtu" in models or not models else "mbap"

    @classmethod
    def start(
        cls,
        profile: str | os.PathLike[str] | Profile = DEFAULT_PROFILE,
        *,
        transport: str | Sequence[str] = "tcp",
        drives: int | Sequence[int] = (1,),
        clock: str = "virtual",
        speed: float = 1.0,
        seed: int = 1,
        bus_timing: bool = True,
    ) -> C20Sim:
        """Start a simulator; use it as a context manager (``with C20Sim.start() as sim:``) or call :meth:`close`.

        Works from any script or unittest, no pytest needed. Bad settings raise C20SimError saying what is wrong.
        """
        settings = check_settings(
            {
                "profile": profile,
                "transport": transport,
                "drives": drives,
                "clock": clock,
                "speed": speed,
                "seed": seed,
                "bus_timing": bus_timing,
            }
        )
        return start(settings)

    def close(self) -> None:
        """Stop the server and its thread (again is harmless)."""
        stop, self._stop = self._stop, None
        if stop is not None:
            stop()

    def __enter__(self) -> C20Sim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- Running code next to the server.

    def call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run ``fn(*args, **kwargs)`` on the simulator's thread, between frames; returns its result."""

        async def run() -> T:
            return fn(*args, **kwargs)

        return self._thread.run(run())

    def _op(self, fn: Callable[..., T], *args: Any) -> T:
        try:
            return self.call(fn, self.sim, *args)
        except ops.ControlError as exc:
            raise C20SimError(str(exc)) from None

    def _address(self, drive: int | None) -> int:
        if drive is None:
            return self.addresses[0]
        if drive not in self.addresses:
            raise C20SimError(f"no drive at address {drive}; drives: {', '.join(map(str, self.addresses))}")
        return drive

    # --- Time.

    def now(self) -> float:
        return self.call(self.sim.now)

    def advance(self, seconds: float) -> float:
        """Move virtual time on by ``seconds`` (instantly); returns the new time."""
        if not self.sim.virtual:
            raise C20SimError(
                "time can only be advanced with the virtual clock; the c20sim marker says clock='realtime'"
            )
        return self._op(ops.advance, seconds)

    def run_until(self, t: float) -> float:
        """Move virtual time on to ``t`` (seconds of model time); returns the time."""
        if not self.sim.virtual:
            raise C20SimError(
                "time can only be advanced with the virtual clock; the c20sim marker says clock='realtime'"
            )
        return self.call(self.sim.run_until, t)

    # --- Runtime control: the clock and set-ups.

    def clock(self) -> dict[str, Any]:
        """The clock: ``clock`` (virtual or realtime), ``t``, ``paused``, ``speed``."""
        return self._op(ops.clock_state)

    def pause(self) -> None:
        """Stop the model's time (``clock="realtime"``); the drives still answer the bus."""
        self._op(ops.pause)

    def resume(self) -> None:
        """Let the model's time run on from where :meth:`pause` stopped it."""
        self._op(ops.resume)

    def set_speed(self, factor: float) -> None:
        """Run the realtime clock at ``factor`` model seconds per wall second (0.001-1000), with no jump."""
        self._op(ops.set_speed, factor)

    def reset(self, setup: str | os.PathLike[str] = "defaults") -> None:
        """Every drive anew, without restarting the server: ``"defaults"`` or a state file's function codes.

        Conditions, faults, generators and link faults go; the ports, the clock and the frame log stay.
        """
        self._op(ops.reset, setup if setup == "defaults" else os.fspath(os.path.abspath(setup)))

    # --- Drives.

    def drive(self, address: int | None = None) -> DriveHandle:
        """One drive, for state, conditions and faults."""
        return DriveHandle(self, self._address(address))

    @property
    def drives(self) -> list[DriveHandle]:
        return [DriveHandle(self, a) for a in self.addresses]

    def state(self, drive: int | None = None) -> Telemetry:
        return self.drive(drive).state()

    def read(self, register: str | int, drive: int | None = None) -> int:
        return self.drive(drive).read(register)

    def set(self, drive: int | None = None, **conditions: object) -> None:
        self.drive(drive).set(**conditions)

    def fault_record(self, drive: int | None = None) -> dict[str, Any]:
        """The fault record of a drive (:meth:`DriveHandle.fault_record`)."""
        return self.drive(drive).fault_record()

    def inject_fault(self, code: int, drive: int | None = None, *, persistent: bool = False) -> None:
        self.drive(drive).inject_fault(code, persistent=persistent)

    def clear_fault(self, drive: int | None = None, *, reset: bool = True) -> bool:
        return self.drive(drive).clear_fault(reset=reset)

    def trip(self, cause: str, drive: int | None = None) -> None:
        """Bring a fault's cause about (``undervoltage``, ``overheat``, ``eeprom``, ...); the drive trips by its model."""
        self.drive(drive).trip(cause)

    def release(self, cause: str, drive: int | None = None) -> None:
        """End a fault's cause; the fault stays until reset."""
        self.drive(drive).release(cause)

    def press(self, key: str | int, drive: int | None = None) -> bool:
        return self.drive(drive).press(key)

    def power_cycle(self, drive: int | None = None) -> None:
        self.drive(drive).power_cycle()

    # --- The line.

    def link_faults(self, drive: int | None = None, **switches: object) -> dict[str, Any]:
        """Switch link faults of ``drive`` (the whole bus if None); with no switches, read them."""
        if drive is not None:
            self._address(drive)
        if switches:
            self._op(ops.set_link_faults, drive, switches)
        return self._op(lambda sim: ops.link_state(ops.links(sim, drive)))

    def clear_link_faults(self, drive: int | None = None) -> None:
        if drive is not None:
            self._address(drive)
        self._op(ops.clear_link_faults, drive)

    def frames(self, drive: int | None = None) -> list[FrameRecord]:
        """The frame log, oldest first (only ``drive``'s frames if given)."""
        records = self.call(lambda: list(self.sim.bus.records))
        return [r for r in records if drive is None or r.slave == drive]

    def clear_frames(self) -> None:
        self.call(self.sim.bus.records.clear)

    # --- The drill.

    def drill(
        self,
        plan: str | os.PathLike[str] | Sequence[str | Mapping[str, object]] | None = None,
        *,
        poll_period: float | None = None,
        timeout: float | None = None,
        warmup: float = 3.0,
        seed: int = 1,
        wait: float = 10.0,
        log: str | os.PathLike[str] | None = None,
    ) -> Judgement:
        """Play a drill (docs/drill.md) on this simulator against the master the test runs, and judge it from the
        wire; needs ``clock="realtime"``. ``plan``: an incident's name (``"crc"``), a list of names or tables
        (``[{"incident": "trip", "cause": "overheat"}]``), a TOML plan file, or None for the standard plan (what the
        first transport carries). Waits up to ``wait`` s for the master's first request, then warms up for
        ``warmup`` s (or takes ``poll_period`` and ``timeout`` as given). Returns the judgement: ``passed``, and a
        verdict per drill with its checks and figures (``c20sim.drillrun.text_report(judgement)``: the report in
        words). The plant is left healthy (no link fault, no cause, no fault held)."""
        from .drill import read_plan, standard_plan
        from .drillrun import RunOptions, load_plan, play

        served = "modbus-tcp" if self.model == "mbap" else "tcp"
        if plan is None:
            chosen = standard_plan(seed, served)
        elif isinstance(plan, (str, os.PathLike)) and os.path.isfile(plan):
            chosen = load_plan(os.fspath(plan), seed, served)
        else:
            items = [plan] if isinstance(plan, str) else list(plan)  # type: ignore[arg-type]
            drills = [{"incident": item} if isinstance(item, str) else dict(item) for item in items]
            doc: dict[str, object] = {"seed": seed, "warmup": warmup, "drill": drills}
            if poll_period is not None or timeout is not None:
                doc.update(poll_period=poll_period, timeout=timeout)
            chosen = read_plan({k: v for k, v in doc.items() if v is not None}, "drill(...)")
        options = RunOptions(chosen, profile=self.profile, wait=wait, log=None if log is None else os.fspath(log))
        judgement, _ = play(self, options)
        return judgement

    # --- Assertions.

    def assert_written(
        self, register: str | int, value: int | None = None, drive: int | None = None, *, count: int | None = None
    ) -> None:
        """Fail unless a master wrote ``value`` (any value for None) to ``register`` of ``drive`` and it was taken.

        ``count`` asks for exactly that many taken writes (``count=0``: never written); None for at least one.
        Taken means the drive received the request (0x06 or 0x10) and its reply (matched to that request,
        even if a link fault then dropped it) was not an exception; a broadcast write, which
        is never answered, counts as taken.
        """
        __tracebackhide__ = True
        address = self._address(drive)
        reg = self._op(ops.parse_register, register)
        records = self.frames()
        seen: list[str] = []
        taken = 0
        for record in records:
            if record.direction is not Direction.RX or record.kind is not RecordKind.REQUEST:
                continue
            if record.slave not in (address, 0):
                continue
            written = _written(record.words).get(reg)
            if written is None:
                continue
            if value is not None and written != value:
                seen.append(f"{written}")
                continue
            if record.slave == 0:
                taken += 1  # broadcast: every listening drive acts on it, none answers
                continue
            reply = next((r for r in records if r.direction is Direction.TX and r.request is record.words), None)
            if reply is None:  # the drive never got it: offline, absent, a reserved address
                seen.append(f"{written}, not received ({record.note or 'no reply'})")
                continue
            if isinstance(reply.words, ExceptionResponse):
                seen.append(f"{written}, refused: {reply.text}")
                continue
            taken += 1
        if (count is None and taken) or taken == count:
            return
        label = self.profile.registers[reg].label
        what = "any value" if value is None else f"{value} (0x{value:04X})"
        others = f"; writes to {label} seen: {', '.join(seen)}" if seen else f"; no write to {label} at all"
        if count is None:
            problem = f"no accepted write of {what} to {label}{others}"
        else:
            problem = f"{taken} accepted write(s) of {what} to {label}, expected {count}{others}"
        raise AssertionError(f"drive {address}: {problem}\n" + format_frames(records))

    def assert_register(self, register: str | int, expected: int, drive: int | None = None, tolerance: int = 0) -> None:
        """Fail unless ``register`` of ``drive`` reads ``expected`` (within ``tolerance``) now."""
        __tracebackhide__ = True
        address = self._address(drive)
        info = self._op(ops.read_register, address, register)
        if abs(info["raw"] - expected) > tolerance:
            within = f" +/- {tolerance}" if tolerance else ""
            raise AssertionError(
                f"drive {address}: {info['register']} ({info['name']}) reads {info['raw']} ({info['text']}), "
                f"expected {expected}{within}; t = {self.now():g} s\n" + format_frames(self.frames())
            )

    def assert_fault(self, code: int, drive: int | None = None) -> None:
        """Fail unless ``drive`` reports fault ``code`` (0 for none) in 2102H."""
        __tracebackhide__ = True
        self.assert_register("2102H", code, drive)

    # --- The audit (docs/audit.md).

    def _live_audit(self) -> liveaudit.LiveAudit:
        found = liveaudit.of(self.sim)
        if found is None:
            raise C20SimError("the audit is off for this simulator")
        return found

    def audit(self, *, ignore: Iterable[str] = ()) -> list[Finding]:
        """What the masters did so far that would fail on a real line: the live audit's findings, worst first
        (those of the rules in ``ignore`` left out)."""
        skip = _rules(ignore)
        found = self.call(lambda: self._live_audit().findings())
        return [f for f in found if f.rule not in skip]

    def clear_audit(self) -> None:
        """Start the audit afresh: what the masters do from now on is judged (a set-up's frames forgotten)."""
        self.call(lambda: self._live_audit().restart())

    def assert_master_clean(self, *, ignore: Iterable[str] = (), severity: str = "note") -> None:
        """Fail if the audit found anything at or above ``severity`` (note: anything), but the rules in ``ignore``;
        the message lists each finding in one line: rule, drive, figure, advice, source."""
        __tracebackhide__ = True
        try:
            level = Severity.parse(severity)
        except ValueError as exc:
            raise C20SimError(f"assert_master_clean: {exc}") from None
        found = [f for f in self.audit(ignore=ignore) if f.severity >= level]
        if found:
            raise AssertionError(
                f"the audit found {len(found)} thing(s) the master would do wrong on a real line:\n"
                + "\n".join(f.line() for f in found)
            )


def _rules(names: Iterable[str]) -> frozenset[str]:
    if isinstance(names, str):
        names = (names,)
    given = frozenset(names)
    unknown = sorted(given - set(RULES))
    if unknown:
        raise C20SimError(f"ignore: unknown rule {unknown[0]!r}; the rules are {', '.join(RULES)}")
    return given


def _written(request: object) -> dict[int, int]:
    """The registers a request record writes (its words are the request the bus decoded)."""
    if isinstance(request, WriteSingleRequest):
        return {request.register: request.value}
    if isinstance(request, WriteMultipleRequest):
        return {request.start + i: v for i, v in enumerate(request.values)}
    return {}


def start(settings: Settings) -> C20Sim:
    """Start a simulator for ``settings`` in a background thread; :meth:`C20Sim.close` stops it."""
    profile = settings.profile if isinstance(settings.profile, Profile) else load_profile(settings.profile)
    sim = Simulator(profile, settings.drives, clock=make_clock(settings.clock, settings.speed), seed=settings.seed)
    given: dict[str, Any] = {
        row.options[0].dest: row.fixture for row in rows() if row.name in settings.transport and row.fixture is not None
    }
    options = ServeOptions(**given, bus_timing=settings.bus_timing)
    thread = _LoopThread()

    async def serve() -> Server:
        server = Server(sim, options)
        await server.start()
        return server

    try:
        server = thread.run(serve())
    except BaseException:
        thread.stop()
        raise

    def stop() -> None:
        try:
            thread.run(server.aclose())
        finally:
            thread.stop()

    return C20Sim(server, thread, stop, settings.transport)

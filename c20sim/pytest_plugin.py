"""The ``c20sim`` pytest fixture: a running C20 on a real port for each test, started clean.

The simulator is served by :class:`~c20sim.serve.Server` on an event loop of
its own, in a background thread, so the fixture works the same in plain and in
pytest-asyncio tests: the test's client (sync or async, any library) talks to
a real port, and the test's own loop is never asked to run the server. Every
call from the test into the simulator (advance time, inject, read) runs on
that loop's thread, between frames, never half-way through one.

Settings come from three overridable fixtures, ``c20sim_profile``,
``c20sim_transport`` and ``c20sim_drives``, and per test from the marker::

    @pytest.mark.c20sim(profile="c20-2200hv", transport="pty", drives=(1, 2), clock="virtual")

The marker wins over the fixtures. The clock is virtual unless the marker
says ``clock="realtime"``: time stands still until the test calls
:meth:`C20Sim.advance`.
"""

from __future__ import annotations

import asyncio
import math
import os
import threading
from collections.abc import Callable, Coroutine, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import pytest

from . import control
from .bus import FrameRecord
from .drive.model import Telemetry
from .errors import C20SimError
from .profile import DEFAULT_PROFILE, Profile, load_profile
from .protocol import ExceptionResponse, WriteMultipleRequest, WriteSingleRequest
from .serve import ServeOptions, Server
from .simulator import Simulator, check_addresses, make_clock

__all__ = ["C20Sim", "DriveHandle", "Settings"]

T = TypeVar("T")

#: Transports the fixture can open; ``tcp`` is RTU over TCP.
TRANSPORTS = ("tcp", "pty", "modbus-tcp")
#: Clocks the marker can ask for.
CLOCKS = ("virtual", "realtime")
#: Frames shown in an assertion's message.
SHOWN_FRAMES = 20


@dataclass(frozen=True)
class Settings:
    """What the fixture starts: profile, transports, drive addresses and clock."""

    profile: str | Profile = DEFAULT_PROFILE
    transport: tuple[str, ...] = ("tcp",)
    drives: tuple[int, ...] = (1,)
    clock: str = "virtual"
    speed: float = 1.0
    seed: int = 1


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

    ``host``/``port`` are the RTU-over-TCP endpoint, ``pty`` the virtual serial
    port's path, ``modbus_tcp_port`` the Modbus TCP port; each is None unless
    that transport was asked for. Methods that take ``drive`` act on the first
    drive when it is None.
    """

    def __init__(self, server: Server, thread: _LoopThread) -> None:
        self._server = server
        self._thread = thread
        #: the simulator itself: touch it only through :meth:`call`
        self.sim: Simulator = server.sim
        self.profile: Profile = server.sim.profile
        self.addresses: tuple[int, ...] = tuple(server.sim.drives)
        ends = server.endpoints
        self.host: str | None = ends.tcp.host if ends.tcp is not None else None
        self.port: int | None = ends.tcp.port if ends.tcp is not None else None
        self.pty: str | None = ends.pty.path if ends.pty is not None else None
        self.modbus_tcp_port: int | None = ends.modbus_tcp.port if ends.modbus_tcp is not None else None

    # --- Running code next to the server.

    def call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run ``fn(*args, **kwargs)`` on the simulator's thread, between frames; returns its result."""

        async def run() -> T:
            return fn(*args, **kwargs)

        return self._thread.run(run())

    def _op(self, fn: Callable[..., T], *args: Any) -> T:
        try:
            return self.call(fn, self.sim, *args)
        except control.ControlError as exc:
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
        return self._op(control.advance, seconds)

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

    def inject_fault(self, code: int, drive: int | None = None, *, persistent: bool = False) -> None:
        self.drive(drive).inject_fault(code, persistent=persistent)

    def clear_fault(self, drive: int | None = None, *, reset: bool = True) -> bool:
        return self.drive(drive).clear_fault(reset=reset)

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
            self._op(control.set_link_faults, drive, switches)
        return self.call(lambda: control.link_state(self.sim.link_faults(drive)))

    def clear_link_faults(self, drive: int | None = None) -> None:
        if drive is not None:
            self._address(drive)
        self._op(control.clear_link_faults, drive)

    def frames(self, drive: int | None = None) -> list[FrameRecord]:
        """The frame log, oldest first (only ``drive``'s frames if given)."""
        records = self.call(lambda: list(self.sim.bus.records))
        return [r for r in records if drive is None or r.slave == drive]

    def clear_frames(self) -> None:
        self.call(self.sim.bus.records.clear)

    # --- Assertions.

    def assert_written(self, register: str | int, value: int, drive: int | None = None) -> None:
        """Fail unless a master wrote ``value`` to ``register`` of ``drive`` (0x06 or 0x10) and it was taken.

        Taken means the drive received the request and its reply (matched to that request,
        even if a link fault then dropped it) was not an exception; a broadcast write, which
        is never answered, counts as taken.
        """
        __tracebackhide__ = True
        address = self._address(drive)
        reg = self._op(control.parse_register, register)
        records = self.frames()
        seen: list[str] = []
        for record in records:
            if record.direction != "rx" or record.kind != "request" or record.slave not in (address, 0):
                continue
            written = _written(record.words).get(reg)
            if written is None:
                continue
            if written != value:
                seen.append(f"{written}")
                continue
            if record.slave == 0:
                return  # broadcast: every listening drive acts on it, none answers
            reply = next((r for r in records if r.direction == "tx" and r.request is record.words), None)
            if reply is None:  # the drive never got it: offline, absent, a reserved address
                seen.append(f"{written}, not received ({record.note or 'no reply'})")
                continue
            if isinstance(reply.words, ExceptionResponse):
                seen.append(f"{written}, refused: {reply.text}")
                continue
            return
        label = self.profile.registers[reg].label
        others = f"; writes to {label} seen: {', '.join(seen)}" if seen else f"; no write to {label} at all"
        raise AssertionError(
            f"drive {address}: no accepted write of {value} (0x{value:04X}) to {label}{others}\n"
            + format_frames(records)
        )

    def assert_register(self, register: str | int, expected: int, drive: int | None = None, tolerance: int = 0) -> None:
        """Fail unless ``register`` of ``drive`` reads ``expected`` (within ``tolerance``) now."""
        __tracebackhide__ = True
        address = self._address(drive)
        info = self._op(control.read_register, address, register)
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


def _written(request: object) -> dict[int, int]:
    """The registers a request record writes (its words are the request the bus decoded)."""
    if isinstance(request, WriteSingleRequest):
        return {request.register: request.value}
    if isinstance(request, WriteMultipleRequest):
        return {request.start + i: v for i, v in enumerate(request.values)}
    return {}


class DriveHandle:
    """One drive of a :class:`C20Sim`: its state, registers, conditions and device faults."""

    def __init__(self, owner: C20Sim, address: int) -> None:
        self._owner = owner
        self.address = address

    def __repr__(self) -> str:
        return f"<c20sim drive {self.address}>"

    def state(self) -> Telemetry:
        """Telemetry now (speed, bus voltage, state, fault, ...)."""
        owner = self._owner

        def telemetry() -> Telemetry:
            owner.sim.sync()
            return control.model(owner.sim, self.address).telemetry()

        return owner._op(lambda _sim: telemetry())

    def read(self, register: str | int) -> int:
        """A register's raw value, as a master reads it (``2100H``, ``0x2100``, ``F00.10`` or ``status1``)."""
        value: int = self._owner._op(control.read_register, self.address, register)["raw"]
        return value

    def set(self, **conditions: object) -> None:
        """Set conditions now: ``supply_v``, ``load_torque_nm``, ``ambient_c``, ``hall_fault``, ..."""
        self._owner._op(control.set_conditions, self.address, conditions)

    def inject_fault(self, code: int, *, persistent: bool = False) -> None:
        self._owner._op(control.inject_fault, self.address, code, persistent)

    def clear_fault(self, *, reset: bool = True) -> bool:
        """Release an injected fault and (with ``reset``) press reset; True if the drive left the fault."""
        return self._owner._op(control.clear_fault, self.address, reset)

    def press(self, key: str | int) -> bool:
        """Press a keypad key (``forward``, ``stop``, ``reset``, ... or a 2000H value); False if refused."""
        return self._owner._op(control.press_key, self.address, key)

    def power_cycle(self) -> None:
        self._owner._op(control.power_cycle, self.address)

    def link_faults(self, **switches: object) -> dict[str, Any]:
        return self._owner.link_faults(self.address, **switches)


# --- Fixtures and the marker.


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "c20sim(profile=None, transport=None, drives=None, clock='virtual', speed=1.0, seed=1): "
        "settings of the c20sim fixture for this test",
    )


@pytest.fixture
def c20sim_profile() -> str | Profile:
    """The profile name, path or :class:`Profile` of the simulated drives (override to change)."""
    return DEFAULT_PROFILE


@pytest.fixture
def c20sim_transport() -> str | Sequence[str]:
    """``tcp`` (RTU over TCP, port 0), ``pty``, ``modbus-tcp``, or several (override to change)."""
    return "tcp"


@pytest.fixture
def c20sim_drives() -> Sequence[int]:
    """Drive addresses on the bus (override to change)."""
    return (1,)


def _transports(value: object) -> tuple[str, ...]:
    if isinstance(value, str):
        names: tuple[object, ...] = (value,)
    elif isinstance(value, Iterable):
        names = tuple(value)
    else:
        raise pytest.UsageError(f"c20sim: transport {value!r}: give a name or a sequence of {', '.join(TRANSPORTS)}")
    for name in names:
        if name not in TRANSPORTS:
            raise pytest.UsageError(f"c20sim: unknown transport {name!r}; use one or more of {', '.join(TRANSPORTS)}")
    if not names:
        raise pytest.UsageError("c20sim: give at least one transport")
    return tuple(str(name) for name in names)


def _drives(value: object) -> tuple[int, ...]:
    """Drive addresses, checked as ``--drives`` is: 1-247, each once."""
    addresses = (value,) if isinstance(value, int) else tuple(value) if isinstance(value, Iterable) else ()
    if not addresses or not all(isinstance(a, int) and not isinstance(a, bool) for a in addresses):
        raise pytest.UsageError(f"c20sim: drives {value!r}: give drive addresses 1-247, such as (1, 2)")
    try:
        return tuple(check_addresses(addresses))
    except ValueError as exc:
        raise pytest.UsageError(f"c20sim: drives {value!r}: {exc}") from None


def _profile(value: object) -> Profile:
    if isinstance(value, Profile):
        return value
    if not isinstance(value, str | os.PathLike):
        raise pytest.UsageError(f"c20sim: profile {value!r}: give a profile name, a path or a Profile")
    try:
        return load_profile(os.fspath(value))
    except C20SimError as exc:
        raise pytest.UsageError(f"c20sim: profile: {exc}") from None


def settings_for(request: pytest.FixtureRequest, profile: object, transport: object, drives: object) -> Settings:
    """The fixtures' values, overridden by the test's ``c20sim`` marker (a setting given as None is left to the
    fixture or the default); a bad setting is a :class:`pytest.UsageError` saying what is wrong."""
    marker = request.node.get_closest_marker("c20sim")
    if marker is not None and marker.args:
        raise pytest.UsageError("c20sim marker: give keywords, such as @pytest.mark.c20sim(drives=(1, 2))")
    given: dict[str, Any] = {k: v for k, v in marker.kwargs.items() if v is not None} if marker is not None else {}
    unknown = set(marker.kwargs if marker is not None else ()) - {
        "profile",
        "transport",
        "drives",
        "clock",
        "speed",
        "seed",
    }
    if unknown:
        raise pytest.UsageError(
            f"c20sim marker: unknown setting {', '.join(sorted(unknown))}; "
            "use profile, transport, drives, clock, speed or seed"
        )
    clock = given.get("clock", "virtual")
    if clock not in CLOCKS:
        raise pytest.UsageError(f"c20sim: unknown clock {clock!r}; use {' or '.join(map(repr, CLOCKS))}")
    speed = given.get("speed", 1.0)
    if isinstance(speed, bool) or not isinstance(speed, int | float) or not math.isfinite(speed) or speed <= 0:
        raise pytest.UsageError(f"c20sim: speed {speed!r}: give a positive number of model seconds per wall second")
    seed = given.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise pytest.UsageError(f"c20sim: seed {seed!r}: give a whole number")
    return Settings(
        profile=_profile(given.get("profile", profile)),
        transport=_transports(given.get("transport", transport)),
        drives=_drives(given.get("drives", drives)),
        clock=clock,
        speed=float(speed),
        seed=seed,
    )


def start(settings: Settings) -> tuple[C20Sim, Callable[[], None]]:
    """Start a simulator for ``settings`` in a background thread; returns it and its stop function."""
    profile = settings.profile if isinstance(settings.profile, Profile) else load_profile(settings.profile)
    sim = Simulator(profile, settings.drives, clock=make_clock(settings.clock, settings.speed), seed=settings.seed)
    options = ServeOptions(
        pty="pty" in settings.transport,
        tcp="127.0.0.1:0" if "tcp" in settings.transport else None,
        modbus_tcp="127.0.0.1:0" if "modbus-tcp" in settings.transport else None,
    )
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

    return C20Sim(server, thread), stop


@pytest.fixture
def c20sim(
    request: pytest.FixtureRequest,
    c20sim_profile: str | Profile,
    c20sim_transport: str | Sequence[str],
    c20sim_drives: Sequence[int],
) -> Iterator[C20Sim]:
    """A running C20 simulator, clean for each test: RTU over TCP on port 0 and a virtual clock by default."""
    running, stop = start(settings_for(request, c20sim_profile, c20sim_transport, c20sim_drives))
    try:
        yield running
    finally:
        stop()

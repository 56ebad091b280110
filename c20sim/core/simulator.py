"""A simulator: drives on one bus, and the clock that says what time it is for them.

This is what every front end shares: ``c20sim serve``, the dashboard, the
pytest plugin and the control API all hold a :class:`Simulator` and hand it
framing events; none of them builds drives or buses of its own. It does no
I/O beyond what the drives do with their state files.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from mypy_extensions import mypyc_attr

from ..drive import behaviours as behaviour_plugins
from ..drive.base import DrivePort
from ..drive.model import Drive
from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.protocol import FrameEvent
from ..wire.registers import BAUD_RATES, Reg
from .bus import Bus, Reply
from .clock import Clock, RealtimeClock, VirtualClock
from .generators import TICK, Generator, clamp
from .linkfaults import LinkFaults
from .slave import Slave

#: Notices a simulator keeps (the newest): each is a different thing to say, so a few are plenty.
MAX_NOTICES = 16

__all__ = [
    "Simulator",
    "check_addresses",
    "make_clock",
    "parse_addresses",
    "set_address",
    "set_baud",
    "state_path_for",
]


def check_addresses(addresses: Iterable[int]) -> list[int]:
    """Drive addresses 1-247, each once; raises ValueError naming the first one that is not."""
    checked: list[int] = []
    for address in addresses:
        if not 1 <= address <= 247:
            raise ValueError(f"address {address} is outside 1-247")
        if address in checked:
            raise ValueError(f"address {address} is listed twice")
        checked.append(address)
    return checked


def _expand(text: str) -> Iterator[int]:
    for part in text.split(","):
        part = part.strip()
        if not part:
            raise ValueError("empty entry; give addresses such as 1,2,5 or 1-3")
        low, dash, high = part.partition("-")
        try:
            first, last = (int(low), int(high)) if dash else (int(part), int(part))
        except ValueError:
            raise ValueError(f"{part!r} is not an address; give addresses such as 1,2,5") from None
        if first > last:
            raise ValueError(f"{part!r} runs backwards")
        yield from range(first, last + 1)  # lazily: a bad address in 1-1000000 is caught at 248


def parse_addresses(text: str) -> list[int]:
    """``"1,2,5"`` or ``"1-3,7"`` -> [1, 2, 3, 7]; raises C20SimError with what is wrong."""
    try:
        return check_addresses(_expand(text))
    except ValueError as exc:
        raise C20SimError(f"bad drive list {text!r}: {exc}") from None


def state_path_for(state: Path | None, address: int, count: int) -> Path | None:
    """One state file per drive: the path itself for one drive, ``NAME.ADDR.SUFFIX`` for several."""
    if state is None or count == 1:
        return state
    return state.with_name(f"{state.stem}.{address}{state.suffix or '.json'}")


def set_baud(drive: DrivePort, profile: Profile, baud: int) -> None:
    """Put a drive at the line speed the command line gave it (F08.01, mirrored by 2009H)."""
    if baud not in BAUD_RATES:
        raise C20SimError(f"baud {baud} is not one the C20 supports: {', '.join(map(str, BAUD_RATES))}")
    cell = profile.registers.canonical(Reg.BAUD)
    if drive.read(cell) != BAUD_RATES.index(baud):
        drive.write(cell, BAUD_RATES.index(baud))


def set_address(drive: DrivePort, profile: Profile, address: int) -> None:
    """Put a drive at the address the command line gave it (F08.00, mirrored by 2008H)."""
    cell = profile.registers.canonical(Reg.ADDRESS)
    if drive.read(cell) != address:
        drive.write(cell, address)


# A Python class where the core is compiled (tools/compile-core): control/liveaudit.py keys a
# WeakKeyDictionary by the simulator, and a compiled class cannot be weakly referenced.
@mypyc_attr(native_class=False)
class Simulator:
    """Drives at ``addresses`` on one bus, advanced by ``clock``."""

    def __init__(
        self,
        profile: Profile,
        addresses: Sequence[int] = (1,),
        *,
        clock: Clock | None = None,
        state: Path | None = None,
        seed: int | None = None,
        log_size: int = 2000,
        baud: int | None = None,
        behaviours: Mapping[str, behaviour_plugins.Factory] | None = None,
    ) -> None:
        if not addresses:
            raise C20SimError("no drives: give at least one address")
        self.profile = profile
        self.clock: Clock = clock if clock is not None else VirtualClock()
        self._baud = baud
        self._factories = behaviour_plugins.load(profile, behaviours)
        t0 = self.clock.now()
        #: generator and behaviour ticks fall at t0 + k * TICK: the same model times however time is stepped
        self._t0 = t0
        self._tick = 0
        #: (address, condition) -> (generator, setter, low, high), applied at every tick
        self._generators: dict[tuple[int, str], tuple[Generator, Callable[[Drive, float], None], float, float]] = {}
        #: the value each generator last set: its condition is set again only when the value changes
        self._applied: dict[tuple[int, str], float] = {}
        self.drives: dict[int, Drive] = {}
        self.ports: dict[int, DrivePort] = {}
        self._steps: dict[int, list[Callable[[Drive, float], None]]] = {}
        for address in addresses:
            drive = Drive(profile, t0=t0, state_path=state_path_for(state, address, len(addresses)))
            self._place(address, drive)
        self.slaves = {address: Slave(profile, self.ports[address]) for address in self.drives}
        self.bus = Bus(self.slaves.values(), log_size=log_size, seed=seed)
        #: what a user should know about the way a master talks to the simulator (a Modbus TCP master on an
        #: RTU port), each said once; the control API's telemetry carries them to the dashboard
        self.notices: deque[str] = deque(maxlen=MAX_NOTICES)

    def notice(self, text: str) -> bool:
        """Keep ``text`` for the front ends to show, unless it was said already; True if it is new."""
        if text in self.notices:
            return False
        self.notices.append(text)
        return True

    def _place(self, address: int, drive: Drive) -> None:
        """Put ``drive`` at ``address``: the command line's address and baud, the profile's behaviours."""
        set_address(drive, self.profile, address)
        if self._baud is not None:
            set_baud(drive, self.profile, self._baud)
        self.drives[address] = drive
        hooks = [factory(address, self.profile) for _, factory in self._factories]
        self.ports[address] = behaviour_plugins.HookedDrive(drive, hooks) if hooks else drive
        steps = [h.on_step for h in hooks if hasattr(h, "on_step")]
        if steps:
            self._steps[address] = steps
        else:
            self._steps.pop(address, None)

    @property
    def virtual(self) -> bool:
        return isinstance(self.clock, VirtualClock)

    def now(self) -> float:
        return self.clock.now()

    def handle(self, event: FrameEvent) -> Reply | None:
        """Serve one framing event at the clock's time."""
        if self._generators or self._steps:
            self.sync()  # generators and behaviours act on the way to now, before the slave sees the drive
        return self.bus.handle(event, self.clock.now())

    def drive(self, address: int | None = None) -> Drive:
        """The drive first configured at ``address`` (the first drive for None)."""
        if address is None:
            return next(iter(self.drives.values()))
        try:
            return self.drives[address]
        except KeyError:
            raise C20SimError(f"no drive at address {address}; drives: {', '.join(map(str, self.drives))}") from None

    def link_faults(self, address: int | None = None) -> LinkFaults:
        """Link faults of one drive, or of the whole bus for None."""
        if address is None:
            return self.bus.link
        self.drive(address)  # a clear error for an unknown address
        return self.bus.link_of(self.slaves[address])

    def advance(self, seconds: float) -> float:
        """Move virtual time on by ``seconds``; returns the new time (:meth:`run_until` ``now + seconds``)."""
        if not math.isfinite(seconds) or seconds < 0:
            raise C20SimError(f"cannot advance by {seconds} s: time does not run backwards, nor to infinity")
        return self.run_until(self.now() + seconds)

    def run_until(self, t: float) -> float:
        """Virtual clock: move time on to ``t`` (no earlier than now) and bring every drive to it; returns the time.

        The one way time is moved by hand: the API, ctl, scenarios, pytest and the dashboard all call it.
        """
        if not isinstance(self.clock, VirtualClock):
            raise C20SimError("time can only be advanced with the virtual clock (--clock virtual)")
        if not math.isfinite(t):
            raise C20SimError(f"cannot run until t = {t}: time does not run to infinity")
        now = self.clock.now()
        if t > now:
            self.clock.advance(t - now)
        self.sync()
        return self.clock.now()

    def wall_seconds_to(self, t: float) -> float:
        """Wall seconds until the clock reads ``t``: 0 once there; a virtual clock is run to it first.

        The realtime wait without a clock read in the caller: ``while (s := sim.wall_seconds_to(t)) > 0:
        await asyncio.sleep(s)``. Pure, as the rest of the core: the caller does the waiting.
        """
        if isinstance(self.clock, VirtualClock):
            self.run_until(t)
            return 0.0
        speed = self.clock.speed if isinstance(self.clock, RealtimeClock) else 1.0  # model seconds per wall second
        left = t - self.clock.now()
        if left <= 0:
            self.sync()
            return 0.0
        return left / speed

    def sync(self) -> None:
        """Bring every drive to the clock's time (for telemetry between requests).

        With generators or behaviours' steps, the drives are advanced tick by tick (:data:`TICK` of
        model time): at each tick the generators' values are applied and the steps run.
        """
        t = self.clock.now()
        if self._generators or self._steps:
            self._run_ticks(t)
        for drive in self.drives.values():
            drive.advance_to(t)

    def _run_ticks(self, t: float) -> None:
        last = math.floor((t - self._t0) / TICK + 1e-9)
        while self._tick < last and (self._generators or self._steps):
            self._tick += 1
            at = self._t0 + self._tick * TICK
            for drive in self.drives.values():
                drive.advance_to(at)
            self._apply(at)
        self._tick = max(self._tick, last)

    def _apply(self, at: float) -> None:
        for key, (generator, setter, low, high) in list(self._generators.items()):
            value = clamp(generator.value(at), low, high)
            if self._applied.get(key) != value:  # a held value is not set again: the drive keeps its steady skip
                setter(self.drives[key[0]], value)
                self._applied[key] = value
            if generator.done(at):
                del self._generators[key]
                self._applied.pop(key, None)
        for address, steps in self._steps.items():
            for step in steps:
                step(self.drives[address], at)

    # --- Generators (c20sim.core.generators): the checking is control.ops'.

    def set_generator(
        self,
        address: int,
        name: str,
        generator: Generator,
        setter: Callable[[Drive, float], None],
        low: float,
        high: float,
    ) -> None:
        """Drive condition ``name`` of drive ``address`` by ``generator`` from now on (replacing one there)."""
        self.sync()
        self._generators[(address, name)] = (generator, setter, low, high)
        value = clamp(generator.value(self.clock.now()), low, high)
        setter(self.drives[address], value)
        self._applied[(address, name)] = value

    def clear_generator(self, address: int, name: str | None = None) -> None:
        """Stop the generator on ``name`` (every one of the drive for None); its condition stays where it is."""
        self.sync()
        for key in [k for k in self._generators if k[0] == address and name in (None, k[1])]:
            del self._generators[key]
            self._applied.pop(key, None)

    def generators(self, address: int) -> dict[str, dict[str, Any]]:
        """The running generators of a drive, by condition, as JSON-ready values."""
        return {k[1]: dict(g[0].describe()) for k, g in self._generators.items() if k[0] == address}

    # --- Runtime control.

    def reset(self, parameters: Mapping[int, int] | None = None) -> None:
        """Every drive anew, as at power-up, with its function codes from ``parameters`` (the profile's
        defaults for those not given; all defaults for None), without restarting: the bus, its ports and
        the frame log stay; conditions, faults, generators and link faults go. A drive with a state file
        keeps it, and writes the new values to it. The command line's addresses and baud stay."""
        self.sync()
        t = self.clock.now()
        self._generators.clear()
        self._applied.clear()
        for address, old in list(self.drives.items()):
            drive = Drive(self.profile, t0=t, state_path=old.parameters.path)
            drive.parameters.restore_defaults()
            if parameters:
                drive.parameters.load(parameters)
            drive.power_cycle()  # take the values as a drive switched on with them
            self._place(address, drive)
            self.slaves[address].attach(self.ports[address])
            self.bus.link_of(self.slaves[address]).clear()
        self.bus.link.clear()
        self.bus.line_baud = next(iter(self.slaves.values())).baud  # as at start: the line at the set-up's baud
        self._t0, self._tick = t, 0


#: --speed: a realtime clock from a thousandth of wall time to a thousand times it (assumed bounds: wider
#: than any bench needs, narrow enough that model times stay finite).
SPEED_RANGE = (0.001, 1000.0)


def make_clock(kind: str, speed: float = 1.0) -> Clock:
    """The clock named on the command line: ``realtime`` (times ``speed``) or ``virtual``."""
    if kind == "virtual":
        return VirtualClock()
    if kind == "realtime":
        if not SPEED_RANGE[0] <= speed <= SPEED_RANGE[1]:  # also refuses nan and inf
            raise C20SimError(
                f"--speed {speed:g}: give a clock speed factor from {SPEED_RANGE[0]:g} to {SPEED_RANGE[1]:g}"
            )
        return RealtimeClock(speed)
    raise C20SimError(f"unknown clock {kind!r}; use realtime or virtual")

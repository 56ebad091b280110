"""A simulator: drives on one bus, and the clock that says what time it is for them.

This is what every front end shares: ``c20sim serve``, the dashboard, the
pytest plugin and the control API all hold a :class:`Simulator` and hand it
framing events; none of them builds drives or buses of its own. It does no
I/O beyond what the drives do with their state files.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

from .bus import Bus, Reply
from .clock import Clock, RealtimeClock, VirtualClock
from .drive.base import DrivePort
from .errors import C20SimError
from .linkfaults import LinkFaults
from .profile import Profile
from .protocol import FrameEvent
from .registers import BAUD_RATES, Reg
from .slave import Slave

__all__ = [
    "DriveFactory",
    "Simulator",
    "check_addresses",
    "make_clock",
    "parse_addresses",
    "set_address",
    "set_baud",
    "state_path_for",
]

#: Builds one drive: (profile, address, state file or None, start time) -> drive.
DriveFactory = Callable[[Profile, int, "Path | None", float], DrivePort]


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


def default_drive_factory(profile: Profile, address: int, state: Path | None, t0: float) -> DrivePort:
    from .drive.model import Drive

    drive = Drive(profile, t0=t0, state_path=state)
    set_address(drive, profile, address)
    return drive


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
        drive_factory: DriveFactory = default_drive_factory,
        log_size: int = 2000,
        baud: int | None = None,
    ) -> None:
        if not addresses:
            raise C20SimError("no drives: give at least one address")
        self.profile = profile
        self.clock: Clock = clock if clock is not None else VirtualClock()
        t0 = self.clock.now()
        self.drives: dict[int, DrivePort] = {
            address: drive_factory(profile, address, state_path_for(state, address, len(addresses)), t0)
            for address in addresses
        }
        if baud is not None:
            for drive in self.drives.values():
                set_baud(drive, profile, baud)
        self.slaves = {address: Slave(profile, drive) for address, drive in self.drives.items()}
        self.bus = Bus(self.slaves.values(), log_size=log_size, seed=seed)

    @property
    def virtual(self) -> bool:
        return isinstance(self.clock, VirtualClock)

    def now(self) -> float:
        return self.clock.now()

    def handle(self, event: FrameEvent) -> Reply | None:
        """Serve one framing event at the clock's time."""
        return self.bus.handle(event, self.clock.now())

    def drive(self, address: int | None = None) -> DrivePort:
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
        """Move virtual time on by ``seconds`` and bring every drive to it; returns the new time."""
        if not isinstance(self.clock, VirtualClock):
            raise C20SimError("time can only be advanced with the virtual clock (--clock virtual)")
        if not math.isfinite(seconds) or seconds < 0:
            raise C20SimError(f"cannot advance by {seconds} s: time does not run backwards, nor to infinity")
        t = self.clock.advance(seconds)
        self.sync()
        return t

    def sync(self) -> None:
        """Bring every drive to the clock's time (for telemetry between requests)."""
        t = self.clock.now()
        for drive in self.drives.values():
            drive.advance_to(t)


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

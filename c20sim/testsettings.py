"""The test handle's settings: what :meth:`c20sim.testing.C20Sim.start` and the pytest marker may give, checked.

A bad setting is a C20SimError saying what is wrong (the plugin makes it a usage error).
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from .core.simulator import check_addresses
from .drive.profile import DEFAULT_PROFILE, Profile, load_profile
from .transport.rows import rows
from .wire.errors import C20SimError

__all__ = ["CLOCKS", "DEFAULT_TRANSPORT", "SETTINGS", "Settings", "check_settings", "transports"]

#: The transport the handle opens unless asked otherwise: RTU over TCP on port 0.
DEFAULT_TRANSPORT = "tcp"


def transports() -> tuple[str, ...]:
    """The transports the handle can open (the rows with a ``fixture`` value: c20sim.transport.rows), the default
    first; ``tcp`` is RTU over TCP."""
    names = [row.name for row in rows() if row.fixture is not None]
    return tuple(sorted(names, key=lambda name: name != DEFAULT_TRANSPORT))


#: Clocks the marker can ask for.
CLOCKS = ("virtual", "realtime")


@dataclass(frozen=True)
class Settings:
    """What the fixture starts: profile, transports, drive addresses and clock."""

    profile: str | Profile = DEFAULT_PROFILE
    transport: tuple[str, ...] = (DEFAULT_TRANSPORT,)
    drives: tuple[int, ...] = (1,)
    clock: str = "virtual"
    speed: float = 1.0
    seed: int = 1
    #: each transaction holds the line for its RS485 time (19200 8N1: about 86 one-register reads a second),
    #: as ``c20sim serve`` does by default; False: only the turnaround
    bus_timing: bool = True


def _transports(value: object) -> tuple[str, ...]:
    known = transports()
    if isinstance(value, str):
        names: tuple[object, ...] = (value,)
    elif isinstance(value, Iterable):
        names = tuple(value)
    else:
        raise C20SimError(f"c20sim: transport {value!r}: give a name or a sequence of {', '.join(known)}")
    for name in names:
        if name not in known:
            raise C20SimError(f"c20sim: unknown transport {name!r}; use one or more of {', '.join(known)}")
    if not names:
        raise C20SimError("c20sim: give at least one transport")
    return tuple(str(name) for name in names)


def _drives(value: object) -> tuple[int, ...]:
    """Drive addresses, checked as ``--drives`` is: 1-247, each once."""
    addresses = (value,) if isinstance(value, int) else tuple(value) if isinstance(value, Iterable) else ()
    if not addresses or not all(isinstance(a, int) and not isinstance(a, bool) for a in addresses):
        raise C20SimError(f"c20sim: drives {value!r}: give drive addresses 1-247, such as (1, 2)")
    try:
        return tuple(check_addresses(addresses))
    except ValueError as exc:
        raise C20SimError(f"c20sim: drives {value!r}: {exc}") from None


def _profile(value: object) -> Profile:
    if isinstance(value, Profile):
        return value
    if not isinstance(value, str | os.PathLike):
        raise C20SimError(f"c20sim: profile {value!r}: give a profile name, a path or a Profile")
    try:
        return load_profile(os.fspath(value))
    except C20SimError as exc:
        raise C20SimError(f"c20sim: profile: {exc}") from None


#: The settings a marker or :meth:`C20Sim.start` may give.
SETTINGS = ("profile", "transport", "drives", "clock", "speed", "seed", "bus_timing")


def check_settings(given: Mapping[str, Any]) -> Settings:
    """Settings from keywords (a missing one takes its default); a bad one is a C20SimError saying what is wrong."""
    unknown = set(given) - set(SETTINGS)
    if unknown:
        raise C20SimError(f"c20sim: unknown setting {', '.join(sorted(unknown))}; use {', '.join(SETTINGS)}")
    clock = given.get("clock", "virtual")
    if clock not in CLOCKS:
        raise C20SimError(f"c20sim: unknown clock {clock!r}; use {' or '.join(map(repr, CLOCKS))}")
    speed = given.get("speed", 1.0)
    if isinstance(speed, bool) or not isinstance(speed, int | float) or not math.isfinite(speed) or speed <= 0:
        raise C20SimError(f"c20sim: speed {speed!r}: give a positive number of model seconds per wall second")
    seed = given.get("seed", 1)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise C20SimError(f"c20sim: seed {seed!r}: give a whole number")
    bus_timing = given.get("bus_timing", True)
    if not isinstance(bus_timing, bool):
        raise C20SimError(f"c20sim: bus_timing {bus_timing!r}: give True or False")
    return Settings(
        profile=_profile(given.get("profile", DEFAULT_PROFILE)),
        transport=_transports(given.get("transport", DEFAULT_TRANSPORT)),
        drives=_drives(given.get("drives", (1,))),
        clock=clock,
        speed=float(speed),
        seed=seed,
        bus_timing=bus_timing,
    )

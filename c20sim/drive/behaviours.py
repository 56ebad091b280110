"""Behaviours: named device quirks that a package adds, selected by the profile.

A package declares an entry point in the group ``c20sim.behaviours``::

    [project.entry-points."c20sim.behaviours"]
    slow-eeprom = "my_quirks:SlowEeprom"

and a profile selects it by name (``behaviours = ["slow-eeprom"]`` at the top
of the TOML file). The entry point is a factory called once per drive as
``factory(address, profile)``; what it returns may define any of these hooks,
each optional:

- ``on_read(drive, cell, value) -> int``: the value a master reads from a storage cell
  (a mirrored 20xxH register arrives as its function code's address);
- ``check_write(drive, cell, value) -> None``: raise :class:`~c20sim.wire.errors.ModbusError` to refuse a
  write (the master gets that exception; nothing of the request is written);
- ``on_write(drive, cell, value) -> int``: the value actually stored;
- ``on_step(drive, t) -> None``: called every :data:`~c20sim.core.generators.TICK` of model time, as the drive
  is advanced (it may set the drive's conditions).

Hooks run in the profile's order; at each tick the generators' values
(:mod:`c20sim.core.generators`) are applied first, then the steps, so a condition is
best driven by one or the other. They see the :class:`~c20sim.drive.model.Drive` itself. An unknown
name, or an entry point that fails to load, is a :class:`~c20sim.wire.errors.ProfileError` naming the
profile, and the behaviours that are installed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from importlib import metadata
from typing import Any

from ..wire.errors import ProfileError
from .model import Drive
from .profile import Profile

__all__ = ["GROUP", "Factory", "HookedDrive", "available", "load"]

#: The entry-point group packages add behaviours to.
GROUP = "c20sim.behaviours"

Factory = Callable[[int, Profile], Any]


def available() -> dict[str, metadata.EntryPoint]:
    """The installed behaviours, by name."""
    return {ep.name: ep for ep in metadata.entry_points(group=GROUP)}


def load(profile: Profile, extra: Mapping[str, Factory] | None = None) -> list[tuple[str, Factory]]:
    """The factories of the behaviours ``profile`` selects, in its order; ``extra`` adds named factories
    (tests) ahead of the installed ones."""
    if not profile.behaviours:
        return []
    installed = available()
    out: list[tuple[str, Factory]] = []
    for name in profile.behaviours:
        if extra is not None and name in extra:
            out.append((name, extra[name]))
            continue
        entry = installed.get(name)
        if entry is None:
            known = ", ".join(sorted({*installed, *(extra or {})})) or "none installed"
            raise ProfileError(
                profile.path,
                "behaviours",
                f"no behaviour {name!r} is installed (entry-point group {GROUP}; installed: {known})",
            )
        try:
            factory = entry.load()
        except Exception as exc:  # a broken plugin: say which, without a traceback
            raise ProfileError(
                profile.path, "behaviours", f"behaviour {name!r} ({entry.value}) cannot be loaded: {exc}"
            ) from None
        if not callable(factory):
            raise ProfileError(profile.path, "behaviours", f"behaviour {name!r} ({entry.value}) is not callable")
        out.append((name, factory))
    return out


class HookedDrive:
    """A :class:`~c20sim.drive.base.DrivePort` that passes a drive's reads and writes through behaviours."""

    def __init__(self, drive: Drive, hooks: Sequence[Any]) -> None:
        self.drive = drive
        self.hooks = list(hooks)
        self._read = [h.on_read for h in hooks if hasattr(h, "on_read")]
        self._check = [h.check_write for h in hooks if hasattr(h, "check_write")]
        self._write = [h.on_write for h in hooks if hasattr(h, "on_write")]
        self.steps = [h.on_step for h in hooks if hasattr(h, "on_step")]

    def advance_to(self, t: float) -> None:
        self.drive.advance_to(t)

    def communicated(self, t: float) -> None:
        self.drive.communicated(t)

    @property
    def running(self) -> bool:
        return self.drive.running

    def read(self, address: int) -> int:
        value = self.drive.read(address)
        for hook in self._read:
            value = int(hook(self.drive, address, value))
        return value

    def check_write(self, address: int, value: int) -> None:
        self.drive.check_write(address, value)
        for hook in self._check:
            hook(self.drive, address, value)

    def write(self, address: int, value: int) -> None:
        for hook in self._write:
            value = int(hook(self.drive, address, value)) & 0xFFFF
        self.drive.write(address, value)

    def write_ram(self, address: int, value: int) -> None:
        for hook in self._write:
            value = int(hook(self.drive, address, value)) & 0xFFFF
        self.drive.write_ram(address, value)

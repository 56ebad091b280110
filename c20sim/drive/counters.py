"""The power-on and running time counters, whole hours kept in EEPROM.

The INVT Goodrive family shows the drive's accumulated power-on time and running time in its P07 group; the
C20's sheet has neither. c20sim keeps both at F07.13 (power-on) and F07.14 (running), read-only, in hours,
in EEPROM (numbers, resolution and what is kept **assumed** for the C20):

- the power-on hour counts model time from power-up; the running hour counts time the inverter drives the
  motor (the states in which the RUN output is on);
- each counter is saved when it reaches a whole hour (one EEPROM save an hour at most); the part of an hour
  not yet counted at a power cycle is lost, as on a drive that saves only whole hours;
- a restore of the defaults (200FH) keeps them.

The hour marks are steps, so a steady segment stops at them and the counts are the same whatever the polling.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from ..wire.registers import fcode_address
from .physics import STEP

__all__ = ["F_POWER_ON_HOURS", "F_RUNNING_HOURS", "HOUR", "Counters"]

F_POWER_ON_HOURS = fcode_address(7, 13)
F_RUNNING_HOURS = fcode_address(7, 14)
#: Steps in an hour.
HOUR = round(3600.0 / STEP)


class Counters:
    """Where one drive's two hour counters stand between their whole hours."""

    __slots__ = ("get", "mark", "on_mark", "record", "run_done", "run_since")

    def __init__(self, get: Callable[[int], int], record: Callable[[Mapping[int, int]], object]) -> None:
        self.get, self.record = get, record
        self.power_up(0)

    def power_up(self, k: int) -> None:
        """Switched on at step ``k``, not running: what was not a whole hour is gone."""
        self.on_mark = k  #: the step the power-on hour under way began
        self.run_done = 0  #: running steps of the hour under way, up to ``run_since``
        self.run_since: int | None = None  #: the step the run under way began (or was last counted from)
        self.mark = self.next_mark()  #: the step the next whole hour falls on (kept: the step loop reads it)

    def driven(self, k: int, on: bool) -> None:
        """The inverter started (``on``) or stopped driving the motor at step ``k``."""
        if on and self.run_since is None:
            self.run_since = k
        elif not on and self.run_since is not None:
            self.run_done += k - self.run_since
            self.run_since = None
        self.mark = self.next_mark()

    def next_mark(self) -> int:
        """The step the next whole hour falls on."""
        mark = self.on_mark + HOUR
        if self.run_since is not None:
            mark = min(mark, self.run_since + HOUR - self.run_done)
        return mark

    def due(self, k: int) -> bool:
        return k >= self.mark

    def tick(self, k: int) -> None:
        """Count the whole hours reached by step ``k`` and save them."""
        counted: dict[int, int] = {}
        while k >= self.on_mark + HOUR:
            self.on_mark += HOUR
            counted[F_POWER_ON_HOURS] = min(counted.get(F_POWER_ON_HOURS, self.get(F_POWER_ON_HOURS)) + 1, 0xFFFF)
        if self.run_since is not None:
            while k >= self.run_since + HOUR - self.run_done:
                self.run_since += HOUR - self.run_done
                self.run_done = 0
                counted[F_RUNNING_HOURS] = min(counted.get(F_RUNNING_HOURS, self.get(F_RUNNING_HOURS)) + 1, 0xFFFF)
        self.mark = self.next_mark()
        if counted:
            self.record(counted)

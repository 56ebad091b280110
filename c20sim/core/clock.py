"""Clocks: what time it is for the model, decided outside the model.

The drive never reads a clock; it is advanced to a time. A :class:`VirtualClock`
is moved by hand (tests, CI, scenarios: an hour passes instantly); a
:class:`RealtimeClock` follows a monotonic wall clock times a speed factor
(serving). Its time source is injectable, so it is tested without waiting.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable

__all__ = ["Clock", "RealtimeClock", "VirtualClock"]


@runtime_checkable
class Clock(Protocol):
    """Anything that says what time (seconds) it is for the model."""

    def now(self) -> float: ...


class VirtualClock:
    """Time that moves only when told to: instant, exact and repeatable."""

    def __init__(self, t0: float = 0.0) -> None:
        self._t = float(t0)

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> float:
        """Move ``dt`` seconds forward; returns the new time."""
        if dt < 0:
            raise ValueError(f"time cannot go backwards (dt = {dt})")
        self._t += dt
        return self._t

    def set(self, t: float) -> None:
        """Jump to ``t``, which must not be in the past."""
        if t < self._t:
            raise ValueError(f"time cannot go backwards ({t} < {self._t})")
        self._t = float(t)


class RealtimeClock:
    """Wall time times ``speed``, from ``t0``: ``speed = 10`` runs the model ten times faster.

    ``source`` is the wall clock (``time.monotonic`` unless a test injects one).
    Changing ``speed``, :meth:`pause` and :meth:`resume` keep the model's time continuous.
    """

    def __init__(self, speed: float = 1.0, *, t0: float = 0.0, source: Callable[[], float] = time.monotonic) -> None:
        if speed <= 0:
            raise ValueError(f"speed must be positive, not {speed}")
        self._source = source
        self._speed = float(speed)
        self._base_wall = source()
        self._base_t = float(t0)
        self._paused = False

    def now(self) -> float:
        if self._paused:
            return self._base_t
        return self._base_t + (self._source() - self._base_wall) * self._speed

    @property
    def speed(self) -> float:
        return self._speed

    @speed.setter
    def speed(self, value: float) -> None:
        if value <= 0:
            raise ValueError(f"speed must be positive, not {value}")
        self._base_t = self.now()
        self._base_wall = self._source()
        self._speed = float(value)

    @property
    def paused(self) -> bool:
        return self._paused

    def pause(self) -> None:
        """Stop the model's time where it is (again is harmless)."""
        if not self._paused:
            self._base_t = self.now()
            self._paused = True

    def resume(self) -> None:
        """Let the model's time run on from where it was paused, with no jump (again is harmless)."""
        if self._paused:
            self._base_wall = self._source()
            self._paused = False

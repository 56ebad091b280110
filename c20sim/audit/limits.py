"""What the audit's rules judge by: the limits no document gives (all assumed), the line demand it reports, and
the bounds of its memory."""

from __future__ import annotations

from dataclasses import dataclass

from ..wire.registers import fcode_address

__all__ = [
    "F_BAUD",
    "F_COMM_TIMEOUT",
    "F_MAX_SPEED",
    "MAX_EVENTS",
    "MAX_SUBJECTS",
    "MAX_WINDOW",
    "Limits",
    "LineDemand",
]

F_MAX_SPEED = fcode_address(0, 3)
F_BAUD = fcode_address(8, 1)
F_COMM_TIMEOUT = fcode_address(8, 2)

#: Times closer than this are one (a frame log rounds them to the microsecond).
_EPSILON = 1e-6
#: Seconds the frames' times may be off within a line-demand window: a reply handed over up to half a millisecond
#: early (c20sim.transport.line.EARLY), the next request stamped on its arrival, a capture's timestamps. A line
#: kept exactly full can read this much above 100 %; only beyond it is more asked than the line carries. Assumed.
_DEMAND_JITTER = 0.002
#: How early a reply may seem to go out against its record's time: the event loop's timers (libuv's) count in
#: whole milliseconds, so a reply due 2 ms after a request may leave after 1.x ms by the frames' clock.
_TIMER_SLACK = 0.001
#: The most transactions the line-demand window holds (a 1 s window at 100,000 transactions a second).
MAX_WINDOW = 100_000
#: The most (drive, subject) counters kept; beyond, new subjects are not followed (the first ones are).
MAX_SUBJECTS = 4096
#: The most findings waiting in :meth:`Auditor.events`; the oldest go first (findings() keeps them all).
MAX_EVENTS = 1024


@dataclass(frozen=True)
class Limits:
    """What the rules judge by, where no document gives a figure: all **assumed**, all settable."""

    window: float = 1.0  #: seconds of traffic the line demand is measured over; assumed
    demand_error: float = 100.0  #: percent of the line: the replies queue and time out
    demand_warning: float = 80.0  #: percent of the line: no room left for retries; assumed
    cyclic_writes: int = 5  #: writes of one function code that make it cyclic; assumed
    wear_error_h: float = 8760.0  #: rated endurance reached within a year: error; assumed
    wear_warning_h: float = 87600.0  #: ... within ten years (a drive's service life): warning; assumed
    watchdog_margin: float = 0.8  #: a silence above this fraction of the comm timeout; assumed
    repeats: int = 3  #: the same refusal this many times is ignored, not a probe; assumed
    resets: int = 3  #: fault resets within ``reset_window`` that make a loop; assumed
    reset_window: float = 60.0  #: seconds; assumed
    enable_hold: float = 5.0  #: seconds 200EH may stay 1 after the last function-code write; assumed

    def demand_error_at(self) -> float:
        """The line demand (percent) from which ``line-demand`` is an error: ``demand_error``, by more than the
        frames' times' jitter over a window (a line kept exactly full reads 100 % give or take that)."""
        return self.demand_error + 100.0 * _DEMAND_JITTER / self.window


@dataclass(frozen=True, slots=True)
class LineDemand:
    """How much of the real line the traffic needs: now (the last window), at its peak, over the whole stream."""

    baud: int
    bits: int
    now: float  #: percent, over the last window
    peak: float  #: percent, the highest window
    mean: float  #: percent, over the whole stream
    transactions: int  #: requests seen
    busy: float  #: seconds of line the whole stream needs

    def as_dict(self) -> dict[str, object]:
        return {
            "baud": self.baud,
            "format": _format(self.bits),
            "now_percent": round(self.now, 1),
            "peak_percent": round(self.peak, 1),
            "mean_percent": round(self.mean, 1),
            "transactions": self.transactions,
            "busy_s": round(self.busy, 6),
        }


def _format(bits: int) -> str:
    return {10: "8N1", 11: "8E1"}.get(bits, f"{bits}-bit")

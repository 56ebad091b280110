"""What ``collision`` and ``early-retry`` share: did a request leave before the last one's reply could finish?"""

from __future__ import annotations

from ...wire.protocol import BROADCAST
from ..findings import FrameRef, Severity
from ..limits import _format
from ..window import Window
from .base import Rule

__all__ = ["EarlyRule"]


class EarlyRule(Rule):
    """A request to a drive sent before the reply to the last one came out (or, with no reply, before one could
    have finished on the line): a ``retry`` (the same bytes again) or not, as the subclass says."""

    retry: bool = False

    def gap(self, audit: Window, seq: int, t: float, data: bytes) -> None:
        last = audit.pending
        if last is None or last.slave == BROADCAST or (data == audit.pending_data) is not self.retry:
            return
        gap = t - audit.pending_t
        need = audit.need
        what = "a retry" if self.retry else "a request"
        self.report(
            audit,
            Severity.ERROR,
            last.slave,
            "",
            (audit.pending_ref(), FrameRef(seq, t)),
            f"{what} {gap * 1000:.1f} ms after the last, before its reply could have finished "
            f"({need * 1000:.1f} ms on {audit.baud} {_format(audit.bits)})",
            gap,
            "wait for the reply, or for a timeout longer than the transaction's line time, before the next request",
            bump=True,
        )

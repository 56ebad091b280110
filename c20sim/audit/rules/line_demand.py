"""``line-demand``: polls faster than the RS485 line can carry."""

from __future__ import annotations

from ..findings import FrameRef, Severity
from ..limits import _format
from ..window import Window
from .base import Rule

__all__ = ["LineDemandRule"]


class LineDemandRule(Rule):
    """The line-demand window's peak against the line: a warning from ``demand_warning``, an error beyond a full
    line (:meth:`~c20sim.audit.limits.Limits.demand_error_at`)."""

    id = "line-demand"
    title = "polls faster than the RS485 line can carry"
    source = "Modbus over Serial Line V1.02 2.5.1"

    def __init__(self) -> None:
        # the finding as last reported: its peak and severity (it is reported again when the peak has grown by
        # more than half a point since, or its severity rises)
        self._reported_peak = -1.0
        self._reported_severity = Severity.NOTE

    def demand(self, audit: Window, seq: int, t: float, percent: float) -> None:
        limits = audit.limits
        if percent < limits.demand_warning or self.id in audit.ignore:
            return
        severity = Severity.ERROR if percent >= limits.demand_error_at() else Severity.WARNING
        if percent <= self._reported_peak + 0.5 and severity <= self._reported_severity:
            return  # a peak a little higher, judged the same: not worth a new finding event
        self._reported_peak, self._reported_severity = percent, severity
        self.report(
            audit,
            severity,
            None,
            "",
            (audit.window_first(), FrameRef(seq, t)),
            f"line demand {percent:.0f} % of {audit.baud} {_format(audit.bits)}: {audit.window_count()} "
            f"transactions in {audit.window_stretch():.3f} s need {audit.window_sum:.3f} s of line",
            percent,
            "poll less often or fewer registers, split the drives over more lines, or raise the baud rate "
            "(F08.01); the replies of a real line would queue and time out",
        )

"""``reset-loop``: fault reset (2000H = 7) in a loop."""

from __future__ import annotations

from ...wire.registers import Command, Reg
from ..findings import FrameRef, Severity
from ..window import Window
from .base import Rule

__all__ = ["ResetLoopRule"]


class ResetLoopRule(Rule):
    """``resets`` fault resets to one drive within ``reset_window`` seconds."""

    id = "reset-loop"
    title = "fault reset (2000H = 7) in a loop"
    source = "sheet 2000H; docs/faults.md"

    def judges(self, register: int, value: int) -> bool:
        return register == Reg.COMMAND and value == Command.RESET

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        ref = FrameRef(seq, t)
        resets = audit.drive(slave).resets
        resets.append(ref)
        limits = audit.limits
        while resets and resets[0].t < ref.t - limits.reset_window:
            resets.popleft()
        if len(resets) >= limits.resets:
            span = ref.t - resets[0].t
            self.report(
                audit,
                Severity.WARNING,
                slave,
                "2000H",
                (resets[0], ref),
                f"fault reset 2000H = 7 sent {len(resets)} times in {span:.1f} s",
                float(len(resets)),
                "read the fault code (2102H) and remove its cause before one reset; a reset loop hides the fault",
            )

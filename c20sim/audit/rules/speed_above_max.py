"""``speed-above-max``: a speed reference above the maximum speed (F00.03)."""

from __future__ import annotations

from ...wire.protocol import ExceptionCode
from ...wire.registers import Reg
from ..findings import FrameRef, Severity
from ..state import _Request
from ..window import Window
from .base import Rule

__all__ = ["SpeedAboveMaxRule"]


class SpeedAboveMaxRule(Rule):
    """2001H written above F00.03 (as the profile gives it, a state file told, or the master wrote it). The
    drive's 0x03 to such a write is this rule's too, so that no refusal rule counts it again."""

    id = "speed-above-max"
    title = "speed reference above the maximum speed"
    source = "sheet 2001H; profile F00.03"

    def judges(self, register: int, value: int) -> bool:
        return register == Reg.SPEED_SETPOINT

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        drive = audit.drive(slave)
        if value > drive.max_speed:
            self.report(
                audit,
                Severity.WARNING,
                slave,
                "2001H",
                (FrameRef(seq, t),),
                f"speed reference 2001H = {value} rpm above the maximum speed F00.03 = {drive.max_speed} rpm",
                float(value),
                f"keep 2001H within F00.03 ({drive.max_speed} rpm): the drive limits it or refuses it (0x03)",
                bump=True,
            )

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return code == ExceptionCode.ILLEGAL_VALUE and request.register == Reg.SPEED_SETPOINT

    def refused(self, audit: Window, request: _Request, code: int, ref: FrameRef) -> None:
        """Nothing more: the write was judged when it was sent."""

"""What a master saw of a drive's fault: the reads of 2102H (fault code) and 2100H (status word 1) it got back.

Two rules judge a master's conduct after a trip it saw (``auto-reset-race``, ``fault-record-unread``); each
keeps its own :class:`_Seen` per drive (at most 256 addresses: bounded by the address byte).
"""

from __future__ import annotations

from dataclasses import dataclass

from ...wire.registers import Reg
from ..findings import FrameRef
from ..window import Window
from .base import Rule

__all__ = ["FaultSeen", "_Seen"]

#: 2100H's value for a drive in fault (the sheet's status word 1).
STATUS_FAULT = 4


@dataclass(slots=True)
class _Seen:
    """A fault a master saw: its code (0 when only 2100H = 4 showed it) and the reply that first showed it."""

    code: int
    ref: FrameRef


def _cell(register: int, values: tuple[int, ...], wanted: int) -> int | None:
    """The value of ``wanted`` among a read of ``values`` from ``register`` on, or None if the read missed it."""
    i = wanted - register
    return values[i] if 0 <= i < len(values) else None


class FaultSeen(Rule):
    """A rule that follows, per drive, the fault the master last saw: from the first reply that showed it (2102H
    not 0, or 2100H = 4) until a reply shows the drive out of it (2102H = 0, or 2100H another state)."""

    def __init__(self) -> None:
        self.seen: dict[int, _Seen] = {}

    def read(self, audit: Window, slave: int, register: int, values: tuple[int, ...], ref: FrameRef) -> None:
        code = _cell(register, values, Reg.FAULT_CODE)
        status = _cell(register, values, Reg.STATUS1)
        faulted = (code is not None and code != 0) or status == STATUS_FAULT
        cleared = (code == 0) or (status is not None and status != STATUS_FAULT)
        before = self.seen.get(slave)
        if faulted:
            if before is None:
                self.seen[slave] = _Seen(code or 0, ref)
                self.fault_seen(audit, slave, self.seen[slave])
            elif code and not before.code:
                before.code = code
        elif cleared and before is not None:
            del self.seen[slave]
        self.looked(audit, slave, register, values, ref)

    def fault_seen(self, audit: Window, slave: int, seen: _Seen) -> None:
        """The master saw a fault of ``slave`` for the first time since it last saw the drive out of one."""

    def looked(self, audit: Window, slave: int, register: int, values: tuple[int, ...], ref: FrameRef) -> None:
        """Every read the drive answered, after the fault followed (for what else a rule reads)."""

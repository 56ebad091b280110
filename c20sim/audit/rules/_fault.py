"""What a master saw of a drive's fault: the reads of 2102H (fault code) and 2100H (status word 1) it got back.

Two rules judge a master's conduct after a trip it saw (``auto-reset-race``, ``fault-record-unread``); each
keeps its own :class:`_Seen` per drive (at most 256 addresses: bounded by the address byte).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ...wire.registers import Reg
from ..findings import FrameRef
from ..window import Window
from .base import Rule

__all__ = ["FaultSeen", "_Seen"]

#: 2100H's value for a drive in fault (the sheet's status word 1).
STATUS_FAULT = 4
#: The registers that show a fault: status word 1 and the fault code.
_STATE = frozenset((Reg.STATUS1, Reg.FAULT_CODE))


@dataclass(slots=True)
class _Seen:
    """A fault a master saw: its code (0 when only 2100H = 4 showed it) and the reply that first showed it."""

    code: int
    ref: FrameRef


def _covers(register: int, count: int, cells: tuple[int, ...]) -> bool:
    """Whether a read of ``count`` registers from ``register`` takes one of ``cells``."""
    return any(register <= cell < register + count for cell in cells)


def _cell(register: int, values: tuple[int, ...], wanted: int) -> int | None:
    """The value of ``wanted`` among a read of ``values`` from ``register`` on, or None if the read missed it."""
    i = wanted - register
    return values[i] if 0 <= i < len(values) else None


class FaultSeen(Rule):
    """A rule that follows, per drive, the fault the master last saw: from the first reply that showed it (2102H
    not 0, or 2100H = 4) until a reply shows the drive out of it (2102H = 0, or 2100H another state)."""

    #: the registers it reads the drive's facts from, beside 2100H and 2102H
    watched: ClassVar[tuple[int, ...]] = ()

    def __init__(self) -> None:
        self.seen: dict[int, _Seen] = {}

    def watches(self, register: int, count: int) -> bool:
        return _covers(register, count, (Reg.STATUS1, Reg.FAULT_CODE, *self.watched))

    def read(self, audit: Window, slave: int, register: int, values: tuple[int, ...], seq: int, t: float) -> None:
        if len(values) == 1 and register in _STATE:  # the usual poll of 2100H or 2102H alone
            value = values[0]
            code = value if register == Reg.FAULT_CODE else None
            faulted = value != 0 if code is not None else value == STATUS_FAULT
            if not faulted and slave not in self.seen:
                return
        else:
            code = _cell(register, values, Reg.FAULT_CODE)
            status = _cell(register, values, Reg.STATUS1)
            faulted = bool(code) or status == STATUS_FAULT
            if code is None and status is None:  # neither: one of the rule's own cells
                self.looked(audit, slave, register, values, FrameRef(seq, t))
                return
        before = self.seen.get(slave)
        if faulted:
            if before is None:
                self.seen[slave] = _Seen(code or 0, FrameRef(seq, t))
                self.fault_seen(audit, slave, self.seen[slave])
            elif code and not before.code:
                before.code = code
        elif before is not None:
            del self.seen[slave]
        if len(values) > 1:
            self.looked(audit, slave, register, values, FrameRef(seq, t))

    def fault_seen(self, audit: Window, slave: int, seen: _Seen) -> None:
        """The master saw a fault of ``slave`` for the first time since it last saw the drive out of one."""

    def looked(self, audit: Window, slave: int, register: int, values: tuple[int, ...], ref: FrameRef) -> None:
        """Every read the drive answered, after the fault followed (for what else a rule reads)."""

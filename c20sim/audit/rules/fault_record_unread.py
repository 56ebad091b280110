"""``fault-record-unread``: a fault the master saw reset without a read of the fault record (F07.27-F07.40)."""

from __future__ import annotations

from ...drive.faultrecord import CURRENT_CONTEXT, FAULT_TYPES, has_record
from ...wire.registers import Command, Reg, address_label
from ..findings import FrameRef, Severity
from ..window import Window
from ._fault import FaultSeen, _Seen

__all__ = ["RECORD_CURRENT", "FaultRecordUnreadRule"]

#: The current fault (F07.27) and the drive's state at it (F07.33-F07.40): what an alarm screen reads.
RECORD_CURRENT = (FAULT_TYPES[0], *CURRENT_CONTEXT)
_FIRST, _LAST = min(RECORD_CURRENT), max(RECORD_CURRENT)
_SPAN = f"{address_label(_FIRST)}-{address_label(_LAST)}, {_FIRST:04X}H-{_LAST:04X}H"


class FaultRecordUnreadRule(FaultSeen):
    """A master saw a fault (2102H not 0, or 2100H = 4) and reset it (2000H = 7) without a read of the current
    fault or the state at it (F07.27, F07.33-F07.40) in between. Judged only for a profile with the record."""

    id = "fault-record-unread"
    title = "resets a fault it saw without reading the fault record"
    source = (
        "INVT GD20 P07.27-P07.40 (the fault record: the family's, its C20 addresses F07.27-F07.40 assumed); "
        "sheet 2000H, 2102H; docs/faults.md"
    )

    watched = RECORD_CURRENT

    def __init__(self) -> None:
        super().__init__()
        self.record_read: set[int] = set()  #: the drives whose record the master read since it saw the fault

    def fault_seen(self, audit: Window, slave: int, seen: _Seen) -> None:
        self.record_read.discard(slave)

    def looked(self, audit: Window, slave: int, register: int, values: tuple[int, ...], ref: FrameRef) -> None:
        if slave in self.seen and any(register <= cell < register + len(values) for cell in RECORD_CURRENT):
            self.record_read.add(slave)

    def judges(self, register: int, value: int) -> bool:
        return register == Reg.COMMAND and value == Command.RESET

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        seen = self.seen.get(slave)
        if seen is None or slave in self.record_read or not has_record(audit.profile.defaults):
            return
        fault = f"fault 0x{seen.code:02X}" if seen.code else "a fault (2100H = 4)"
        self.report(
            audit,
            Severity.WARNING,
            slave,
            "F07.27",
            (seen.ref, FrameRef(seq, t)),
            f"{fault} seen, reset 2000H = 7 sent {t - seen.ref.t:.2f} s later without a read of the fault record "
            f"({_SPAN})",
            t - seen.ref.t,
            f"when a fault shows, read the record ({_SPAN}: the fault, and the frequency, current, bus voltage, "
            "temperature and terminals at the trip) before resetting it: an alarm screen shows it and finding the "
            "cause needs it; the next trips shift it out",
            bump=True,
        )

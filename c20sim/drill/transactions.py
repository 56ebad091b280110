"""A drill's frames as transactions: each request with the reply that followed it, settled (good, refused or
failed), and the line's time for one; what the checks (:mod:`c20sim.drill.checks`) and the judge read."""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass

from ..audit.findings import FrameRef
from ..wire.protocol import crc_ok, transaction_time


@dataclass(slots=True)
class _Txn:
    seq: int
    t: float
    request: bytes
    reply: bytes | None = None
    reply_t: float = 0.0
    reply_seq: int = 0
    status: str = "failed"  #: good, refused (an exception other than 0x06), failed (none, broken, 0x06)
    code: int = -1

    @property
    def ref(self) -> FrameRef:
        return FrameRef(self.seq, self.t)

    def settle(self) -> None:
        data = self.reply
        if not data:
            self.status = "failed"
            return
        request = self.request
        if len(data) > len(request) and data.startswith(request):
            data = data[len(request) :]  # the master's own echo, then the reply
        if (
            len(data) < 5
            or not crc_ok(data)
            or len(request) < 2
            or data[0] != request[0]
            or data[1] & 0x7F != request[1]
        ):
            self.status = "failed"
        elif data[1] & 0x80:
            self.code = data[2]
            self.status = "failed" if data[2] == 0x06 else "refused"
        else:
            self.status = "good"

    def written(self) -> tuple[int, int] | None:
        """(register, value) of a single or first multiple write, else None."""
        r = self.request
        if len(r) == 8 and r[1] == 0x06:
            reg, value = struct.unpack_from(">HH", r, 2)
            return reg, value
        if len(r) >= 11 and r[1] == 0x10:
            return struct.unpack_from(">H", r, 2)[0], struct.unpack_from(">H", r, 7)[0]
        return None

    def reads(self, register: int) -> bool:
        r = self.request
        if len(r) != 8 or r[1] not in (0x03, 0x04):
            return False
        start, count = struct.unpack_from(">HH", r, 2)
        return bool(start <= register < start + count)


def _transactions(frames: Iterable[tuple[float, str, bytes]]) -> list[_Txn]:
    txns: list[_Txn] = []
    for seq, (t, direction, data) in enumerate(frames, 1):
        if direction == "rx":
            txns.append(_Txn(seq, t, data))
        elif txns and txns[-1].reply is None:
            last = txns[-1]
            last.reply, last.reply_t, last.reply_seq = data, t, seq
    for txn in txns:
        txn.settle()
    return txns


class _Line:
    def __init__(self, baud: int, bits: int, turnaround: float) -> None:
        self.baud, self.bits, self.turnaround = baud, bits, turnaround

    def time(self, request: bytes) -> float:
        """The transaction's time on the line: the request, the turnaround and its usual reply."""
        reply = 8
        if len(request) == 8 and request[1] in (0x03, 0x04):
            reply = 5 + 2 * struct.unpack_from(">H", request, 4)[0]
        return transaction_time(len(request), reply, self.baud, self.bits, self.turnaround)

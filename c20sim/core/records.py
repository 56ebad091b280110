"""A frame-log record: one frame in or out, its direction and kind (moved out of bus.py, which re-exports them)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from ..wire.decode import describe
from ..wire.protocol import FrameKind, MbapHeader, Request, Response, crc_ok
from ..wire.registers import RegisterMap
from ..wire.values import quick_init

__all__ = ["Direction", "FrameRecord", "RecordKind"]


class Direction(enum.StrEnum):
    """Which way a frame went on the line (equal to its JSON string)."""

    RX = "rx"  #: master to drive
    TX = "tx"  #: drive to master


class RecordKind(enum.StrEnum):
    """What a frame-log record is (equal to its JSON string)."""

    REQUEST = "request"  #: a good frame from the master
    REPLY = "reply"  #: the drive's normal answer
    EXCEPTION = "exception"  #: the drive's exception answer
    DROPPED = "dropped"  #: a reply a link fault kept off the wire
    CRC_ERROR = FrameKind.CRC_ERROR.value  #: a frame of the right length with a bad CRC
    LENGTH_ERROR = FrameKind.LENGTH_ERROR.value  #: a known function with the wrong number of bytes
    NOISE = FrameKind.NOISE.value  #: bytes that are no frame

    @property
    def error(self) -> bool:
        """A framing error, a drop or an exception: what an "errors only" view shows."""
        return self not in (RecordKind.REQUEST, RecordKind.REPLY)


@quick_init
@dataclass(frozen=True, slots=True)
class FrameRecord:
    """One frame on the line, for the frame log.

    ``words`` is the frame in words, or the decoded message to put in words
    when someone reads :attr:`text`: the log costs next to nothing until it is
    read, which keeps a request cheap.
    """

    t: float  #: the line's time: arrival of the frame's last byte (or when the line took a request that waited), or when the reply is due
    direction: Direction
    data: bytes
    kind: RecordKind
    slave: int | None
    words: str | Request | Response
    note: str = ""  #: framing error detail, or an injected link fault
    model_t: float | None = None  #: the drives' time when the frame was served
    registers: RegisterMap | None = field(default=None, compare=False, repr=False)
    request: Request | None = field(default=None, compare=False, repr=False)
    #: the wall-clock time (Unix seconds) of ``t``, where an I/O layer knows it (a record read back from JSON)
    wall: float | None = field(default=None, compare=False)
    #: a Modbus TCP exchange: the request's MBAP header; ``data`` is then the RTU frame on the line behind the
    #: gateway, and :attr:`wire` the Modbus TCP frame on the TCP connection
    mbap: MbapHeader | None = field(default=None, compare=False)
    #: the gateway's own answer (exception 0x0B after silence on the line): on the TCP connection, not on the line
    from_gateway: bool = field(default=False, compare=False)

    @property
    def text(self) -> str:
        """The frame in words."""
        if isinstance(self.words, str):
            return self.words
        return describe(self.words, self.registers, self.request)

    @property
    def wire(self) -> bytes:
        """The bytes the master's connection carried: ``data`` on an RTU line; for Modbus TCP the MBAP frame (empty
        where the gateway forwarded nothing: a broken or dropped reply on the line)."""
        if self.mbap is None:
            return self.data
        forwarded = (
            self.direction is Direction.RX
            or self.from_gateway
            or (
                self.kind in (RecordKind.REPLY, RecordKind.EXCEPTION)
                and len(self.data) >= 4
                and crc_ok(self.data)
                and self.data[0] == self.mbap.unit
            )
        )
        return self.mbap.adu(self.data[1:-2]) if forwarded and len(self.data) >= 3 else b""

    def as_dict(self, wall_offset: float | None = None) -> dict[str, object]:
        """JSON-ready; ``wall_offset`` (Unix time minus the line's clock, from the I/O layer that stamped ``t``)
        adds ``wall``: when the frame was on the line, by the wall clock."""
        wall = self.wall if self.wall is not None else None if wall_offset is None else self.t + wall_offset
        return {
            "t": round(self.t, 6),
            **({} if wall is None else {"wall": round(wall, 3)}),
            "model_t": None if self.model_t is None else round(self.model_t, 6),
            "dir": str(self.direction),
            "hex": self.wire.hex(" ").upper(),
            **(
                {}
                if self.mbap is None
                else {
                    "modbus_tcp": {"transaction": self.mbap.transaction, "unit": self.mbap.unit},
                    "rtu": None if self.from_gateway else self.data.hex(" ").upper(),
                }
            ),
            "kind": str(self.kind),
            "slave": self.slave,
            "text": self.text,
            "note": self.note,
        }

"""Modbus RTU as the ZBLD.C20 speaks it: CRC, frames, and framing by silence.

Sans-I/O (after h11): :class:`RtuFramer` is fed bytes with their arrival time
and hands back :class:`FrameEvent` values; it never reads a port or a clock.
A frame ends after 3.5 character times of silence; a gap of more than 1.5
characters inside a frame makes it invalid (sheet, section 1). A character is
as long as the line's format makes it: 10 bits for the sheet's 8N1. Transports
without line timing (TCP) also complete a frame as soon as the expected length
of a known function code is reached, and garbage, truncated frames and frames
sent back to back are split apart so that none of them costs the next valid
frame. A strict framer (``--line-timing``) does what the drive does instead:
whatever lies between two silences of t3.5 is one frame, good or bad.
"""

from __future__ import annotations

import enum
import functools
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

from .values import quick_init

__all__ = [
    "BROADCAST",
    "MAX_ADU",
    "MAX_WRITE_REGISTERS",
    "SHEET_CHAR_BITS",
    "Direction",
    "ExceptionCode",
    "ExceptionResponse",
    "FrameEvent",
    "FrameKind",
    "FunctionCode",
    "MbapHeader",
    "ReadRequest",
    "ReadResponse",
    "Request",
    "Response",
    "UnsupportedRequest",
    "WriteMultipleRequest",
    "WriteMultipleResponse",
    "WriteSingleRequest",
    "WriteSingleResponse",
    "char_bits",
    "char_time",
    "crc16",
    "crc16_table",
    "crc_ok",
    "decode_request",
    "decode_response",
    "encode",
    "expected_length",
    "frame_time",
    "mbap_adus",
    "silence_times",
    "transaction_time",
    "with_crc",
]

#: Longest RTU frame (Modbus serial line spec): address + 253-byte PDU + CRC.
MAX_ADU = 256
#: Most registers one 0x10 request can carry (Modbus application spec).
MAX_WRITE_REGISTERS = 123
#: Address 0: a write to every drive, never answered (sheet 1.a).
BROADCAST = 0
#: Times closer than this count as equal (float sums of timestamps).
_EPSILON = 1e-9


class FunctionCode(enum.IntEnum):
    """The function codes of the sheet, section 1.b."""

    READ_REGISTERS = 0x03  #: read register operation
    WRITE_SINGLE = 0x06  #: write single register operation
    WRITE_MULTIPLE = 0x10  #: write multiple register operations


class ExceptionCode(enum.IntEnum):
    """Exception codes of the sheet, section 1.4 ("exception code")."""

    ILLEGAL_FUNCTION = 0x01  #: Illegal order: the slave does not support this command
    ILLEGAL_ADDRESS = 0x02  #: Illegal data address: the requested address is out of range
    ILLEGAL_VALUE = 0x03  #: Illegal data value: the data contains values that are not allowed
    OPERATION_FAILED = 0x04  #: operation failed, e.g. function code written while 200EH = 0
    PASSWORD_ERROR = 0x05  #: the password written at the validation address is wrong
    FRAME_ERROR = 0x06  #: data frame error: wrong frame length or bad RTU CRC
    READ_ONLY = 0x07  #: parameter is read-only
    NOT_WHILE_RUNNING = 0x08  #: parameter cannot be changed during operation

    @property
    def meaning(self) -> str:
        return _EXCEPTION_MEANINGS[self]


_EXCEPTION_MEANINGS = {
    ExceptionCode.ILLEGAL_FUNCTION: "illegal function",
    ExceptionCode.ILLEGAL_ADDRESS: "illegal data address",
    ExceptionCode.ILLEGAL_VALUE: "illegal data value",
    ExceptionCode.OPERATION_FAILED: "operation failed",
    ExceptionCode.PASSWORD_ERROR: "password error",
    ExceptionCode.FRAME_ERROR: "data frame error",
    ExceptionCode.READ_ONLY: "parameter is read-only",
    ExceptionCode.NOT_WHILE_RUNNING: "parameter cannot be changed while running",
}


# --- CRC-16/MODBUS: poly 0xA001 (reflected 0x8005), init 0xFFFF, low byte first.


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16_table(data: bytes | bytearray) -> int:
    """CRC-16/MODBUS of ``data`` (sheet 1.d), table-driven in Python: the reference, and :func:`crc16` where
    the compiled one is not installed."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for byte in data:
        crc = (crc >> 8) ^ table[(crc ^ byte) & 0xFF]
    return crc


#: CRC-16/MODBUS of ``data`` (sheet 1.d). Two a request (the request's check, the reply's CRC): compiled
#: where the optional extra is installed (``pip install c20sim[fast]``: fastcrc, wheels for the common
#: platforms): 0.05 us against 0.35 us for 6 bytes, 0.12 us against 11 us for a 125-register reply; else
#: the table.
crc16: Callable[[bytes], int]
try:
    from fastcrc.crc16 import modbus as crc16
except ImportError:  # the extra is not installed
    crc16 = crc16_table


def with_crc(body: bytes) -> bytes:
    """``body`` followed by its CRC, low byte first."""
    return body + crc16(body).to_bytes(2, "little")


def crc_ok(frame: bytes) -> bool:
    """True if the last two bytes of ``frame`` are the CRC of the rest."""
    return len(frame) >= 4 and crc16(frame[:-2]) == int.from_bytes(frame[-2:], "little")


# --- Frame values.


@quick_init
@dataclass(frozen=True, slots=True)
class ReadRequest:
    """0x03: read ``count`` registers from ``start``."""

    slave: int
    start: int
    count: int
    function: int = FunctionCode.READ_REGISTERS


@quick_init
@dataclass(frozen=True, slots=True)
class WriteSingleRequest:
    """0x06: write ``value`` to ``register``."""

    slave: int
    register: int
    value: int
    function: int = FunctionCode.WRITE_SINGLE


@dataclass(frozen=True, slots=True)
class WriteMultipleRequest:
    """0x10: write ``values`` from ``start``.

    ``count`` and ``byte_count`` are kept as sent, so that the slave can refuse
    a frame whose counts disagree with its data (exception 0x03).
    """

    slave: int
    start: int
    values: tuple[int, ...]
    count: int = -1
    byte_count: int = -1
    function: int = FunctionCode.WRITE_MULTIPLE

    def __post_init__(self) -> None:
        if self.count < 0:
            object.__setattr__(self, "count", len(self.values))
        if self.byte_count < 0:
            object.__setattr__(self, "byte_count", 2 * len(self.values))


@quick_init
@dataclass(frozen=True, slots=True)
class UnsupportedRequest:
    """A well-formed frame with a function code the C20 does not implement."""

    slave: int
    function: int
    data: bytes


Request = ReadRequest | WriteSingleRequest | WriteMultipleRequest | UnsupportedRequest


@quick_init
@dataclass(frozen=True, slots=True)
class ReadResponse:
    slave: int
    values: tuple[int, ...]
    function: int = FunctionCode.READ_REGISTERS


@quick_init
@dataclass(frozen=True, slots=True)
class WriteSingleResponse:
    slave: int
    register: int
    value: int
    function: int = FunctionCode.WRITE_SINGLE


@quick_init
@dataclass(frozen=True, slots=True)
class WriteMultipleResponse:
    slave: int
    start: int
    count: int
    function: int = FunctionCode.WRITE_MULTIPLE


@quick_init
@dataclass(frozen=True, slots=True)
class ExceptionResponse:
    """An exception reply: the request's function code with its MSB set."""

    slave: int
    request_function: int
    code: ExceptionCode

    @property
    def function(self) -> int:
        return (self.request_function | 0x80) & 0xFF


Response = ReadResponse | WriteSingleResponse | WriteMultipleResponse | ExceptionResponse


def encode(message: Request | Response) -> bytes:
    """The RTU frame of a request or response, CRC included."""
    encoder = _ENCODERS.get(message.__class__)
    if encoder is None:  # pragma: no cover - exhaustive over the unions
        raise TypeError(f"cannot encode {message!r}")
    return with_crc(encoder(message))


_SIX = struct.Struct(">BBHH").pack


def _read_response(m: ReadResponse) -> bytes:
    values = m.values
    return struct.pack(f">BBB{len(values)}H", m.slave, FunctionCode.READ_REGISTERS, 2 * len(values), *values)


def _write_multiple_request(m: WriteMultipleRequest) -> bytes:
    head = struct.pack(">BBHHB", m.slave, FunctionCode.WRITE_MULTIPLE, m.start, m.count, m.byte_count)
    return head + struct.pack(f">{len(m.values)}H", *m.values)


#: The body (without CRC) of each message, by its class: a dict, not a match, since every reply is encoded.
_ENCODERS: dict[type, Callable[[Any], bytes]] = {
    ReadRequest: lambda m: _SIX(m.slave, FunctionCode.READ_REGISTERS, m.start, m.count),
    WriteSingleRequest: lambda m: _SIX(m.slave, FunctionCode.WRITE_SINGLE, m.register, m.value),
    WriteMultipleRequest: _write_multiple_request,
    UnsupportedRequest: lambda m: bytes((m.slave, m.function)) + m.data,
    ReadResponse: _read_response,
    WriteSingleResponse: lambda m: _SIX(m.slave, FunctionCode.WRITE_SINGLE, m.register, m.value),
    WriteMultipleResponse: lambda m: _SIX(m.slave, FunctionCode.WRITE_MULTIPLE, m.start, m.count),
    ExceptionResponse: lambda m: bytes((m.slave, m.function, m.code)),
}


Direction = Literal["request", "response"]


def expected_length(frame: bytes, direction: Direction) -> int | None:
    """Length the frame starting with these bytes must have, or None if unknown.

    None means either that the function code is not one the C20 knows, or that
    the byte giving the length (the byte count of a 0x10 request or 0x03 reply) has not arrived yet.
    """
    if len(frame) < 2:
        return None
    function = frame[1]
    if direction == "request":
        if function in (FunctionCode.READ_REGISTERS, FunctionCode.WRITE_SINGLE):
            return 8
        if function == FunctionCode.WRITE_MULTIPLE:
            return 9 + frame[6] if len(frame) >= 7 else None
        return None
    if function & 0x80:
        return 5
    if function == FunctionCode.READ_REGISTERS:
        return 5 + frame[2] if len(frame) >= 3 else None
    if function in (FunctionCode.WRITE_SINGLE, FunctionCode.WRITE_MULTIPLE):
        return 8
    return None


def _known_function(frame: bytes, direction: Direction) -> bool:
    function = frame[1]
    if direction == "response" and function & 0x80:
        return True
    return function in (FunctionCode.READ_REGISTERS, FunctionCode.WRITE_SINGLE, FunctionCode.WRITE_MULTIPLE)


def decode_request(frame: bytes, *, check_crc: bool = True) -> Request:
    """Decode a request frame; ``check_crc=False`` for a framer's FRAME event, checked already.

    Raises ValueError for a frame that is not a well-formed request.
    """
    if check_crc and not crc_ok(frame):
        raise ValueError("bad CRC")
    length = expected_length(frame, "request")
    if length is None:
        if _known_function(frame, "request"):
            raise ValueError("truncated frame")
        return UnsupportedRequest(frame[0], frame[1], bytes(frame[2:-2]))
    if len(frame) != length:
        raise ValueError(f"frame of {len(frame)} bytes, a function 0x{frame[1]:02X} request has {length}")
    slave, function = frame[0], frame[1]
    if function == FunctionCode.READ_REGISTERS:
        start, count = struct.unpack_from(">HH", frame, 2)
        return ReadRequest(slave, start, count)
    if function == FunctionCode.WRITE_SINGLE:
        register, value = struct.unpack_from(">HH", frame, 2)
        return WriteSingleRequest(slave, register, value)
    start, count, byte_count = struct.unpack_from(">HHB", frame, 2)
    data = frame[7:-2]
    values = struct.unpack(f">{len(data) // 2}H", data[: len(data) // 2 * 2])
    return WriteMultipleRequest(slave, start, values, count, byte_count)


def decode_response(frame: bytes) -> Response:
    """Decode a response frame whose CRC and length have been checked.

    Raises ValueError for a frame that is not a well-formed response.
    """
    if not crc_ok(frame):
        raise ValueError("bad CRC")
    length = expected_length(frame, "response")
    if length is None:
        raise ValueError(f"function 0x{frame[1]:02X} is not one the C20 answers")
    if len(frame) != length:
        raise ValueError(f"frame of {len(frame)} bytes, a function 0x{frame[1]:02X} response has {length}")
    slave, function = frame[0], frame[1]
    if function & 0x80:
        try:
            code = ExceptionCode(frame[2])
        except ValueError:
            raise ValueError(f"exception code 0x{frame[2]:02X} is not one the C20 sends") from None
        return ExceptionResponse(slave, function & 0x7F, code)
    if function == FunctionCode.READ_REGISTERS:
        byte_count = frame[2]
        if byte_count % 2:
            raise ValueError(f"odd byte count {byte_count}")
        return ReadResponse(slave, struct.unpack_from(f">{byte_count // 2}H", frame, 3))
    first, second = struct.unpack_from(">HH", frame, 2)
    if function == FunctionCode.WRITE_SINGLE:
        return WriteSingleResponse(slave, first, second)
    return WriteMultipleResponse(slave, first, second)


# --- Framing.


def char_bits(data_bits: int = 8, parity: str = "N", stop_bits: int = 1) -> int:
    """Bits one character takes on the line: start, data, parity if any, stop.

    The sheet's line is 8N1 ("start bit: 1bit data bit: 8bit check bit: no check
    stop bit: 1bit"): 10 bits. 8E1, 8O1 and 8N2 take 11.
    """
    return 1 + data_bits + (0 if parity.upper() == "N" else 1) + stop_bits


#: Bits of one character of the sheet's 8N1 line.
SHEET_CHAR_BITS = char_bits()


def char_time(baud: int, bits: int = SHEET_CHAR_BITS) -> float:
    """Seconds one character of ``bits`` bits (see :func:`char_bits`) takes at ``baud``."""
    return bits / baud


def silence_times(baud: int, bits: int = SHEET_CHAR_BITS) -> tuple[float, float]:
    """(t1.5, t3.5) in seconds; fixed at 0.75 ms and 1.75 ms above 19200 baud (Modbus serial line spec)."""
    if baud > 19200:
        return 0.00075, 0.00175
    return 1.5 * char_time(baud, bits), 3.5 * char_time(baud, bits)


def frame_time(length: int, baud: int, bits: int = SHEET_CHAR_BITS) -> float:
    """Seconds a frame of ``length`` bytes holds an RS485 line: its characters and the t3.5 before it."""
    return _frame_time(length, baud, bits)


@functools.lru_cache(maxsize=4096)  # on every request's path (bus timing, the audit): a master sends few lengths
def _frame_time(length: int, baud: int, bits: int) -> float:
    return length * char_time(baud, bits) + silence_times(baud, bits)[1]


def transaction_time(
    request: int, reply: int, baud: int, bits: int = SHEET_CHAR_BITS, turnaround: float = 0.0
) -> float:
    """Seconds one transaction holds an RS485 line at ``baud``: the request (``request`` bytes) and the reply
    (``reply`` bytes, 0 for a broadcast or silence), each with the t3.5 before it, and the drive's
    ``turnaround`` between them. The line's real time, whatever transport carried the frames: the bus timing
    of every transport and the audit's line demand both use it.

    >>> round(transaction_time(8, 7, 19200) * 1000, 3)  # a one-register read at 19200 8N1
    11.458
    """
    time = frame_time(request, baud, bits)
    if reply:
        time += turnaround + frame_time(reply, baud, bits)
    return time


class FrameKind(enum.Enum):
    FRAME = "frame"  #: CRC and length good
    CRC_ERROR = "crc error"  #: the right length for its function code, but a bad CRC
    LENGTH_ERROR = "length error"  #: a known function code, but the wrong number of bytes
    NOISE = "noise"  #: too short to be a frame, or broken by a gap inside it


class MbapHeader(NamedTuple):
    """What a Modbus TCP request's MBAP header says that its RTU form does not: the transaction id (the unit is
    the RTU frame's address)."""

    transaction: int
    unit: int

    def adu(self, pdu: bytes) -> bytes:
        """The Modbus TCP frame of ``pdu`` under this header: transaction, protocol 0, length, unit, PDU."""
        return struct.pack(">HHHB", self.transaction, 0, len(pdu) + 1, self.unit) + pdu


def mbap_adus(data: bytes) -> list[MbapHeader] | None:
    """The MBAP headers of ``data`` if it is nothing but whole Modbus TCP frames (one or more, back to back) and
    not a good RTU frame; else None. A master speaking Modbus TCP to an RTU port sends exactly that."""
    if len(data) < 8 or data[2] or data[3] or crc_ok(data):  # an MBAP header's protocol id (bytes 2-3) is 0
        return None
    found: list[MbapHeader] = []
    at = 0
    while at < len(data):
        if len(data) - at < 8:
            return None
        transaction, protocol, length, unit = struct.unpack_from(">HHHB", data, at)
        if protocol != 0 or not 2 <= length <= 254 or at + 6 + length > len(data):
            return None
        found.append(MbapHeader(transaction, unit))
        at += 6 + length
    return found


@quick_init
@dataclass(frozen=True, slots=True)
class FrameEvent:
    """One outcome of framing, for the bus and the frame log."""

    kind: FrameKind
    data: bytes
    t: float  #: arrival time of the frame's last byte
    note: str = ""
    #: the Modbus TCP header the frame came under (a gateway's request), or None on an RTU line
    mbap: MbapHeader | None = None

    @property
    def is_frame(self) -> bool:
        return self.kind is FrameKind.FRAME

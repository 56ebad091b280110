"""Frames in words, for the frame log and for ``c20sim decode``.

``write 2000H = 0001: forward run``; ``2100H = 0005: off (bus voltage not
established)``; ``exception 0x02 to read: illegal data address``. A broken
frame is named for what is wrong with it: the CRC it should have had, or the
length its function code needs.

:func:`split_frames` cuts a captured byte stream into frames by the protocol:
a request's function code gives its length (a 0x10 request's byte count),
the reply that follows is read as the answer to it (a 0x03 reply's byte
count, 8 bytes for an echo, 5 for an exception), and the CRC decides; bytes
that start no frame are gathered as noise until one does. One case cannot be
told apart: a 0x06 request that got no answer, then the same request again,
reads as a request and its echo.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, cast

from .protocol import (
    ExceptionCode,
    ExceptionResponse,
    FunctionCode,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    crc16,
    crc_ok,
    decode_request,
    decode_response,
    expected_length,
)
from .registers import Reg, RegisterMap, address_label, format_fcode, ram_alias_of, status2_words

__all__ = ["Decoded", "Piece", "decode_frame", "describe", "register_label", "split_frames"]

_FUNCTION_WORDS: dict[int, str] = {
    FunctionCode.READ_REGISTERS: "read",
    FunctionCode.WRITE_SINGLE: "write",
    FunctionCode.WRITE_MULTIPLE: "write multiple",
}


def register_label(address: int, registers: RegisterMap | None) -> str:
    """``2000H`` or ``F00.10``, with the register's name where the map knows it; a function code's RAM-only
    address (bit 15 set: 800AH) reads ``F00.10 (keypad speed setting, RAM only)``."""
    base = ram_alias_of(address)
    if base is not None:
        spec = registers.get(base) if registers else None
        return f"{format_fcode(base)} ({spec.name}, RAM only)" if spec else f"{format_fcode(base)} (RAM only)"
    label = address_label(address)
    spec = registers.get(address) if registers else None
    return f"{label} ({spec.name})" if spec else label


def _value(address: int, raw: int, registers: RegisterMap | None) -> str:
    base = ram_alias_of(address)
    if base is not None:  # the RAM-only address: the function code's meaning, said to be RAM only
        label, address = f"{format_fcode(base)} (RAM only)", base
    else:
        label = address_label(address)
    spec = registers.get(address) if registers else None
    if address == Reg.STATUS2:
        words = f": {status2_words(raw)}"
    else:
        # a hex register reads the same in words as its raw value: say it once
        words = f": {spec.describe(raw)}" if spec and (raw in spec.values or not spec.hex_display) else ""
    return f"{label} = {raw:04X}{words}"


def describe(message: Request | Response, registers: RegisterMap | None = None, request: Request | None = None) -> str:
    """One message in words. A read reply names its registers when given its request."""
    match message:
        case ReadRequest(_, start, 1):
            return f"read {register_label(start, registers)}"
        case ReadRequest(_, start, count):
            return f"read {count} registers from {register_label(start, registers)}"
        case WriteSingleRequest(_, register, value) | WriteSingleResponse(_, register, value):
            return f"write {_value(register, value, registers)}"
        case WriteMultipleRequest(_, start, values):
            parts = "; ".join(_value(start + i, v, registers) for i, v in enumerate(values))
            return f"write {len(values)} registers from {start:04X}H: {parts}"
        case UnsupportedRequest(_, function, _):
            return f"function 0x{function:02X}, which the C20 does not support"
        case ReadResponse(_, values):
            if isinstance(request, ReadRequest):
                return "; ".join(_value(request.start + i, v, registers) for i, v in enumerate(values))
            return "read reply: " + " ".join(f"{v:04X}" for v in values)
        case WriteMultipleResponse(_, start, count):
            return f"wrote {count} registers from {start:04X}H"
        case ExceptionResponse(_, function, code):
            what = _FUNCTION_WORDS.get(function, f"function 0x{function:02X}")
            return f"exception 0x{int(code):02X} to {what}: {code.meaning}"
    raise TypeError(f"cannot describe {message!r}")  # pragma: no cover


@dataclass(frozen=True)
class Decoded:
    """What ``c20sim decode`` says of one frame."""

    ok: bool
    kind: str  #: "request", "response", "request or echo", "exception", "broken"
    text: str
    message: Request | Response | None = None


def decode_frame(data: bytes, registers: RegisterMap | None = None) -> Decoded:
    """Decode a frame of unknown direction, or say what is wrong with it."""
    if len(data) < 4:
        return Decoded(False, "broken", f"{len(data)} byte(s): too short for a frame (address, function, CRC)")
    slave, function = data[0], data[1]
    expected = crc16(data[:-2]).to_bytes(2, "little")
    crc_text = (
        "CRC ok"
        if data[-2:] == expected
        else (f"bad CRC: got {data[-2:].hex(' ').upper()}, expected {expected.hex(' ').upper()}")
    )
    who = "broadcast" if slave == 0 else f"slave {slave}"
    candidates = _candidates(data)
    if not candidates:
        return Decoded(False, "broken", f"{who}: {_length_problem(data)}; {crc_text}")
    kind, message = candidates[0]
    if data[-2:] != expected:
        return Decoded(False, "broken", f"{who}: {describe(message, registers)}; {crc_text}", message)
    if function == FunctionCode.WRITE_SINGLE:
        kind = "request or echo"
    return Decoded(True, kind, f"{who}: {describe(message, registers)}; {crc_text}", message)


def _candidates(data: bytes) -> list[tuple[str, Request | Response]]:
    """Readings of ``data`` whose length fits, CRC aside (checked by the caller)."""
    fixed = data[:-2] + crc16(data[:-2]).to_bytes(2, "little")
    found: list[tuple[str, Request | Response]] = []
    function = data[1]
    if function & 0x80:
        if len(data) == 5 and data[2] in ExceptionCode._value2member_map_:
            found.append(("exception", decode_response(fixed)))
        return found
    if function not in _FUNCTION_WORDS:
        return [("request", decode_request(fixed))]
    for kind, decoder in (("request", decode_request), ("response", decode_response)):
        try:
            found.append((kind, decoder(fixed)))
        except ValueError:
            continue
    return found


def _length_problem(data: bytes) -> str:
    function = data[1]
    n = len(data)
    if function & 0x80:
        if n == 5:
            return f"exception code 0x{data[2]:02X} is not one the C20 sends"
        return f"wrong length: {n} bytes; an exception reply has 5"
    if function == FunctionCode.READ_REGISTERS:
        return f"wrong length: {n} bytes; a 0x03 request has 8, a reply 5 + its byte count ({5 + data[2]} for byte count {data[2]})"
    if function == FunctionCode.WRITE_SINGLE:
        return f"wrong length: {n} bytes; a 0x06 request and its echo have 8"
    count = f" ({9 + data[6]} for this byte count)" if n >= 7 else ""
    return f"wrong length: {n} bytes; a 0x10 request has 9 + its byte count{count}, a reply 8"


# --- A stream of frames.

#: The longest an RTU frame is (Modbus serial line): a function the C20 does not know is cut at a CRC within it.
_MAX_FRAME = 256


@dataclass(frozen=True)
class Piece:
    """One frame of a stream (a request, a reply or an exception), or bytes that are no frame."""

    offset: int  #: where it starts in the stream
    data: bytes
    kind: Literal["request", "reply", "exception", "noise"]
    text: str
    message: Request | Response | None = None
    request: Request | None = None  #: for a reply: the request it answers, when the stream had it


def _at(data: bytes, i: int, direction: Literal["request", "response"]) -> int | None:
    """The length of a frame with a good CRC at ``data[i:]`` read as ``direction``, or None."""
    length = expected_length(data[i : i + 7], direction)
    if length is not None:
        return length if i + length <= len(data) and crc_ok(data[i : i + length]) else None
    if direction == "request" and len(data) - i >= 4 and data[i + 1] not in _FUNCTION_WORDS and not data[i + 1] & 0x80:
        # a function the C20 does not know: its length is unknown, the first good CRC ends it
        for end in range(i + 4, min(len(data), i + _MAX_FRAME) + 1):
            if crc_ok(data[i:end]):
                return end - i
    return None


def _reply_to(message: Response, pending: Request | None) -> bool:
    """Whether ``message`` can be ``pending``'s reply: the same slave and function, and for a write the echo
    of what it wrote (a 0x06 reply that differs from the request is the next request, not its echo)."""
    if pending is None or message.slave != pending.slave or message.function & 0x7F != pending.function:
        return False
    if isinstance(message, WriteSingleResponse) and isinstance(pending, WriteSingleRequest):
        return (message.register, message.value) == (pending.register, pending.value)
    if isinstance(message, WriteMultipleResponse) and isinstance(pending, WriteMultipleRequest):
        return (message.start, message.count) == (pending.start, pending.count)
    return True


def _piece(
    data: bytes,
    i: int,
    direction: Literal["request", "response"],
    pending: Request | None,
    registers: RegisterMap | None,
) -> Piece | None:
    """The frame at ``data[i:]`` read as ``direction`` (a reply: to ``pending``), or None."""
    length = _at(data, i, direction)
    if length is None:
        return None
    frame = data[i : i + length]
    who = "broadcast" if frame[0] == 0 else f"slave {frame[0]}"
    try:
        if direction == "request":
            request = decode_request(frame)
            return Piece(i, frame, "request", f"{who}: {describe(request, registers)}", request)
        response = decode_response(frame)
    except ValueError:
        return None
    answered = pending if _reply_to(response, pending) else None
    kind: Literal["reply", "exception"] = "exception" if frame[1] & 0x80 else "reply"
    return Piece(i, frame, kind, f"{who}: {describe(response, registers, answered)}", response, answered)


def split_frames(data: bytes, registers: RegisterMap | None = None, after: Request | None = None) -> list[Piece]:
    """Cut a captured stream into frames by the protocol (request, then its reply), and noise.

    ``after``: the request sent just before the stream starts (its reply may come first).
    """
    out: list[Piece] = []
    pending: Request | None = after  # the request whose reply may come next
    noise_from: int | None = None
    i = 0
    while i < len(data):
        # after a request, its reply is the likelier reading (a 0x06 request and its echo are the same bytes);
        # a reply that answers nothing before it comes last (a capture that starts mid-exchange)
        reply = _piece(data, i, "response", pending, registers)
        found = reply if reply is not None and reply.request is not None else None
        found = found or _piece(data, i, "request", pending, registers) or reply
        if found is None:
            noise_from = i if noise_from is None else noise_from
            i += 1
            continue
        if noise_from is not None:
            out.append(_noise(data, noise_from, i))
            noise_from = None
        out.append(found)
        i += len(found.data)
        pending = None
        if found.kind == "request" and found.data[0] != 0:  # a broadcast is never answered
            pending = cast(Request, found.message)
    if noise_from is not None:
        out.append(_noise(data, noise_from, len(data)))
    return out


def _noise(data: bytes, start: int, end: int) -> Piece:
    return Piece(start, data[start:end], "noise", f"{end - start} byte(s) that start no frame")

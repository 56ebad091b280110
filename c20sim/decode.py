"""Frames in words, for the frame log and for ``c20sim decode``.

``write 2000H = 0001: forward run``; ``2100H = 0005: off (bus voltage not
established)``; ``exception 0x02 to read: illegal data address``. A broken
frame is named for what is wrong with it: the CRC it should have had, or the
length its function code needs.
"""

from __future__ import annotations

from dataclasses import dataclass

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
    decode_request,
    decode_response,
)
from .registers import Reg, RegisterMap, address_label, status2_words

__all__ = ["Decoded", "decode_frame", "describe", "register_label"]

_FUNCTION_WORDS: dict[int, str] = {
    FunctionCode.READ_REGISTERS: "read",
    FunctionCode.WRITE_SINGLE: "write",
    FunctionCode.WRITE_MULTIPLE: "write multiple",
}


def register_label(address: int, registers: RegisterMap | None) -> str:
    """``2000H`` or ``F00.10``, with the register's name where the map knows it."""
    label = address_label(address)
    spec = registers.get(address) if registers else None
    return f"{label} ({spec.name})" if spec else label


def _value(address: int, raw: int, registers: RegisterMap | None) -> str:
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

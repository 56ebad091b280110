"""The master of ``c20sim exercise``: one request at a time to one drive, every frame logged.

Its errors say what the drive did (silent, refused); :func:`register_of` and :func:`parse_value` read a
register and a value as a person types them.
"""

from __future__ import annotations

import json
import time
from typing import IO, Any, Protocol

from ..wire.amounts import parse_value
from ..wire.decode import describe
from ..wire.errors import C20SimError
from ..wire.protocol import (
    ExceptionCode,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteSingleRequest,
    crc_ok,
    decode_request,
    decode_response,
    encode,
)
from ..wire.registers import (
    RegisterMap,
    RegisterSpec,
    address_label,
    is_fcode,
)
from ..wire.vocabulary import UnknownRegister, resolve_register
from .masterlinks import Link

__all__ = [
    "DriveRefused",
    "DriveSilent",
    "Interrupted",
    "Master",
    "NoReply",
    "is_function_code",
    "parse_value",
    "register_of",
]

#: The exceptions a Modbus TCP gateway adds (Modbus application protocol, 7).
GATEWAY = {0x0A: "gateway path unavailable", 0x0B: "gateway: the drive did not answer"}


class DriveSilent(C20SimError):
    """No reply (or a broken one) within the timeout."""


class Interrupted(C20SimError):
    """Ctrl-C during the programme; the message says how stopping the drive went."""


class NoReply(DriveSilent):
    """Nothing came back at all: no drive at that address, or no drive on that link."""


class DriveRefused(C20SimError):
    """The drive answered an exception."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


def register_of(word: str, registers: RegisterMap, owner: str = "the profile") -> RegisterSpec:
    """A register in the one vocabulary of every tool (:func:`~c20sim.wire.registers.resolve_register`): a short
    name (``speed``), the sheet's name, an address (``3006H``, ``0x3006``, ``12294``) or a function code."""
    try:
        return registers[resolve_register(word, registers, owner)]
    except UnknownRegister as exc:
        raise C20SimError(str(exc)) from None


# --- The master: one request at a time, every frame logged.


class Clock(Protocol):
    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """The monotonic clock, from the capture's start."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self.t0

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class Master:
    """Reads and writes single registers of the drive at ``address``; logs every frame as a JSON line."""

    def __init__(
        self,
        link: Link,
        registers: RegisterMap,
        address: int = 1,
        *,
        clock: Clock | None = None,
        timeout: float = 0.5,
        log: IO[str] | None = None,
    ) -> None:
        self.link = link
        self.registers = registers
        self.address = address
        self.clock: Clock = clock if clock is not None else WallClock()
        self.timeout = timeout
        self.log = log
        self.frames = 0

    def _record(
        self,
        t: float,
        direction: str,
        data: bytes,
        message: Request | Response | None,
        after: Any,
        words: str = "",
        note: str = "",
    ) -> None:
        if self.log is None:
            return
        kind = "request" if direction == "rx" else "exception" if words else "reply"
        text = words or (describe(message, self.registers, after) if message is not None else "broken reply")
        item = {"t": round(t, 6), "dir": direction, "hex": data.hex(" ").upper(), "kind": kind}
        item |= {"slave": self.address, "text": text}
        if note:
            item["note"] = note
        self.log.write(json.dumps(item) + "\n")
        self.frames += 1

    def header(self, port: str, baud: int, fmt: str) -> None:
        """The capture's first line: how it is carried (``c20sim fit`` models each transaction's time on it)."""
        if self.log is not None:
            note = f"link {port} {baud} {fmt}"
            item = {"t": round(self.clock.now(), 6), "dir": "rx", "hex": "", "kind": "link", "slave": self.address}
            self.log.write(json.dumps(item | {"text": f"carried by {port}, {baud} baud {fmt}", "note": note}) + "\n")

    def mark(self, note: str) -> None:
        """A line in the log saying what the user did by hand (no bytes on the wire): replay passes over it."""
        if self.log is not None:
            item = {"t": round(self.clock.now(), 6), "dir": "rx", "hex": "", "kind": "mark", "slave": self.address}
            self.log.write(json.dumps(item | {"text": note, "note": note}) + "\n")

    def transact(self, request: Request) -> Response:
        frame = encode(request)
        self._record(self.clock.now(), "rx", frame, request, None)
        reply = self.link.exchange(frame, self.timeout)
        t = self.clock.now()
        what = describe(request, self.registers)
        for _ in range(2):  # a late reply to a request abandoned before (Ctrl-C in a wait) is not this one's
            if not reply or not crc_ok(reply) or _answers(request, frame, reply):
                break
            try:
                late: Response | None = decode_response(reply)
            except ValueError:
                late = None
            self._record(t, "tx", reply, late, None, note="a late reply to an earlier request: not this one's")
            reply = self.link.receive(self.timeout)
            t = self.clock.now()
        if not reply:
            raise NoReply(f"no reply to {what} within {self.timeout:g} s")
        if not crc_ok(reply):
            self._record(t, "tx", reply, None, request)
            raise DriveSilent(f"a broken reply (bad CRC) to {what}: {reply.hex(' ').upper()}")
        if len(reply) == 5 and reply[1] & 0x80:  # an exception: the sheet's, or a gateway's (0x0A, 0x0B)
            code = reply[2]
            name = ExceptionCode(code).meaning if code in ExceptionCode._value2member_map_ else GATEWAY.get(code, "")
            words = f"exception 0x{code:02X}{' (' + name + ')' if name else ''}"
            self._record(t, "tx", reply, None, request, words)
            raise DriveRefused(f"the drive answered {words} to {what}", code)
        try:
            response = decode_response(reply)
        except ValueError as exc:
            self._record(t, "tx", reply, None, request)
            raise DriveSilent(f"a broken reply to {what}: {exc}: {reply.hex(' ').upper()}") from None
        self._record(t, "tx", reply, response, request)
        return response

    def probe(self, frame: bytes, note: str) -> bytes:
        """Send ``frame`` as it is (a bad CRC, a short frame, a broadcast: the dialect probe's) and return what came
        back, b"" for silence; both logged, the request with ``note``. An exception reply is returned, not raised."""
        try:
            request: Request | None = decode_request(frame)
        except ValueError:
            request = None
        words = "" if request is not None else "a broken frame, sent on purpose"
        self._record(self.clock.now(), "rx", frame, request, None, words, note=note)
        reply = self.link.exchange(frame, self.timeout)
        if not reply:
            return b""
        t = self.clock.now()
        words = f"exception 0x{reply[2]:02X}" if len(reply) == 5 and reply[1] & 0x80 and crc_ok(reply) else ""
        try:
            response: Response | None = None if words or not crc_ok(reply) else decode_response(reply)
        except ValueError:
            response = None
        self._record(t, "tx", reply, response, request, words)
        return reply

    def read(self, address: int) -> int:
        response = self.transact(ReadRequest(self.address, address, 1))
        if not isinstance(response, ReadResponse) or len(response.values) != 1:
            raise DriveSilent(f"an unexpected reply to a read of {address_label(address)}")
        return response.values[0]

    def write(self, address: int, value: int) -> None:
        self.transact(WriteSingleRequest(self.address, address, value))


def is_function_code(registers: RegisterMap, address: int) -> bool:
    """A function code, or a 20xxH register whose value is one (kept in EEPROM)."""
    return is_fcode(address) or is_fcode(registers.canonical(address))


def _answers(request: Request, frame: bytes, reply: bytes) -> bool:
    """Whether ``reply`` can answer ``request``: its slave and function, a write's echo, a read's byte count."""
    if len(reply) < 5 or reply[0] != frame[0] or reply[1] & 0x7F != frame[1]:
        return False
    if reply[1] & 0x80:
        return True  # an exception to this function
    if isinstance(request, WriteSingleRequest):
        return reply == frame
    if isinstance(request, ReadRequest):
        return reply[2] == 2 * request.count
    return True

"""``c20sim exercise PORT``: a C20 master for a person at a bench, and the identification programme.

The same master does two jobs. ``c20sim exercise PORT read speed status fault``
reads single registers by name and prints them in units; ``c20sim exercise
PORT write setpoint 1500`` writes one, saying what it writes (and saying so
loudly when it is a function code, which the drive keeps in EEPROM). With
``--out FILE`` and no action it runs the short identification programme
(:func:`programme`): a hold at rest, a run, speed steps with holds, optionally
a load change the user makes by hand when told, and a stop, polling the
physical registers (:data:`POLL`) at a steady rate all along. The capture is
the JSONL frame log ``c20sim record`` and ``serve --log-frames`` write
(``t``, ``dir``, ``hex``, ``kind``, ``slave``, ``text``), which ``c20sim fit``
and ``c20sim replay`` read.

Safety: the programme refuses to start a drive that is not stopped, faulted,
or not under communication control with the Modbus speed reference; a drive
that answers an exception or stays silent, or trips, is told to stop and the
programme ends with one line saying why; Ctrl-C stops the drive first.

PORT is a serial device or a pty (opened by :func:`c20sim.transport.device.open_serial`),
``tcp://HOST:PORT`` (raw RTU frames over TCP: a serial device server, ``serve --tcp``)
or ``modbus-tcp://HOST:PORT`` (Modbus TCP, MBAP; ``serve --modbus-tcp``). The
bytes are made and checked by :mod:`c20sim.wire.protocol`: its encoder, CRC and
frame lengths.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import json
import math
import os
import socket
import struct
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import IO, Any, Protocol, TypeVar

from ..core.simulator import Simulator
from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..wire.decode import describe
from ..wire.errors import C20SimError
from ..wire.framing import RtuFramer
from ..wire.protocol import (
    ExceptionCode,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteSingleRequest,
    crc_ok,
    decode_response,
    encode,
    expected_length,
    with_crc,
)
from ..wire.registers import BAUD_RATES, Command, Reg, RegisterMap, RegisterSpec, address_label, is_fcode
from ..wire.vocabulary import SHORT_NAMES, UnknownRegister, resolve_register

__all__ = [
    "NAMES",
    "POLL",
    "DriveRefused",
    "DriveSilent",
    "Master",
    "NoReply",
    "SimulatedLink",
    "SimulatedTime",
    "Step",
    "open_link",
    "programme",
    "register_of",
    "run_programme",
    "simulated_capture",
]

#: The short names of the one register vocabulary (kept here for those who import them from exercise).
NAMES = SHORT_NAMES

T = TypeVar("T")

#: What the programme polls, in turn: the physical quantities, the status words and the fault code.
POLL: tuple[int, ...] = (
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.BUS_VOLTAGE,
    Reg.OUTPUT_VOLTAGE,
    Reg.STATUS1,
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.RAMP_FREQUENCY,
    Reg.OUTPUT_FREQUENCY,
    Reg.FAULT_CODE,
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.BUS_VOLTAGE,
    Reg.TEMPERATURE,
    Reg.OUTPUT_POWER,
    Reg.STATUS2,
    Reg.HALL,
)

#: The settings read once before the programme starts: the fit takes the ramps and pole pairs from them.
SETTINGS: tuple[int, ...] = (
    Reg.DRIVE_ID,
    Reg.SOFTWARE_VERSION,
    Reg.POLE_PAIRS,
    Reg.ACCEL_TIME,
    Reg.DECEL_TIME,
    Reg.CONTROL_MODE,
    Reg.RUN_CHANNEL,
    Reg.SPEED_SOURCE,
)

#: What the programme polls while the speed ramps, every :data:`RAMP_PERIOD` (a ramp may last a tenth of a
#: second): the current, which carries the inertia, and the speed.
RAMP_POLL: tuple[int, ...] = (Reg.OUTPUT_CURRENT, Reg.MOTOR_SPEED)

#: Seconds between reads while a step ramps: 50 a second, within what a line at 19200 baud carries (74 one-register
#: reads a second with a 2 ms turnaround), so that none waits for the line behind the one before.
RAMP_PERIOD = 0.02

#: Rounds of the link's timing reads at the start: a one-register read, and one of 8 (answered, or refused with
#: an exception where the drive reads one at a time): replies of two lengths tell a link that keeps the line's
#: time (a longer reply takes longer) from one that does not.
TIMING_ROUNDS = 10

#: Silences in a row the programme tolerates (a lost frame on a real line) before it stops the drive.
SILENCES_IN_A_ROW = 3

STATUS_STOPPED = 3

#: The marks of a load change in the log: ``{"dir": "rx", "hex": "", "kind": "mark", "note": "load-on"}``.
LOAD_ON, LOAD_OFF = "load-on", "load-off"


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
    """A register in the one vocabulary of every tool (:func:`~c20sim.wire.vocabulary.resolve_register`): a short
    name (``speed``), the sheet's name, an address (``3006H``, ``0x3006``, ``12294``) or a function code."""
    try:
        return registers[resolve_register(word, registers, owner)]
    except UnknownRegister as exc:
        raise C20SimError(str(exc)) from None


def parse_value(spec: RegisterSpec, text: str) -> int:
    """A value for ``spec`` in its units (``1500``, ``2.5`` s) or by name (``stop``, ``forward-run``): raw.

    Never a value other than the one typed: a number outside the register's range, one that would wrap in 16 bits
    (65536), one between the register's steps (2.55 s where it counts 0.1 s) or not finite (nan, inf) is refused
    in one line.
    """
    wanted = text.strip().lower().replace("_", " ").replace("-", " ")
    for raw, name in spec.values.items():
        if name.lower().replace("-", " ") == wanted or name.lower().split(" (")[0] == wanted:
            return raw
    if spec.address == Reg.COMMAND:
        for command in Command:
            if command.key.replace("_", " ") == wanted:
                return int(command)
    where = f"{spec.label} {spec.name}"
    try:
        number = float(int(text, 16)) if spec.hex_display and text.lower().startswith("0x") else float(text)
    except ValueError:
        names = ", ".join(f"{raw} = {name}" for raw, name in spec.values.items())
        raise C20SimError(
            f"{where}: {text!r} is not a number" + (f" nor a value's name ({names})" if names else "")
        ) from None
    low, high = _amount(spec, spec.minimum), _amount(spec, spec.maximum)
    if not math.isfinite(number):
        raise C20SimError(f"{where}: {text} is not a finite number; give one from {low} to {high}")
    raw = round(number / spec.scale)
    if not spec.minimum <= raw <= spec.maximum or not (-0x8000 if spec.signed else 0) <= raw <= 0xFFFF:
        raise C20SimError(f"{where}: {text} is outside {low} to {high}")
    if not math.isclose(raw * spec.scale, number, rel_tol=1e-9, abs_tol=1e-9):
        step = f"{spec.scale:g} {spec.unit}".rstrip()
        raise C20SimError(
            f"{where}: {text} is not a whole number of its steps of {step}; the nearest is {_amount(spec, raw)}"
        )
    return raw & 0xFFFF


def _amount(spec: RegisterSpec, raw: int) -> str:
    """A raw value as a number in the register's units, with its name where it has one: ``8 (jog stop)``."""
    if spec.hex_display:
        text = f"0x{raw & 0xFFFF:04X}"
    else:
        decimals = max(0, len(f"{spec.scale:g}".partition(".")[2]))
        text = f"{raw * spec.scale:.{decimals}f} {spec.unit}".rstrip()
    name = spec.values.get(raw & 0xFFFF)
    return f"{text} ({name})" if name else text


# --- The links: one RTU frame out, one back, over whatever carries them.


class Link(Protocol):
    """Carries one request frame (RTU, with its CRC) and returns the reply frame, or b"" for silence."""

    def exchange(self, frame: bytes, timeout: float) -> bytes: ...

    def receive(self, timeout: float) -> bytes:
        """The next reply, without sending (after a late reply to an abandoned request was read instead)."""
        ...

    def close(self) -> None: ...


def _reply_complete(buffer: bytes | bytearray) -> bool:
    length = expected_length(bytes(buffer[:3]), "response")
    return length is not None and len(buffer) >= length


class SerialLink:
    """A serial port or a pty, opened as every port of c20sim is (exclusive, in the line's format)."""

    def __init__(self, device: str, baud: int, parity: str, stopbits: int) -> None:
        from ..transport.device import open_serial

        try:
            self.port = open_serial(device, baud, parity, stopbits)
        except (OSError, ValueError) as exc:
            raise C20SimError(f"{device}: cannot open: {getattr(exc, 'strerror', None) or exc}") from None
        self.baud = baud

    def exchange(self, frame: bytes, timeout: float) -> bytes:
        try:
            return self._exchange(frame, timeout)
        except OSError as exc:  # pyserial's SerialException is one: an adapter unplugged
            raise C20SimError(f"{self.port.port}: the port failed: {exc}") from None

    def _exchange(self, frame: bytes, timeout: float) -> bytes:
        port = self.port
        port.reset_input_buffer()
        port.write(frame)
        port.flush()  # the request is on the wire: the reply's time counts from here
        return self._receive(timeout)

    def receive(self, timeout: float) -> bytes:
        try:
            return self._receive(timeout)
        except OSError as exc:
            raise C20SimError(f"{self.port.port}: the port failed: {exc}") from None

    def _receive(self, timeout: float) -> bytes:
        port = self.port
        deadline = time.monotonic() + timeout
        buffer = bytearray()
        wanted = 3  # enough to know the reply's length (an exception's, or a read's byte count)
        while len(buffer) < wanted:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            port.timeout = left
            chunk = port.read(wanted - len(buffer))  # returns as soon as these bytes are in
            if not chunk:
                break
            buffer += chunk
            length = expected_length(bytes(buffer[:3]), "response")
            if length is None and len(buffer) >= 3:
                break  # not a reply the C20 gives: what came is returned, and refused by its CRC
            wanted = length if length is not None else 3
        return bytes(buffer)

    def close(self) -> None:
        self.port.close()


def _connect(host: str, port: int, where: str) -> socket.socket:
    try:
        sock = socket.create_connection((host, port), timeout=5.0)
    except OSError as exc:
        raise C20SimError(f"{where}: cannot connect: {exc.strerror or exc}") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _drain(sock: socket.socket) -> None:
    """Read and drop whatever the socket holds (bounded: a few KiB at most)."""
    sock.setblocking(False)
    try:
        for _ in range(16):
            if not sock.recv(256):
                break
    except (BlockingIOError, InterruptedError):
        pass
    finally:
        sock.setblocking(True)


def _send(sock: socket.socket, data: bytes, where: str) -> None:
    try:
        sock.sendall(data)
    except OSError as exc:
        raise C20SimError(f"{where}: connection lost: {exc.strerror or exc}") from None


class TcpLink:
    """Raw RTU frames over TCP (a serial device server, ``serve --tcp``)."""

    def __init__(self, host: str, port: int, where: str) -> None:
        self.sock = _connect(host, port, where)
        self.where = where

    def exchange(self, frame: bytes, timeout: float) -> bytes:
        _drain(self.sock)  # a late reply to an earlier request is not this one's
        _send(self.sock, frame, self.where)
        return self.receive(timeout)

    def receive(self, timeout: float) -> bytes:
        deadline = time.monotonic() + timeout
        buffer = bytearray()
        while not _reply_complete(buffer) and len(buffer) < 256:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(256 - len(buffer))
            except TimeoutError:
                break
            except OSError as exc:
                raise C20SimError(f"{self.where}: connection lost: {exc.strerror or exc}") from None
            if not chunk:
                raise C20SimError(f"{self.where}: the server closed the connection")
            buffer += chunk
        length = expected_length(bytes(buffer[:3]), "response")
        return bytes(buffer[:length]) if length is not None else bytes(buffer)

    def close(self) -> None:
        self.sock.close()


class MbapLink:
    """Modbus TCP: the RTU frame's CRC comes off and an MBAP header goes on; the reply the other way."""

    def __init__(self, host: str, port: int, where: str) -> None:
        self.sock = _connect(host, port, where)
        self.where = where
        self.transaction = 0

    def _recv(self, count: int, deadline: float) -> bytes | None:
        data = bytearray()
        while len(data) < count:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(count - len(data))
            except TimeoutError:
                return None
            except OSError as exc:
                raise C20SimError(f"{self.where}: connection lost: {exc.strerror or exc}") from None
            if not chunk:
                raise C20SimError(f"{self.where}: the server closed the connection")
            data += chunk
        return bytes(data)

    def exchange(self, frame: bytes, timeout: float) -> bytes:
        self.transaction = (self.transaction + 1) & 0xFFFF
        unit, pdu = frame[0], frame[1:-2]
        _send(self.sock, struct.pack(">HHHB", self.transaction, 0, len(pdu) + 1, unit) + pdu, self.where)
        deadline = time.monotonic() + timeout
        while True:
            header = self._recv(7, deadline)
            if header is None:
                return b""
            transaction, protocol, length, reply_unit = struct.unpack(">HHHB", header)
            if protocol != 0 or not 2 <= length <= 254:
                raise C20SimError(f"{self.where}: not Modbus TCP: a bad MBAP header {header.hex(' ')}")
            body = self._recv(length - 1, deadline)
            if body is None:
                return b""
            if transaction == self.transaction:  # an older answer, after its timeout: skip it
                return with_crc(bytes((reply_unit,)) + body)

    def receive(self, timeout: float) -> bytes:
        return b""  # the transaction id has told every reply apart already: none is late here

    def close(self) -> None:
        self.sock.close()


def open_link(port: str, baud: int, parity: str = "N", stopbits: int = 1) -> Link:
    """PORT as the user gives it: a device path, ``tcp://HOST:PORT`` or ``modbus-tcp://HOST:PORT``."""
    for scheme, kind in (("tcp://", TcpLink), ("modbus-tcp://", MbapLink)):
        if port.startswith(scheme):
            host, sep, number = port[len(scheme) :].rpartition(":")
            if not sep or not number.isdigit() or not 0 < int(number) < 65536:
                raise C20SimError(f"{port}: expected {scheme}HOST:PORT, such as {scheme}127.0.0.1:5020")
            return kind(host.strip("[]") or "127.0.0.1", int(number), port)
    if "://" in port:
        raise C20SimError(f"{port}: give a serial device, tcp://HOST:PORT or modbus-tcp://HOST:PORT")
    return SerialLink(port, baud, parity, stopbits)


class SimulatedLink:
    """c20sim in this process under a virtual clock: the programme's captures in tests and benchmarks (an hour of
    model time in seconds). A reply comes after the profile's turnaround, silence after the timeout."""

    def __init__(self, sim: Simulator) -> None:
        if not sim.virtual:
            raise C20SimError("a simulated link needs a simulator with a virtual clock")
        self.sim = sim

    def exchange(self, frame: bytes, timeout: float) -> bytes:
        sim = self.sim
        framer = RtuFramer(sim.bus.line_baud, complete_on_length=True, check_gaps=False)
        framer.feed(frame, sim.now())
        framer.flush()
        reply = b""
        for event in framer.events():
            answer = sim.handle(event)
            if answer is not None:
                sim.advance(answer.delay)
                reply += answer.data
        if not reply:
            sim.advance(timeout)
        return reply

    def receive(self, timeout: float) -> bytes:
        return b""  # each exchange is whole, in virtual time: no reply comes late

    def close(self) -> None:
        """Nothing to close."""


class SimulatedTime:
    """The simulator's virtual clock as the master's: a sleep moves model time on."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim

    def now(self) -> float:
        return self.sim.now()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.sim.advance(seconds)


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


# --- The identification programme.


@dataclass(frozen=True)
class Step:
    """One stretch of the programme: writes at its start, then polling for ``hold`` seconds."""

    say: str
    writes: tuple[tuple[int, int], ...] = ()
    hold: float = 0.0
    prompt: str = ""  #: a change the user makes by hand, confirmed before the step starts
    mark: str = ""  #: written to the log (an empty rx frame of kind "mark") once the user confirmed: load-on ...
    until_stopped: bool = False  #: poll on until status word 1 reads stopped (at most ``hold`` more)
    ramp: float = 0.0  #: seconds from the step's start that the speed ramps: :data:`RAMP_POLL` is read then


def programme(
    speeds: Sequence[float], hold: float, accel_s: float, decel_s: float, max_rpm: float, load: bool
) -> list[Step]:
    """The steps: rest, run and speed steps (each held ``hold`` s past its ramp), a load change, a stop.

    ``accel_s``/``decel_s`` are the drive's ramp times to ``max_rpm`` (2003H, 2004H), so each hold starts
    once the ramp is done.
    """
    steps = [Step("at rest: the supply without load", hold=min(hold, 3.0))]
    last = 0.0
    for index, rpm in enumerate(speeds):
        ramp = abs(rpm - last) / max_rpm * (accel_s if rpm > last else decel_s)
        writes: tuple[tuple[int, int], ...] = ((Reg.SPEED_SETPOINT, round(rpm)),)
        if index == 0:
            writes += ((Reg.COMMAND, int(Command.FORWARD)),)
        steps.append(Step(f"{'run at' if index == 0 else 'step to'} {rpm:g} rpm", writes, ramp + hold, ramp=ramp))
        last = rpm
    if load:
        steps.append(Step(f"with the load, at {last:g} rpm", (), hold, "apply the load now", LOAD_ON))
        steps.append(Step(f"load taken off, at {last:g} rpm", (), hold, "take the load off now", LOAD_OFF))
    stop_ramp = last / max_rpm * decel_s
    steps.append(Step("stop", ((Reg.COMMAND, int(Command.STOP)),), stop_ramp + 2.0, until_stopped=True, ramp=stop_ramp))
    steps.append(Step("at rest after the stop", hold=min(hold, 3.0)))
    return steps


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


Progress = Callable[[int, int, Step, float, float, dict[int, int]], None]
Confirm = Callable[[str], None]


def _stop(master: Master) -> str:
    """Tell the drive to stop; the words for the user on how it went."""
    try:
        master.write(Reg.COMMAND, int(Command.STOP))
    except C20SimError as exc:
        return f"telling it to stop failed too ({exc}): stop it by hand"
    return "the drive was told to stop (2000H = 5)"


def _again(master: Master, ask: Callable[[], T]) -> T:
    """``ask()`` asked again where its reply was lost, up to :data:`SILENCES_IN_A_ROW` times in all."""
    for attempt in range(SILENCES_IN_A_ROW):
        try:
            return ask()
        except DriveSilent:
            if attempt == SILENCES_IN_A_ROW - 1:
                raise
    raise AssertionError("unreachable")


def _read_again(master: Master, address: int) -> int:
    return _again(master, lambda: master.read(address))


def check_ready(master: Master) -> dict[int, int]:
    """The settings, read; C20SimError (one line) if the drive is not one the programme may start."""
    values: dict[int, int] = {}
    for address in SETTINGS:
        values[address] = _read_again(master, address)
    status = _read_again(master, Reg.STATUS1)
    fault = _read_again(master, Reg.FAULT_CODE)
    registers = master.registers
    if status != STATUS_STOPPED:
        state = registers[Reg.STATUS1].describe(status)
        raise C20SimError(
            f"the drive is not stopped ({state}, 2100H = {status}); the programme starts only a stopped drive"
        )
    if fault:
        raise C20SimError(f"the drive reports fault 0x{fault:02X}; reset it first (write command reset)")
    if values[Reg.RUN_CHANNEL] != 2:
        channel = registers[Reg.RUN_CHANNEL].describe(values[Reg.RUN_CHANNEL])
        raise C20SimError(
            f"run commands come from the {channel} (2006H = {values[Reg.RUN_CHANNEL]}); the programme needs "
            "communication: write run-channel 2 (a function code) first"
        )
    if values[Reg.SPEED_SOURCE] != 3:
        source = registers[Reg.SPEED_SOURCE].describe(values[Reg.SPEED_SOURCE])
        raise C20SimError(
            f"the speed reference comes from {source} (2007H = {values[Reg.SPEED_SOURCE]}); the programme needs "
            "Modbus: write speed-source 3 (a function code) first"
        )
    return values


def time_the_link(master: Master) -> None:
    """:data:`TIMING_ROUNDS` of a one-register read and a read of 8 (3000H-3007H; refused or not): at rest, 20 ms
    apart, so that neither waits for the line behind the one before."""
    for _ in range(TIMING_ROUNDS):
        master.clock.sleep(0.02)
        with contextlib.suppress(DriveSilent):  # a lost reply: that round has one timing fewer
            master.read(Reg.BUS_VOLTAGE)
        master.clock.sleep(0.02)
        with contextlib.suppress(DriveRefused, DriveSilent):  # refused: a drive that reads one at a time
            master.transact(ReadRequest(master.address, Reg.SET_FREQUENCY, 8))


def run_programme(
    master: Master,
    steps: Sequence[Step],
    *,
    rate: float,
    progress: Progress | None = None,
    confirm: Confirm | None = None,
) -> int:
    """Run ``steps``, polling :data:`POLL` at ``rate`` reads a second; returns the reads made.

    A refusal, silence (:data:`SILENCES_IN_A_ROW` in a row) or a trip stops the drive and raises
    C20SimError in one line; KeyboardInterrupt stops it and raises :class:`Interrupted`.
    """
    period = 1.0 / rate
    reads = 0
    silent = 0
    last: dict[int, int] = {}
    poll, ramp_poll = _cycle(POLL), _cycle(RAMP_POLL)
    started = False
    steps = list(steps)
    setpoint = 0  #: the speed set before the step being run
    repeated: set[int] = set()
    try:
        for index, step in enumerate(steps):
            in_ramp = 0  #: current reads answered while this step ramps
            if step.prompt and confirm is not None:
                confirm(step.prompt)
            if step.mark:
                master.mark(step.mark)
            before = setpoint
            for address, value in step.writes:
                _again(master, functools.partial(master.write, address, value))  # the same value again: harmless
                started = started or address == Reg.COMMAND
                setpoint = value if address == Reg.SPEED_SETPOINT else setpoint
            begin = master.clock.now()
            end = begin + step.hold
            k = 0
            ramp_due = begin
            while True:
                now = master.clock.now()
                if now >= end and not (step.until_stopped and last.get(Reg.STATUS1) != STATUS_STOPPED):
                    break
                if step.until_stopped and now >= end + step.hold + 10.0:
                    raise C20SimError("the drive did not stop within its ramp and 10 s more")
                ramping = now < begin + step.ramp  # the current and speed every RAMP_PERIOD while the speed ramps
                due = begin + k * period
                if ramping:
                    if ramp_due > now:
                        master.clock.sleep(ramp_due - now)
                    ramp_due = max(ramp_due, now) + RAMP_PERIOD
                    k = math.floor((now - begin) / period)  # the steady rate picks up where the ramp ends
                elif due > now:
                    master.clock.sleep(due - now)
                else:
                    k = max(k, math.floor((now - begin) / period))  # late: go on at the rate, no burst
                k += 1
                address = next(ramp_poll) if ramping else next(poll)
                try:
                    last[address] = master.read(address)
                    silent = 0
                except DriveSilent:
                    silent += 1
                    if silent >= SILENCES_IN_A_ROW:
                        raise
                    continue
                reads += 1
                in_ramp += ramping and address == Reg.OUTPUT_CURRENT
                if address == Reg.FAULT_CODE and last[address]:
                    name = master.registers[Reg.FAULT_CODE].describe(last[address])
                    raise C20SimError(f"the drive tripped: fault {name} in step '{step.say}'")
                if progress is not None:
                    progress(index, len(steps), step, master.clock.now() - begin, step.hold, last)
            if step.ramp and in_ramp < 2 and before and setpoint and index not in repeated:
                # the ramp's reads were lost (a reply lost costs the timeout): back to the speed before, and again
                repeated |= {index + 1, index + 2}
                back = Step(f"{step.say}: again, its ramp's reads were lost", ((Reg.SPEED_SETPOINT, before),))
                steps[index + 1 : index + 1] = [
                    dataclasses.replace(back, hold=step.ramp + 1.0, ramp=step.ramp),
                    dataclasses.replace(step, say=f"{step.say} (again)", hold=step.ramp + 1.0),
                ]
    except KeyboardInterrupt:
        raise Interrupted(_stop(master) if started else "the drive was not started") from None
    except C20SimError as exc:
        if started:
            raise C20SimError(f"{exc}; {_stop(master)}") from None
        raise
    return reads


def simulated_capture(
    sim: Simulator,
    out: IO[str],
    *,
    speeds: Sequence[float],
    hold: float,
    rate: float = 10.0,
    load_nm: float | None = None,
    address: int = 1,
) -> int:
    """The programme run on c20sim in this process, in virtual time, its capture written to ``out``; the load
    change (``load_nm``) made as a user would when told. Returns the reads made. Tests and benchmarks use it."""
    registers = sim.profile.registers
    master = Master(SimulatedLink(sim), registers, address, clock=SimulatedTime(sim), log=out)
    master.header("simulated", sim.bus.line_baud, "8N1")
    settings = check_ready(master)
    time_the_link(master)
    accel = settings[Reg.ACCEL_TIME] * registers[Reg.ACCEL_TIME].scale
    decel = settings[Reg.DECEL_TIME] * registers[Reg.DECEL_TIME].scale
    steps = programme(speeds, hold, accel, decel, sim.profile.motor.rated_speed_rpm, load_nm is not None)
    drive = sim.drive(address)

    def confirm(prompt: str) -> None:
        drive.set_load_torque((load_nm or 0.0) if prompt.startswith("apply") else 0.0)

    return run_programme(master, steps, rate=rate, confirm=confirm)


def _cycle(items: Sequence[int]) -> Iterator[int]:
    while True:
        yield from items


# --- The command.


def _bar(
    index: int, count: int, step: Step, held: float, hold: float, last: dict[int, int], registers: RegisterMap
) -> str:
    done = (index + min(held / hold, 1.0) if hold else index + 1) / count
    bar = "#" * round(done * 20)
    shown = []
    for address in (Reg.MOTOR_SPEED, Reg.OUTPUT_CURRENT, Reg.BUS_VOLTAGE):
        if address in last:
            shown.append(registers[address].describe(last[address]))
    return f"[{bar:<20}] {done * 100:3.0f}% step {index + 1}/{count}: {step.say} | {'  '.join(shown)}"


def cmd_exercise(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    registers = profile.registers
    action = args.action
    if action is None:
        if not args.out:
            raise C20SimError("give --out FILE for the capture, or an action: read NAME..., write NAME VALUE")
    elif action == "read":
        if not args.words:
            raise C20SimError("read what? give register names, such as: read speed status fault")
        specs = [register_of(word, registers, f"the profile {profile.name}") for word in args.words]
    elif action == "write":
        if len(args.words) != 2:
            raise C20SimError("write needs a register and a value, such as: write setpoint 1500")
        spec = register_of(args.words[0], registers, f"the profile {profile.name}")
        if not spec.access.writable:
            raise C20SimError(f"{spec.label} {spec.name} is read-only")
        value = parse_value(spec, args.words[1])
    else:
        raise C20SimError(f"unknown action {action!r}: read, write, or none for the identification programme")
    if not 0 < args.rate <= 100:
        raise C20SimError(f"--rate {args.rate:g}: give reads a second, above 0 and at most 100")
    if not 0 <= args.hold <= 86400:
        raise C20SimError(f"--hold {args.hold:g}: give seconds, from 0 to 86400 (a day)")
    if not 0 < args.timeout <= 60:
        raise C20SimError(f"--timeout {args.timeout:g}: give seconds, above 0 and at most 60")
    if not 1 <= args.address <= 247:
        raise C20SimError(f"--address {args.address}: give the drive's address, 1-247 (2008H)")
    speeds = _speeds(args.speeds, profile.motor.rated_speed_rpm) if action is None else []
    baud = args.baud or BAUD_RATES[min(profile.default(Reg.BAUD), len(BAUD_RATES) - 1)]
    link = open_link(args.port, baud, args.parity, args.stopbits)
    try:
        if action == "read":
            master = Master(link, registers, args.address, timeout=args.timeout)
            for index, spec in enumerate(specs):
                raw = _first(master.read, spec.address, args, baud) if index == 0 else master.read(spec.address)
                print(f"{spec.label} {spec.name}: {spec.describe(raw)}")
            return 0
        if action == "write":
            master = Master(link, registers, args.address, timeout=args.timeout)
            words = f"{spec.label} {spec.name} = {spec.describe(value)} (raw {value})"
            if is_function_code(registers, spec.address):
                print(f"writing a function code, kept in the drive's EEPROM: {words}")
            else:
                print(f"writing {words}")
            _first(master.write, spec.address, args, baud, value)
            return 0
        return _run(args, link, registers, speeds, profile.motor.rated_speed_rpm, baud)
    finally:
        link.close()


def _first(act: Callable[..., T], address: int, args: argparse.Namespace, baud: int, *more: int) -> T:
    """The first exchange with the drive: silence there is the address's or the link's, not the action's."""
    try:
        return act(address, *more)
    except NoReply:
        serial = "" if args.port.startswith(("tcp://", "modbus-tcp://")) else f", {baud} baud {args.parity}"
        raise C20SimError(
            f"{args.port}: no drive answered at address {args.address} within {args.timeout:g} s; check --address "
            f"(the drive's 2008H, 1 as shipped) and the link (the port{serial})"
        ) from None


def _speeds(text: str | None, rated: float) -> list[float]:
    """--speeds: rpm, each above 0 and at most the rated speed; one line for anything else."""
    if text is None:
        return [rated * f for f in (0.3, 0.6, 0.9, 0.5)]
    out = []
    for word in text.split(","):
        try:
            speed = float(word)
        except ValueError:
            raise C20SimError(f"--speeds {text}: {word.strip()!r} is not a number; give rpm such as 900,1800") from None
        if not (math.isfinite(speed) and 0 < speed <= rated):
            raise C20SimError(f"--speeds {text}: each speed above 0 and at most {rated:g} rpm (the profile's rated)")
        out.append(speed)
    return out


def link_port(link: Link) -> str:
    """What the capture's header calls the link: serial, pty, tcp or modbus-tcp."""
    if isinstance(link, SerialLink):
        return "pty" if os.path.realpath(link.port.port or "").startswith("/dev/pts/") else "serial"
    return "modbus-tcp" if isinstance(link, MbapLink) else "tcp"


def _run(
    args: argparse.Namespace, link: Link, registers: RegisterMap, speeds: list[float], rated: float, link_baud: int
) -> int:
    try:
        out = open(args.out, "w", encoding="utf-8")  # noqa: SIM115 - closed below, after the stop
    except OSError as exc:
        raise C20SimError(f"--out {args.out}: cannot write: {exc.strerror}") from None
    tty = sys.stdout.isatty()
    with out:
        master = Master(link, registers, args.address, timeout=args.timeout, log=out)
        master.header(link_port(link), link_baud, f"8{args.parity}{args.stopbits}")
        settings = check_ready(master)
        time_the_link(master)
        accel = settings[Reg.ACCEL_TIME] * registers[Reg.ACCEL_TIME].scale
        decel = settings[Reg.DECEL_TIME] * registers[Reg.DECEL_TIME].scale
        steps = programme(speeds, args.hold, accel, decel, rated, args.load_change)
        total = sum(s.hold for s in steps)
        print(
            f"exercise {args.port}: {len(steps)} steps, about {total:.0f} s, polling {args.rate:g} reads/s; "
            f"writes 2001H (speed setting) and 2000H (run, stop) only, no function code; Ctrl-C stops the drive"
        )
        shown = [-1]

        def progress(index: int, count: int, step: Step, held: float, hold: float, last: dict[int, int]) -> None:
            if tty:
                line = _bar(index, count, step, held, hold, last, registers)
                print("\r" + line[:150].ljust(150), end="", flush=True)
            elif shown[0] != index:
                shown[0] = index
                print(f"step {index + 1}/{count}: {step.say}", flush=True)

        def confirm(prompt: str) -> None:
            print(("\n" if tty else "") + f"{prompt}, then press Enter (Ctrl-C stops the drive)", flush=True)
            if sys.stdin.readline() == "":
                raise C20SimError(f"no answer to '{prompt}' (stdin closed)")

        try:
            reads = run_programme(master, steps, rate=args.rate, progress=progress, confirm=confirm)
        except Interrupted as exc:
            print(f"\ninterrupted: {exc}; {master.frames} frames in {args.out}", file=sys.stderr)
            return 130
        finally:
            if tty:
                print()
    print(f"done: {reads} reads, {master.frames} frames written to {args.out}; fit it: c20sim fit {args.out}")
    return 0


def add_exercise_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "exercise",
        help="a C20 master: read or write registers by name, or run the identification programme (--out)",
        description="Talk to a C20 (or c20sim) as a master. 'read NAME...' and 'write NAME VALUE' for a person at "
        "a bench (values in units); with no action and --out FILE, the short identification programme (rest, run, "
        "speed steps, optionally a load change, stop), polling the physical registers and writing the capture as "
        "a JSONL frame log for c20sim fit.",
    )
    parser.add_argument("port", help="a serial device or pty, tcp://HOST:PORT (RTU over TCP) or modbus-tcp://HOST:PORT")
    parser.add_argument("action", nargs="?", help="read or write (none: the identification programme)")
    parser.add_argument("words", nargs="*", help="registers to read; or the register and value to write")
    parser.add_argument("--address", type=int, default=1, help="the drive's address (default 1)")
    parser.add_argument(
        "--baud", type=int, choices=BAUD_RATES, help="the serial line's baud (default: the profile's, 19200 as shipped)"
    )
    parser.add_argument("--parity", default="N", choices=["N", "E", "O"], help="serial parity (default N)")
    parser.add_argument("--stopbits", type=int, default=1, choices=[1, 2], help="serial stop bits (default 1)")
    parser.add_argument("--timeout", type=float, default=0.5, help="seconds to wait for a reply (default 0.5)")
    parser.add_argument(
        "--profile", default=DEFAULT_PROFILE, help=f"register names and rated speed (default {DEFAULT_PROFILE})"
    )
    parser.add_argument("--out", metavar="FILE", help="write the programme's capture here (JSONL frame log)")
    parser.add_argument("--rate", type=float, default=10.0, help="reads a second while polling (default 10)")
    parser.add_argument("--hold", type=float, default=8.0, help="seconds each speed is held past its ramp (default 8)")
    parser.add_argument(
        "--speeds", metavar="LIST", help="speeds to step through, rpm (default 30,60,90,50 %% of rated)"
    )
    parser.add_argument("--load-change", action="store_true", help="ask for a load change by hand, and hold with it")
    parser.set_defaults(func=cmd_exercise, trailing_words=_trailing_words)


def _trailing_words(args: argparse.Namespace, extras: list[str]) -> list[str]:
    """``exercise PORT --address 7 read speed``: argparse leaves the words after an option over; take them as the
    action and its words. Options among them stay over, for argparse's one-line error."""
    if any(word.startswith("-") and not _is_number(word) for word in extras):
        return extras
    words = list(extras)
    if args.action is None:
        args.action = words.pop(0)
    args.words = [*args.words, *words]
    return []


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True

"""The links of ``c20sim exercise``: one RTU frame out, one back, over a serial port, RTU over TCP, Modbus TCP,
or c20sim in this process in virtual time."""

from __future__ import annotations

import os
import socket
import struct
import time
from typing import Protocol

from ..core.simulator import Simulator
from ..wire.errors import C20SimError
from ..wire.framing import RtuFramer
from ..wire.protocol import expected_length, with_crc

__all__ = ["Link", "MbapLink", "SerialLink", "SimulatedLink", "SimulatedTime", "TcpLink", "link_port", "open_link"]

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


def link_port(link: Link) -> str:
    """What the capture's header calls the link: serial, pty, tcp or modbus-tcp."""
    if isinstance(link, SerialLink):
        return "pty" if os.path.realpath(link.port.port or "").startswith("/dev/pts/") else "serial"
    return "modbus-tcp" if isinstance(link, MbapLink) else "tcp"

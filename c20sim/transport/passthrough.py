"""Pass-through sides: byte pipes that a sniffer joins, passing every byte on unchanged (``c20sim record``).

A side is a serial port, a pty a master opens like a device (with a stable
link), or a TCP listener taking one master at a time (RTU over TCP, as a
serial device server). Each reads into a callback and writes what it is
given without blocking: a side that reads nothing has at most
:data:`MAX_UNSENT` bytes queued, and what is past that is counted and dropped,
so a stuck master cannot stall the drive's side. The ports are opened as the
serving ports open theirs (:mod:`.device`).
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

from ..wire.errors import C20SimError
from .device import open_pty, open_serial, remove_link
from .tcp import parse_host_port

__all__ = ["MAX_UNSENT", "PtySide", "SerialSide", "Side", "TcpSide"]

#: Bytes waiting to be written to one side before the sniffer drops them (a side that reads nothing).
MAX_UNSENT = 64 * 1024

Receive = Callable[[bytes], None]
Lost = Callable[[str], None]


class _FdSide:
    """A serial port or a pty master: a file descriptor read and written without blocking."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.fd = -1
        self._unsent = bytearray()
        self.dropped = 0

    def start(self, receive: Receive, lost: Lost) -> None:
        os.set_blocking(self.fd, False)
        asyncio.get_running_loop().add_reader(self.fd, self._readable, receive, lost)

    def _readable(self, receive: Receive, lost: Lost) -> None:
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:  # an unplugged adapter, a pty whose other end is gone (EIO)
            asyncio.get_running_loop().remove_reader(self.fd)
            lost(f"{self.name}: {exc.strerror}")
            return
        if not data:  # readable with nothing to read: hung up
            asyncio.get_running_loop().remove_reader(self.fd)
            lost(f"{self.name}: hung up")
            return
        receive(data)

    def send(self, data: bytes) -> None:
        if self._unsent:
            self._queue(data)
            return
        try:
            written = os.write(self.fd, data)
        except BlockingIOError:
            written = 0
        except OSError:
            self.dropped += len(data)
            return
        if written < len(data):
            self._queue(data[written:])
            asyncio.get_running_loop().add_writer(self.fd, self._writable)

    def _queue(self, data: bytes) -> None:
        room = MAX_UNSENT - len(self._unsent)
        self._unsent += data[:room]
        self.dropped += max(0, len(data) - room)

    def _writable(self) -> None:
        try:
            written = os.write(self.fd, self._unsent)
        except BlockingIOError:
            return
        except OSError:
            written = len(self._unsent)
        del self._unsent[:written]
        if not self._unsent:
            asyncio.get_running_loop().remove_writer(self.fd)

    def close(self) -> None:
        if self.fd >= 0:
            loop = asyncio.get_running_loop()
            loop.remove_reader(self.fd)
            loop.remove_writer(self.fd)


class SerialSide(_FdSide):
    def __init__(self, device: str, baud: int, parity: str, stopbits: int) -> None:
        super().__init__(device)
        self.device, self.baud, self.parity, self.stopbits = device, baud, parity, stopbits
        self._port: Any = None

    async def open(self) -> None:
        import serial

        try:
            self._port = open_serial(self.device, self.baud, self.parity, self.stopbits)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise C20SimError(f"{self.device}: cannot open the serial port: {exc}") from None
        self.fd = self._port.fileno()

    def close(self) -> None:
        super().close()
        if self._port is not None:
            self._port.close()


class PtySide(_FdSide):
    """A pty the master opens like a serial device; ``link`` a stable symlink to it."""

    def __init__(self, link: str | None) -> None:
        super().__init__("pty")
        self.link = Path(link) if link else None
        self._slave = -1

    async def open(self) -> None:
        self.fd, self._slave, self.name = open_pty(self.link, "--master-link")

    def close(self) -> None:
        super().close()
        for fd in (self.fd, self._slave):
            if fd >= 0:
                os.close(fd)
        self.fd = self._slave = -1
        remove_link(self.link, self.name)


class TcpSide:
    """Raw RTU over TCP, as a serial device server: one master connection at a time."""

    def __init__(self, where: str) -> None:
        self.host, self.port = parse_host_port(where, "--master-tcp")
        self.name = where
        self._server: asyncio.Server | None = None
        self._transport: asyncio.Transport | None = None
        self._receive: Receive | None = None
        self.dropped = 0

    async def open(self) -> None:
        try:
            self._server = await asyncio.get_running_loop().create_server(
                lambda: _TcpConnection(self), self.host, self.port
            )
        except OSError as exc:
            raise C20SimError(f"--master-tcp {self.name}: cannot listen: {exc.strerror}") from None
        host, port = self._server.sockets[0].getsockname()[:2]
        self.name = f"{host}:{port}"

    def start(self, receive: Receive, lost: Lost) -> None:
        self._receive = receive  # a master that hangs up may connect again: never lost

    def send(self, data: bytes) -> None:
        if self._transport is None or self._transport.is_closing():
            self.dropped += len(data)
            return
        if self._transport.get_write_buffer_size() > MAX_UNSENT:
            self.dropped += len(data)
            return
        self._transport.write(data)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
        if self._server is not None:
            self._server.close()


class _TcpConnection(asyncio.Protocol):
    def __init__(self, side: TcpSide) -> None:
        self.side = side
        self.transport: asyncio.Transport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        if self.side._transport is not None and not self.side._transport.is_closing():
            self.transport.close()  # one master at a time: the line has one
            return
        self.side._transport = self.transport

    def data_received(self, data: bytes) -> None:
        if self.side._transport is self.transport and self.side._receive is not None:
            self.side._receive(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.side._transport is self.transport:
            self.side._transport = None


Side = SerialSide | PtySide | TcpSide

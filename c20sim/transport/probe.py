"""A minimal blocking Modbus master for probes: one register read at a time.

``c20sim plant-check`` and the container's health check use it to ask a bus
(RTU frames over TCP, or Modbus TCP) whether its drives answer. It is
deliberately small and stdlib-only, so a probe costs a process start and a
few packets; tests use pymodbus as the independent master instead.

A read that gets no answer within the timeout closes the connection, so a
late reply can never be taken for the answer to the next request.
"""

from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass

from ..wire.protocol import (
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    decode_response,
    encode,
    expected_length,
    with_crc,
)

__all__ = ["NoAnswer", "Prober"]

#: the longest reply a one-register read can get (RTU: 7 bytes; Modbus TCP: 7 + 5); more is a peer's mistake
_MAX_REPLY = 256


class NoAnswer(Exception):
    """The bus gave no usable answer: timeout, refused or closed connection, or a malformed reply."""


@dataclass
class Prober:
    """Reads single registers from drives on one bus at ``host:port``."""

    host: str
    port: int
    modbus_tcp: bool = False
    timeout: float = 0.5

    def __post_init__(self) -> None:
        self._sock: socket.socket | None = None
        self._transaction = 0
        self._deadline = 0.0

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> Prober:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def read(self, drive: int, register: int) -> int | ExceptionResponse:
        """The register's value, or the drive's exception reply; raises NoAnswer.

        ``timeout`` bounds the whole read (connect, send, every byte of the reply), so a peer that
        trickles bytes cannot hold a probe longer than one timeout.
        """
        self._deadline = time.monotonic() + self.timeout
        try:
            sock = self._connect()
            request = encode(ReadRequest(drive, register, 1))
            if self.modbus_tcp:
                return self._read_mbap(sock, drive, request[:-2])
            sock.sendall(request)
            reply = self._receive_rtu(sock)
        except (OSError, NoAnswer) as exc:
            self.close()
            if isinstance(exc, NoAnswer):
                raise
            raise NoAnswer(_describe(exc)) from None
        except UnicodeError:  # a host name the resolver cannot even encode (a label over 63 characters)
            self.close()
            raise NoAnswer(f"not a host name: {self.host!r}") from None
        return self._check(reply, drive)

    def _connect(self) -> socket.socket:
        if self._sock is None:
            self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return self._sock

    def _receive_rtu(self, sock: socket.socket) -> bytes:
        data = b""
        while True:
            need = expected_length(data, "response")
            if need is not None and len(data) >= need:
                return data[:need]
            if len(data) >= 3 and need is None:
                raise NoAnswer(f"a reply that is not a C20 read reply: {data.hex(' ')}")
            data += self._recv(sock, (need or 3) - len(data))

    def _read_mbap(self, sock: socket.socket, drive: int, pdu_with_unit: bytes) -> int | ExceptionResponse:
        self._transaction = (self._transaction + 1) & 0xFFFF
        pdu = pdu_with_unit[1:]
        sock.sendall(struct.pack(">HHHB", self._transaction, 0, len(pdu) + 1, drive) + pdu)
        header = self._exactly(sock, 7)
        transaction, protocol, length, unit = struct.unpack(">HHHB", header)
        if protocol != 0 or not 2 <= length <= _MAX_REPLY or transaction != self._transaction:
            raise NoAnswer(f"a Modbus TCP header that does not answer the request: {header.hex(' ')}")
        body = self._exactly(sock, length - 1)
        # the RTU form of the same reply, so one decoder checks both
        return self._check(with_crc(bytes([unit]) + body), drive)

    def _exactly(self, sock: socket.socket, count: int) -> bytes:
        data = b""
        while len(data) < count:
            data += self._recv(sock, count - len(data))
        return data

    def _recv(self, sock: socket.socket, count: int) -> bytes:
        remaining = self._deadline - time.monotonic()
        if remaining <= 0:
            raise NoAnswer(f"timed out after {self.timeout:g} s")
        sock.settimeout(remaining)
        try:
            chunk = sock.recv(min(count, _MAX_REPLY))
        except TimeoutError:
            raise NoAnswer(f"timed out after {self.timeout:g} s") from None
        if not chunk:
            raise NoAnswer("the connection was closed")
        return chunk

    def _check(self, reply: bytes, drive: int) -> int | ExceptionResponse:
        try:
            response = decode_response(reply)
        except ValueError as exc:
            self.close()
            raise NoAnswer(f"a malformed reply ({exc}): {reply.hex(' ')}") from None
        if response.slave != drive:
            self.close()
            raise NoAnswer(f"a reply from address {response.slave}, not {drive}")
        if isinstance(response, ExceptionResponse):
            return response
        if not isinstance(response, ReadResponse) or len(response.values) != 1:
            self.close()
            raise NoAnswer(f"a reply that is not one register: {reply.hex(' ')}")
        return response.values[0]


def _describe(exc: OSError) -> str:
    if isinstance(exc, TimeoutError):
        return "connect timed out"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    if isinstance(exc, socket.gaierror):
        return f"unknown host ({exc.strerror})"
    return exc.strerror or str(exc)

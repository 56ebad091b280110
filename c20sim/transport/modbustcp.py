"""Modbus TCP in front of the bus: an Ethernet gateway (MBAP to the RTU line and back).

Modbus TCP: the MBAP header is taken off, the request goes to the bus as the
RTU frame a gateway would put on the line, and the reply comes back under the
request's transaction id. Where the line stays silent (absent drive, dropped
or corrupt reply, or a reply from another address than the unit asked) the
gateway answers exception 0x0B after its timeout, as gateways do; a broadcast (unit 0) gets no answer. The frame log keeps what the
TCP connection carried (the MBAP frames, their transaction id and unit) with
the RTU frame on the line beside it.

The listening, the connection limit, backpressure and the peer watch are
:mod:`.tcp`'s, shared with RTU over TCP.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import struct
import time
from collections.abc import Callable

from ..core.bus import Direction, FrameRecord, RecordKind, Reply
from ..wire.framing import RtuFramer
from ..wire.protocol import BROADCAST, MbapHeader, crc_ok, expected_length, with_crc
from .line import Line
from .tcp import GATEWAY_TIMEOUT, _Connection, _TcpServer

__all__ = ["GATEWAY_BUSY", "GATEWAY_NO_RESPONSE", "MBAP_PIPELINE", "ModbusTcpServer"]

log = logging.getLogger("c20sim.transport.tcp")  # the TCP ports' one logger, as before the split

#: Modbus TCP exception 0x0B: gateway target device failed to respond.
GATEWAY_NO_RESPONSE = 0x0B

#: Requests a Modbus TCP client may have outstanding at once (pipelining); an RTU-over-TCP client has one.
MBAP_PIPELINE = 4

#: Modbus TCP exception 0x06 (slave device busy): the MGate's answer when a master's request queue is full.
GATEWAY_BUSY = 0x06


class _MbapConnection(_Connection):
    def __init__(self, owner: ModbusTcpServer) -> None:
        super().__init__(owner)
        # the gateway, typed: mypyc refuses narrowing ``owner`` in a subclass
        self._gateway = owner
        self._buffer = bytearray()
        self._timers: set[asyncio.TimerHandle] = set()
        #: replies held while a split reply's second half is still to go (None: no split pending); at most one a
        #: request in hand, so no more than the connection's share of the line
        self._held: list[bytes] | None = None
        self._outstanding = 0  #: requests not yet answered (on the line, or waiting for the gateway's timeout)
        self._write_paused = False
        self._paused = False
        self._room = True  #: False while its peer's queue on the line is full

    def data_received(self, data: bytes) -> None:
        self._buffer += data
        self._parse()

    def pause_writing(self) -> None:
        self._write_paused = True
        self._flow()

    def resume_writing(self) -> None:
        self._write_paused = False
        self._parse()

    def _flow(self) -> None:
        hold = self._outstanding >= MBAP_PIPELINE or self._write_paused or not self._room
        if hold and not self._paused:
            self._paused = True
            self.pause_reading()
        elif not hold and self._paused:
            self._paused = False
            self.resume_reading()

    def _done(self) -> None:
        """One request answered (or left unanswered, a broadcast): room for the next."""
        self._outstanding -= 1
        if self.transport is not None:
            self.loop.call_soon(self._parse)

    def _parse(self) -> None:
        buf = self._buffer
        line = self.owner.line
        self._room = True
        while len(buf) >= 7 and self._outstanding < MBAP_PIPELINE and not self._write_paused:
            if self.transport is None:
                return
            if not line.has_room(self.peer, self):
                # its address's queue is full: the request waits in our buffer and the socket is not read
                self._room = False
                line.when_room(self.peer, self, self._parse)
                break
            transaction, protocol, length, unit = struct.unpack_from(">HHHB", buf)
            if protocol != 0 or not 2 <= length <= 254:
                log.info("modbus tcp: bad MBAP header %s; closing the connection", bytes(buf[:7]).hex(" "))
                size = expected_length(bytes(buf), "request")
                if size is not None and len(buf) >= size and crc_ok(bytes(buf[:size])):
                    self._gateway.rtu_seen(bytes(buf))  # an RTU master at the Modbus TCP port: said once
                self.close()
                return
            if len(buf) < 6 + length:
                return
            pdu = bytes(buf[7 : 6 + length])
            del buf[: 6 + length]
            self._request(transaction, unit, pdu)
        self._flow()

    def _request(self, transaction: int, unit: int, pdu: bytes) -> None:
        line = self.owner.line
        loop = self.loop
        # one whole frame, fed at once and flushed: no gap is judged, so the framer needs no baud of the line's
        framer = RtuFramer(check_gaps=False)
        # arrival on the clock every port stamps with (uvloop's loop time counts whole milliseconds, cached)
        framer.feed(with_crc(bytes((unit,)) + pdu), time.perf_counter())
        framer.flush()

        header = MbapHeader(transaction, unit)

        def respond(reply: Reply | None) -> None:
            if reply is not None and len(reply.data) >= 4 and crc_ok(reply.data) and reply.data[0] == unit:
                if reply.wrong_transaction > 0:  # a link fault: a copy under another id first, the right one later
                    self._answer(transaction ^ 0x5A5A, unit, reply.data[1:-2])
                    right = reply

                    def late() -> None:
                        self._timers.discard(held)
                        if self.transport is not None:
                            self._answer(transaction, unit, right.data[1:-2], right.split)
                        self._done()

                    held = loop.call_later(reply.wrong_transaction, late)
                    self._timers.add(held)
                    return
                self._answer(transaction, unit, reply.data[1:-2], reply.split)
                self._done()
            elif unit != BROADCAST and self.transport is not None:
                # The line stayed silent (or answered garbage): the gateway says so after its timeout.
                answer = bytes((pdu[0] | 0x80, GATEWAY_NO_RESPONSE))

                def time_out() -> None:
                    self._timers.discard(timer)
                    if self.transport is not None:
                        self._log_gateway_answer(header, answer)
                    self._answer(transaction, unit, answer)
                    self._done()

                timer = loop.call_later(self._gateway.timeout, time_out)
                self._timers.add(timer)
            else:
                self._done()

        def expired(busy: bool = False) -> None:
            # waited longer than the gateway's timeout for the line (0x0B), or refused: its peer's queue is full
            # (0x06): the gateway answers at once, the request never goes on the line
            code = GATEWAY_BUSY if busy else GATEWAY_NO_RESPONSE
            answer = bytes((pdu[0] | 0x80, code))
            if unit != BROADCAST and self.transport is not None:
                self._log_gateway_answer(header, answer)
                self._answer(transaction, unit, answer)
            self._done()

        for event in framer.events():
            self._outstanding += 1
            if not line.submit(
                dataclasses.replace(event, mbap=header),
                respond,
                self,
                peer=self.peer,
                expire=expired,
                wait_limit=self._gateway.timeout,
            ):
                expired(busy=True)

    def drop_waiting(self) -> None:
        self.owner.line.cancel(self)

    def _answer(self, transaction: int, unit: int, pdu: bytes, split: float = 0.0) -> None:
        adu = struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu
        if self._held is not None:  # a split reply's second half is still to go: this one follows it, whole
            self._held.append(adu)
            return
        if split > 0:  # a link fault: two TCP segments (asyncio's sockets send with TCP_NODELAY)
            self.send(adu[:7])
            self._held = []

            def second_half() -> None:
                self._timers.discard(timer)
                held, self._held = self._held or [], None
                self.send(adu[7:])
                for data in held:  # nothing ever goes between a reply's two segments
                    self.send(data)

            timer = self.loop.call_later(split, second_half)
            self._timers.add(timer)
            return
        self.send(adu)

    def _log_gateway_answer(self, header: MbapHeader, answer: bytes) -> None:
        """The frame log's record of the gateway's own exception (0x0B, 0x06): on the TCP connection, never on the
        line."""
        sim = self.owner.line.sim
        if answer[1] == GATEWAY_BUSY:
            why = f"gateway busy: {self.owner.line.peer_queue} requests of this master wait for the line already"
        else:
            why = f"gateway target device failed to respond (no good reply on the line within {self._gateway.timeout:g} s)"
        sim.bus.record(
            FrameRecord(
                asyncio.get_running_loop().time(),
                Direction.TX,
                with_crc(bytes((header.unit,)) + answer),
                RecordKind.EXCEPTION,
                header.unit,
                f"gateway: exception 0x{answer[1]:02X} to function 0x{answer[0] & 0x7F:02X}: {why}",
                model_t=sim.now(),
                mbap=header,
                from_gateway=True,
            )
        )

    def connection_lost(self, exc: Exception | None) -> None:
        if self.refused:
            return
        for timer in self._timers:
            timer.cancel()
        self.owner.line.cancel(self)
        self._buffer.clear()
        super().connection_lost(exc)


class ModbusTcpServer(_TcpServer):
    """Modbus TCP (MBAP) in front of the RTU bus, as an Ethernet gateway."""

    option = "--modbus-tcp"

    def __init__(
        self,
        line: Line,
        host: str,
        port: int,
        *,
        timeout: float = GATEWAY_TIMEOUT,
        max_connections: int | None = None,
    ) -> None:
        super().__init__(line, host, port, max_connections=max_connections)
        self.timeout = timeout
        #: where RTU over TCP is served (HOST:PORT), or None: for the word to an RTU master that came here
        self.rtu_tcp: Callable[[], str | None] = lambda: None

    def _connection(self) -> _Connection:
        return _MbapConnection(self)

    def rtu_seen(self, data: bytes) -> None:
        """An RTU frame (with its CRC) arrived here, as from a master that speaks RTU over TCP: the connection is
        closed (it is no Modbus TCP), the frame logged, and the mistake said once, as the opposite one is."""
        where = self.rtu_tcp()
        use = (
            f"use --tcp (RTU over TCP, open on {where})"
            if where
            else "use --tcp HOST:PORT (RTU over TCP, not open now)"
        )
        self.wrong_protocol(
            data,
            "an RTU frame (with its CRC) on the Modbus TCP port: not answered, the connection closed",
            f"Modbus TCP {self.name}: this looks like Modbus RTU over TCP: {use}",
            "this port answers Modbus TCP (MBAP) frames only, as a gateway would",
        )

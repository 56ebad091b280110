"""TCP in front of the bus: raw RTU frames (a serial device server) and Modbus TCP (a gateway).

RTU over TCP: each connection has its own framer, so a client that leaves in
the middle of a frame costs the others nothing; every connection feeds the one
line, so requests are served one at a time and each reply goes to the
connection that asked. A frame completes on its length (TCP has no line
timing); a broken frame is ended by 20 ms of silence. Connections are asyncio
protocols feeding the shared line by callbacks: no task per request.

Backpressure, as a real gateway's server loop: a connection is not read while
its requests are on the line (one for RTU over TCP, :data:`MBAP_PIPELINE` for
Modbus TCP) or while replies it has not taken fill its write buffer; the
kernel's socket buffer and TCP flow control hold the rest. Requests a closed
connection left waiting are dropped at once: a connection that is not being
read would not see its peer's close, so every connection's socket is also
watched for the peer's end (:class:`PeerWatch`, epoll's EPOLLRDHUP), and the
line asks the watch before it takes each waiting request.

Many masters: the line serves peers (client addresses) in turn and each
peer's connections in turn (:mod:`.line`); each port takes at most
``max_connections`` connections (:data:`MAX_CONNECTIONS`, a gateway's
figures) and closes the next one at once, with one log line (then one a
minute while it goes on). A Modbus TCP request that waited for the line
longer than the gateway's timeout is answered exception 0x0B, and one
refused because its peer's queue is full exception 0x06, as an MGate
answers them; RTU over TCP drops both, as a serial device server would.

Modbus TCP: the MBAP header is taken off, the request goes to the bus as the
RTU frame a gateway would put on the line, and the reply comes back under the
request's transaction id. Where the line stays silent (absent drive, dropped
or corrupt reply, or a reply from another address than the unit asked) the
gateway answers exception 0x0B after its timeout, as gateways do; a broadcast (unit 0) gets no answer. The frame log keeps what the
TCP connection carried (the MBAP frames, their transaction id and unit) with
the RTU frame on the line beside it.

A Modbus TCP master pointed at the RTU-over-TCP port by mistake sends MBAP
frames: the port answers nothing, as a serial device server in front of a
drive would, but says once (the server's log, so stderr, and the simulator's
notices, which the dashboard shows) where Modbus TCP is served. The opposite
mistake, an RTU master at the Modbus TCP port, sends no MBAP header: the
connection is closed, as a gateway would, and the simulator says once where
RTU over TCP is served.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import errno
import logging
import select
import socket
import struct
import time
from collections.abc import Callable
from typing import Any, cast

from ..core.bus import Direction, FrameRecord, RecordKind, Reply
from ..wire.errors import C20SimError
from ..wire.framing import RtuFramer
from ..wire.protocol import BROADCAST, MbapHeader, crc_ok, expected_length, mbap_adus, with_crc
from .endpoint import RtuEndpoint, stream_framer
from .line import Line

__all__ = ["MAX_CONNECTIONS", "ModbusTcpServer", "PeerWatch", "RtuOverTcpServer", "host_port", "parse_host_port"]

log = logging.getLogger(__name__)

#: Modbus TCP exception 0x0B: gateway target device failed to respond.
GATEWAY_NO_RESPONSE = 0x0B

#: Requests a Modbus TCP client may have outstanding at once (pipelining); an RTU-over-TCP client has one.
MBAP_PIPELINE = 4

#: Modbus TCP exception 0x06 (slave device busy): the MGate's answer when a master's request queue is full.
GATEWAY_BUSY = 0x06

#: Bytes of replies a client has not read, above which its connection is no longer read.
WRITE_HIGH_WATER = 16 * 1024

#: Connections each wire port takes at once (``--max-connections``). RTU over TCP: a Moxa NPort 5400 in TCP
#: Server mode takes "Max Connection 1, 2, 3, 4" (factory default 1; its user manual, TCP Server Mode); we take
#: its most, 4, so that several masters may share the line as the bus-timing tests do. Modbus TCP: 32, assumed
#: (the MGate MB3280/MB3480's figure for Modbus TCP client connections as we recall it; not found in a manual).
MAX_CONNECTIONS = {"--tcp": 4, "--modbus-tcp": 32}

#: The gateway's response timeout (``--gateway-timeout``): the MGate's "Response timeout", 10-120000 ms,
#: default 1000 ms (Moxa MGate W5X08 user manual, Mode settings; the MGate MB3000 manual names the field, its
#: default there assumed the same).
GATEWAY_TIMEOUT = 1.0

#: While connections are refused, one log line at most this often (seconds).
REFUSAL_LOG_INTERVAL = 60.0


class PeerWatch:
    """Notices a peer's close on connections the loop is not reading (paused by backpressure).

    One epoll instance watches every connection's socket for EPOLLRDHUP (the peer ended its sending half or
    closed), EPOLLHUP and EPOLLERR (a reset), never for data; its own descriptor is on the loop, and
    :meth:`poll` is also called by the line before it takes a waiting request. A peer that ended is gone: its
    waiting requests leave the line (``gone()``), as asyncio's own EOF handling would close it once read.
    """

    def __init__(self) -> None:
        self._epoll: select.epoll | None = None
        self._watched: dict[int, Callable[[], None]] = {}
        with contextlib.suppress(AttributeError, OSError):  # epoll: Linux only; elsewhere closes are seen when read
            self._epoll = select.epoll()
            asyncio.get_running_loop().add_reader(self._epoll.fileno(), self.poll)

    def watch(self, sock: object, gone: Callable[[], None]) -> int:
        """Watch ``sock``; ``gone()`` once when its peer has ended. Returns its descriptor (-1: not watched)."""
        if self._epoll is None:
            return -1
        try:
            fd = int(cast(Any, sock).fileno())
            self._epoll.register(fd, select.EPOLLRDHUP | select.EPOLLHUP | select.EPOLLERR)
        except (AttributeError, OSError, ValueError):
            return -1
        self._watched[fd] = gone
        return fd

    def forget(self, fd: int, gone: Callable[[], None]) -> None:
        """Stop watching ``fd`` if ``gone`` is still its callback (a closed descriptor may be reused)."""
        if fd < 0 or self._epoll is None or self._watched.get(fd) != gone:
            return
        del self._watched[fd]
        with contextlib.suppress(OSError, ValueError):
            self._epoll.unregister(fd)

    def poll(self) -> None:
        if self._epoll is None or not self._watched:
            return
        try:
            events = self._epoll.poll(0)
        except OSError:
            return
        for fd, _mask in events:
            gone = self._watched.pop(fd, None)
            with contextlib.suppress(OSError, ValueError):
                self._epoll.unregister(fd)
            if gone is not None:
                gone()

    def close(self) -> None:
        if self._epoll is not None:
            with contextlib.suppress(RuntimeError, ValueError):
                asyncio.get_running_loop().remove_reader(self._epoll.fileno())
            self._epoll.close()
            self._epoll = None
        self._watched.clear()


#: The port an option's example names, where it is not a wire port's (the README's ports).
_EXAMPLE_PORTS = {"--control": 8020, "--metrics": 9120}


def parse_host_port(text: str, option: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPV6]:PORT`` (a zone too: ``[fe80::1%eth0]:502``); port 0 asks for a free one."""
    port = _EXAMPLE_PORTS.get(option, 5020)
    usage = f"give HOST:PORT, such as 127.0.0.1:{port} or [::1]:{port} (port 0 picks a free port)"
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise C20SimError(f"{option} {text!r}: no ']' after the IPv6 address; {usage}")
        host, rest = text[1:end], text[end + 1 :]
        if not rest.startswith(":"):
            raise C20SimError(f"{option} {text!r}: no port after [{host}]; {usage}")
        port_text = rest[1:]
    else:
        host, sep, port_text = text.rpartition(":")
        if not sep:
            raise C20SimError(f"{option} {text!r}: {usage}")
        if ":" in host:
            raise C20SimError(f"{option} {text!r}: put an IPv6 address in brackets: [{host}]:{port_text}")
    if not host:
        raise C20SimError(f"{option} {text!r}: no host; {usage}")
    try:
        port = int(port_text)
    except ValueError:
        raise C20SimError(f"{option} {text!r}: the port {port_text!r} is not a number; {usage}") from None
    if not 0 <= port <= 65535:
        raise C20SimError(f"{option} {text!r}: port {port} is outside 0-65535")
    return host, port


def host_port(host: str, port: int) -> str:
    """``HOST:PORT`` for messages, an IPv6 address (with its zone) in brackets."""
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


async def _listen(factory: Callable[[], asyncio.Protocol], host: str, port: int, option: str) -> asyncio.Server:
    try:
        return await asyncio.get_running_loop().create_server(factory, host, port)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise C20SimError(
                f"{option} {host_port(host, port)}: the port is in use; stop the program holding it or choose another port (0 picks a free one)"
            ) from None
        if exc.errno == errno.EACCES:
            raise C20SimError(
                f"{option} {host_port(host, port)}: permission denied; ports below 1024 need root, choose another"
            ) from None
        raise C20SimError(f"{option} {host_port(host, port)}: cannot listen: {exc.strerror or exc}") from None


class _Connection(asyncio.Protocol):
    """One client's TCP connection; subclasses turn its bytes into framing events."""

    def __init__(self, owner: _TcpServer) -> None:
        self.owner = owner
        self.transport: asyncio.Transport | None = None
        self.refused = False  #: closed at once: the port had its connections already
        self.peer: object = None  #: the client's address, for the line's turns
        self._fd = -1

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)  # uvloop's transports do not subclass asyncio's
        self.loop = asyncio.get_running_loop()  # once: each get_running_loop() costs a getpid() system call
        peername = transport.get_extra_info("peername")
        self.peer = peername[0] if isinstance(peername, tuple) and peername else peername
        if len(self.owner.connections) >= self.owner.max_connections:
            self.refused = True
            self.owner.refuse(peername)
            self.transport.abort()
            self.transport = None
            return
        self.transport.set_write_buffer_limits(high=WRITE_HIGH_WATER)
        self.owner.connections.add(self)
        if self.owner.watch is not None:
            self._fd = self.owner.watch.watch(transport.get_extra_info("socket"), self.peer_gone)

    def peer_gone(self) -> None:
        """The peer ended the connection (seen even while it is not read): its waiting requests leave at once."""
        self._fd = -1
        self.drop_waiting()
        if self.transport is not None:
            self.transport.abort()  # nothing more is read or sent; connection_lost follows

    def drop_waiting(self) -> None:
        """Take this connection's requests off the line (subclasses)."""

    def connection_lost(self, exc: Exception | None) -> None:
        # The client left, perhaps mid-frame: that costs the others nothing.
        if self.refused:
            return
        if self.owner.watch is not None:
            self.owner.watch.forget(self._fd, self.peer_gone)
        self.owner.connections.discard(self)
        self.transport = None

    def pause_reading(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.pause_reading()

    def resume_reading(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.resume_reading()

    def send(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


class _TcpServer:
    option = ""

    def __init__(self, line: Line, host: str, port: int, *, max_connections: int | None = None) -> None:
        self.line = line
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self.connections: set[_Connection] = set()
        #: connections taken at once; the next is closed at once (:data:`MAX_CONNECTIONS`)
        self.max_connections = MAX_CONNECTIONS[self.option] if max_connections is None else max_connections
        self.refused = 0  #: connections closed at once, the port being full
        self._refusal_logged = -REFUSAL_LOG_INTERVAL
        self._refused_unlogged = 0
        self.watch: PeerWatch | None = None  #: made in start(), on the loop

    def wrong_protocol(self, data: bytes, words: str, text: str, why: str) -> None:
        """Bytes of the other Modbus framing on this port: not answered, logged as noise in ``words``, and ``text``
        said once (stderr, the frame log's notices, the dashboard)."""
        sim = self.line.sim
        sim.bus.noise += 1
        now = asyncio.get_running_loop().time()
        sim.bus.record(FrameRecord(now, Direction.RX, data, RecordKind.NOISE, None, words, model_t=sim.now()))
        if sim.notice(text):
            log.warning("c20sim: %s; %s", text, why)

    def refuse(self, peername: object) -> None:
        """A connection over the cap: counted, and logged once (then once a minute while refusals go on)."""
        self.refused += 1
        self._refused_unlogged += 1
        now = time.monotonic()
        if now - self._refusal_logged < REFUSAL_LOG_INTERVAL:
            return
        more = f" ({self._refused_unlogged - 1} more since the last word)" if self._refused_unlogged > 1 else ""
        log.warning(
            "c20sim: %s %s: refused a connection from %s: %d connections are open, the most it takes "
            "(--max-connections)%s",
            self.option,
            self.name,
            peername,
            self.max_connections,
            more,
        )
        self._refusal_logged = now
        self._refused_unlogged = 0

    @property
    def name(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    def _connection(self) -> _Connection:
        raise NotImplementedError

    async def start(self) -> None:
        # Bind one address: "localhost" resolves to 127.0.0.1 and ::1, and with port 0 each would get
        # a port of its own while the ready file can name only one.
        try:
            infos = await asyncio.get_running_loop().getaddrinfo(self.host, self.port, type=socket.SOCK_STREAM)
        except OSError as exc:
            raise C20SimError(
                f"{self.option} {host_port(self.host, self.port)}: cannot resolve the host: {exc}"
            ) from None
        address = self.host if "%" in self.host else str(infos[0][4][0])  # keep an IPv6 zone: fe80::1%eth0
        if self.max_connections < 1:
            raise C20SimError(f"--max-connections {self.max_connections}: give 1 or more connections per port")
        self.watch = PeerWatch()
        self.line.sweeps.append(self.watch.poll)
        self._server = await _listen(self._connection, address, self.port, self.option)
        # typeshed says a tuple, uvloop's Server gives a list, and compiled code (mypyc) checks the type
        sockets: Any = cast(Any, self._server).sockets
        self.host, self.port = sockets[0].getsockname()[:2]

    async def wait_closed(self) -> None:
        if self._server is not None:
            await self._server.wait_closed()

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for connection in list(self.connections):
            connection.close()
        if self.watch is not None:
            if self.watch.poll in self.line.sweeps:
                self.line.sweeps.remove(self.watch.poll)
            self.watch.close()


class _RtuConnection(_Connection):
    endpoint: RtuEndpoint | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        if self.refused:
            return
        line = self.owner.line
        framer = stream_framer(line.sim.bus.line_baud)  # TCP carries no line timing
        self.endpoint = RtuEndpoint(
            line,
            framer,
            lambda data, _baud: self.send(data),
            name=f"tcp {transport.get_extra_info('peername')}",
            pause=self.pause_reading,
            resume=self.resume_reading,
            peer=self.peer,
            wait_limit=cast(RtuOverTcpServer, self.owner).timeout,
        )

    def drop_waiting(self) -> None:
        if self.endpoint is not None:
            self.endpoint.close()

    def data_received(self, data: bytes) -> None:
        if self.endpoint is None:
            return
        if self.endpoint.between_frames:
            headers = mbap_adus(data)
            if headers is not None:  # a Modbus TCP master at the RTU port: no drive answers that
                cast(RtuOverTcpServer, self.owner).mbap_seen(data, headers)
                return
        self.endpoint.feed(data)

    def pause_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.write_blocked(True)

    def resume_writing(self) -> None:
        if self.endpoint is not None:
            self.endpoint.write_blocked(False)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.endpoint is not None:
            self.endpoint.close()
        super().connection_lost(exc)


class RtuOverTcpServer(_TcpServer):
    """Raw RTU frames over TCP, as a serial device server carries them."""

    option = "--tcp"

    def __init__(
        self,
        line: Line,
        host: str,
        port: int,
        *,
        max_connections: int | None = None,
        timeout: float = GATEWAY_TIMEOUT,
    ) -> None:
        super().__init__(line, host, port, max_connections=max_connections)
        #: a request that waited this long for the line is dropped, as a device server's master has given up
        self.timeout = timeout
        #: where Modbus TCP is served (HOST:PORT), or None: for the word to a Modbus TCP master that came here
        self.modbus_tcp: Callable[[], str | None] = lambda: None

    def _connection(self) -> _Connection:
        return _RtuConnection(self)

    def mbap_seen(self, data: bytes, headers: list[MbapHeader]) -> None:
        """Modbus TCP frames arrived here: not answered (they are no RTU frames), logged, and said once."""
        first = headers[0]
        words = f"Modbus TCP (MBAP) on the RTU-over-TCP port: transaction {first.transaction}, unit {first.unit}"
        words += (f", and {len(headers) - 1} more" if len(headers) > 1 else "") + ": not answered"
        where = self.modbus_tcp()
        use = f"use --modbus-tcp (open on {where})" if where else "use --modbus-tcp HOST:PORT (not open now)"
        self.wrong_protocol(
            data,
            words,
            f"RTU over TCP {self.name}: this looks like Modbus TCP: {use}",
            "this port answers no Modbus TCP frame, as a drive would not",
        )


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
        framer = RtuFramer(line.sim.bus.line_baud, check_gaps=False)
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

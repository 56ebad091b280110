"""TCP in front of the bus: raw RTU frames (a serial device server) and Modbus TCP (a gateway).

RTU over TCP: each connection has its own framer, so a client that leaves in
the middle of a frame costs the others nothing; every connection shares the
line's lock, so requests are served one at a time and each reply goes to the
connection that asked. A frame completes on its length (TCP has no line
timing); a broken frame is ended by 20 ms of silence.

Modbus TCP: the MBAP header is taken off, the request goes to the bus as the
RTU frame a gateway would put on the line, and the reply comes back under the
request's transaction id. Where the line stays silent (absent drive, dropped
or corrupt reply) the gateway answers exception 0x0B after its timeout, as
gateways do; a broadcast (unit 0) gets no answer.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import struct

from ..errors import C20SimError
from ..protocol import BROADCAST, RtuFramer, crc_ok, with_crc
from ..simulator import Simulator
from .endpoint import RtuEndpoint

__all__ = ["ModbusTcpServer", "RtuOverTcpServer", "parse_host_port"]

log = logging.getLogger(__name__)

#: Silence that ends a broken frame on TCP, where bytes carry no line timing.
TCP_SILENCE = 0.02
#: Modbus TCP exception 0x0B: gateway target device failed to respond.
GATEWAY_NO_RESPONSE = 0x0B


def parse_host_port(text: str, option: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:502`` for IPv6); port 0 asks the system for a free one."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise C20SimError(f"{option} {text!r}: give HOST:PORT, such as 127.0.0.1:5020 (port 0 picks a free port)")
    host = host.strip("[]")
    try:
        port = int(port_text)
    except ValueError:
        raise C20SimError(f"{option} {text!r}: the port {port_text!r} is not a number; give HOST:PORT") from None
    if not 0 <= port <= 65535:
        raise C20SimError(f"{option} {text!r}: port {port} is outside 0-65535")
    return host, port


async def _listen(handler: object, host: str, port: int, option: str) -> asyncio.Server:
    try:
        return await asyncio.start_server(handler, host, port)  # type: ignore[arg-type]
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise C20SimError(
                f"{option} {host}:{port}: the port is in use; stop the program holding it or choose another port (0 picks a free one)"
            ) from None
        if exc.errno == errno.EACCES:
            raise C20SimError(
                f"{option} {host}:{port}: permission denied; ports below 1024 need root, choose another"
            ) from None
        raise C20SimError(f"{option} {host}:{port}: cannot listen: {exc.strerror or exc}") from None


class _TcpServer:
    option = ""

    def __init__(self, sim: Simulator, line: asyncio.Lock, host: str, port: int) -> None:
        self.sim = sim
        self.line = line
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._connections: set[asyncio.StreamWriter] = set()

    @property
    def name(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"

    async def start(self) -> None:
        self._server = await _listen(self._accept, self.host, self.port, self.option)
        self.port = self._server.sockets[0].getsockname()[1]

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._connections.add(writer)
        try:
            await self._connection(reader, writer)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass  # the client left, perhaps mid-frame: that costs the others nothing
        except asyncio.CancelledError:
            pass  # shutting down: this task is the connection's top level, nothing waits on it
        finally:
            self._connections.discard(writer)
            writer.close()

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        raise NotImplementedError

    async def wait_closed(self) -> None:
        if self._server is not None:
            await self._server.wait_closed()

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for writer in list(self._connections):
            writer.close()  # the connection's read ends, and its handler with it


class RtuOverTcpServer(_TcpServer):
    """Raw RTU frames over TCP, as a serial device server carries them."""

    option = "--tcp"

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        async def send(data: bytes) -> None:
            writer.write(data)
            await writer.drain()

        framer = RtuFramer(self.sim.bus.line_baud, complete_on_length=True, check_gaps=False, silence=TCP_SILENCE)
        peer = writer.get_extra_info("peername")
        endpoint = RtuEndpoint(self.sim, framer, send, self.line, name=f"tcp {peer}")
        try:
            while data := await reader.read(4096):
                endpoint.feed(data)
        finally:
            endpoint.close()


class ModbusTcpServer(_TcpServer):
    """Modbus TCP (MBAP) in front of the RTU bus, as an Ethernet gateway."""

    option = "--modbus-tcp"

    def __init__(self, sim: Simulator, line: asyncio.Lock, host: str, port: int, *, timeout: float = 0.5) -> None:
        super().__init__(sim, line, host, port)
        self.timeout = timeout

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        loop = asyncio.get_running_loop()
        while True:
            header = await reader.readexactly(7)
            transaction, protocol, length, unit = struct.unpack(">HHHB", header)
            if protocol != 0 or not 2 <= length <= 254:
                log.info("modbus tcp: bad MBAP header %s; closing the connection", header.hex(" "))
                return
            pdu = await reader.readexactly(length - 1)
            framer = RtuFramer(self.sim.bus.line_baud, check_gaps=False)
            framer.feed(with_crc(bytes((unit,)) + pdu), loop.time())
            framer.flush()
            for event in framer.events():
                async with self.line:
                    reply = self.sim.handle(event)
                    if reply is not None:
                        await asyncio.sleep(reply.delay)
                answer: bytes | None = None
                if reply is not None and len(reply.data) >= 4 and crc_ok(reply.data):
                    answer = reply.data[1:-2]
                elif unit != BROADCAST:
                    await asyncio.sleep(self.timeout)
                    answer = bytes((pdu[0] | 0x80, GATEWAY_NO_RESPONSE))
                if answer is not None:
                    writer.write(struct.pack(">HHHB", transaction, 0, len(answer) + 1, unit) + answer)
                    await writer.drain()

"""One line, many masters: a closed connection leaves the line at once, masters are served in turn, ports are capped.

Through real sockets on loopback. A crowd connects from 127.0.0.2 (Linux routes all of 127/8 to loopback), the
polite master from 127.0.0.1, so the line tells them apart by peer address as a gateway does. Every wait is for
a condition with a deadline a busy machine does not reach; the fairness test judges latency in transactions'
time measured on this machine's own run (the polite master alone), so load slows it, it does not turn it red.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Callable

from c20sim.core.bus import FrameRecord
from c20sim.wire.registers import Reg
from tests.integration.conftest import ServeFactory, mbap_read

CROWD_HOST = "127.0.0.2"


def mbap_write(transaction: int, register: int, value: int) -> bytes:
    pdu = struct.pack(">BHH", 6, register, value)
    return struct.pack(">HHHB", transaction & 0xFFFF, 0, len(pdu) + 1, 1) + pdu


async def until(check: Callable[[], bool], what: str, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.002)


async def connect(port: int, host: str = "127.0.0.1") -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection("127.0.0.1", port, local_addr=(host, 0))


async def mbap_ask(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, transaction: int) -> bytes:
    writer.write(mbap_read(transaction, Reg.STATUS1))
    await writer.drain()
    header = await reader.readexactly(7)
    length = struct.unpack_from(">H", header, 4)[0]
    body = await reader.readexactly(length - 1)
    assert struct.unpack_from(">H", header)[0] == transaction
    return body


async def test_a_write_queued_by_a_closed_connection_never_reaches_the_drive(serve: ServeFactory) -> None:
    """A holds the line (each reply 0.3 s late); B queues four writes of the set speed behind it and closes. The
    line drops B's writes when B closes, though B's socket is not being read (four requests out): none reaches
    the drive, the line waits for nobody, and a fresh master is answered at once after A's transaction."""
    served = await serve(bus_timing=True)
    served.sim.link_faults(1).delay = 0.3
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    before = served.sim.drives[1].read(Reg.SPEED_SETPOINT)
    port = served.modbus_tcp_port
    ra, a = await connect(port)
    a.write(mbap_read(1, Reg.STATUS1))
    await a.drain()
    await until(lambda: served.server.line.busy, "A's request on the line")
    _rb, b = await connect(port)
    b.write(b"".join(mbap_write(i, Reg.SPEED_SETPOINT, 1234) for i in range(4)))
    await b.drain()
    await until(lambda: served.server.line.waiting == 4, "B's four writes to wait for the line")
    b.close()
    await until(lambda: served.server.line.waiting == 0, "B's writes to leave the line when B closes", timeout=5.0)
    await ra.readexactly(11)  # A's reply, after its 0.3 s
    body = await mbap_ask(ra, a, 2)
    assert body[:2] == bytes((3, 2)), body.hex()  # function 3, two bytes: answered
    a.close()
    writes = [r for r in seen if r.direction == "rx" and r.kind == "request" and r.data[1:2] == b"\x06"]
    assert writes == []
    assert served.sim.drives[1].read(Reg.SPEED_SETPOINT) == before

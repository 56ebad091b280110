"""One line, many masters: a closed connection leaves the line at once, masters are served in turn, ports are capped.

Through real sockets on loopback. A crowd connects from 127.0.0.2 (Linux routes all of 127/8 to loopback), the
polite master from 127.0.0.1, so the line tells them apart by peer address as a gateway does. Every wait is for
a condition with a deadline a busy machine does not reach; the fairness test judges latency in transactions'
time measured on this machine's own run (the polite master alone), so load slows it, it does not turn it red.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import subprocess
import sys
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path

import pytest

from c20sim.core.bus import FrameRecord
from c20sim.wire.protocol import with_crc
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file
from tests.integration.conftest import ServeFactory, mbap_read

pytestmark = pytest.mark.serial  # a polite master's reply times beside crowds, in real time: .ci/run runs it alone

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


CROWD_READ = (
    Reg.SPEED_SETPOINT
)  #: the crowd reads a register the polite master does not: the frame log tells them apart


def crowd_requests(records: list[FrameRecord], crowd: bytes) -> int:
    return sum(1 for r in records if r.direction == "rx" and r.kind == "request" and r.data == crowd)


async def test_500_connections_that_queue_and_close_leave_the_line_at_once(serve: ServeFactory) -> None:
    """500 Modbus TCP connections from 16 addresses each queue four reads (each address's 32 queued, the rest
    refused 0x06 at once) and close. Of their requests at most the one on the line when the last closed is served
    after it; nothing is left waiting; the polite master's read that follows is the next on the line."""
    served = await serve(bus_timing=True, max_connections=600, gateway_timeout=60.0)
    line = served.server.line
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    crowd_frame = with_crc(bytes((1,)) + struct.pack(">BHH", 3, CROWD_READ, 1))
    port = served.modbus_tcp_port
    writers: list[asyncio.StreamWriter] = []
    try:
        for i in range(500):
            _r, w = await connect(port, f"127.0.1.{1 + i % 16}")
            w.write(b"".join(mbap_read(4 * i + k, CROWD_READ) for k in range(4)))
            writers.append(w)
        await until(lambda: line.waiting >= 16 * 32 - 16, "the crowd's requests to fill their addresses' queues")
        assert line.waiting <= 16 * 32
    finally:
        for w in writers:
            w.close()
    closed = len(seen)
    await until(lambda: line.waiting == 0, "the closed connections' requests to leave the line")
    ra, a = await connect(port)
    body = await mbap_ask(ra, a, 1)
    a.close()
    assert body[:2] == bytes((3, 2)), body.hex()
    assert crowd_requests(seen[closed:], crowd_frame) <= 1
    assert line.cancelled >= 16 * 32 - 17


async def _poll(port: int, count: int, interval: float) -> list[float]:
    """A polite master on 127.0.0.1: one read every ``interval``; each read's time to its reply."""
    reader, writer = await connect(port)
    times: list[float] = []
    try:
        for i in range(count):
            start = time.perf_counter()
            body = await asyncio.wait_for(mbap_ask(reader, writer, i), timeout=10.0)
            times.append(time.perf_counter() - start)
            assert body[:2] == bytes((3, 2)), body.hex()
            await asyncio.sleep(interval)
    finally:
        writer.close()
    return sorted(times)


async def _pipeliner(port: int, stop: asyncio.Event) -> None:
    """Keeps four reads in flight (a pipelining Modbus TCP client); after an exception answer, waits 0.1 s."""
    reader, writer = await connect(port, CROWD_HOST)
    transaction = 0
    try:
        while not stop.is_set():
            writer.write(b"".join(mbap_read(transaction + k, CROWD_READ) for k in range(4)))
            transaction += 4
            refused = False
            for _ in range(4):
                header = await reader.readexactly(7)
                body = await reader.readexactly(struct.unpack_from(">H", header, 4)[0] - 1)
                refused = refused or body[0] & 0x80 != 0
            if refused:
                await asyncio.sleep(0.1)
    except (ConnectionError, asyncio.IncompleteReadError):
        pass
    finally:
        writer.close()


async def _non_reader(port: int, stop: asyncio.Event) -> None:
    """Sends reads and never reads a reply."""
    _reader, writer = await connect(port, CROWD_HOST)
    try:
        transaction = 0
        while not stop.is_set():
            writer.write(b"".join(mbap_read(transaction + k, CROWD_READ) for k in range(64)))
            transaction += 64
            try:
                await asyncio.wait_for(writer.drain(), timeout=0.1)
            except TimeoutError:
                await asyncio.sleep(0.1)  # the server reads no more of it: its buffers are full
    except ConnectionError:
        pass
    finally:
        writer.close()


@pytest.mark.parametrize("crowd", ["1 pipelining client", "20 non-readers", "500 connections"])
async def test_a_polite_master_keeps_its_share_beside_a_crowd(serve: ServeFactory, crowd: str) -> None:
    """A polite master (one read every 30 ms, from 127.0.0.1) beside a crowd from 127.0.0.2: its 99th percentile
    stays within two transactions' time of its fair share. Two peers share the line in turn, so its fair share is
    the crowd's transaction on the line when it asks, then its own: its own 99th percentile alone plus one
    transaction; a transaction's time is its median alone, both measured first on this machine (the crowd's
    clients run on the test's loop too, so load lengthens both)."""
    served = await serve(bus_timing=True, max_connections=600)
    port = served.modbus_tcp_port
    alone = await _poll(port, 40, 0.03)
    alone_p99 = alone[int(0.99 * (len(alone) - 1))]
    median = alone[len(alone) // 2]  # one transaction's time, as this machine delivers it
    stop = asyncio.Event()
    if crowd == "1 pipelining client":
        tasks = [asyncio.create_task(_pipeliner(port, stop))]
    elif crowd == "20 non-readers":
        tasks = [asyncio.create_task(_non_reader(port, stop)) for _ in range(20)]
    else:
        tasks = [asyncio.create_task(_pipeliner(port, stop)) for _ in range(500)]
    try:
        await until(lambda: served.server.line.waiting >= 1, "the crowd to queue for the line")
        beside = await _poll(port, 100, 0.03)
    finally:
        stop.set()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    p99 = beside[int(0.99 * (len(beside) - 1))]
    fair = alone_p99 + median
    assert p99 <= fair + 2 * median, (
        f"p99 {p99 * 1e3:.1f} ms beside {crowd}; fair share {fair * 1e3:.1f} ms, a transaction {median * 1e3:.1f} ms"
    )


@pytest.mark.parametrize("protocol", ["tcp", "modbus_tcp"])
async def test_a_port_at_its_cap_closes_the_next_connection_with_one_log_line(
    serve: ServeFactory, protocol: str, caplog: pytest.LogCaptureFixture
) -> None:
    """--max-connections 2: the third and later connections are closed at once (the client reads end of file),
    one log line says so for all five; the two taken are still answered, and when one leaves another gets in."""
    served = await serve(max_connections=2)
    server = served.server.endpoints.tcp if protocol == "tcp" else served.server.endpoints.modbus_tcp
    assert server is not None
    port = server.port
    taken = [await connect(port) for _ in range(2)]
    await until(lambda: len(server.connections) == 2, "two connections taken")
    for _ in range(5):
        reader, writer = await connect(port)
        assert await asyncio.wait_for(reader.read(100), timeout=10.0) == b""
        writer.close()
    refusals = [r for r in caplog.records if "refused a connection" in r.getMessage()]
    assert len(refusals) == 1, [r.getMessage() for r in refusals]
    assert f"{server.option} {server.name}: refused a connection from ('127.0.0.1'," in refusals[0].getMessage()
    assert "2 connections are open, the most it takes (--max-connections)" in refusals[0].getMessage()
    assert server.refused == 5
    ra, a = taken[0]
    if protocol == "modbus_tcp":
        assert (await mbap_ask(ra, a, 7))[:2] == bytes((3, 2))
    a.close()
    await until(lambda: len(server.connections) == 1, "one connection to leave")
    rc, c = await connect(port)
    if protocol == "modbus_tcp":
        assert (await mbap_ask(rc, c, 8))[:2] == bytes((3, 2))
    else:
        c.write(with_crc(bytes((1,)) + struct.pack(">BHH", 3, Reg.STATUS1, 1)))
        reply = await asyncio.wait_for(rc.readexactly(7), timeout=10.0)
        assert reply[:3] == bytes((1, 3, 2))
    await until(lambda: len(server.connections) == 2, "the new connection taken")
    c.close()
    taken[1][1].close()


async def test_a_request_that_waited_past_the_gateway_timeout_is_answered_0x0B_and_never_put_on_the_line(
    serve: ServeFactory,
) -> None:
    """--gateway-timeout 0.2 and a reply held 0.5 s: the request queued behind it waits past 0.2 s and is answered
    exception 0x0B (gateway target failed to respond) without going on the line."""
    served = await serve(bus_timing=True, gateway_timeout=0.2)
    served.sim.link_faults(1).delay = 0.5
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    ra, a = await connect(served.modbus_tcp_port)
    rb, b = await connect(served.modbus_tcp_port)
    a.write(mbap_read(1, Reg.STATUS1))
    await a.drain()
    await until(lambda: served.server.line.busy, "A's request on the line")
    body = await asyncio.wait_for(mbap_ask(rb, b, 2), timeout=10.0)
    assert body == bytes((0x83, 0x0B))
    await ra.readexactly(11)
    requests = [r for r in seen if r.direction == "rx" and r.kind == "request"]
    assert len(requests) == 1  # B's never went on the line
    assert served.server.line.expired == 1
    a.close()
    b.close()


def test_the_served_cli_drops_a_closed_connections_writes_too(tmp_path: Path) -> None:
    """The same through ``c20sim serve`` (uvloop, bus timing as shipped), its replies held 0.3 s through the control
    API: B's four writes queued behind A's read never reach the drive once B has closed."""
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--modbus-tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"]
    proc = subprocess.Popen([*command, "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        info = wait_for_ready_file(ready, proc)
        control = info["control"].rstrip("/")
        port = int(info["modbus_tcp"].rsplit(":", 1)[1])

        def api(method: str, path: str, body: object) -> None:
            request = urllib.request.Request(
                control + path,
                data=json.dumps(body).encode(),
                method=method,
                headers={"Content-Type": "application/json"},
            )
            urllib.request.urlopen(request, timeout=10).close()

        def ask(sock: socket.socket, frame: bytes) -> bytes:
            sock.sendall(frame)
            header = recv(sock, 7)
            return recv(sock, struct.unpack_from(">H", header, 4)[0] - 1)

        def recv(sock: socket.socket, n: int) -> bytes:
            data = b""
            while len(data) < n:
                chunk = sock.recv(n - len(data))
                assert chunk, "the server closed the connection"
                data += chunk
            return data

        a = socket.create_connection(("127.0.0.1", port), timeout=10)
        assert ask(a, mbap_read(1, Reg.SPEED_SETPOINT))[:2] == bytes((3, 2))
        before = ask(a, mbap_read(2, Reg.SPEED_SETPOINT))
        api("PATCH", "/drives/1/link", {"delay": 0.3})
        a.sendall(mbap_read(3, Reg.STATUS1))  # on the line before B connects, where it holds it 0.3 s
        b = socket.create_connection(("127.0.0.1", port), timeout=10, source_address=(CROWD_HOST, 0))
        b.sendall(b"".join(mbap_write(i, Reg.SPEED_SETPOINT, 1234) for i in range(4)))
        b.close()
        recv(a, 11)  # A's reply, 0.3 s late
        api("DELETE", "/drives/1/link", {})
        assert ask(a, mbap_read(4, Reg.SPEED_SETPOINT)) == before  # B's writes never reached the drive
        a.close()
    finally:
        proc.kill()
        proc.wait()
        assert proc.stderr is not None
        proc.stderr.close()


async def test_over_rtu_over_tcp_a_request_past_the_gateway_timeout_is_dropped(serve: ServeFactory) -> None:
    """RTU over TCP, --gateway-timeout 0.2, a reply held 0.5 s: B's read that waited behind it past 0.2 s gets no
    answer and never goes on the line (a device server's master has given up); B's next read is answered."""
    served = await serve(bus_timing=True, gateway_timeout=0.2)
    served.sim.link_faults(1).delay = 0.5
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    read = with_crc(bytes((1,)) + struct.pack(">BHH", 3, Reg.STATUS1, 1))
    ra, a = await connect(served.tcp_port)
    rb, b = await connect(served.tcp_port)
    a.write(read)
    await a.drain()
    await until(lambda: served.server.line.busy, "A's request on the line")
    b.write(read)
    await b.drain()
    assert await asyncio.wait_for(ra.readexactly(7), timeout=10.0) == bytes.fromhex("0103020003f845")
    await until(lambda: served.server.line.expired == 1, "B's request to expire")
    served.sim.link_faults(1).delay = 0.0
    b.write(read)
    await b.drain()
    assert await asyncio.wait_for(rb.readexactly(7), timeout=10.0) == bytes.fromhex("0103020003f845")
    requests = [r for r in seen if r.direction == "rx" and r.kind == "request"]
    assert len(requests) == 2  # A's, and B's second: B's first never went on the line, so had no reply
    a.close()
    b.close()

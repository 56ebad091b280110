"""No client can starve the bus: backpressure per connection, and a closed connection's requests dropped.

Through real sockets: a raw client sends a burst of 5,000 read requests and
closes, then a fresh pymodbus client must be answered, and the burst must not
have been served behind its back. A client that sends without ever reading
must not grow the server's memory while another client's polls are answered.
A connection has its share of the line (one request; four on Modbus TCP) and
no more while another waits. ``bench/abuse.py`` measures the reply times;
tests count, they do not time: every wait is for a condition, with deadlines
a busy machine does not reach, so load makes these tests slower, not red.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusTcpClient, ModbusTcpClient
from pymodbus.exceptions import ModbusIOException

from c20sim.core.bus import FrameRecord
from c20sim.wire.protocol import ReadRequest, ReadResponse, encode
from c20sim.wire.registers import Reg
from tests.conftest import wait_for_ready_file
from tests.integration.conftest import ServeFactory, mbap_read

BURST = 5000

RTU_READ = encode(ReadRequest(1, Reg.STATUS1, 1))
#: The burst reads a register the poller does not, so the frame log tells the two apart.
RTU_BURST_READ = encode(ReadRequest(1, Reg.SPEED_SETPOINT, 1))


#: Requests a connection may have on the line at once: one for an RTU master (on a pty or RTU over TCP), four
#: for a pipelining Modbus TCP client (README). Written out here, not imported, so a changed constant fails.
LIMIT = {"pty": 1, "tcp": 1, "modbus_tcp": 4}


async def until(check: Callable[[], bool], what: str, timeout: float = 20.0) -> None:
    """Poll ``check`` on the test's loop (the served simulator runs on it too) until it holds."""
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        await asyncio.sleep(0.005)


def burst_served(records: list[FrameRecord]) -> int:
    return sum(1 for r in records if r.direction == "rx" and r.kind == "request" and r.data == RTU_BURST_READ)


@pytest.mark.parametrize("protocol", ["tcp", "modbus_tcp"])
async def test_a_closed_burst_is_dropped_and_a_fresh_client_is_answered(serve: ServeFactory, protocol: str) -> None:
    served = await serve()
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    port = served.tcp_port if protocol == "tcp" else served.modbus_tcp_port
    if protocol == "tcp":
        burst = RTU_BURST_READ * BURST
        framer = FramerType.RTU
    else:
        burst = b"".join(mbap_read(i, Reg.SPEED_SETPOINT) for i in range(BURST))
        framer = FramerType.SOCKET
    _reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(burst)
    await writer.drain()
    writer.close()
    await writer.wait_closed()

    client = AsyncModbusTcpClient("127.0.0.1", port=port, framer=framer, timeout=10.0, retries=0)
    assert await client.connect()
    try:
        result = await client.read_holding_registers(Reg.STATUS1, count=1, device_id=1)
    finally:
        client.close()
    assert not result.isError()
    # Both connections gone and nothing waiting on the line: no more of the burst can be served.
    tcp_server = served.server.endpoints.tcp if protocol == "tcp" else served.server.endpoints.modbus_tcp
    assert tcp_server is not None
    await until(lambda: not tcp_server.connections, "both connections to be gone")
    assert served.server.line.waiting == 0
    count = burst_served(seen)
    # Served one at a time, 2 ms each, until the server sees the close (milliseconds; a busy machine may take
    # longer): 500 is a second of serving, a tenth of the burst.
    assert count < BURST // 10, f"{count} of the closed connection's {BURST} requests were served"


@pytest.mark.parametrize("transport", ["pty", "tcp", "modbus_tcp"])
async def test_a_connection_that_pipelines_lets_another_in_after_its_share(serve: ServeFactory, transport: str) -> None:
    """A sends ten requests at once; each reply holds the line 0.5 s. B, on RTU over TCP, asks once while A's
    first is on the line: the line serves its masters in turn, so B goes next, after A's one request, though A
    has four waiting on Modbus TCP. Told from the frame log's order, not from times: a busier machine only makes it
    slower. (The gateway's timeout is raised: at its default of 1 s, requests that waited two 0.5 s replies
    would be dropped.)"""
    served = await serve(gateway_timeout=30.0)
    served.sim.link_faults(1).delay = 0.5
    seen: list[FrameRecord] = []
    served.sim.bus.subscribe(seen.append)
    closers: list[Callable[[], object]] = []
    try:
        if transport == "pty":
            fd = os.open(served.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            closers.append(lambda: os.close(fd))
            tty.setraw(fd)
            os.write(fd, RTU_READ * 10)
        else:
            port = served.tcp_port if transport == "tcp" else served.modbus_tcp_port
            _ra, a = await asyncio.open_connection("127.0.0.1", port)
            closers.append(a.close)
            a.write(RTU_READ * 10 if transport == "tcp" else b"".join(mbap_read(i, Reg.STATUS1) for i in range(10)))
            await a.drain()
        await until(lambda: served.server.line.busy, "A's first request on the line")
        _rb, b = await asyncio.open_connection("127.0.0.1", served.tcp_port)
        closers.append(b.close)
        b.write(RTU_BURST_READ)
        await b.drain()
        await until(lambda: burst_served(seen) == 1, "B's request to be served")
    finally:
        for close in closers:
            close()
    requests = [r.data for r in seen if r.direction == "rx" and r.kind == "request"]
    before_b = requests.index(RTU_BURST_READ)
    assert before_b == 1, f"B was served after {before_b} of A's requests; expected 1 (turns)"


@pytest.mark.parametrize("protocol", ["tcp", "modbus_tcp"])
async def test_a_connection_with_its_share_on_the_line_is_not_read(serve: ServeFactory, protocol: str) -> None:
    """Ten requests at once, the first reply held for the whole test: the line holds the connection's share (one
    request; four on Modbus TCP), no more, and its socket is not read (the rest waits in the kernel)."""
    served = await serve()
    served.sim.link_faults(1).delay = 30.0
    line = served.server.line
    limit = LIMIT[protocol]
    port = served.tcp_port if protocol == "tcp" else served.modbus_tcp_port
    tcp_server = served.server.endpoints.tcp if protocol == "tcp" else served.server.endpoints.modbus_tcp
    assert tcp_server is not None
    _reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(RTU_READ * 10 if protocol == "tcp" else b"".join(mbap_read(i, Reg.STATUS1) for i in range(10)))
        await writer.drain()
        # Once the share is on the line, nothing can take any of it off for 30 s.
        await until(lambda: line.busy and line.waiting >= limit - 1, "the connection's requests on the line")
        (connection,) = tcp_server.connections
        assert connection.transport is not None
        assert (line.waiting + 1, connection.transport.is_reading()) == (limit, False)
    finally:
        writer.close()


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError(f"no VmRSS for {pid}")


@pytest.fixture
def server(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], dict[str, str]]]:
    ready = tmp_path / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0"]
    proc = subprocess.Popen([*command, "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        yield proc, wait_for_ready_file(ready, proc)
    finally:
        proc.kill()
        proc.wait()
        assert proc.stderr is not None
        proc.stderr.close()


#: What the flooder sends at most: far more than the kernel holds for one connection (its send buffer and the
#: server's receive buffer), so that a server which reads it all shows it in its memory.
FLOOD_CAP = 64 * 1024 * 1024
#: The flooder has been held this long at a stretch: the server has stopped reading it.
HELD = 0.5


def flood_without_reading(port: int, payload: bytes, stop: threading.Event, sent: list[int]) -> None:
    """Send ``payload`` over and over, never read a byte back, until the server has held it for :data:`HELD`
    seconds at a stretch after ``stop`` (the polls are done), or :data:`FLOOD_CAP` bytes went."""
    with socket.create_connection(("127.0.0.1", port)) as sock:
        sock.setblocking(False)
        chunk = payload * 512
        held_since: float | None = None
        while sent[0] < FLOOD_CAP:
            try:
                sent[0] += sock.send(chunk)
                held_since = None
            except BlockingIOError:  # the server stopped reading: exactly what it should do
                now = time.monotonic()
                held_since = now if held_since is None else held_since
                if stop.is_set() and now - held_since >= HELD:
                    return
                time.sleep(0.01)


@pytest.mark.parametrize("protocol", ["tcp", "modbus_tcp"])
def test_a_client_that_never_reads_costs_no_memory_and_locks_no_one_out(
    server: tuple[subprocess.Popen[bytes], dict[str, str]], protocol: str
) -> None:
    """A client floods requests and never reads a reply; another polls 20 times meanwhile. Every poll is answered
    (each may take up to 10 s: a busy machine is slower, not wrong), the flood ends once the server has stopped
    reading it (held half a second at a stretch) or 64 MiB went, and the server's memory has not grown by more
    than 20 MiB: what the server has not read stays in the kernel. A server that never stops reading takes all
    64 MiB into its memory, however fast or slow the machine."""
    proc, info = server
    port = int(info[protocol].rsplit(":", 1)[1])
    payload = RTU_READ if protocol == "tcp" else mbap_read(1, Reg.STATUS1)
    framer = FramerType.RTU if protocol == "tcp" else FramerType.SOCKET
    before = rss_kib(proc.pid)
    stop, sent = threading.Event(), [0]
    flooder = threading.Thread(target=flood_without_reading, args=(port, payload, stop, sent), daemon=True)
    flooder.start()
    answered = asked = 0
    peak = before
    poller = ModbusTcpClient("127.0.0.1", port=port, framer=framer, timeout=10.0, retries=0)
    try:
        assert poller.connect()
        for _ in range(20):
            asked += 1
            with contextlib.suppress(ModbusIOException):  # unanswered: counted by asked - answered
                answered += not poller.read_holding_registers(Reg.STATUS1, count=1, device_id=1).isError()
            peak = max(peak, rss_kib(proc.pid))
    finally:
        poller.close()
        stop.set()
    flooder.join(120)
    assert not flooder.is_alive(), "the flood did not end in 120 s"
    peak = max(peak, rss_kib(proc.pid))
    grown_mib = (peak - before) / 1024
    assert sent[0] > 0
    assert answered == asked, f"{asked - answered} of {asked} polls unanswered while a client flooded"
    assert grown_mib < 20, (
        f"RSS grew by {grown_mib:.1f} MiB ({before} KiB -> {peak} KiB) while a client sent {sent[0] >> 20} MiB"
    )


async def test_a_pipelined_frame_split_across_reads_is_not_broken_while_the_connection_waits(
    serve: ServeFactory,
) -> None:
    """RTU over TCP, a reply delayed 1 s: a second request sent meanwhile in two pieces, 50 ms apart, is not read
    until the first is answered, and its first piece must not be timed out as a broken frame (20 ms of silence)
    while the second waits in the kernel's buffer. The 50 ms are a silence the test makes (more than the 20 ms);
    a busy machine may lengthen them, by up to 0.95 s, and the test still holds. (The gateway's timeout is raised:
    at its default of 1 s, the second request, which waits the first's 1 s, would be dropped.)"""
    served = await serve(gateway_timeout=30.0)
    served.sim.link_faults(1).delay = 1.0
    first, second = RTU_READ, RTU_BURST_READ
    reader, writer = await asyncio.open_connection("127.0.0.1", served.tcp_port)
    try:
        writer.write(first + second[:3])
        await writer.drain()
        await until(lambda: served.server.line.busy, "the first request on the line")
        await asyncio.sleep(0.05)  # the rest of the second frame comes later, while the first is on the line
        writer.write(second[3:])
        await writer.drain()
        replies = await asyncio.wait_for(reader.readexactly(14), timeout=10.0)
    finally:
        writer.close()
    assert replies[:7] == encode(ReadResponse(1, (3,))), replies.hex(" ")
    assert replies[7:] == encode(ReadResponse(1, (0,))), replies.hex(" ")

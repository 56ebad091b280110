"""Bus timing on every transport (issue 27): a transaction holds the shared line for its RS485 time.

The line's time is computed here from the serial settings (``transaction_time`` at the drive's baud, the
character size of --parity/--stopbits, the profile's turnaround), never written in: what the tests assert is
a lower bound (N transactions never take less than the line's time for them), which no load on the machine
can break, and the line's own accounting (the counters), which is exact.
"""

from __future__ import annotations

import asyncio
import itertools
import time
from collections.abc import AsyncIterator

import pytest
from pymodbus import FramerType
from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient

from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.serve import ServeOptions, Server
from c20sim.transport.line import EARLY, DueTimer
from c20sim.wire.protocol import (
    FrameEvent,
    FrameKind,
    ReadRequest,
    char_bits,
    encode,
    frame_time,
    transaction_time,
    with_crc,
)
from c20sim.wire.registers import Reg
from tests.integration.conftest import mbap_read

pytestmark = pytest.mark.serial  # a transaction's time on the line is real time: .ci/run runs it alone

N = 12


@pytest.fixture
async def started() -> AsyncIterator[list[Server]]:
    servers: list[Server] = []
    yield servers
    for server in servers:
        await server.aclose()


async def serve(started: list[Server], **options: object) -> Server:
    sim = Simulator(load_profile("c20-400hr"), (1,), clock=VirtualClock())
    settings: dict[str, object] = {"tcp": "127.0.0.1:0", "modbus_tcp": "127.0.0.1:0", "bus_timing": True, **options}
    server = Server(sim, ServeOptions(**settings))  # type: ignore[arg-type]
    await server.start()
    started.append(server)
    return server


def one_read_time(server: Server, parity: str = "N") -> float:
    """The line's time of one single-register read at the drive's baud, the line's format, the turnaround."""
    sim = server.sim
    turnaround = sim.profile.protocol.turnaround_ms / 1000.0
    return transaction_time(8, 7, sim.bus.line_baud, char_bits(8, parity, 1), turnaround)


async def client(server: Server, framer: FramerType) -> AsyncModbusTcpClient:
    if framer is FramerType.RTU:
        assert server.endpoints.tcp is not None
        port = server.endpoints.tcp.port
    else:
        assert server.endpoints.modbus_tcp is not None
        port = server.endpoints.modbus_tcp.port
    master = AsyncModbusTcpClient("127.0.0.1", port=port, framer=framer, timeout=5.0, retries=0)
    assert await master.connect()
    return master


async def reads(master: AsyncModbusTcpClient | AsyncModbusSerialClient, n: int) -> None:
    for _ in range(n):
        reply = await master.read_holding_registers(Reg.STATUS1, count=1, device_id=1)
        assert reply.registers == [3]


async def test_a_master_on_the_pty_meets_the_lines_time_too(started: list[Server]) -> None:
    server = await serve(started, pty=True)
    assert server.endpoints.pty is not None
    master = AsyncModbusSerialClient(server.endpoints.pty.path, framer=FramerType.RTU, timeout=5.0, retries=0)
    assert await master.connect()
    try:
        began = time.monotonic()
        await reads(master, N)
        took = time.monotonic() - began
    finally:
        master.close()
    assert took >= N * one_read_time(server)
    assert server.sim.bus.counters_of(1).line_busy_s == pytest.approx(N * one_read_time(server), rel=1e-9)


@pytest.mark.parametrize(("framer", "parity"), [(FramerType.RTU, "N"), (FramerType.RTU, "E"), (FramerType.SOCKET, "N")])
async def test_n_transactions_never_take_less_than_the_lines_time(
    started: list[Server], framer: FramerType, parity: str
) -> None:
    server = await serve(started, parity=parity)
    master = await client(server, framer)
    try:
        began = time.monotonic()
        await reads(master, N)
        took = time.monotonic() - began
    finally:
        master.close()
    line = N * one_read_time(server, parity)
    assert took >= line
    counters = server.sim.bus.counters_of(1)
    assert counters.line_busy_s == pytest.approx(line, rel=1e-9)
    assert 0.0 < counters.line_share <= 1.0


async def test_two_masters_share_the_line(started: list[Server]) -> None:
    server = await serve(started)
    first, second = await client(server, FramerType.RTU), await client(server, FramerType.SOCKET)
    try:
        began = time.monotonic()
        await asyncio.gather(reads(first, N), reads(second, N))
        took = time.monotonic() - began
    finally:
        first.close()
        second.close()
    # Each master alone would take N transactions' time; together they queue as behind a serial device server.
    line = 2 * N * one_read_time(server)
    assert took >= line
    assert server.sim.bus.counters_of(1).line_busy_s == pytest.approx(line, rel=1e-9)


async def test_masters_that_queue_for_the_line_are_audited_at_their_line_times(started: list[Server]) -> None:
    """Two RTU-over-TCP masters that each wait for their replies, and a Modbus TCP client with two requests in
    flight, queue for the line as behind a serial device server or a gateway: each request goes on the line
    when the last transaction ends, and the frame log and the live audit see it there. No collision, no early
    retry (before, a request was stamped when it arrived, mid-transaction, and the audit called it one). One
    master sending its next request before its own reply still collides."""
    from c20sim.control import liveaudit

    server = await serve(started)
    first, second = await client(server, FramerType.RTU), await client(server, FramerType.RTU)
    try:
        await asyncio.gather(reads(first, N), reads(second, N))
    finally:
        first.close()
        second.close()
    assert server.endpoints.modbus_tcp is not None
    reader, writer = await asyncio.open_connection("127.0.0.1", server.endpoints.modbus_tcp.port)
    writer.write(mbap_read(1, Reg.MOTOR_SPEED) + mbap_read(2, Reg.MOTOR_SPEED))
    answers = [await reader.readexactly(11) for _ in range(2)]
    writer.close()
    assert [answer[:2] for answer in answers] == [b"\0\x01", b"\0\x02"]

    audit = liveaudit.of(server.sim)
    assert audit is not None
    assert audit.findings() == []
    requests = [record.t for record in server.sim.bus.records if str(record.direction) == "rx"]
    assert len(requests) == 2 * N + 2
    gaps = [later - earlier for earlier, later in itertools.pairwise(requests)]
    assert min(gaps) >= one_read_time(server) - EARLY  # one transaction at a time on the line

    # one RTU master sending its next request before its reply: on a real line the two collide
    assert server.endpoints.tcp is not None
    reader, writer = await asyncio.open_connection("127.0.0.1", server.endpoints.tcp.port)
    writer.write(encode(ReadRequest(1, Reg.STATUS1, 1)) + encode(ReadRequest(1, Reg.STATUS2, 1)))
    assert len(await reader.readexactly(14)) == 14
    writer.close()
    assert [(f.rule, f.drive) for f in audit.findings()] == [("collision", 1)]


async def test_a_masters_second_request_behind_another_waiting_master_is_logged_in_order(
    started: list[Server],
) -> None:
    """Master A reads; B writes two reads at once while A's is on the line. B's first waits for the line and is
    logged when the line takes it; its second, read with it, collides with B's own reply, and is logged no
    earlier than the first (it was logged 11 ms before it, and the audit read a gap of -11 ms)."""
    from c20sim.control import liveaudit

    server = await serve(started)
    assert server.endpoints.tcp is not None
    port = server.endpoints.tcp.port
    a_reader, a_writer = await asyncio.open_connection("127.0.0.1", port)
    b_reader, b_writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        a_writer.write(encode(ReadRequest(1, Reg.STATUS1, 1)))
        deadline = time.monotonic() + 5.0
        while not server.line.busy:  # A's read on the line
            assert time.monotonic() < deadline, "A's request never reached the line"
            await asyncio.sleep(0.0005)
        b_writer.write(encode(ReadRequest(1, Reg.STATUS1, 1)) + encode(ReadRequest(1, Reg.STATUS2, 1)))
        await a_reader.readexactly(7)
        await b_reader.readexactly(14)
    finally:
        a_writer.close()
        b_writer.close()
    requests = [record.t for record in server.sim.bus.records if str(record.direction) == "rx"]
    assert len(requests) == 3
    assert requests == sorted(requests)
    audit = liveaudit.of(server.sim)
    assert audit is not None
    (collision,) = audit.findings()
    assert collision.rule == "collision"
    assert collision.figure.startswith("a request 0.0 ms after the last")


async def test_the_line_is_held_for_the_transaction_or_only_the_turnaround(started: list[Server]) -> None:
    timed = await serve(started)
    plain = await serve(started, bus_timing=False)
    request = encode(ReadRequest(1, Reg.STATUS1, 1))
    for server, hold in ((timed, one_read_time(timed)), (plain, timed.sim.profile.protocol.turnaround_ms / 1000)):
        line = server.line
        got: list[object] = []
        before = time.perf_counter()  # the ports' clock, which free_at is on
        line.submit(FrameEvent(FrameKind.FRAME, request, before), got.append)
        after = time.perf_counter()
        assert line.busy and got == []  # the reply waits for the line's time
        free_at = line.free_at
        assert free_at is not None and before + hold <= free_at <= after + hold
        while not got:
            await asyncio.sleep(0.001)
        assert not line.busy


async def test_a_silent_request_holds_the_line_for_its_frame(started: list[Server]) -> None:
    server = await serve(started)
    line = server.line
    got: list[object] = []
    before = time.perf_counter()  # the ports' clock, which free_at is on
    line.submit(FrameEvent(FrameKind.FRAME, with_crc(bytes.fromhex("07 03 21 00 00 01")), before), got.append)
    assert got == [None]  # no drive at 7: silence, known at once
    assert line.busy  # but the request was on the line
    free_at = line.free_at
    assert free_at is not None and free_at >= before + frame_time(8, 19200, 10)


def test_back_to_back_transactions_never_outrun_the_line_on_uvloop() -> None:
    """A master that sends each request the moment its reply comes, on serve's loop: a reply handed over up to
    EARLY before its time does not shorten the line, so N transactions take N line times, less EARLY at most
    (only the last reply can come early). Before, each reply's early half millisecond was the next one's gain:
    a back-to-back master got 75.5 reads a second where the line carries 74.3."""
    import uvloop  # serve's loop

    n = 40
    request = encode(ReadRequest(1, Reg.STATUS1, 1))

    async def back_to_back() -> tuple[float, float]:
        server = await serve([])
        try:
            assert server.endpoints.tcp is not None
            reader, writer = await asyncio.open_connection("127.0.0.1", server.endpoints.tcp.port)
            began = time.perf_counter()
            for _ in range(n):
                writer.write(request)
                assert (await reader.readexactly(7))[:3] == bytes.fromhex("01 03 02")
            took = time.perf_counter() - began
            writer.close()
            return took, one_read_time(server)
        finally:
            await server.aclose()

    took, line = uvloop.run(back_to_back())
    assert took >= n * line - EARLY, f"{n} reads in {took * 1000:.2f} ms; the line needs {n * line * 1000:.2f} ms"


def test_a_modbus_tcp_request_is_stamped_on_the_ports_clock_on_uvloop() -> None:
    """A Modbus TCP request's time is its arrival on the clock every port stamps with (time.perf_counter), never
    before it was sent: uvloop's loop time, which stamped it before, counts whole milliseconds from the start
    of the loop's turn, up to a millisecond early, beside RTU frames stamped to the microsecond."""
    import uvloop  # serve's loop

    async def stamps() -> list[tuple[float, float]]:
        server = await serve([], bus_timing=False)
        try:
            assert server.endpoints.modbus_tcp is not None
            reader, writer = await asyncio.open_connection("127.0.0.1", server.endpoints.modbus_tcp.port)
            sent: list[float] = []
            for tid in range(8):
                await asyncio.sleep(0.0003 * tid)  # at other points of the loop's millisecond
                sent.append(time.perf_counter())
                writer.write(mbap_read(tid, Reg.MOTOR_SPEED))
                await reader.readexactly(11)
            writer.close()
            logged = [record.t for record in server.sim.bus.records if str(record.direction) == "rx"]
            return list(zip(sent, logged, strict=True))
        finally:
            await server.aclose()

    for sent, logged in uvloop.run(stamps()):
        assert logged >= sent, f"logged {(sent - logged) * 1e6:.0f} us before it was sent"


async def _fire_times(hold: float, count: int, *, busy: bool = False) -> list[float]:
    """How long after each due time a ``DueTimer`` called back (negative: early), on the running loop; ``busy``:
    while another task turns the loop without a pause (a serving loop under load)."""
    loop = asyncio.get_running_loop()
    lateness: list[float] = []
    if busy:

        async def spin() -> None:
            while True:
                await asyncio.sleep(0)

        spinner = asyncio.ensure_future(spin())
        lateness = await _fire_times(hold, count)
        spinner.cancel()
        return lateness
    for i in range(count):
        fired = loop.create_future()
        due = time.perf_counter() + hold
        DueTimer(loop, due, lambda f=fired: f.set_result(time.perf_counter()))
        lateness.append(await fired - due)
        await asyncio.sleep(0.0003 * (i % 5))  # start at other points of the loop's millisecond
    return lateness


@pytest.mark.parametrize("busy", [False, True], ids=["idle", "busy"])
@pytest.mark.parametrize("hold", [0.013458, 0.0005, 0.002])
def test_a_held_reply_is_handed_over_at_most_half_a_millisecond_early_on_uvloop(hold: float, busy: bool) -> None:
    # uvloop rounds a delay to whole milliseconds, and a busy loop counts from a truncated clock: a plain
    # call_later(13.458 ms) fires 0.3-1.5 ms early, and a master would see a line faster than the real one.
    import uvloop  # serve's loop (a dependency wherever serve runs on it)

    lateness = uvloop.run(_fire_times(hold, 40, busy=busy))
    assert min(lateness) >= -EARLY, f"{-min(lateness) * 1e6:.0f} us early"


@pytest.mark.parametrize("hold", [0.013458, 0.0005])
async def test_a_held_reply_is_never_handed_over_before_its_time_on_asyncio(hold: float) -> None:
    lateness = await _fire_times(hold, 40)
    assert min(lateness) >= 0.0, f"{-min(lateness) * 1e6:.0f} us early"

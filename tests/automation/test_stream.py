"""``GET /stream``: telemetry and frames over a WebSocket; a slow reader skips and is told, never slows the wire.

The simulator is served on a background thread as serve serves it (RTU over
TCP and the control API, port 0); the stream is read by aiohttp's own
WebSocket client and the wire by pymodbus.
"""

from __future__ import annotations

import asyncio
import json
import socket
import statistics
import time
from collections.abc import AsyncIterator, Iterator
from typing import Any

import aiohttp
import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from c20sim.control.http import ControlApi
from c20sim.core.bus import Direction, FrameRecord, RecordKind
from tests.tui.conftest import Served, serving


@pytest.fixture
def served() -> Iterator[Served]:
    with serving() as s:
        yield s


@pytest.fixture
async def session() -> AsyncIterator[aiohttp.ClientSession]:
    async with aiohttp.ClientSession() as s:
        yield s


def master(served: Served) -> ModbusTcpClient:
    client = ModbusTcpClient("127.0.0.1", port=served.port, framer=FramerType.RTU, timeout=2, retries=0)
    assert client.connect()
    return client


def api_of(served: Served) -> ControlApi:
    assert served.server.control is not None
    return served.server.control


async def messages(ws: aiohttp.ClientWebSocketResponse, until: Any, timeout: float = 10.0) -> list[dict[str, Any]]:
    """Messages from the stream until ``until(messages)`` holds; fails with what came if it never does."""
    got: list[dict[str, Any]] = []
    deadline = asyncio.get_running_loop().time() + timeout
    while not until(got):
        left = deadline - asyncio.get_running_loop().time()
        assert left > 0, f"the stream did not give what was awaited; it gave {[m['type'] for m in got]}"
        message = await ws.receive(timeout=left)
        assert message.type is aiohttp.WSMsgType.TEXT, message
        got.append(json.loads(message.data))
    return got


def frames_in(got: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [f for m in got if m["type"] == "frames" for f in m["frames"]]


async def test_stream_gives_telemetry_and_every_frame_with_its_seq(
    served: Served, session: aiohttp.ClientSession
) -> None:
    async with session.ws_connect(f"{served.url}/stream?hz=20") as ws:
        first = await messages(ws, lambda got: len(got) >= 1)
        telemetry = first[0]
        assert telemetry["type"] == "telemetry"
        (drive,) = telemetry["drives"]
        assert (drive["address"], drive["state"], drive["status"]) == (1, "stopped", 3)
        assert drive["registers"] == {"status2": 0x0041, "output_frequency": 0, "set_frequency": 0}
        assert drive["causes"]["undervoltage"] is False
        assert drive["conditions"]["supply_v"] == 48.0
        client = await asyncio.to_thread(master, served)
        try:
            await asyncio.to_thread(client.write_register, 0x2001, 1500, device_id=1)
            await asyncio.to_thread(client.read_holding_registers, 0x2100, count=1, device_id=1)
            await asyncio.to_thread(client.read_holding_registers, 0x0032, count=1, device_id=1)
        finally:
            client.close()
        got = await messages(ws, lambda got: len(frames_in(got)) >= 6)
    frames = frames_in(got)
    assert [f["seq"] for f in frames] == [0, 1, 2, 3, 4, 5]
    assert [(f["dir"], f["kind"]) for f in frames] == [
        ("rx", "request"), ("tx", "reply"), ("rx", "request"), ("tx", "reply"), ("rx", "request"), ("tx", "exception")
    ]  # fmt: skip
    assert frames[0]["hex"] == "01 06 20 01 05 DC D1 03"
    assert frames[0]["text"] == "write 2001H = 05DC: 1500 rpm"
    assert all(m["missed"] == 0 for m in got if m["type"] == "frames")
    assert [m["n"] for m in got if m["type"] == "telemetry"] == sorted(m["n"] for m in got if m["type"] == "telemetry")


async def test_stream_checks_its_query(served: Served, session: aiohttp.ClientSession) -> None:
    for query, error in (
        ("hz=0", "hz=0: outside 0.1-50"),
        ("hz=fast", "hz='fast' is not a number; give 0.1-50"),
        ("buffer=0", "buffer=0: outside 1-10000"),
        ("rate=5", "unknown query parameter 'rate'"),
    ):
        async with session.get(f"{served.url}/stream?{query}") as response:
            assert response.status == 400, query
            assert error in (await response.json())["error"], query


async def test_a_reader_that_stops_reading_skips_frames_and_is_told_how_many(
    served: Served, session: aiohttp.ClientSession
) -> None:
    """Frames come faster than a reader takes them: its buffer keeps the newest, each message says how many were
    skipped before it, and every frame is either received or counted as missed."""
    parts, each, buffer = 5, 20_000, 50
    async with session.ws_connect(f"{served.url}/stream?hz=0.1&buffer={buffer}") as ws:
        await messages(ws, lambda got: len(got) >= 1)  # the first telemetry: the reader is there

        def flood() -> None:
            bus = served.sim.bus
            for i in range(each):
                bus.record(FrameRecord(float(i), Direction.RX, b"\x01", RecordKind.NOISE, None, "x" * 200))

        for _ in range(parts):
            await asyncio.to_thread(served.call, flood)
        last = parts * each - 1
        got = await messages(ws, lambda got: bool(frames_in(got)) and frames_in(got)[-1]["seq"] == last)
    batches = [m for m in got if m["type"] == "frames"]
    missed = sum(m["missed"] for m in batches)
    received = sum(len(m["frames"]) for m in batches)
    assert missed + received == parts * each, (missed, received)
    assert 0 < received <= parts * buffer * 2, received  # at most a buffer's worth a batch
    expected = 0
    for batch in batches:  # every gap in the numbers is a skip that was told, where it happened
        expected += batch["missed"]
        for frame in batch["frames"]:
            assert frame["seq"] == expected, (frame["seq"], expected)
            expected += 1


def test_a_reader_that_never_reads_does_not_slow_the_wire(served: Served) -> None:
    """A WebSocket client that never reads (the fastest telemetry, the biggest buffer) while a master polls:
    every reply arrives, right; the latencies are printed (tests never assert wall time)."""
    with socket.create_connection(("127.0.0.1", int(served.url.rsplit(":", 1)[1]))) as raw:
        raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        key = "dGhlIHNhbXBsZSBub25jZQ=="
        raw.sendall(
            f"GET /stream?hz=50&buffer=10000 HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        assert raw.recv(12) == b"HTTP/1.1 101"  # upgraded; from here on nothing is read
        client = master(served)
        latencies = []
        try:
            for i in range(3000):
                start = time.perf_counter()
                response = client.read_holding_registers(0x2100, count=1, device_id=1)
                latencies.append(time.perf_counter() - start)
                assert not response.isError(), f"request {i}: {response}"
                assert response.registers == [3], f"request {i}: {response.registers}"
        finally:
            client.close()
        (stream,) = api_of(served).streams
        skipped = len(stream.frames) == stream.frames.maxlen
    latencies.sort()
    print(
        f"\n3000 replies with a stream reader that never reads: p50 {statistics.median(latencies) * 1e6:.0f} us, "
        f"p99 {latencies[int(len(latencies) * 0.99)] * 1e6:.0f} us, worst {latencies[-1] * 1e3:.1f} ms; "
        f"the reader's buffer {'full (skipping)' if skipped else 'not full'}"
    )


async def test_stream_readers_are_bounded(served: Served, session: aiohttp.ClientSession) -> None:
    from c20sim.control.httpstream import MAX_STREAMS

    readers = [await session.ws_connect(f"{served.url}/stream?frames=0") for _ in range(MAX_STREAMS)]
    try:
        async with session.get(f"{served.url}/stream") as response:
            assert response.status == 503
            assert (await response.json())[
                "error"
            ] == f"{MAX_STREAMS} stream readers are attached already; close one first"
        async with session.get(f"{served.url}/") as response:
            assert (await response.json())["stream_readers"] == MAX_STREAMS
        await readers.pop().close()
        await asyncio.sleep(0)
        deadline = asyncio.get_running_loop().time() + 10
        while True:  # the one closed is let go; another may take its place
            try:
                readers.append(await session.ws_connect(f"{served.url}/stream?frames=0"))
                break
            except aiohttp.WSServerHandshakeError as exc:
                assert exc.status == 503 and asyncio.get_running_loop().time() < deadline, exc
                await asyncio.sleep(0.05)
    finally:
        for ws in readers:
            await ws.close()


def test_closing_the_api_does_not_wait_for_a_reader_that_never_reads(served: Served) -> None:
    with socket.create_connection(("127.0.0.1", int(served.url.rsplit(":", 1)[1]))) as raw:
        raw.sendall(
            b"GET /stream?hz=50 HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        assert raw.recv(12) == b"HTTP/1.1 101"
        served.thread.run(api_of(served).close(), timeout=5.0)  # the close handshake is not awaited for long
        assert api_of(served).readers == 0


@pytest.mark.parametrize(
    ("last", "now", "expected"),
    [(0.0, 0.05, 0.2), (0.0, 0.2, 0.4), (0.0, 0.61, 0.8), (1.0, 1.0, 1.2)],
)
def test_the_stream_keeps_its_beat(last: float, now: float, expected: float) -> None:
    from c20sim.control.httpstream import _next_beat

    assert _next_beat(last, 0.2, now) == pytest.approx(expected)

"""The shared line: requests from several streams served one at a time, a delayed reply holding the line."""

from __future__ import annotations

import asyncio

import pytest

from c20sim.core.bus import Reply
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.transport.line import Line
from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, WriteSingleRequest, encode


def frame(data: bytes) -> FrameEvent:
    return FrameEvent(FrameKind.FRAME, data, 0.0)


async def test_a_delayed_reply_holds_the_line_and_the_next_request_waits() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())  # default turnaround: 2 ms
    line = Line(sim)
    got: list[tuple[str, bytes | None]] = []
    done = asyncio.Event()

    def to(name: str) -> object:
        def respond(reply: Reply | None) -> None:
            got.append((name, None if reply is None else reply.data))
            if len(got) == 3:
                done.set()

        return respond

    write = encode(WriteSingleRequest(1, 0x2001, 1234))
    read = encode(ReadRequest(1, 0x2001, 1))
    line.submit(frame(write), to("a"))  # type: ignore[arg-type]
    line.submit(frame(read), to("b"))  # type: ignore[arg-type]
    line.submit(frame(encode(ReadRequest(9, 0x2001, 1))), to("c"))  # type: ignore[arg-type]
    # The write is served at once; its reply is due in 2 ms, and the read waits behind it.
    assert line.busy
    assert sim.drive(1).read(0x2001) == 1234
    assert got == []
    await asyncio.wait_for(done.wait(), 5)
    assert got == [("a", write), ("b", bytes.fromhex("01 03 02 04 D2 3A D9")), ("c", None)]
    assert not line.busy


async def test_close_drops_what_waits() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    line = Line(sim)
    got: list[bytes | None] = []
    line.submit(frame(encode(ReadRequest(1, 0x2103, 1))), lambda r: got.append(r and r.data))
    line.submit(frame(encode(WriteSingleRequest(1, 0x2001, 7))), lambda r: got.append(r and r.data))
    line.close()
    assert sim.drive(1).read(0x2001) == 0  # the queued write was never served
    # A request after the close is answered after its own turnaround, later than the dropped reply was due.
    after = asyncio.get_running_loop().create_future()
    line.submit(frame(encode(ReadRequest(1, 0x2001, 1))), after.set_result)
    reply = await asyncio.wait_for(after, 5)
    assert reply is not None and reply.data == bytes.fromhex("01 03 02 00 00 B8 44")
    assert got == []


async def test_a_bug_while_serving_is_silence_for_the_asker_and_the_line_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    line = Line(sim)

    def broken(event: FrameEvent) -> Reply | None:
        raise RuntimeError("a bug")

    real, sim.handle = sim.handle, broken  # type: ignore[method-assign]
    got: list[Reply | None] = []
    line.submit(frame(encode(ReadRequest(1, 0x2103, 1))), got.append)
    assert got == [None]
    assert "bug while serving" in caplog.text
    sim.handle = real  # type: ignore[method-assign]
    after = asyncio.get_running_loop().create_future()
    line.submit(frame(encode(ReadRequest(1, 0x2103, 1))), after.set_result)
    reply = await asyncio.wait_for(after, 5)
    assert reply is not None and reply.data == bytes.fromhex("01 03 02 00 20 B9 9C")


async def test_peers_and_their_masters_are_served_in_turn_and_a_full_peer_waits_for_room() -> None:
    """Peer P has masters p1 (three requests) and p2 (one), peer Q has q1 (two), all queued behind a held reply:
    the line takes P, Q, P, Q, ... and within P p1, p2, p1. A peer at its bound (peer_queue) is refused until the
    line takes one of its requests; the master waiting for room is woken then, and a cancelled one is not."""
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    sim.link_faults(1).delay = 0.05
    line = Line(sim)
    order: list[str] = []
    done = asyncio.Event()

    def to(name: str) -> object:
        def respond(reply: Reply | None) -> None:
            order.append(name)
            if len(order) == 7:
                done.set()

        return respond

    read = frame(encode(ReadRequest(1, 0x2100, 1)))
    line.submit(read, to("first"), "first")  # type: ignore[arg-type]
    assert line.busy
    for name, source, peer in [
        ("p1a", "p1", "P"),
        ("p1b", "p1", "P"),
        ("p1c", "p1", "P"),
        ("p2a", "p2", "P"),
        ("q1a", "q1", "Q"),
        ("q1b", "q1", "Q"),
    ]:
        assert line.submit(read, to(name), source, peer=peer)  # type: ignore[arg-type]
    assert (line.waiting, line.waiting_of("P"), line.waiting_of("Q")) == (6, 4, 2)
    line.peer_queue = 4
    assert not line.has_room("P", "p3")
    assert not line.submit(read, to("refused"), "p3", peer="P")  # type: ignore[arg-type]
    woken: list[str] = []
    line.when_room("P", "p3", lambda: woken.append("p3"))
    line.when_room("P", "p4", lambda: woken.append("p4"))
    line.cancel("p4")  # gone before there was room: never woken
    await asyncio.wait_for(done.wait(), 5)
    assert order == ["first", "p1a", "q1a", "p2a", "q1b", "p1b", "p1c"]
    assert woken == ["p3"]
    assert line.refused == 1
    assert (line.waiting, line.waiting_of("P"), line.waiting_of("Q")) == (0, 0, 0)


async def test_the_deadline_heap_forgets_what_closed_connections_queued() -> None:
    """20,000 connections each queue 4 requests behind a busy line and close: the line's deadline heap keeps no
    more than twice what waits, plus a little (it kept all 80,000, each holding its connection, until their
    deadlines)."""
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    line = Line(sim)
    read = frame(encode(ReadRequest(1, 0x2100, 1)))
    answered: list[Reply | None] = []
    line.submit(read, answered.append, object(), wait_limit=60.0)  # on the line: the rest wait
    assert line.busy
    for _ in range(20_000):
        source = object()
        for _ in range(4):
            assert line.submit(read, answered.append, source, wait_limit=60.0)
        assert line.cancel(source) == 4
    assert (line.waiting, line.cancelled) == (0, 80_000)
    assert len(line._deadlines) <= 64
    line.close()

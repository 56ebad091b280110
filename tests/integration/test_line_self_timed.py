"""A line-timed port's replies: handed over at once, while the line stays busy for the turnaround."""

from __future__ import annotations

import asyncio

from c20sim.core.bus import Reply
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.transport.line import Line, SelfTimed
from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, encode


def frame(data: bytes) -> FrameEvent:
    return FrameEvent(FrameKind.FRAME, data, 0.0)


async def test_a_self_timed_reply_is_handed_over_at_once_and_the_line_stays_busy() -> None:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())  # default turnaround: 2 ms
    line = Line(sim)
    timed: list[Reply | None] = []
    plain = asyncio.get_running_loop().create_future()
    line.submit(frame(encode(ReadRequest(1, 0x2103, 1))), SelfTimed(timed.append))
    line.submit(frame(encode(ReadRequest(1, 0x2100, 1))), plain.set_result)
    # The self-timed port has its reply, with its delay still to wait on its own clock; the line is busy.
    assert [(r.data, r.delay) for r in timed if r is not None] == [(bytes.fromhex("01 03 02 00 20 B9 9C"), 0.002)]
    assert line.busy
    assert not plain.done()  # the next request waits for the turnaround, as before
    reply = await asyncio.wait_for(plain, 5)
    assert reply is not None and reply.data == bytes.fromhex("01 03 02 00 03 F8 45")
    assert len(timed) == 1  # handed over once, not again when the delay ended
    assert not line.busy

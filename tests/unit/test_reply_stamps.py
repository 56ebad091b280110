"""A reply's record is stamped when its last byte leaves (docs/line-timing.md): the turnaround after its request
where the reply goes whole, the end of its transaction on the line with bus timing (the line tells the bus when
the transaction starts there, and whether the request was on the wire as it came)."""

from __future__ import annotations

import asyncio
import time

import pytest

from c20sim.core.bus import Direction, FrameRecord
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.transport.line import Line, SelfTimed
from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, encode, frame_time, transaction_time
from c20sim.wire.registers import Reg

REQUEST = encode(ReadRequest(1, Reg.STATUS1, 1))  # 8 bytes; its reply 7
TURNAROUND = 0.002  # the default profile's


def _served(timed_from: tuple[float, bool] | None) -> list[FrameRecord]:
    sim = Simulator(load_profile(), (1,), clock=VirtualClock())
    records: list[FrameRecord] = []
    sim.bus.subscribe(records.append)
    sim.bus.timed_from = timed_from
    sim.handle(FrameEvent(FrameKind.FRAME, REQUEST, 10.0))
    return records


def test_untimed_the_reply_is_stamped_the_turnaround_after_its_request() -> None:
    rx, tx = _served(None)
    assert (rx.direction, tx.direction) == (Direction.RX, Direction.TX)
    assert (rx.t, tx.t) == (10.0, pytest.approx(10.0 + TURNAROUND, abs=1e-12))


def test_timed_the_reply_is_stamped_at_the_end_of_its_transaction_on_the_line() -> None:
    _, tx = _served((10.5, False))  # the line was free again at 10.5: the transaction starts there
    assert tx.t == pytest.approx(10.5 + transaction_time(8, 7, 19200, 10, TURNAROUND), abs=1e-12)


def test_timed_on_a_line_timed_port_the_request_s_own_time_is_not_counted_again() -> None:
    _, tx = _served((10.0, True))
    whole = transaction_time(8, 7, 19200, 10, TURNAROUND)
    assert tx.t == pytest.approx(10.0 + whole - frame_time(8, 19200, 10), abs=1e-12)


@pytest.mark.parametrize("self_timed", [False, True])
def test_the_line_tells_the_bus_for_each_request_and_forgets_it_after(self_timed: bool) -> None:
    async def serve_one() -> tuple[list[FrameRecord], float, tuple[float, bool] | None]:
        sim = Simulator(load_profile(), (1,), clock=VirtualClock())
        records: list[FrameRecord] = []
        sim.bus.subscribe(records.append)
        line = Line(sim, bus_timing=True)
        replied = asyncio.get_running_loop().create_future()

        def respond(reply: object) -> None:
            if not replied.done():
                replied.set_result(reply)

        arrived = time.perf_counter()
        line.submit(FrameEvent(FrameKind.FRAME, REQUEST, arrived), SelfTimed(respond) if self_timed else respond)
        await asyncio.wait_for(replied, 5)
        line.close()
        return records, arrived, sim.bus.timed_from

    records, arrived, left = asyncio.run(serve_one())
    rx, tx = records
    spent = transaction_time(8, 7, 19200, 10, TURNAROUND) - (frame_time(8, 19200, 10) if self_timed else 0.0)
    assert rx.t == arrived
    assert spent <= tx.t - arrived < spent + 0.05  # from when the line took it (microseconds after it came)
    assert left is None  # a request served without the line afterwards is stamped untimed

"""The due queue: held replies of every bus on a loop leave in due order, those of one millisecond together."""

from __future__ import annotations

import asyncio
import random
import time
from collections.abc import Callable
from typing import Any

import pytest

from c20sim.transport.due import EARLY, DueQueue, due_timer, queue_of


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


class Armed:
    def __init__(self, delay: float, callback: Callable[[], None]) -> None:
        self.delay, self.callback, self.cancelled = delay, callback, False

    def cancel(self) -> None:
        self.cancelled = True

    def fire(self) -> None:
        """The loop runs it: a timer handle that ran is done."""
        assert not self.cancelled
        self.cancelled = True
        self.callback()


class FakeLoop:
    """What the queue asks of a loop: call_later (recorded, fired by the test) and the exception handler."""

    def __init__(self) -> None:
        self.armed: list[Armed] = []
        self.errors: list[dict[str, Any]] = []

    def call_later(self, delay: float, callback: Callable[[], None]) -> Armed:
        self.armed.append(Armed(delay, callback))
        return self.armed[-1]

    def live(self) -> list[Armed]:
        return [a for a in self.armed if not a.cancelled]

    def call_exception_handler(self, context: dict[str, Any]) -> None:
        self.errors.append(context)


def make(t: float = 10.0) -> tuple[DueQueue, FakeLoop, Clock]:
    loop, clock = FakeLoop(), Clock(t)
    return DueQueue(loop, clock), loop, clock  # type: ignore[arg-type]


def test_one_timer_for_the_earliest_and_a_batch_in_due_order() -> None:
    queue, loop, clock = make()
    ran: list[str] = []
    for due, name in ((10.0133, "c"), (10.0131, "a"), (10.0132, "b"), (10.0139, "d"), (10.0200, "e")):
        queue.schedule(due, ran.append, name)
    (armed,) = loop.live()  # one loop timer, for the earliest (a was scheduled after c: re-armed)
    assert armed.delay == pytest.approx(0.0131)
    clock.t = 10.0131  # the loop fires it on time
    armed.fire()
    # due by now + EARLY (10.0136): a, b, c in due order, in this one turn; d waits, re-armed for it
    assert ran == ["a", "b", "c"] and (queue.released, queue.largest_batch) == (3, 3)
    (armed,) = loop.live()
    assert armed.delay == pytest.approx(0.0008)
    clock.t = 10.0133  # a loop counting whole milliseconds fired early: more than EARLY before d, nothing leaves
    armed.fire()
    assert ran == ["a", "b", "c"]
    (armed,) = loop.live()
    assert armed.delay == pytest.approx(0.0006)
    clock.t = 10.0140
    armed.fire()
    assert ran == ["a", "b", "c", "d"] and len(queue) == 1
    clock.t = 10.0300  # late: e leaves at once, and nothing is armed any more
    loop.live()[0].fire()
    assert ran == ["a", "b", "c", "d", "e"] and loop.live() == [] and len(queue) == 0


def test_equal_dues_leave_in_the_order_scheduled_and_never_more_than_early_before() -> None:
    queue, loop, clock = make()
    ran: list[tuple[int, float]] = []
    rng = random.Random(3)
    dues = [10.0 + rng.randrange(0, 40) * 0.0001 for _ in range(300)]  # 300 replies over 4 ms, many equal
    for i, due in enumerate(dues):
        queue.schedule(due, lambda i=i, due=due: ran.append((i, due)))
    while loop.live():
        armed = loop.live()[0]
        clock.t += max(0.0, armed.delay) + rng.random() * 0.0003  # the loop fires somewhat late, or on time
        before = len(ran)
        armed.fire()
        assert all(due - clock.t <= EARLY + 1e-12 for _, due in ran[before:])
    assert ran == sorted(enumerate(dues), key=lambda pair: (pair[1], pair[0]))


def test_a_cancelled_entry_never_runs_and_the_heap_stays_bounded() -> None:
    queue, loop, clock = make()
    ran: list[int] = []
    entries = [queue.schedule(10.01 + i * 1e-5, ran.append, i) for i in range(300)]
    for entry in entries[:250]:
        entry.cancel()
        entry.cancel()  # twice is once
    assert len(queue) == 50 and len(queue._heap) <= 2 * 50 + 64
    clock.t = 11.0
    loop.live()[-1].fire()
    assert ran == list(range(250, 300))
    for entry in entries[250:]:
        entry.cancel()  # run already: nothing
    assert len(queue) == 0
    entry = queue.schedule(12.0, ran.append, -1)
    entry.cancel()  # the last one waiting: the loop timer goes too
    assert loop.live() == [] and len(queue) == 0


def test_a_failing_callback_does_not_hold_up_the_rest() -> None:
    queue, loop, clock = make()
    ran: list[str] = []

    def boom() -> None:
        raise RuntimeError("bug")

    queue.schedule(10.001, boom)
    queue.schedule(10.002, ran.append, "after")
    clock.t = 10.002
    loop.live()[0].fire()
    assert ran == ["after"] and [str(e["exception"]) for e in loop.errors] == ["bug"]


@pytest.mark.parametrize("loop_name", ["asyncio", "uvloop"])
def test_on_a_real_loop_replies_of_one_millisecond_leave_in_due_order(loop_name: str) -> None:
    """120 callbacks due within the same 0.3 ms, armed in a shuffled order: they run in due order, none more than
    EARLY before its due time, from one queue per loop."""

    async def main() -> tuple[list[float], list[float], DueQueue]:
        loop = asyncio.get_running_loop()
        base = time.perf_counter() + 0.02
        dues = [base + i * 0.0000025 for i in range(120)]
        order = dues[:]
        random.Random(5).shuffle(order)
        fired: list[float] = []
        ran: list[float] = []
        done = loop.create_future()

        def hit(due: float) -> None:
            fired.append(time.perf_counter())
            ran.append(due)
            if len(ran) == len(dues):
                done.set_result(None)

        for due in order:
            due_timer(loop, due, hit, due)
        await asyncio.wait_for(done, 5.0)
        return ran, [f - d for f, d in zip(fired, ran, strict=True)], queue_of(loop)

    if loop_name == "uvloop":
        uvloop = pytest.importorskip("uvloop")
        ran, lateness, queue = uvloop.run(main())
    else:
        ran, lateness, queue = asyncio.run(main())
    assert ran == sorted(ran)
    assert min(lateness) >= -EARLY
    assert queue.released == 120 and len(queue) == 0


async def test_many_lines_on_one_loop_hand_their_held_replies_over_from_one_queue_in_due_order() -> None:
    """40 buses under bus timing, a read submitted to each in turn: each line holds its reply for the transaction's
    time on its line; the replies come from the loop's one queue, in the order they were due, none early."""
    from c20sim.core.clock import RealtimeClock
    from c20sim.core.simulator import Simulator
    from c20sim.drive.profile import load_profile
    from c20sim.transport.line import Line
    from c20sim.wire.protocol import FrameEvent, FrameKind, ReadRequest, encode

    loop = asyncio.get_running_loop()
    queue = queue_of(loop)
    released = queue.released
    profile = load_profile()
    lines = [Line(Simulator(profile, (1,), clock=RealtimeClock(), seed=i), bus_timing=True) for i in range(40)]
    frame = encode(ReadRequest(1, 0x2100, 1))
    handed: list[tuple[int, float]] = []
    dues: dict[int, float] = {}
    done = loop.create_future()

    def respond(i: int, reply: object) -> None:
        assert reply is not None
        handed.append((i, time.perf_counter()))
        if len(handed) == len(lines) and not done.done():
            done.set_result(None)

    for i, line in enumerate(lines):
        line.submit(FrameEvent(FrameKind.FRAME, frame, time.perf_counter()), lambda r, i=i: respond(i, r))
        assert line.busy and line.free_at is not None
        dues[i] = line.free_at
    assert len(queue) >= len(lines)  # held in the loop's queue, not a loop timer each
    await asyncio.wait_for(done, 5.0)
    assert [i for i, _ in handed] == sorted(dues, key=lambda i: dues[i])
    assert all(at >= dues[i] - EARLY for i, at in handed)
    assert queue.released - released == len(lines)
    for line in lines:
        line.close()

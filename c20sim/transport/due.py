"""Held replies of every bus on one event loop, released in due order from one timer.

Under bus timing each reply is held until its transaction's time on the RS485 line has passed (13.458 ms for
a one-register read at 19200 baud). A plant serves hundreds of buses from one loop: at 256 buses polled as
fast as their lines allow, 19,000 replies a second, about 19 due in any one millisecond. With a loop timer a
reply (:class:`~c20sim.transport.line.DueTimer`), uvloop, which counts whole milliseconds, fires those of one
millisecond in the order they were armed, not in the order they are due, each a timer of its own that the
collector tracks while it waits.

:class:`DueQueue` keeps the held replies of one loop in a heap by due time and arms one loop timer, for the
earliest. When it fires it releases, in due order, every reply due by then (up to :data:`EARLY` ahead, the
rounding of a loop that counts whole milliseconds, as :class:`DueTimer` does), and arms the timer again for the
next: replies due in the same millisecond leave in one turn of the loop, the earliest first. An entry is
what :func:`due_timer` returns: ``due`` and ``cancel()``, as a DueTimer's.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import time
import weakref
from collections.abc import Callable

__all__ = ["EARLY", "DueEntry", "DueQueue", "due_timer"]

#: How early a held reply may be handed over: half a millisecond, the rounding of a loop that counts whole ones
#: (the line's :data:`~c20sim.transport.line.EARLY`).
EARLY = 0.0005


class DueEntry:
    """One held callback: ``due`` (``time.perf_counter``) and ``cancel()``."""

    __slots__ = ("_args", "_callback", "_queue", "cancelled", "due")

    def __init__(self, queue: DueQueue, due: float, callback: Callable[..., object], args: tuple[object, ...]):
        self._queue = queue
        self.due = due
        self._callback = callback
        self._args = args
        self.cancelled = False

    def cancel(self) -> None:
        if not self.cancelled:
            self.cancelled = True
            self._args = ()  # what it held goes now, not when the heap gets to it
            self._queue._cancelled_one()

    def _run(self) -> None:
        self._callback(*self._args)


class DueQueue:
    """The held callbacks of one loop: a heap by due time, one loop timer armed for the earliest."""

    def __init__(self, loop: asyncio.AbstractEventLoop, clock: Callable[[], float] = time.perf_counter) -> None:
        self._loop = loop
        self._clock = clock
        self._heap: list[tuple[float, int, DueEntry]] = []
        self._seq = itertools.count()
        self._armed: asyncio.TimerHandle | None = None
        self._armed_for = 0.0  #: the due time the loop timer was armed for
        self._cancelled = 0  #: cancelled entries still in the heap
        #: released so far, and the most that left in one turn of the loop (for the bench and the tests)
        self.released = 0
        self.largest_batch = 0

    def __len__(self) -> int:
        return len(self._heap) - self._cancelled

    def schedule(self, due: float, callback: Callable[..., object], *args: object) -> DueEntry:
        """Call ``callback(*args)`` when the clock reaches ``due``: at most :data:`EARLY` before, in due order
        with every other entry (equal dues: in the order scheduled)."""
        entry = DueEntry(self, due, callback, args)
        heapq.heappush(self._heap, (due, next(self._seq), entry))
        if self._armed is None or due < self._armed_for:
            self._arm(due)
        return entry

    def _arm(self, due: float) -> None:
        if self._armed is not None:
            self._armed.cancel()
        self._armed_for = due
        self._armed = self._loop.call_later(max(0.0, due - self._clock()), self._fire)

    def _cancelled_one(self) -> None:
        self._cancelled += 1
        if self._cancelled > 64 and self._cancelled * 2 > len(self._heap):
            # most of the heap no longer waits (lines closed): rebuild it, so that it is bounded by what waits
            self._heap = [item for item in self._heap if not item[2].cancelled]
            heapq.heapify(self._heap)
            self._cancelled = 0
        if not len(self) and self._armed is not None:
            self._armed.cancel()
            self._armed = None
            self._heap.clear()
            self._cancelled = 0

    def _fire(self) -> None:
        self._armed = None
        heap = self._heap
        batch = 0
        while heap:
            due, _, entry = heap[0]
            if entry.cancelled:
                heapq.heappop(heap)
                self._cancelled -= 1
                continue
            if due - self._clock() > EARLY:  # the loop's millisecond fired early: wait the rest
                self._arm(due)
                break
            heapq.heappop(heap)
            entry.cancelled = True  # run once; a cancel() from the callback is a no-op
            batch += 1
            try:
                entry._run()
            except Exception as exc:  # the callback's own bug must not hold up the replies behind it
                self._loop.call_exception_handler({"message": "a held reply's callback failed", "exception": exc})
        self.released += batch
        self.largest_batch = max(self.largest_batch, batch)


_queues: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, DueQueue] = weakref.WeakKeyDictionary()


def queue_of(loop: asyncio.AbstractEventLoop) -> DueQueue:
    """The loop's due queue (made on first use, gone with the loop)."""
    found = _queues.get(loop)
    if found is None:
        found = _queues[loop] = DueQueue(loop)
    return found


def due_timer(loop: asyncio.AbstractEventLoop, due: float, callback: Callable[..., object], *args: object) -> DueEntry:
    """``callback(*args)`` at ``due`` on ``loop``, from its shared :class:`DueQueue`: what the line holds a reply
    with (a :class:`~c20sim.transport.line.DueTimer`'s interface)."""
    return queue_of(loop).schedule(due, callback, *args)

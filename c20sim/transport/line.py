"""The shared line: one request at a time, and a reply holds the line for its turnaround, or its line time.

Every transport hands its framing events to the one :class:`Line` of its
simulator, with a callback that puts the reply on the stream that asked. The
bus serves events in arrival order; a reply due after a delay (the profile's
turnaround, an injected delay) keeps the line busy until it is sent, and the
events that arrive meanwhile wait their turn, as on a real RS485 line or
behind a serial gateway. No task and no lock per request: callbacks on the
event loop, which is what keeps a request cheap.

Many masters, in turn. Requests wait in one queue per master (the source that
submitted them: a connection, a pty, a serial port), and masters in one queue
per peer (the address a TCP connection comes from; a local port is its own
peer). The line takes the next request from the next peer in turn, and
within a peer from the next master in turn, as a gateway serves its masters:
a host with 500 connections gets the line as often as a host with one, a
connection that pipelines as often as one that waits for each answer. Each
peer's queue is bounded (:data:`PEER_QUEUE`, the MGate MB3000's request
queue per master): a master whose peer's queue is full holds its next
request and is not read (:meth:`Line.has_room`, :meth:`Line.when_room`)
until the line has taken one of its peer's, so a flooding host costs the
line a bounded queue and no work per request. A request that waited longer than its submitter's limit (the gateway's
response timeout) is never put on the line: its submitter's ``expire``
answers it (exception 0x0B on Modbus TCP) or it is dropped (RTU over TCP).
Each endpoint also submits at most a few requests at a time and reads no
more until they are answered (backpressure), and a closed endpoint's waiting
requests are dropped with :meth:`Line.cancel`, as a gateway forgets a
connection that went away. Before each request it takes from the queue the
line runs its ``sweeps`` (the TCP ports' watch for peers that closed), so a
request whose connection is known to be gone is never served.

Bus timing (``serve --bus-timing``, on by default in every front end): each
transaction holds the line for the time it would take on RS485 at the drive's
serial settings (:func:`~c20sim.wire.protocol.transaction_time`, which the
bus computes for every event: the request and the reply at the line's baud
and character size, each after its t3.5, and the turnaround between), and a
master over TCP gets its reply only when that time is over. Masters on every
transport then meet the real line's throughput and queue behind each other as
behind a serial device server. A held reply may be handed over up to
:data:`EARLY` before its time (the loop's timer counts whole milliseconds),
but the line stays the transaction's until its end, and the next one starts
there at the earliest: back to back, masters get no more transactions a
second than the line carries. A silent request (broadcast, absent drive)
holds the line for its own frame. A line-timed port has put the request on its
wire already: its transactions hold the line for the rest.

When the bus's line speed changes (the only drive took a 2009H write, or a
reset), the bus tells the line (:meth:`~c20sim.core.bus.Bus.on_line`), and
the line tells every endpoint attached to it, after the reply that
acknowledged the change has been handed over at the old speed: nothing polls.
"""

from __future__ import annotations

import asyncio
import dataclasses
import heapq
import itertools
import logging
import time
from bisect import bisect_left
from collections import deque
from collections.abc import Callable

from ..core.bus import LineSettings, Reply
from ..core.simulator import Simulator
from ..wire.protocol import FrameEvent
from .due import DueEntry, due_timer

__all__ = ["EARLY", "LATENCY_BUCKETS", "PEER_QUEUE", "DueTimer", "Latency", "Line", "Respond", "SelfTimed"]

log = logging.getLogger(__name__)

#: Called with the reply to put on the wire, or None where the line stays silent.
Respond = Callable[[Reply | None], None]


class SelfTimed:
    """A respond callback that waits out a reply's delay on its own, finer clock (a line-timed port).

    The line hands it the reply as soon as it is built, and stays busy for the
    reply's delay all the same.
    """

    def __init__(self, respond: Respond) -> None:
        self.respond = respond

    def __call__(self, reply: Reply | None) -> None:
        self.respond(reply)


#: Upper bounds (seconds) of the reply latency histogram's buckets: from a fast TCP reply to a slow line's.
LATENCY_BUCKETS: tuple[float, ...] = (
    0.0001,
    0.0002,
    0.0005,
    0.001,
    0.002,
    0.005,
    0.01,
    0.02,
    0.05,
    0.1,
    0.2,
    0.5,
    1.0,
)


class Latency:
    """How long replies took, from the request's last byte to the reply handed to its port: a histogram.

    Counting costs a bisect and two additions per reply on the serving loop; reading it
    (``GET /metrics``) costs nothing on the wire's path.
    """

    __slots__ = ("count", "counts", "sum")

    def __init__(self) -> None:
        self.counts = [0] * (len(LATENCY_BUCKETS) + 1)  #: per bucket, the last one above every bound
        self.count = 0
        self.sum = 0.0

    def observe(self, seconds: float) -> None:
        self.counts[bisect_left(LATENCY_BUCKETS, seconds)] += 1
        self.count += 1
        self.sum += seconds


#: How early a held reply may be handed over: half a millisecond, the rounding of a loop that counts whole ones.
EARLY = 0.0005


class DueTimer:
    """Calls ``callback(*args)`` when ``time.perf_counter()`` reaches ``due``: at most :data:`EARLY` before, and
    within about a millisecond after (the loop's timer resolution). ``cancel()`` as a timer handle's.

    asyncio's loop counts float seconds on the same monotonic clock and never fires early. uvloop counts whole
    milliseconds (libuv's): it rounds the delay to the nearest one, which an idle loop waits out from now
    (+-0.5 ms), but a busy loop fires at the first turn past that millisecond of a clock truncated to the
    millisecond: a plain ``call_later(0.013458)`` there fired up to 1.5 ms early (bench/bench_plant.py, part
    0). So when it fires, the timer looks at the clock: more than :data:`EARLY` before ``due``, it waits the
    rest, which the loop rounds to a whole millisecond or more (more than 0.5 ms is never rounded to none, so
    the loop does not spin), and looks again.
    """

    __slots__ = ("_args", "_callback", "_handle", "_loop", "due")

    def __init__(self, loop: asyncio.AbstractEventLoop, due: float, callback: Callable[..., object], *args: object):
        self._loop = loop
        self.due = due
        self._callback = callback
        self._args = args
        self._handle = loop.call_later(max(0.0, due - time.perf_counter()), self._fire)

    def _fire(self) -> None:
        early = self.due - time.perf_counter()
        if early > EARLY:
            self._handle = self._loop.call_later(early, self._fire)
            return
        self._callback(*self._args)

    def cancel(self) -> None:
        self._handle.cancel()


def _nothing(reply: Reply | None) -> None:
    """The respond of a delay whose reply was handed over already."""


#: Requests one peer (a master's address; a local port) may have waiting for the line. The MGate MB3000's user
#: manual: "The request queue is full, and 32 request queue is for each master" (its Modbus TCP Exception
#: setting, Request dropped: exception 0x06). That a master there is one IP address is assumed.
PEER_QUEUE = 32


class _Waiting:
    """A request waiting for the line."""

    __slots__ = ("deadline", "event", "expire", "peer", "respond", "source", "waiting")

    def __init__(
        self,
        event: FrameEvent,
        respond: Respond,
        source: object,
        peer: object,
        expire: Callable[[], None] | None,
        deadline: float | None,
    ) -> None:
        self.event = event
        self.respond = respond
        self.source = source
        self.peer = peer
        self.expire = expire
        self.deadline = deadline
        self.waiting = True  #: False once served, expired or cancelled (the deadline heap forgets it lazily)


class Line:
    """Serves framing events from every endpoint of one simulator, in order."""

    def __init__(self, sim: Simulator, *, bus_timing: bool = False) -> None:
        self.sim = sim
        #: hold the line for each transaction's time on RS485 (else only for a reply's turnaround)
        self.bus_timing = bus_timing
        #: per peer, per master (source), its requests in order; both levels in turn (dicts keep the order)
        self._queues: dict[object, dict[object, deque[_Waiting]]] = {}
        self._peer_of: dict[object, object] = {}  #: each master with requests waiting -> its peer
        self._peer_waiting: dict[object, int] = {}  #: requests waiting per peer
        #: per peer whose queue is full, the masters holding a request for it, in order
        self._room_waiters: dict[object, dict[object, Callable[[], None]]] = {}
        self._count = 0
        self._deadlines: list[tuple[float, int, _Waiting]] = []  #: a heap of the waiting requests' deadlines
        self._seq = itertools.count()
        #: called before the line takes a request from its queue (the TCP ports' watch for peers that closed)
        self.sweeps: list[Callable[[], None]] = []
        #: requests per peer that may wait (:data:`PEER_QUEUE`)
        self.peer_queue = PEER_QUEUE
        #: requests refused (a peer's queue full), expired (waited past their limit), cancelled (their master went)
        self.refused = 0
        self.expired = 0
        self.cancelled = 0
        self._busy = False
        self._timer: DueEntry | None = None
        #: when the last held transaction ends (``time.perf_counter``): its reply may be handed over up to
        #: :data:`EARLY` before, but the line is its until then, so the next one starts here at the earliest
        self._held_until = 0.0
        self._last_source: object = None  #: who asked for the last transaction served
        self._last_peer: object = None  #: and its peer
        self._last_on_line = 0.0  #: its request's time in the frame log
        self._event_loop: asyncio.AbstractEventLoop | None = None
        self._baud_listeners: list[Callable[[int], None]] = []
        #: what the bus last told of the line, and a new baud told while a reply was in hand (for the endpoints
        #: once it is handed over at the old one)
        self._settings = sim.bus.line_settings
        self._told: int | None = None
        self._in_hand = False  #: a transaction is being served and its reply not yet handed over or held
        self._unwatch = sim.bus.on_line(self._line_told)
        #: the replies' latency (request's last byte to reply handed over), for GET /metrics
        self.latency = Latency()
        #: seconds the line has been held: a transaction's RS485 time with bus timing, else delayed replies
        self.busy_seconds = 0.0

    def on_baud(self, listener: Callable[[int], None]) -> Callable[[], None]:
        """Call ``listener`` with the new line speed, once the reply that changed it is handed over (as the bus
        tells the line); returns a function that detaches it."""
        self._baud_listeners.append(listener)

        def detach() -> None:
            if listener in self._baud_listeners:
                self._baud_listeners.remove(listener)

        return detach

    @property
    def busy(self) -> bool:
        """True while a delayed reply holds the line."""
        return self._busy

    @property
    def free_at(self) -> float | None:
        """When the transaction holding the line ends (``time.perf_counter``, the monotonic clock the ports stamp
        frames with); None while the line is free."""
        return self._timer.due if self._timer is not None else None

    def _loop(self) -> asyncio.AbstractEventLoop:
        if self._event_loop is None:
            self._event_loop = asyncio.get_running_loop()  # once: each call costs a getpid() system call
        return self._event_loop

    @property
    def waiting(self) -> int:
        """Requests queued behind the one being served."""
        return self._count

    def waiting_of(self, peer: object) -> int:
        """Requests of ``peer`` waiting for the line."""
        return self._peer_waiting.get(peer, 0)

    def submit(
        self,
        event: FrameEvent,
        respond: Respond,
        source: object = None,
        *,
        peer: object = None,
        expire: Callable[[], None] | None = None,
        wait_limit: float | None = None,
    ) -> bool:
        """Serve ``event`` now if the line is free, else in ``source``'s turn; False (and nothing queued) when
        ``peer``'s queue is full. ``source`` names the master who asked (for cancel and turns), ``peer`` its
        address (None: the source is its own peer). A request still waiting ``wait_limit`` seconds after this
        call is not served: ``expire()`` is called, or ``respond(None)`` without one."""
        if peer is None:
            peer = source
        if self._peer_waiting.get(peer, 0) >= self.peer_queue:
            self.refused += 1  # its caller should have asked has_room() first
            return False
        # counted from now: a request framed from bytes read earlier (held by backpressure) waits for the line
        # only from here
        deadline = None if wait_limit is None else time.perf_counter() + wait_limit
        item = _Waiting(event, respond, source, peer, expire, deadline)
        sources = self._queues.get(peer)
        if sources is None:
            sources = self._queues[peer] = {}
        queue = sources.get(source)
        if queue is None:
            queue = sources[source] = deque()
            self._peer_of[source] = peer
        queue.append(item)
        self._peer_waiting[peer] = self._peer_waiting.get(peer, 0) + 1
        self._count += 1
        if deadline is not None:
            heapq.heappush(self._deadlines, (deadline, next(self._seq), item))
        if not self._busy:
            self._serve_waiting()
        return True

    def has_room(self, peer: object, source: object) -> bool:
        """May ``source`` of ``peer`` (None: its own) queue a request now? Else the caller waits: see
        :meth:`when_room`."""
        return self._peer_waiting.get(source if peer is None else peer, 0) < self.peer_queue

    def when_room(self, peer: object, source: object, callback: Callable[[], None]) -> None:
        """Call ``callback`` (soon, on the loop) when ``peer``'s queue has room, its masters woken in turn.

        A master whose peer's queue is full holds its request and reads no more (backpressure), so a host that
        floods costs the line a bounded queue and no work per request."""
        key = source if peer is None else peer
        self._room_waiters.setdefault(key, {})[source] = callback

    def cancel(self, source: object) -> int:
        """Drop the waiting requests of ``source`` (a connection that closed); returns how many."""
        for key in [key for key, waiters in self._room_waiters.items() if source in waiters]:
            del self._room_waiters[key][source]
            if not self._room_waiters[key]:
                del self._room_waiters[key]
        peer = self._peer_of.pop(source, _NO_PEER)
        if peer is _NO_PEER:
            return 0
        sources = self._queues[peer]
        queue = sources.pop(source)
        if not sources:
            del self._queues[peer]
        for item in queue:
            item.waiting = False
        self._forget(peer, len(queue))
        self.cancelled += len(queue)
        self._compact()
        return len(queue)

    def _compact(self) -> None:
        """Drop the deadlines of requests no longer waiting once they are most of the heap: a host that opens and
        closes connections costs no memory beyond what waits (the heap forgets served and cancelled requests
        lazily, at their deadline, and each holds its connection until then)."""
        heap = self._deadlines
        while heap and not heap[0][2].waiting:  # the one served is most often the earliest: it goes at once
            heapq.heappop(heap)
        if len(heap) > 2 * self._count + 64:
            heap[:] = [entry for entry in heap if entry[2].waiting]  # in place: a caller may hold the list
            heapq.heapify(heap)

    def _forget(self, peer: object, count: int) -> None:
        self._count -= count
        left = self._peer_waiting[peer] - count
        if left:
            self._peer_waiting[peer] = left
        else:
            del self._peer_waiting[peer]
        waiters = self._room_waiters.get(peer)
        if waiters:
            for _ in range(min(count, len(waiters))):
                source = next(iter(waiters))
                self._loop().call_soon(waiters.pop(source))
            if not waiters:
                del self._room_waiters[peer]

    def close(self) -> None:
        self._unwatch()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._queues.clear()
        self._peer_of.clear()
        self._peer_waiting.clear()
        self._room_waiters.clear()
        self._deadlines.clear()
        self._count = 0
        self._busy = False

    def _next(self) -> _Waiting:
        """The next request in turn: the first peer's first master's first; both go to the back of their turns.
        The peer and the master served last go behind the others first (their queue may have been empty then)."""
        queues = self._queues
        peer, sources = next(iter(queues.items()))
        if peer is self._last_peer and len(queues) > 1:
            del queues[peer]
            queues[peer] = sources
            peer, sources = next(iter(queues.items()))
        source, queue = next(iter(sources.items()))
        if source is self._last_source and len(sources) > 1:
            del sources[source]
            sources[source] = queue
            source, queue = next(iter(sources.items()))
        self._last_peer = peer
        item = queue.popleft()
        del sources[source]
        if queue:
            sources[source] = queue  # to the back of its peer's masters
        else:
            del self._peer_of[source]
        del self._queues[peer]
        if sources:
            self._queues[peer] = sources  # to the back of the peers
        item.waiting = False
        self._forget(peer, 1)
        self._compact()
        return item

    def _expire_due(self, now: float) -> None:
        """Take out every waiting request past its deadline, and let its submitter answer it."""
        heap = self._deadlines
        while heap and heap[0][0] <= now:
            item = heapq.heappop(heap)[2]
            if not item.waiting:
                continue
            sources = self._queues[item.peer]
            queue = sources[item.source]
            queue.remove(item)
            if not queue:
                del sources[item.source]
                del self._peer_of[item.source]
                if not sources:
                    del self._queues[item.peer]
            item.waiting = False
            self._forget(item.peer, 1)
            self.expired += 1
            if item.expire is not None:
                try:
                    item.expire()
                except Exception:
                    log.exception("bug while answering an expired request; the simulator keeps serving")
            else:
                _deliver(item.respond, None)

    def _serve_waiting(self) -> None:
        while self._count and not self._busy:
            for sweep in self.sweeps:
                sweep()  # may cancel the requests of masters that went
            if self._deadlines:
                self._expire_due(time.perf_counter())
            if not self._count:
                return
            item = self._next()
            event, respond, source = item.event, item.respond, item.source
            asked = on_line = event.t
            if asked < self._held_until and self._queued_for_the_line(event, respond, source):
                on_line = self._held_until
            # the line takes requests in order: none is logged before the last (a master's second request, read
            # with its first, behind another master's that waited for the line)
            on_line = max(on_line, self._last_on_line)
            if on_line != asked:
                event = dataclasses.replace(event, t=on_line)
            self._last_source, self._last_on_line = source, on_line
            self._in_hand = True  # a baud the bus tells now waits until this reply is handed over
            # with bus timing the transaction starts on the line when it is free, and its reply's record is stamped
            # at the transaction's end there: when the reply is handed over (its last byte leaves)
            start = max(time.perf_counter(), self._held_until)
            self.sim.bus.timed_from = (start, isinstance(respond, SelfTimed)) if self.bus_timing else None
            failed = False
            try:
                reply = self.sim.handle(event)
            except Exception:
                log.exception("bug while serving %s; the simulator keeps serving", event)
                reply, failed = None, True
            finally:
                self.sim.bus.timed_from = None  # a request served without the line (a scenario's) stamps as untimed
            if failed:  # (not a continue inside the finally's try: mypyc, which compiles this module, has none)
                self._in_hand = False
                _deliver(respond, None)  # the line stays silent, and whoever waits learns it at once
                self._announce_baud()
                continue
            hold = reply.delay if reply is not None else 0.0
            if self.bus_timing:
                bus = self.sim.bus
                hold = bus.last_line_time - (bus.last_request_time if isinstance(respond, SelfTimed) else 0.0)
            if hold > 0:
                self.busy_seconds += hold
                if reply is None or isinstance(respond, SelfTimed):
                    if reply is not None:
                        self.latency.observe(time.perf_counter() - asked)
                    _deliver(respond, reply)  # silence is known at once; a line-timed port paces its own reply
                    respond = _nothing
                self._busy = True
                self._in_hand = False
                due = start + hold if self.bus_timing else max(time.perf_counter(), self._held_until) + hold
                self._held_until = due
                self._timer = due_timer(self._loop(), due, self._release, reply, respond, asked)
                return
            if reply is not None:
                self.latency.observe(time.perf_counter() - asked)
            _deliver(respond, reply)
            self._in_hand = False
            self._announce_baud()

    def _queued_for_the_line(self, event: FrameEvent, respond: Respond, source: object) -> bool:
        """True when a request that came while the line was the last transaction's waited for the line, as
        behind a serial device server or a gateway, which puts it on the line when that transaction ends: that
        is then its time in the frame log, as a request that found the line free has its arrival's. So the
        audit judges the line by the times it was used: two masters that each wait for their replies do not
        collide, nor does a Modbus TCP client's second request in flight. A master's own next RTU request sent
        before its reply keeps its arrival (on a real line it collides with the reply), and so does every
        request of a port whose bytes are on the line as they come (line-timed)."""
        if isinstance(respond, SelfTimed):
            return False
        return event.mbap is not None or source is not self._last_source

    def _release(self, reply: Reply | None, respond: Respond, asked: float) -> None:
        self._timer = None
        self._busy = False
        if reply is not None and respond is not _nothing:  # handed over now: its latency ends here
            self.latency.observe(time.perf_counter() - asked)
        _deliver(respond, reply)
        self._announce_baud()
        self._serve_waiting()

    def _line_told(self, settings: LineSettings) -> None:
        """The bus's word that the line changed: a new baud goes to the endpoints now, or, while a reply is in hand
        or held, once it is handed over (at the old baud)."""
        if settings.baud != self._settings.baud:
            self._told = settings.baud
        self._settings = settings
        if not self._in_hand and not self._busy:
            self._announce_baud()

    def _announce_baud(self) -> None:
        baud = self._told
        if baud is None:
            return
        self._told = None
        for listener in list(self._baud_listeners):
            try:
                listener(baud)
            except Exception:
                log.exception("bug while changing a port to %d baud; the simulator keeps serving", baud)


_NO_PEER = object()


def _deliver(respond: Respond, reply: Reply | None) -> None:
    try:
        respond(reply)
    except Exception:
        log.exception("bug while sending %s; the simulator keeps serving", reply)

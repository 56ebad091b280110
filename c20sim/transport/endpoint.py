"""One stream of RTU bytes in front of the line: the glue every transport shares.

A pty, a serial port and each RTU-over-TCP connection own an
:class:`RtuEndpoint`: bytes go into its framer stamped with the loop's time,
silence is watched with a timer at the framer's deadline, and each framing
event goes to the shared :class:`~c20sim.transport.line.Line`, which serves
requests from every stream one at a time. The reply comes back through
``send`` on the stream that asked, with the baud it goes out at.

Backpressure: an endpoint has at most ``limit`` requests on the line (one,
as an RTU master waits for each answer) and no reply it could not hand to
its stream; at its limit it reads on until its next request is framed and
held (stamped with its arrival: a master that retries before its reply is
seen doing so, at the time it did), then, as while a reply cannot be handed
over, it asks its transport to stop reading, so the kernel's buffer and TCP
flow control hold the rest, as libmodbus's server loop does. Frames already read wait in the framer, bounded by one
read, and framed a slice at a time as room comes (framing a 64 KiB burst
at once would hold the loop for tens of milliseconds). When the endpoint
closes, its requests still waiting on the line are dropped, with the bytes
not yet framed.

Arrival times come from ``time.perf_counter``, not the loop's clock: uvloop's
loop time has 1 ms resolution, coarser than t1.5 at 19200 baud (0.86 ms).
The loop only schedules the silence timer.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
from collections.abc import Callable

from ..core.bus import Reply
from ..wire.framing import RtuFramer
from ..wire.protocol import SHEET_CHAR_BITS, FrameEvent, char_time
from .line import Line

__all__ = ["UNTIMED_SILENCE", "RtuEndpoint", "stream_framer"]

#: Silence that ends a broken frame where bytes carry no line timing (TCP, a pty or a USB adapter without
#: --line-timing): lenient, since operating systems deliver bytes in bursts. A valid frame completes on its
#: length at once; only a broken one waits this long.
UNTIMED_SILENCE = 0.02

log = logging.getLogger(__name__)

#: Bytes of a read handed to the framer at a time: more than any frame, so a normal read is one slice.
FEED_SLICE = 512


def stream_framer(baud: int, *, line_timing: bool = False, bits: int = SHEET_CHAR_BITS) -> RtuFramer:
    """The framer of a byte stream: strict, held to t1.5/t3.5 with line timing, else completed on length.

    ``bits``: bits of one character in the line's format (10 for 8N1; see :func:`~c20sim.wire.protocol.char_bits`).
    """
    if line_timing:
        return RtuFramer(baud, bits=bits, strict=True)
    return RtuFramer(baud, complete_on_length=True, check_gaps=False, silence=UNTIMED_SILENCE)


class RtuEndpoint:
    """Frames a byte stream for the line; ``send`` writes a reply to the same stream."""

    def __init__(
        self,
        line: Line,
        framer: RtuFramer,
        send: Callable[[bytes, int], None],
        *,
        on_baud: Callable[[int], None] | None = None,
        name: str = "",
        pause: Callable[[], None] | None = None,
        resume: Callable[[], None] | None = None,
        limit: int = 1,
        peer: object = None,
        wait_limit: float | None = None,
    ) -> None:
        self.line = line
        self.framer = framer
        self._send = send
        self._on_baud = on_baud
        self.name = name
        self._pause = pause
        self._resume = resume
        self.limit = limit
        self.peer = peer  #: the line's turns: the address the stream comes from (None: it is its own peer)
        self.wait_limit = wait_limit  #: a request that waited this long for the line is dropped (None: never)
        self._loop = asyncio.get_running_loop()
        self._tick: asyncio.TimerHandle | None = None
        self._closed = False
        self._detach = line.on_baud(self._baud_changed)
        self._outstanding = 0  #: requests on the line, not yet answered
        self._held: FrameEvent | None = None  #: the next framed request, waiting for room on the line
        self._write_blocked = False
        self._paused = False
        self._wake: asyncio.Handle | None = None
        self._unfed = bytearray()  #: bytes read but not yet framed (all of one read, back to back)
        self._unfed_t = 0.0
        self._resumed_at = 0.0
        self._at_limit = False  #: the stream had its limit of requests on the line when last collected
        self._just_resumed = False
        self._generation = 0  #: bumped when the stream's master goes: older requests are not answered
        self._respond_now = functools.partial(self._respond, 0)  #: the respond of this generation's requests

    @property
    def outstanding(self) -> int:
        """Requests of this endpoint on the line, not yet answered."""
        return self._outstanding

    @property
    def between_frames(self) -> bool:
        """True when no bytes of an unfinished frame wait: the next bytes start a frame."""
        return not self._unfed and not self.framer.pending

    @property
    def paused(self) -> bool:
        """True while the transport is asked not to read."""
        return self._paused

    def write_blocked(self, blocked: bool) -> None:
        """The stream will take no more replies for now (its buffer is full), or will again."""
        self._write_blocked = blocked
        if not blocked:
            self._schedule_collect()
        else:
            self._flow()

    def feed(self, data: bytes) -> None:
        """Bytes arrived now."""
        if self._closed:
            return
        now = time.perf_counter()
        if (self._just_resumed or self._at_limit) and self.framer.pending and not self._unfed:
            # The first bytes read after a pause were held by us, not silent, and so is the rest of a frame read
            # while the stream is at its limit on the line (it would wait for the line): they follow the buffered
            # ones.
            deadline = self.framer.deadline()
            assert deadline is not None
            now = min(now, deadline - self.framer.t35 + len(data) * char_time(self.framer.baud))
        self._just_resumed = False
        if not self._unfed and self._held is None and len(data) <= FEED_SLICE:
            self.framer.feed(data, now)  # the usual read, framed at once: what a first slice would be
        else:
            self._unfed += data
            self._unfed_t = now
        self._collect()

    def close(self) -> None:
        """Stop serving; a half-received frame is dropped, waiting requests are dropped, a pending reply is not
        sent."""
        self._closed = True
        self._detach()
        self.line.cancel(self)
        self._held = None
        self._unfed.clear()
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None

    def reset(self) -> None:
        """The stream's master went away: drop its requests waiting on the line and the bytes not yet framed."""
        self.line.cancel(self)
        self._generation += 1  # a reply still due to the old master is dropped
        self._respond_now = functools.partial(self._respond, self._generation)
        self._outstanding = 0
        self._held = None
        self._unfed.clear()
        self.framer.flush()
        while self.framer.next_event() is not None:
            pass
        self._schedule_collect()

    def _collect(self) -> None:
        if self._closed:
            return
        while self._outstanding < self.limit and not self._write_blocked:
            event = self._held if self._held is not None else self._next_event()
            self._held = None
            if event is None:
                break
            if not self.line.has_room(self.peer, self):
                self._held = event  # its peer's queue is full: held, and nothing more is read, until there is room
                self.line.when_room(self.peer, self, self._schedule_collect)
                break
            self._outstanding += 1
            if not self.line.submit(event, self._respond_now, self, peer=self.peer, wait_limit=self.wait_limit):
                self._outstanding -= 1  # its peer's queue is full: dropped, as a device server drops it (counted)
        if self._held is None and (self._outstanding >= self.limit or self._write_blocked):
            self._held = self._next_event()
        self._flow()
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        # No silence is timed while bytes wait unframed or unread (paused): they follow the buffered ones at once;
        # nor while the stream is at its limit on the line: the rest of a frame read meanwhile would wait for the
        # line there anyway, and its silence counts from when the stream may send again.
        at_limit = self._outstanding >= self.limit
        if self._at_limit and not at_limit:
            self._resumed_at = time.perf_counter()
        self._at_limit = at_limit
        waits = self._unfed or self._paused or at_limit
        deadline = self._deadline() if self.framer.pending and not waits else None
        if deadline is not None:
            self._tick = self._loop.call_later(max(0.0, deadline - time.perf_counter()), self._on_silence)

    def _next_event(self) -> FrameEvent | None:
        """The next framed event, framing the bytes read a slice at a time until there is one."""
        event = self.framer.next_event()
        while event is None and self._unfed:
            chunk = bytes(self._unfed[:FEED_SLICE])
            del self._unfed[:FEED_SLICE]
            self.framer.feed(chunk, self._unfed_t)
            event = self.framer.next_event()
        return event

    def _on_silence(self) -> None:
        self._tick = None
        now = time.perf_counter()
        deadline = self._deadline()
        if deadline is not None and now < deadline:  # the loop's timer fired early (its clock is coarser)
            self._tick = self._loop.call_later(deadline - now, self._on_silence)
            return
        self.framer.tick(now)
        self._collect()

    def _deadline(self) -> float | None:
        """When silence ends the buffered frame: the framer's time, but counted from a resume at the earliest
        (bytes the transport held while paused were not silence)."""
        deadline = self.framer.deadline()
        return None if deadline is None else max(deadline, self._resumed_at + self.framer.t35)

    def _flow(self) -> None:
        """Ask the transport to stop reading while the line or the stream has no room, and to read again."""
        # At its limit of requests on the line the stream is still read until its next request is framed (held):
        # that request's arrival is stamped as it came, so a master that sends again before its reply (an early
        # retry) is seen doing so, as a capture of the stream sees it; then nothing more is read.
        hold = self._held is not None or bool(self._unfed) or self._write_blocked
        if hold and not self._paused and self._pause is not None:
            self._paused = True
            self._pause()
        elif not hold and self._paused and self._resume is not None:
            self._paused = False
            self._resumed_at = time.perf_counter()
            self._just_resumed = True
            self._resume()

    def _schedule_collect(self) -> None:
        # Not at once: a reply is delivered from inside the line's loop, and the next request of the same
        # stream goes behind those other streams have already queued.
        if self._wake is None and not self._closed:
            self._wake = self._loop.call_soon(self._woken)

    def _woken(self) -> None:
        self._wake = None
        self._collect()

    def _respond(self, generation: int, reply: Reply | None) -> None:
        if generation != self._generation:
            return  # asked by a master that has gone (counted off by reset)
        self._outstanding -= 1
        if self._closed:
            return
        if self._held is not None or self._unfed or self._paused or self.framer.pending:
            self._schedule_collect()  # else nothing waits: the next read frames and submits by itself
        if reply is None:
            return
        if reply.split > 0 and len(reply.data) > 1:  # a link fault: the reply in two pieces, a gap between
            half = len(reply.data) // 2
            self._write(reply.data[:half], reply.baud)
            self._loop.call_later(reply.split, self._write, reply.data[half:], reply.baud)
            return
        self._write(reply.data, reply.baud)

    def _write(self, data: bytes, baud: int) -> None:
        if self._closed:
            return
        try:
            self._send(data, baud)
        except OSError as exc:
            log.info("reply on %s not sent: %s", self.name, exc)

    def _baud_changed(self, baud: int) -> None:
        self.framer.set_baud(baud)
        if self._on_baud is not None:
            self._on_baud(baud)

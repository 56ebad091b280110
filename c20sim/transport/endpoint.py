"""One stream of RTU bytes in front of the line: the glue every transport shares.

A pty, a serial port and each RTU-over-TCP connection own an
:class:`RtuEndpoint`: bytes go into its framer stamped with the loop's time,
silence is watched with a timer at the framer's deadline, and each framing
event goes to the shared :class:`~c20sim.transport.line.Line`, which serves
requests from every stream one at a time. The reply comes back through
``send`` on the stream that asked, with the baud it goes out at.

Arrival times come from ``time.perf_counter``, not the loop's clock: uvloop's
loop time has 1 ms resolution, coarser than t1.5 at 19200 baud (0.86 ms).
The loop only schedules the silence timer.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from ..bus import Reply
from ..protocol import SHEET_CHAR_BITS, RtuFramer
from .line import Line

__all__ = ["UNTIMED_SILENCE", "RtuEndpoint", "stream_framer"]

#: Silence that ends a broken frame where bytes carry no line timing (TCP, a pty or a USB adapter without
#: --line-timing): lenient, since operating systems deliver bytes in bursts. A valid frame completes on its
#: length at once; only a broken one waits this long.
UNTIMED_SILENCE = 0.02

log = logging.getLogger(__name__)


def stream_framer(baud: int, *, line_timing: bool = False, bits: int = SHEET_CHAR_BITS) -> RtuFramer:
    """The framer of a byte stream: strict, held to t1.5/t3.5 with line timing, else completed on length.

    ``bits``: bits of one character in the line's format (10 for 8N1; see :func:`~c20sim.protocol.char_bits`).
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
    ) -> None:
        self.line = line
        self.framer = framer
        self._send = send
        self._on_baud = on_baud
        self.name = name
        self._loop = asyncio.get_running_loop()
        self._tick: asyncio.TimerHandle | None = None
        self._closed = False
        self._detach = line.on_baud(self._baud_changed)

    def feed(self, data: bytes) -> None:
        """Bytes arrived now."""
        if self._closed:
            return
        self.framer.feed(data, time.perf_counter())
        self._collect()

    def close(self) -> None:
        """Stop serving; a half-received frame is dropped, a pending reply is not sent."""
        self._closed = True
        self._detach()
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None

    def _collect(self) -> None:
        event = self.framer.next_event()
        while event is not None:
            self.line.submit(event, self._respond)
            event = self.framer.next_event()
        if self._tick is not None:
            self._tick.cancel()
            self._tick = None
        deadline = self.framer.deadline()
        if deadline is not None:
            self._tick = self._loop.call_later(max(0.0, deadline - time.perf_counter()), self._on_silence)

    def _on_silence(self) -> None:
        self._tick = None
        now = time.perf_counter()
        deadline = self.framer.deadline()
        if deadline is not None and now < deadline:  # the loop's timer fired early (its clock is coarser)
            self._tick = self._loop.call_later(deadline - now, self._on_silence)
            return
        self.framer.tick(now)
        self._collect()

    def _respond(self, reply: Reply | None) -> None:
        if reply is None or self._closed:
            return
        try:
            self._send(reply.data, reply.baud)
        except OSError as exc:
            log.info("reply on %s not sent: %s", self.name, exc)

    def _baud_changed(self, baud: int) -> None:
        self.framer.set_baud(baud)
        if self._on_baud is not None:
            self._on_baud(baud)

"""One stream of RTU bytes in front of the line: the glue every transport shares.

A pty, a serial port and each RTU-over-TCP connection own an
:class:`RtuEndpoint`: bytes go into its framer stamped with the loop's time,
silence is watched with a timer at the framer's deadline, and each framing
event goes to the shared :class:`~c20sim.transport.line.Line`, which serves
requests from every stream one at a time. The reply comes back through
``send`` on the stream that asked.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from ..bus import Reply
from ..protocol import RtuFramer
from .line import Line

__all__ = ["RtuEndpoint"]

log = logging.getLogger(__name__)


class RtuEndpoint:
    """Frames a byte stream for the line; ``send`` writes a reply to the same stream."""

    def __init__(
        self,
        line: Line,
        framer: RtuFramer,
        send: Callable[[bytes], None],
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

    def feed(self, data: bytes) -> None:
        """Bytes arrived now."""
        if self._closed:
            return
        self.framer.feed(data, self._loop.time())
        self._collect()

    def close(self) -> None:
        """Stop serving; a half-received frame is dropped, a pending reply is not sent."""
        self._closed = True
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
            self._tick = self._loop.call_at(deadline, self._on_silence)

    def _on_silence(self) -> None:
        self._tick = None
        self.framer.tick(self._loop.time())
        self._collect()

    def _respond(self, reply: Reply | None) -> None:
        if reply is None or self._closed:
            return
        try:
            self._send(reply.data)
        except OSError as exc:
            log.info("reply on %s not sent: %s", self.name, exc)
            return
        if reply.new_baud is not None:
            self.framer.set_baud(reply.new_baud)
            if self._on_baud is not None:
                self._on_baud(reply.new_baud)

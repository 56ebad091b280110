"""One stream of RTU bytes in front of the simulator: the glue every transport shares.

A pty, a serial port and each RTU-over-TCP connection own an
:class:`RtuEndpoint`: bytes go into its framer stamped with the loop's time,
silence is watched with a timer at the framer's deadline, and each framing
event is served under the line's lock, so that requests from several
connections are served one at a time, as on one RS485 line. The reply goes
back on the stream that asked, after the turnaround delay.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable

from ..protocol import FrameEvent, RtuFramer
from ..simulator import Simulator

__all__ = ["RtuEndpoint"]

log = logging.getLogger(__name__)


class RtuEndpoint:
    """Frames a byte stream and serves it; ``send`` writes a reply to the same stream."""

    def __init__(
        self,
        sim: Simulator,
        framer: RtuFramer,
        send: Callable[[bytes], Awaitable[None]],
        line: asyncio.Lock,
        *,
        on_baud: Callable[[int], None] | None = None,
        name: str = "",
    ) -> None:
        self.sim = sim
        self.framer = framer
        self._send = send
        self._line = line
        self._on_baud = on_baud
        self.name = name
        self._loop = asyncio.get_running_loop()
        self._events: asyncio.Queue[FrameEvent] = asyncio.Queue()
        self._tick: asyncio.TimerHandle | None = None
        self._worker = asyncio.create_task(self._serve(), name=f"c20sim endpoint {name}")

    def feed(self, data: bytes) -> None:
        """Bytes arrived now."""
        self.framer.feed(data, self._loop.time())
        self._collect()

    def close(self) -> None:
        """Stop serving; a half-received frame is dropped."""
        if self._tick is not None:
            self._tick.cancel()
        self._worker.cancel()

    async def wait_closed(self) -> None:
        with contextlib.suppress(asyncio.CancelledError):
            await self._worker

    def _collect(self) -> None:
        for event in self.framer.events():
            self._events.put_nowait(event)
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

    async def _serve(self) -> None:
        while True:
            event = await self._events.get()
            async with self._line:
                try:
                    reply = self.sim.handle(event)
                except Exception:
                    log.exception("bug while serving %s on %s; the simulator keeps serving", event, self.name)
                    continue
                if reply is None:
                    continue
                if reply.delay > 0:
                    await asyncio.sleep(reply.delay)
                try:
                    await self._send(reply.data)
                except (ConnectionError, OSError) as exc:
                    log.info("reply on %s not sent: %s", self.name, exc)
                    continue
                if reply.new_baud is not None:
                    self.framer.set_baud(reply.new_baud)
                    if self._on_baud is not None:
                        self._on_baud(reply.new_baud)

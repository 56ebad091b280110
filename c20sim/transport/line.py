"""The shared line: one request at a time, and a reply holds the line for its turnaround.

Every transport hands its framing events to the one :class:`Line` of its
simulator, with a callback that puts the reply on the stream that asked. The
bus serves events in arrival order; a reply due after a delay (the profile's
turnaround, an injected delay) keeps the line busy until it is sent, and the
events that arrive meanwhile wait their turn, as on a real RS485 line or
behind a serial gateway. No task and no lock per request: callbacks on the
event loop, which is what keeps a request cheap.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable

from ..bus import Reply
from ..protocol import FrameEvent
from ..simulator import Simulator

__all__ = ["Line", "Respond"]

log = logging.getLogger(__name__)

#: Called with the reply to put on the wire, or None where the line stays silent.
Respond = Callable[[Reply | None], None]


class Line:
    """Serves framing events from every endpoint of one simulator, in order."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self._waiting: deque[tuple[FrameEvent, Respond]] = deque()
        self._busy = False
        self._timer: asyncio.TimerHandle | None = None

    @property
    def busy(self) -> bool:
        """True while a delayed reply holds the line."""
        return self._busy

    def submit(self, event: FrameEvent, respond: Respond) -> None:
        """Serve ``event`` now if the line is free, else when it is."""
        self._waiting.append((event, respond))
        if not self._busy:
            self._serve_waiting()

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self._waiting.clear()
        self._busy = False

    def _serve_waiting(self) -> None:
        while self._waiting and not self._busy:
            event, respond = self._waiting.popleft()
            try:
                reply = self.sim.handle(event)
            except Exception:
                log.exception("bug while serving %s; the simulator keeps serving", event)
                continue
            if reply is not None and reply.delay > 0:
                self._busy = True
                loop = asyncio.get_running_loop()
                self._timer = loop.call_later(reply.delay, self._release, reply, respond)
                return
            _deliver(respond, reply)

    def _release(self, reply: Reply, respond: Respond) -> None:
        self._timer = None
        self._busy = False
        _deliver(respond, reply)
        self._serve_waiting()


def _deliver(respond: Respond, reply: Reply | None) -> None:
    try:
        respond(reply)
    except Exception:
        log.exception("bug while sending %s; the simulator keeps serving", reply)

"""``GET /stream``: a WebSocket of telemetry and frame records, each reader with a bounded buffer of its own.

Each client has a bounded buffer of frames and one slot of telemetry: a client that reads slowly, or not at all,
skips frames and is told how many (``missed``); it never holds the serving loop or a reply.
"""

from __future__ import annotations

import asyncio
import json
import math
from collections import deque
from typing import Any, Protocol

from aiohttp import web

from ..core.bus import FrameRecord
from ..transport.wallclock import WALL_OFFSET

__all__ = ["MAX_STREAMS", "StreamClient", "StreamHost"]


class StreamHost(Protocol):
    """What the stream reads of the API (:class:`c20sim.control.http.ControlApi`)."""

    closing: bool

    def snapshot(self) -> dict[str, Any]: ...


#: The telemetry rates a stream client may ask for (``?hz=``), and the default.
STREAM_HZ = (0.1, 50.0)
DEFAULT_HZ = 5.0
#: A stream client's frame buffer (``?buffer=``): at most this many frames wait for it; older ones are skipped.
STREAM_BUFFER = (1, 10_000)
DEFAULT_BUFFER = 1000
#: Stream readers at once: each costs a buffer and a sender; beyond this the answer is 503.
MAX_STREAMS = 32
#: The query parameters of ``GET /stream``.
STREAM_QUERY = ("hz", "frame_hz", "buffer", "frames", "token")
#: Frame batches a second a client may ask for (``?frame_hz=``), and the default: a busy bus costs a reader at
#: most ``buffer`` frames a batch.
FRAME_HZ = (0.1, 100.0)
DEFAULT_FRAME_HZ = 20.0
#: Frames put in words per turn of the loop: a big batch is cut so that a request waits for no more than one chunk.
CHUNK = 32


class StreamClient:
    """One stream reader: a bounded buffer of frames (the oldest skipped when full) and a wake-up."""

    def __init__(self, buffer: int) -> None:
        self.frames: deque[tuple[int, FrameRecord]] = deque(maxlen=buffer)
        self.wake = asyncio.Event()
        self.sent = -1  #: the seq of the last frame sent (or skipped past)

    def push(self, seq: int, record: FrameRecord) -> None:
        self.frames.append((seq, record))  # a full deque drops its oldest: that is the skip
        if not self.wake.is_set():
            self.wake.set()


async def _drain(ws: web.WebSocketResponse) -> None:
    async for _message in ws:
        pass


async def _serve_stream(
    api: StreamHost,
    ws: web.WebSocketResponse,
    client: StreamClient,
    period: float,
    frame_period: float,
    reader: asyncio.Future[Any],
) -> None:
    """Send telemetry every ``period`` and the frames as they come, until the client goes or the API closes.

    Sending waits for the client (a full socket holds this task only); meanwhile its frame buffer fills and
    the oldest frames are skipped, counted in the next message's ``missed``.
    """
    loop = asyncio.get_running_loop()
    due = frames_due = loop.time()
    while not ws.closed and not reader.done() and not api.closing:
        now = loop.time()
        if now >= due:
            await ws.send_str(json.dumps(api.snapshot()))
            due = _next_beat(due, period, loop.time())
            continue
        if client.frames and now >= frames_due:
            await _send_frames(ws, client)
            frames_due = _next_beat(frames_due, frame_period, loop.time())
            continue
        waits: list[asyncio.Future[Any]] = [reader]
        if client.frames:  # frames wait for their beat: more of them coming need not wake this task
            wake_at = min(due, frames_due)
        else:
            wake_at = due
            client.wake.clear()
            waits.append(asyncio.ensure_future(client.wake.wait()))
        await asyncio.wait(waits, timeout=max(0.0, wake_at - now), return_when=asyncio.FIRST_COMPLETED)
        for wait in waits[1:]:
            wait.cancel()


def _next_beat(last: float, period: float, now: float) -> float:
    """The first beat after ``now`` of a clock that ticked at ``last`` every ``period``: telemetry and frames asked
    for at the same rate go out together (one redraw for a viewer), and a late tick is not made up for."""
    return last + period * (math.floor((now - last) / period) + 1)


async def _send_frames(ws: web.WebSocketResponse, client: StreamClient) -> None:
    """The frames waiting, in words, as one message; ``missed``: how many were skipped since the last one."""
    batch: list[tuple[int, FrameRecord]] = []
    while client.frames:
        batch.append(client.frames.popleft())
    missed = batch[0][0] - client.sent - 1
    client.sent = batch[-1][0]
    records: list[dict[str, Any]] = []
    for start in range(0, len(batch), CHUNK):
        if start:
            await asyncio.sleep(0)  # let a request in between chunks
        records += [{"seq": seq, **record.as_dict(WALL_OFFSET)} for seq, record in batch[start : start + CHUNK]]
    await ws.send_str(json.dumps({"type": "frames", "missed": max(0, missed), "frames": records}))

"""The frame log's routes: ``GET /stream``, a WebSocket of telemetry and frame records, and ``GET /frames``,
``DELETE /frames`` (:func:`handlers`).

Each stream client has a bounded buffer of frames and one slot of telemetry: a client that reads slowly, or not at all,
skips frames and is told how many (``missed``); it never holds the serving loop or a reply.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections import deque
from typing import Any, Protocol

from aiohttp import web

from ..core.bus import FrameRecord
from ..core.simulator import Simulator
from ..transport.wallclock import WALL_OFFSET
from . import ops
from .httpbody import Handler, reply
from .ops import ControlError, unknown

log = logging.getLogger(__name__)

__all__ = ["MAX_STREAMS", "StreamClient", "StreamHost", "handlers"]


class StreamHost(Protocol):
    """What the frame log's routes read of the API (:class:`c20sim.control.http.ControlApi`)."""

    sim: Simulator
    closing: bool
    readers: int
    streams: set[StreamClient]
    #: serve's --log-frames writer, for its drop count (or None)
    frame_log: Any

    @property
    def seen(self) -> int: ...

    @property
    def first_seq(self) -> int: ...

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


def handlers(api: StreamHost) -> dict[str, Handler]:
    """The handlers of the frame log's rows, by the row's name."""

    async def stream(request: web.Request) -> web.StreamResponse:
        return await _stream(api, request)

    async def get_frames(request: web.Request) -> web.Response:
        return await _frames(api, request)

    async def delete_frames(request: web.Request) -> web.Response:
        api.sim.bus.records.clear()
        return reply({"frames": [], "next": api.seen})

    return {"stream": stream, "frames": get_frames, "clear_frames": delete_frames}


def _query_number(request: web.Request, name: str, default: float, bounds: tuple[float, float]) -> float:
    if name not in request.query:
        return default
    text = request.query[name]
    try:
        value = float(text)
    except ValueError:
        raise ControlError(f"{name}={text!r} is not a number; give {bounds[0]:g}-{bounds[1]:g}") from None
    if not bounds[0] <= value <= bounds[1]:
        raise ControlError(f"{name}={text}: outside {bounds[0]:g}-{bounds[1]:g}")
    return value


async def _stream(api: StreamHost, request: web.Request) -> web.StreamResponse:
    """``GET /stream``: the query checked, the WebSocket upgraded, served until the client or the API goes."""
    for key in request.query:
        if key not in STREAM_QUERY:
            raise unknown("query parameter", key, STREAM_QUERY)
    hz = _query_number(request, "hz", DEFAULT_HZ, STREAM_HZ)
    frame_period = 1.0 / _query_number(request, "frame_hz", DEFAULT_FRAME_HZ, FRAME_HZ)
    size = int(_query_number(request, "buffer", DEFAULT_BUFFER, STREAM_BUFFER))
    with_frames = request.query.get("frames", "1") not in ("0", "false", "no")
    if api.readers >= MAX_STREAMS:
        raise ControlError(f"{MAX_STREAMS} stream readers are attached already; close one first", status=503)
    # no compression: it would cost the serving loop CPU per message; a peer gone quiet delays a close by 1 s
    ws = web.WebSocketResponse(heartbeat=10.0, max_msg_size=4096, compress=False, timeout=1.0)
    client = StreamClient(size)
    api.readers += 1  # counted from here: the upgrade below awaits, and others may come meanwhile
    try:
        await ws.prepare(request)
        client.sent = api.seen - 1
        if with_frames:
            api.streams.add(client)
        # what the client sends is read (and ignored) beside the sender; it ends when the client goes
        reader: asyncio.Future[Any] = asyncio.ensure_future(_drain(ws))
        try:
            await _serve_stream(api, ws, client, 1.0 / hz, frame_period, reader)
        finally:
            reader.cancel()
            with contextlib.suppress(asyncio.CancelledError, ConnectionError):
                await reader  # the close below reads the peer's answer itself
            await ws.close()
    except ConnectionError:  # reset, or gone mid-message or mid-close: the reader has left, nothing to do
        log.debug("control API: a stream reader left (%s)", request.remote)
    finally:
        api.readers -= 1
        api.streams.discard(client)
    return ws


async def _frames(api: StreamHost, request: web.Request) -> web.Response:
    """``GET /frames``: the frame log, in words (a large answer put in words off the loop)."""
    query = request.query

    def arg(name: str, low: int) -> int | None:
        if name not in query:
            return None
        try:
            value = int(query[name])
        except ValueError:
            raise ControlError(f"{name}={query[name]!r} is not a number") from None
        if value < low:
            raise ControlError(f"{name}={value} must be at least {low}")
        return value

    for key in query:
        if key not in ("last", "slave", "since"):
            raise unknown("query parameter", key, ["last", "slave", "since"])
    kept = ops.select_frames(
        api.sim, last=arg("last", 1), slave=arg("slave", 0), since=arg("since", 0) or 0, first_seq=api.first_seq
    )
    dropped = api.frame_log.dropped if api.frame_log is not None else 0
    seen = api.seen
    if len(kept) <= CHUNK:
        return reply({"frames": ops.frames_in_words(kept, WALL_OFFSET), "next": seen, "log_dropped": dropped})

    def words() -> str:
        # the records are frozen: put in words and JSON in a worker thread, so a large answer (up to the whole
        # frame log) never holds the loop that answers the masters
        return json.dumps({"frames": ops.frames_in_words(kept, WALL_OFFSET), "next": seen, "log_dropped": dropped})

    return web.Response(text=await asyncio.to_thread(words), content_type="application/json")

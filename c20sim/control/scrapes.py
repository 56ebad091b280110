"""``GET /metrics`` answered off the serving loop: the figures read on the loop in turns, the text rendered in a
process of its own, and answers made within :data:`METRICS_CACHE` of each other shared."""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import logging
import os
import sys
import threading
from collections.abc import Callable
from typing import Any

from ..core.simulator import Simulator
from ..transport.line import Line

log = logging.getLogger(__name__)

__all__ = ["METRICS_CACHE", "METRICS_RATE", "Scrapes"]

_METRICS = "c20sim.control.metrics"

#: GET /metrics answers made within this many seconds of each other are one (a scrape every second or slower
#: is always fresh; four scrapers at once cost one).
METRICS_CACHE = 0.5

#: Answers a listener gives a second at most, all its scrapers together (assumed: a hundred times four
#: Prometheus servers' ``scrape_interval: 15s`` default and ten times four at 1 s, the shortest in common use).
#: A scrape over the rate waits for its turn, which costs nothing (how many wait is bounded by the listener's
#: connection cap); answered at once, four scrapers back to back took 3,000 answers a second, a third of a
#: core beside the wire (bench/RESULTS.md).
METRICS_RATE = 50.0

#: Seconds a closing listener waits for its killed metrics process to be reaped (a kill ends it at once).
RENDERER_JOIN = 5.0

#: Seconds the metrics process may take to start and import what it renders with (a loaded machine: seconds).
RENDERER_START = 60.0

#: How much lower the metrics process's priority is than the server's (``nice``; Unix).
RENDERER_NICE = 10


class Scrapes:
    """The scrapes of one listener: ``await scrape(accept, line)``; ``close()``."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        #: the last answer per format (when made, body, Content-Type), and the one being made
        self._scraped: dict[str, tuple[float, bytes, str]] = {}
        self._scraping: dict[str, asyncio.Future[tuple[bytes, str]]] = {}
        self._renderer: Any = None  #: the metrics process (a ProcessPoolExecutor of one), made at the first scrape
        self._renderer_failed = False
        self.closed = False
        #: guards the hand-over of a process started in a worker thread: a close meanwhile (even one that cancelled
        #: the scrape waiting for it) stops it, and none is left running
        self._lock = threading.Lock()
        #: the loop time from which the next answer may go (:data:`METRICS_RATE`)
        self._next_answer = 0.0

    async def scrape(self, accept: str, line: Line | None = None) -> tuple[bytes, str]:
        """GET /metrics' body and Content-Type. The figures are read on the loop, 32 drives a turn (about 10 us
        a drive); the families are built and written in a process of their own (tens of milliseconds of Python
        at 247 drives: on the loop they held the wire as long, and in a thread they would hold the interpreter's
        lock as long, in slices); scrapers within :data:`METRICS_CACHE` of each other, or asking while one is
        made, share one answer; and all scrapers together get :data:`METRICS_RATE` answers a second at most."""
        if _METRICS not in sys.modules:  # prometheus_client's import (tens of ms) in a worker thread, off the loop
            await asyncio.to_thread(importlib.import_module, _METRICS)
        from prometheus_client.exposition import choose_encoder

        from .metrics import render, snapshot_in_turns  # imports prometheus_client: only when scraped

        kind = choose_encoder(accept)[1]
        loop = asyncio.get_running_loop()
        await self._turn(loop)
        cached = self._scraped.get(kind)
        if cached is not None and loop.time() - cached[0] < METRICS_CACHE:
            return cached[1], cached[2]
        making = self._scraping.get(kind)
        if making is not None:
            return await asyncio.shield(making)
        future: asyncio.Future[tuple[bytes, str]] = loop.create_future()
        self._scraping[kind] = future
        try:
            taken = await snapshot_in_turns(self.sim, line)
            body, content_type = await self._render(render, taken, accept)
        except BaseException as exc:
            future.set_exception(exc)
            future.exception()  # retrieved: no "never retrieved" warning when nobody else waited
            raise
        finally:
            del self._scraping[kind]
        self._scraped[kind] = (loop.time(), body, content_type)
        future.set_result((body, content_type))
        return body, content_type

    async def _turn(self, loop: asyncio.AbstractEventLoop) -> None:
        """Wait for this scrape's turn: answers go :data:`METRICS_RATE` a second at most, in arrival order."""
        now = loop.time()
        at = max(now, self._next_answer)
        self._next_answer = at + 1.0 / METRICS_RATE
        if at > now:
            await asyncio.sleep(at - now)

    async def _render(self, render: Callable[..., tuple[bytes, str]], *args: object) -> tuple[bytes, str]:
        """``render(*args)`` in the metrics process; in a worker thread where a process cannot be started."""
        loop = asyncio.get_running_loop()
        if self._renderer is None and not self._renderer_failed:
            started = await asyncio.to_thread(self._start)
            self._renderer_failed = started is None
        if self._renderer is not None:
            try:
                return await loop.run_in_executor(self._renderer, render, *args)
            except (OSError, RuntimeError) as exc:  # BrokenProcessPool is a RuntimeError
                log.info("GET /metrics: the rendering process failed (%s); a worker thread does it", exc)
                _stop_renderer(self._renderer)
                self._renderer = None
                self._renderer_failed = True
        return await asyncio.to_thread(render, *args)

    def _start(self) -> Any:
        """In a worker thread: start the metrics process and hand it over, unless the listener closed meanwhile;
        the process in use (None: none)."""
        pool = _start_renderer()
        with self._lock:
            keep = pool is not None and not self.closed and self._renderer is None
            if keep:
                self._renderer = pool
            current = self._renderer
        if pool is not None and not keep:
            _stop_renderer(pool)  # closed while it started, or another scrape's came first: it goes at once
        return current

    def close(self) -> None:
        """Stop the metrics process (killed, reaped, its queues closed); a scrape after this renders in a thread."""
        with self._lock:
            self.closed = True
            pool, self._renderer = self._renderer, None
        if pool is not None:
            _stop_renderer(pool)


def _start_renderer() -> Any:
    """The metrics process (a ProcessPoolExecutor of one, "spawn": nothing of this process's threads is
    copied), started and warmed (c20sim and prometheus_client imported) in the calling worker thread: the fork,
    the exec and the first hand-off stay off the serving loop. The process runs at a lower priority
    (:data:`RENDERER_NICE`): on a machine with few cores its tens of milliseconds of rendering give way to the
    server and its masters. None where no process can be started."""
    import concurrent.futures
    import multiprocessing

    try:
        pool = concurrent.futures.ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"), initializer=_lower_priority
        )
        pool.submit(_warm).result(RENDERER_START)
    except (OSError, ValueError, NotImplementedError, RuntimeError, TimeoutError) as exc:
        log.info("GET /metrics: no process for the rendering (%s); a worker thread does it", exc)
        return None
    return pool


def _lower_priority() -> None:
    """The metrics process's initializer: :data:`RENDERER_NICE` (where the system has priorities)."""
    with contextlib.suppress(AttributeError, OSError):
        os.nice(RENDERER_NICE)


def _warm() -> None:
    """Import what rendering needs, in the metrics process, before the first snapshot is handed to it."""
    from . import metrics  # noqa: F401


def _stop_renderer(pool: Any) -> None:
    """End the metrics process now: a serve stopping waits for no scrape. The process is killed first (it may
    still be starting: a new interpreter importing c20sim, seconds on a loaded machine; the pool keeps its
    processes in ``_processes`` on every Python from 3.8 to 3.13); then the pool is shut down waiting for its
    manager thread, which sees the process gone, reaps it (no zombie) and closes the pool's queues, so their
    semaphores are released here rather than reported leaked by the resource tracker at exit (``shutdown(wait=False)``
    left both to the interpreter's exit)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            process.kill()
    pool.shutdown(wait=True, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError, AssertionError):
            process.join(RENDERER_JOIN)

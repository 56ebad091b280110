"""``GET /metrics`` answered off the serving loop: the figures read on the loop in turns, the text rendered in a
process of its own, and answers made within :data:`METRICS_CACHE` of each other shared."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from ..core.simulator import Simulator
from ..transport.line import Line

log = logging.getLogger(__name__)

__all__ = ["METRICS_CACHE", "Scrapes"]

#: GET /metrics answers made within this many seconds of each other are one (a scrape every second or slower
#: is always fresh; four scrapers at once cost one).
METRICS_CACHE = 0.5


class Scrapes:
    """The scrapes of one listener: ``await scrape(accept, line)``; ``close()``."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        #: the last answer per format (when made, body, Content-Type), and the one being made
        self._scraped: dict[str, tuple[float, bytes, str]] = {}
        self._scraping: dict[str, asyncio.Future[tuple[bytes, str]]] = {}
        self._renderer: Any = None  #: the metrics process (a ProcessPoolExecutor of one), made at the first scrape
        self._renderer_failed = False

    async def scrape(self, accept: str, line: Line | None = None) -> tuple[bytes, str]:
        """GET /metrics' body and Content-Type. The figures are read on the loop, 32 drives a turn (about 30 us
        a drive); the families are built and written in a process of their own (tens of milliseconds of Python
        at 247 drives: on the loop they held the wire as long, and in a thread they would hold the interpreter's
        lock as long, in slices); scrapers within :data:`METRICS_CACHE` of each other, or asking while one is
        made, share one answer."""
        from prometheus_client.exposition import choose_encoder

        from .metrics import render, snapshot_in_turns  # imports prometheus_client: only when scraped

        kind = choose_encoder(accept)[1]
        loop = asyncio.get_running_loop()
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

    async def _render(self, render: Callable[..., tuple[bytes, str]], *args: object) -> tuple[bytes, str]:
        """``render(*args)`` in the metrics process (started at the first scrape, "spawn": nothing of this
        process's threads is copied); in a worker thread where a process cannot be started."""
        loop = asyncio.get_running_loop()
        if self._renderer is None and not self._renderer_failed:
            import concurrent.futures
            import multiprocessing

            try:
                self._renderer = concurrent.futures.ProcessPoolExecutor(
                    max_workers=1, mp_context=multiprocessing.get_context("spawn")
                )
            except (OSError, ValueError, NotImplementedError) as exc:
                log.info("GET /metrics: no process for the rendering (%s); a worker thread does it", exc)
                self._renderer_failed = True
        if self._renderer is not None:
            try:
                return await loop.run_in_executor(self._renderer, render, *args)
            except (OSError, RuntimeError) as exc:  # BrokenProcessPool is a RuntimeError
                log.info("GET /metrics: the rendering process failed (%s); a worker thread does it", exc)
                _stop_renderer(self._renderer)
                self._renderer = None
                self._renderer_failed = True
        return await asyncio.to_thread(render, *args)

    def close(self) -> None:
        if self._renderer is not None:
            _stop_renderer(self._renderer)
            self._renderer = None


def _stop_renderer(pool: Any) -> None:
    """End the metrics process now: a serve stopping waits for no scrape. ``shutdown(wait=False)`` alone leaves
    the interpreter's exit joining the process, which may still be starting (a new interpreter importing c20sim:
    seconds on a loaded machine), so the process is killed too (the pool keeps its processes in ``_processes``
    on every Python from 3.8 to 3.13)."""
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            process.kill()

"""``GET /metrics`` off the serving loop (control/scrapes.py): the rendering process is stopped cleanly when the
listener closes (reaped, no warning), runs at a lower priority, and scrapers together get a bounded answer rate."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from c20sim.control import scrapes
from c20sim.control.scrapes import METRICS_RATE, RENDERER_NICE, Scrapes
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from tests.conftest import wait_for_ready_file

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc (Linux)")


def _sim() -> Simulator:
    return Simulator(load_profile("c20-400hr"), (1, 2, 3), clock=VirtualClock())


def _renderer_pid(taken: Scrapes) -> int:
    processes = list(taken._renderer._processes.values())  # the pool of one
    assert len(processes) == 1
    pid = processes[0].pid
    assert isinstance(pid, int)
    return pid


def _nice(pid: int) -> int:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[16])  # the 19th field of stat: nice


def test_close_kills_and_reaps_the_rendering_process() -> None:
    async def scrape_then_close() -> tuple[int, int, bytes]:
        taken = Scrapes(_sim())
        body, _ = await taken.scrape("")
        pid = _renderer_pid(taken)
        nice = _nice(pid)
        taken.close()
        return pid, nice, body

    pid, nice, body = asyncio.run(scrape_then_close())
    assert b'c20sim_requests_total{drive="3"} 0.0' in body  # rendered, by the process
    assert nice == os.getpriority(os.PRIO_PROCESS, 0) + RENDERER_NICE
    # reaped by close itself: no zombie left to this process (waitpid knows no such child), and gone
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)
    assert not Path(f"/proc/{pid}").exists()


def test_a_close_while_the_process_starts_leaves_none(monkeypatch: pytest.MonkeyPatch) -> None:
    started, closed = threading.Event(), threading.Event()
    real = scrapes._start_renderer
    pids: list[int] = []

    def slow_start() -> object:
        pool = real()  # started and warmed; then held until the listener has closed
        pids.extend(process.pid for process in pool._processes.values())
        started.set()
        closed.wait(30)
        return pool

    monkeypatch.setattr(scrapes, "_start_renderer", slow_start)

    async def close_while_starting() -> None:
        taken = Scrapes(_sim())
        scrape = asyncio.create_task(taken.scrape(""))
        assert await asyncio.to_thread(started.wait, 30)
        taken.close()  # as serve's close: the scrape waiting for the process is cancelled with the loop's tasks
        scrape.cancel()
        closed.set()
        with contextlib.suppress(asyncio.CancelledError):
            await scrape
        assert taken._renderer is None

    asyncio.run(close_while_starting())  # asyncio.run waits for the worker thread that started the process
    (pid,) = pids
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # stopped and reaped by the thread that started it: none left running
    assert not Path(f"/proc/{pid}").exists()


def test_a_scrape_after_close_renders_in_a_thread_and_starts_no_process() -> None:
    async def close_then_scrape() -> tuple[bytes, object]:
        taken = Scrapes(_sim())
        taken.close()
        body, _ = await taken.scrape("")
        return body, taken._renderer

    body, renderer = asyncio.run(close_then_scrape())
    assert b"c20sim_model_time_seconds 0.0" in body
    assert renderer is None


def test_scrapers_together_get_answers_at_the_rate_and_in_arrival_order(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(scrapes, "METRICS_CACHE", 60.0)  # every answer from the cache: only the rate paces them

    async def ten_at_once() -> list[tuple[int, float]]:
        taken = Scrapes(_sim())
        try:
            await taken.scrape("")  # the first answer: rendered
            loop = asyncio.get_running_loop()
            answered: list[tuple[int, float]] = []

            async def one(i: int) -> None:
                await taken.scrape("")
                answered.append((i, loop.time()))

            began = loop.time()
            await asyncio.gather(*(one(i) for i in range(10)))
            return [(i, t - began) for i, t in answered]
        finally:
            taken.close()

    answered = asyncio.run(ten_at_once())
    assert [i for i, _ in answered] == list(range(10))
    times = [t for _, t in answered]
    # each waits for its slot, one every 1/METRICS_RATE after the first's: never sooner (less the loop's timer
    # granularity; a late turn of the loop may make one later); ten answered at once would come within 1 ms
    early = [times[0] + k / METRICS_RATE - 0.002 - t for k, t in enumerate(times)]
    assert max(early) <= 0, times


def test_serve_stopped_after_a_scrape_exits_0_with_nothing_on_stderr_and_no_renderer_left(tmp_path: Path) -> None:
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "c20sim",
            "serve",
            "--tcp",
            "127.0.0.1:0",
            "--metrics",
            "127.0.0.1:0",
            "--ready-file",
            str(ready),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        info = wait_for_ready_file(ready, proc, timeout=60)
        with urllib.request.urlopen(info["metrics"], timeout=30) as response:
            assert b"c20sim_requests_total" in response.read()
        children = [
            int(pid)
            for task in Path(f"/proc/{proc.pid}/task").iterdir()
            for pid in (task / "children").read_text().split()
        ]
        renderers = [pid for pid in children if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()]
        assert len(renderers) == 1
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    assert err.decode() == ""  # no "leaked semaphore objects" from the resource tracker, no traceback
    deadline = time.monotonic() + 10
    while Path(f"/proc/{renderers[0]}").exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert not Path(f"/proc/{renderers[0]}").exists()

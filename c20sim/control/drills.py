"""The drill on a served simulator (``POST /drill``, ``GET /drill``, ``DELETE /drill``): one at a time, run off the
serving loop.

The runner itself (:func:`c20sim.drillrun.serve_runner`) lives with the front ends; ``serve`` attaches it to its
simulator here, so the operations can start it without this layer importing a front end. A drill plays its plan
in a worker thread that acts on the simulator only through the serving loop, between frames; the answer to the
masters never waits for it.
"""

from __future__ import annotations

import threading
import time
import weakref
from collections.abc import Callable, Mapping
from typing import Any

from ..core.simulator import Simulator
from .ops import ControlError

__all__ = ["DrillService", "Runner", "attach", "detach", "of"]

#: (the request's fields, a progress callback, the stop event) -> the report (JSON-ready)
Runner = Callable[[Mapping[str, Any], Callable[[str], None], threading.Event], dict[str, Any]]

_SERVICES: weakref.WeakKeyDictionary[Simulator, DrillService] = weakref.WeakKeyDictionary()


class DrillService:
    """The drill of one served simulator: idle, running (what it plays now), done (its report) or failed."""

    def __init__(self, runner: Runner) -> None:
        self.runner = runner
        self._lock = threading.Lock()
        self.state = "idle"
        self.progress = ""
        self.report: dict[str, Any] | None = None
        self.error = ""
        self.started: float | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {
                "state": self.state,
                "progress": self.progress,
                "error": self.error or None,
                "running_s": None if self.started is None else round(time.monotonic() - self.started, 1),
                "report": self.report,
            }

    def start(self, fields: Mapping[str, Any]) -> dict[str, Any]:
        with self._lock:
            if self.state == "running":
                raise ControlError("a drill is running: DELETE /drill stops it", status=409)
            self.state, self.progress, self.report, self.error = "running", "waiting for a master", None, ""
            self.started = time.monotonic()
            self._stop = threading.Event()
            self._thread = threading.Thread(target=self._run, args=(dict(fields), self._stop), daemon=True)
            self._thread.start()
        return self.status()

    def stop(self) -> dict[str, Any]:
        """Ask the running drill to stop (at once: it is not waited for here, on the serving loop, which its thread
        needs); GET /drill says when it has."""
        with self._lock:
            if self.state == "running":
                self._stop.set()
                self.progress = "stopping"
        return self.status()

    def _progress(self, line: str) -> None:
        with self._lock:
            self.progress = line.removeprefix("drill: ")

    def _run(self, fields: dict[str, Any], stop: threading.Event) -> None:
        try:
            report = self.runner(fields, self._progress, stop)
        except Exception as exc:  # a bad plan, a master that never came: said in GET /drill
            with self._lock:
                self.state, self.error, self.started = "failed", str(exc), None
            return
        with self._lock:
            self.state, self.report, self.started = "done", report, None
            self.progress = "stopped" if stop.is_set() else "done"


def attach(sim: Simulator, runner: Runner) -> DrillService:
    """Give ``sim`` its drill service (serve does, with the drill's runner)."""
    found = _SERVICES.get(sim)
    if found is None:
        found = _SERVICES[sim] = DrillService(runner)
    return found


def detach(sim: Simulator) -> None:
    """The serve of ``sim`` is stopping: its running drill is told to stop, and the service goes (the service's
    runner holds the simulator, so the weak map alone would keep both)."""
    found = _SERVICES.pop(sim, None)
    if found is not None:
        found.stop()


def of(sim: Simulator) -> DrillService:
    """The simulator's drill service; 409 where it has none (a simulator not served by c20sim serve)."""
    found = _SERVICES.get(sim)
    if found is None:
        raise ControlError("no drill here: the drill runs on a simulator c20sim serve serves", status=409)
    return found

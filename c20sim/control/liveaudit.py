"""The audit, live: an :class:`~c20sim.audit.Auditor` fed every frame the bus records.

``serve`` starts one for its simulator (``--no-audit``: none); ``GET /audit``
reads it, ``DELETE /audit`` starts it afresh, the telemetry snapshot (``GET
/telemetry``, ``/stream``) carries a summary, and a drive's counters carry the
line demand. The auditor works on the event loop, between frames: the
listener the bus calls for each record queues it, and once :data:`BATCH`
records wait, the audit runs them once the reply has gone (the loop's next
turn): a microsecond or two a frame, off the reply's path, and no I/O (the
engine is pure). Every read of the audit audits what waits first, so no answer
is behind the line; when the engine runs changes nothing it says, since it sees
the same frames in the same order. It judges the frames' times, which the ports stamp
on the monotonic clock: the master's rhythm as a plant would see it, whatever
the model's clock (virtual, or a realtime clock at a speed factor).

The line's baud and character size are the bus's to tell (:meth:`~c20sim.core.bus.Bus.on_line`): when they
change, the records queued so far (which went at the old settings) are audited first, then the auditor takes
the new ones. Nothing is polled per record.
"""

from __future__ import annotations

import asyncio
import threading
import time
import weakref
from collections.abc import Iterable
from typing import Any

from ..audit import Auditor, Finding, Limits, LineDemand
from ..audit.engine import F_COMM_TIMEOUT, F_MAX_SPEED
from ..core.bus import Direction, FrameRecord, LineSettings
from ..core.simulator import Simulator

__all__ = ["BATCH", "MAX_QUEUE", "LiveAudit", "of", "start"]

#: Records that wait before the audit runs: 16 transactions at a time take one loop callback, and the
#: engine runs them warm (bench/bench_path.py: about 3.3 us a request against 5.6 us for a run each); a run
#: holds the loop about 20 us (its median), once every 16 transactions.
BATCH = 32
#: Records waiting for the audit before it runs at once (the loop is busy: a burst of frames).
MAX_QUEUE = 4096


class LiveAudit:
    """One simulator's live audit."""

    def __init__(self, sim: Simulator, *, ignore: Iterable[str] = (), limits: Limits | None = None) -> None:
        self.sim = sim
        self.ignore = tuple(ignore)
        self.limits = limits
        self._bus = sim.bus
        self.auditor = self._fresh()
        # the records the audit has still to see, all at the auditor's line settings (the bus tells a change,
        # which audits the queue first: it is seldom, and a record then needs no baud of its own)
        #: (t, data, is a request) of each record queued: numbers and bytes, not the record and its decoded
        #: message, which a collection would walk while they wait (a tuple of them the collector stops tracking)
        self._queue: list[tuple[float, bytes, bool]] = []
        self._scheduled = False
        #: the loop the batches were last scheduled on, and its thread: asking for the running loop is a getpid()
        #: system call on Python 3.11, so it is asked again only when that loop no longer runs, or for a record
        #: fed from another thread (which gets the running loop of its own thread, or none)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._loop_thread = 0
        self._unsubscribe = self._bus.subscribe(self._feed)
        self._unwatch = self._bus.on_line(self._line_changed)

    def _fresh(self) -> Auditor:
        sim = self.sim
        line = self._bus.line_settings
        auditor = Auditor(sim.profile, baud=line.baud, bits=line.char_bits, ignore=self.ignore, limits=self.limits)
        spec = sim.profile.registers.get(F_COMM_TIMEOUT)
        for address, drive in sim.drives.items():
            timeout = drive.read(F_COMM_TIMEOUT) * spec.scale if spec is not None else None
            speed = drive.read(F_MAX_SPEED) if sim.profile.registers.get(F_MAX_SPEED) is not None else None
            auditor.know(address, comm_timeout=timeout, max_speed=speed)
        return auditor

    def _feed(self, record: FrameRecord) -> None:
        """The bus's listener, called while a request is served: it only queues the record, and once
        :data:`BATCH` wait, on an event loop, the audit runs once the reply has gone (``call_soon``), so it
        never delays one."""
        if record.from_gateway:
            return  # the Modbus TCP gateway's own answer (0x0B after silence): never on the line
        queue = self._queue
        queue.append((record.t, record.data, record.direction is Direction.RX))
        if len(queue) < BATCH:
            return
        if self._scheduled:
            if len(queue) >= MAX_QUEUE:
                self.drain()  # the loop is not getting round to it: keep the queue bounded
            return
        loop = self._loop
        if loop is None or not loop.is_running() or threading.get_ident() != self._loop_thread:
            try:
                loop = self._loop = asyncio.get_running_loop()
            except RuntimeError:  # no loop (a scenario run, a unit test): audit the batch at once
                self._loop = None
                self.drain()
                return
            self._loop_thread = threading.get_ident()
        self._scheduled = True
        loop.call_soon(self.drain)

    def _line_changed(self, line: LineSettings) -> None:
        """The bus's word that the line changed (a 2009H write it followed, a reset, the serial settings): what
        is queued went at the old settings and is audited at them; the next records at the new."""
        self.drain()
        auditor = self.auditor
        if line.char_bits != auditor.bits:
            auditor.bits = line.char_bits
            auditor.set_baud(line.baud)
            auditor._requests.clear()  # their costs were at the old character size (set_baud clears on a new baud)
        else:
            auditor.set_baud(line.baud)

    def drain(self) -> None:
        """Audit the records queued so far."""
        self._scheduled = False
        records = self._queue
        if not records:
            return
        self._queue = []
        auditor = self.auditor
        request, reply = auditor.request, auditor.reply
        for t, data, is_request in records:
            if is_request:
                request(t, data)
            else:
                reply(t, data)

    def findings(self) -> list[Finding]:
        """The findings so far; 200EH left on is judged at the line's time now (the monotonic clock the ports
        stamp frames with, whatever the model's clock)."""
        self.drain()
        if self.auditor.frames:
            self.auditor.check_idle(time.monotonic())
        return self.auditor.findings()

    def report(self) -> dict[str, Any]:
        findings = self.findings()
        worst = max((f.severity for f in findings), default=None)
        return {
            "frames": self.auditor.frames,
            "worst": None if worst is None else worst.label,
            "line_demand": self.line_demand().as_dict(),
            "findings": [f.as_dict() for f in findings],
        }

    def summary(self) -> dict[str, Any]:
        """What the telemetry snapshot carries: the count by severity, the worst, and the line demand."""
        self.drain()
        findings = self.auditor.findings()
        counts = {"error": 0, "warning": 0, "note": 0}
        for finding in findings:
            counts[finding.severity.label] += 1
        demand = self.line_demand()
        return {
            "findings": counts,
            "rules": sorted({f.rule for f in findings}),
            "line_demand_percent": round(demand.now, 1),
            "line_demand_peak_percent": round(demand.peak, 1),
        }

    def line_demand(self) -> LineDemand:
        """The line demand now: ``now`` over the last window by the ports' clock (0 % once the masters are quiet)."""
        self.drain()
        return self.auditor.line_demand(time.monotonic() if self.auditor.frames else None)

    def restart(self) -> None:
        """Forget what was seen: the next frames are judged afresh (the drives' settings read again)."""
        self._queue.clear()
        self.auditor = self._fresh()

    def close(self) -> None:
        self._unsubscribe()
        self._unwatch()
        _LIVE.pop(self.sim, None)


_LIVE: weakref.WeakKeyDictionary[Simulator, LiveAudit] = weakref.WeakKeyDictionary()


def start(sim: Simulator, *, ignore: Iterable[str] = (), limits: Limits | None = None) -> LiveAudit:
    """The simulator's live audit, started now unless it runs already."""
    found = _LIVE.get(sim)
    if found is None:
        found = _LIVE[sim] = LiveAudit(sim, ignore=ignore, limits=limits)
    return found


def of(sim: Simulator) -> LiveAudit | None:
    """The simulator's live audit, or None when it is off."""
    return _LIVE.get(sim)

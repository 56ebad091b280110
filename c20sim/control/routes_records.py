"""The routes of what the serve records and judges: the frame log, the audit and the drill."""

from __future__ import annotations

from typing import Any

from ..core.simulator import Simulator
from . import drills, liveaudit
from .ops import ControlError
from .routing import Field, Route


def _live_audit(sim: Simulator) -> liveaudit.LiveAudit:
    found = liveaudit.of(sim)
    if found is None:
        raise ControlError("the audit is off (serve --no-audit)", status=409)
    return found


def _audit(sim: Simulator) -> dict[str, Any]:
    return _live_audit(sim).report()


def _clear_audit(sim: Simulator) -> dict[str, Any]:
    audit = _live_audit(sim)
    audit.restart()
    return audit.report()


def _drill(sim: Simulator) -> dict[str, Any]:
    return drills.of(sim).status()


def _start_drill(sim: Simulator, **fields: Any) -> dict[str, Any]:
    if sim.virtual:
        raise ControlError("a drill needs the realtime clock: serve without --clock virtual", status=409)
    return drills.of(sim).start(fields)


def _stop_drill(sim: Simulator) -> dict[str, Any]:
    return drills.of(sim).stop()


_SECONDS = {"type": "number", "exclusiveMinimum": 0, "maximum": 600}
_DRILL_FIELDS = (
    Field(
        "plan",
        {"type": ["array", "null"], "items": {"type": ["string", "object"]}, "maxItems": 200},
        doc='incidents by name or as tables ({"incident": "trip", "hold": 1}); null: the standard plan',
    ),
    Field("warmup", _SECONDS, doc="seconds of the master's rhythm first (3)"),
    Field("poll_period", _SECONDS, doc="the master's poll period, given instead of learned"),
    Field("timeout", _SECONDS, doc="the master's timeout, given instead of learned"),
    Field("seed", {"type": "integer", "minimum": 0}, doc="the faults' randomness (1)"),
    Field("wait", _SECONDS, doc="seconds to wait for the master's first request (60)"),
)


#: The frame log, the audit and the drill.
RECORDS: tuple[Route, ...] = (
    Route(
        "GET",
        "/frames",
        "frames",
        "- (query: last=N (N >= 1), slave=N, since=SEQ); log_dropped: records --log-frames lost",
        help="the frame log",
    ),
    Route(
        "GET",
        "/audit",
        "audit",
        "- (what the masters would do wrong on a real line: findings, line demand; docs/audit.md)",
        _audit,
        help="the audit's findings and the line demand (docs/audit.md)",
    ),
    Route(
        "DELETE",
        "/audit",
        "clear_audit",
        "- (the audit starts afresh: findings and line demand forgotten)",
        _clear_audit,
        help="start the audit afresh",
    ),
    Route(
        "GET",
        "/drill",
        "drill",
        "- (the drill: idle, running (what it plays now), done (its report: a verdict per drill) or failed)",
        _drill,
        help="the drill's state and report (docs/drill.md)",
    ),
    Route(
        "POST",
        "/drill",
        "start_drill",
        '{"plan": ["crc", {"incident": "trip", "hold": 1}], "warmup": 3} (plays incidents on the master that '
        "polls this serve and judges how it survives them, off the serving loop; realtime clock; docs/drill.md)",
        _start_drill,
        _DRILL_FIELDS,
        changes=True,
        help="start a drill on the master polling this serve (docs/drill.md)",
    ),
    Route(
        "DELETE",
        "/drill",
        "stop_drill",
        "- (asks the running drill to stop: the plant is left healthy, the drills played so far judged; GET /drill says when)",
        _stop_drill,
        changes=True,
        help="stop the running drill",
    ),
    Route("DELETE", "/frames", "clear_frames", "- (empties the frame log)", changes=True, help="empty the frame log"),
)

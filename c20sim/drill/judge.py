"""The drill's judge: frames and the incident schedule in, verdicts out; no I/O, no clock.

The same frames (a live run's frame log, or that log read back by ``c20sim drill --judge``) and the same
marks (when the warm-up, the probe and each incident started and ended, on the frames' clock) give the same
verdicts. A verdict is frozen: its checks, each with a figure in words, a number, and the frames that show it.

The master's rhythm is learned from the warm-up: its poll period (the median time between two asks of its most
frequent request) and its request rate; its timeout from the probe (one reply kept off the wire: the time from
that request to the master's next one). A plan may give the period and timeout instead.
"""

from __future__ import annotations

import itertools
import statistics
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from .checks import (
    CHECKS,
    MAX_RETRIES,
    RECOVER_POLLS,
    RESET_WATCH,
    CheckResult,
    _check,
    _Drill,
)
from .incidents import SOURCES, Learned
from .plan import Drill, Plan
from .transactions import _Line, _transactions

__all__ = [
    "MAX_RETRIES",
    "CheckResult",
    "Judgement",
    "Mark",
    "Verdict",
    "judge",
    "learn",
    "watch_seconds",
]


@dataclass(frozen=True, slots=True)
class Mark:
    """A point of the run on the frames' clock: ``warmup``, ``probe``, ``learned``, or an incident's ``start``,
    ``end`` and ``watched`` (``index``: the drill's place in the plan, from 1)."""

    t: float
    event: str
    index: int = 0
    incident: str = ""

    def as_dict(self) -> dict[str, object]:
        return {
            "kind": "drill",
            "t": round(self.t, 6),
            "event": self.event,
            "index": self.index,
            "incident": self.incident,
        }


@dataclass(frozen=True, slots=True)
class Verdict:
    """How the master came through one drill."""

    index: int
    incident: str
    passed: bool
    checks: tuple[CheckResult, ...]
    start: float | None  #: on the frames' clock; None: never played
    end: float | None
    source: str

    @property
    def label(self) -> str:
        return f"{self.index} {self.incident}"

    @property
    def figure(self) -> str:
        """The failed checks' figures, or all of them when it passed."""
        failed = [c for c in self.checks if not c.passed]
        return "; ".join(f"{c.check}: {c.figure}" for c in (failed or self.checks))

    def line(self) -> str:
        return f"{'pass' if self.passed else 'FAIL'} {self.label}: {self.figure}"

    def as_dict(self) -> dict[str, object]:
        return {
            "index": self.index,
            "incident": self.incident,
            "passed": self.passed,
            "start": None if self.start is None else round(self.start, 6),
            "end": None if self.end is None else round(self.end, 6),
            "source": self.source,
            "checks": [c.as_dict() for c in self.checks],
        }


@dataclass(frozen=True, slots=True)
class Judgement:
    learned: Learned | None
    verdicts: tuple[Verdict, ...]
    requests: int
    problem: str = ""  #: why nothing could be judged (no warm-up, no probe answer), else empty

    @property
    def passed(self) -> bool:
        return not self.problem and all(v.passed for v in self.verdicts)


def watch_seconds(drill: Drill, learned: Learned) -> float:
    """How long after its end an incident is watched: the master's timeout plus 5 poll periods, and 3 s more for
    a drive incident (a reset, a run)."""
    extra = RESET_WATCH if drill.incident.group == "drive" else 0.0
    return learned.timeout + RECOVER_POLLS * learned.period + extra


def learn(frames: Iterable[tuple[float, str, bytes]], marks: Sequence[Mark], given: Learned | None = None) -> Learned:
    """The master's rhythm from the warm-up (``warmup`` to ``probe``) and its timeout from the probe (``probe``
    to ``learned``); ValueError saying what is missing."""
    times = {m.event: m.t for m in marks if m.event in ("warmup", "probe", "learned")}
    if "warmup" not in times or "probe" not in times:
        raise ValueError("no warm-up in the marks: the frame log was not written by c20sim drill")
    start, probe = times["warmup"], times["probe"]
    txns = _transactions(frames)
    warm = [x for x in txns if start <= x.t < probe]
    rate = len(warm) / (probe - start) if probe > start else 0.0
    if given is not None:
        return Learned(given.period, given.timeout, rate, True)
    if len(warm) < 3:
        raise ValueError(
            f"the master sent {len(warm)} requests in the {probe - start:.1f} s warm-up; at least 3 are needed"
        )
    common = Counter(x.request for x in warm).most_common(1)[0][0]
    at = [x.t for x in warm if x.request == common]
    if len(at) >= 2:
        period = statistics.median(b - a for a, b in itertools.pairwise(at))
    else:
        period = statistics.median(b.t - a.t for a, b in itertools.pairwise(warm))
    end = times.get("learned", txns[-1].t if txns else probe)
    probed = [x for x in txns if probe <= x.t <= end]
    timeout = None
    for a, b in itertools.pairwise(probed):
        if a.status == "failed" and not a.reply:
            timeout = b.t - a.t
            break
    if timeout is None:
        raise ValueError("the master sent no request after the probe's unanswered one; its timeout is unknown")
    return Learned(round(period, 4), round(timeout, 4), rate)


def judge(
    frames: Sequence[tuple[float, str, bytes]],
    plan: Plan,
    marks: Sequence[Mark],
    *,
    baud: int = 19200,
    bits: int = 10,
    turnaround: float = 0.002,
) -> Judgement:
    """The verdict on every drill of ``plan`` from ``frames`` and the run's ``marks``."""
    given = Learned(plan.poll_period, plan.timeout, 0.0, True) if plan.poll_period and plan.timeout else None
    txns = _transactions(frames)
    try:
        learned = learn(frames, marks, given)
    except ValueError as exc:
        return Judgement(None, (), len(txns), str(exc))
    line = _Line(baud, bits, turnaround)
    times = {m.event: m.t for m in marks if m.event in ("warmup", "probe")}
    warm = [x for x in txns if times.get("warmup", 0.0) <= x.t < times.get("probe", 0.0)]
    repeats_when_warm = any(a.status == "good" and b.request == a.request for a, b in itertools.pairwise(warm))
    by: dict[tuple[int, str], float] = {(m.index, m.event): m.t for m in marks if m.index}
    verdicts = []
    for drill in plan.drills:
        source = SOURCES[drill.incident.source]
        start, end = by.get((drill.index, "start")), by.get((drill.index, "end"))
        if start is None or end is None:
            missing = _check("recovers", False, "not played: the run ended before it", -1)
            verdicts.append(Verdict(drill.index, drill.name, False, (missing,), start, end, source))
            continue
        watched = by.get((drill.index, "watched"), end + watch_seconds(drill, learned))
        played = _Drill(drill, txns, start, end, watched, learned, line)
        played.repeats_when_warm = repeats_when_warm
        checks = tuple(CHECKS[name].judge(played) for name in drill.incident.checks)
        verdicts.append(Verdict(drill.index, drill.name, all(c.passed for c in checks), checks, start, end, source))
    return Judgement(learned, tuple(verdicts), len(txns))


def marks_of(items: Iterable[Mapping[str, object]]) -> list[Mark]:
    """The marks among a frame log's parsed lines (``{"kind": "drill", ...}``)."""
    out = []
    for item in items:
        t, event, index, incident = item.get("t"), item.get("event"), item.get("index", 0), item.get("incident", "")
        if (
            isinstance(t, (int, float))
            and isinstance(event, str)
            and isinstance(index, int)
            and isinstance(incident, str)
        ):
            out.append(Mark(float(t), event, index, incident))
    return out

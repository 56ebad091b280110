"""The drill's checks over the frames of one played drill: what a robust master does, judged from the wire.

:class:`_Drill` holds the transactions of one drill's span and a method per check; :data:`CHECKS` is the table
of checks, one row each (its name, when it passes, its source, the method that judges it), that the incidents
name and the judge runs.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from ..audit.findings import FrameRef
from ..drive.faultrecord import CURRENT_CONTEXT, FAULT_TYPES
from ..wire.registers import Command, Reg
from .incidents import SOURCES, Learned
from .plan import Drill
from .transactions import _Line, _Txn

#: Retries of one request in a row a robust master stops at; assumed (the guide gives no figure; 3 is the usual
#: default of masters and gateways).
MAX_RETRIES = 3
#: Request rate during an incident above this many times the warm-up's is a storm; assumed.
STORM_RATE = 3.0
#: Poll periods (after its timeout) within which a master is back after an incident; assumed.
RECOVER_POLLS = 5
#: Poll periods (after its timeout) within which a master reads the status or fault code after a trip; assumed.
NOTICE_POLLS = 3
#: Seconds more a drive incident is watched, for a reset and a run; assumed.
RESET_WATCH = 3.0
#: A master that polls one request (it asks it again after a good reply when all is well) and repeats a failed
#: request within this share of its poll period retries it; a repeat later than that is its next poll. Assumed:
#: it leaves a quarter of the period to the jitter of a master's scheduling.
POLL_SHARE = 0.75
#: Times closer than this are one (a frame log rounds them to the microsecond).
_EPSILON = 2e-6

#: The fault record's current fault (F07.27) and the state at it (F07.33-F07.40): a read of any is a read of it.
_RECORD = (FAULT_TYPES[0], *CURRENT_CONTEXT)

_RUN = frozenset((Command.FORWARD, Command.REVERSE, Command.JOG_FORWARD, Command.JOG_REVERSE))


@dataclass(frozen=True, slots=True)
class CheckResult:
    check: str
    passed: bool
    figure: str
    value: float
    frames: tuple[FrameRef, ...]
    source: str

    def as_dict(self) -> dict[str, object]:
        return {
            "check": self.check,
            "passed": self.passed,
            "figure": self.figure,
            "value": round(self.value, 6),
            "frames": [{"seq": f.seq, "t": round(f.t, 6)} for f in self.frames],
            "source": self.source,
        }


def _check(name: str, passed: bool, figure: str, value: float, frames: Iterable[FrameRef] = ()) -> CheckResult:
    return CheckResult(name, passed, figure, value, tuple(frames)[:4], SOURCES[CHECKS[name].source])


class _Drill:
    """The frames of one played drill, and the checks over them."""

    def __init__(
        self, drill: Drill, txns: list[_Txn], start: float, end: float, watched: float, learned: Learned, line: _Line
    ) -> None:
        self.drill, self.start, self.end, self.watched, self.learned, self.line = (
            drill,
            start,
            end,
            watched,
            learned,
            line,
        )
        self.all = txns
        #: the master asked a request again after its good reply in the warm-up (it polls one request)
        self.repeats_when_warm = False
        self.during = [x for x in txns if start - _EPSILON <= x.t <= end + _EPSILON]
        replies = drill.values.get("replies")
        if drill.incident.group == "reply" and isinstance(replies, int):
            # a reply fault acts on the next N replies: exactly the first N requests from its start
            self.during = [x for x in txns if x.t >= start - _EPSILON][:replies]
        self.span = [x for x in txns if start - _EPSILON <= x.t <= watched + _EPSILON]

    def _next(self, txn: _Txn) -> _Txn | None:
        i = self.all.index(txn)
        return self.all[i + 1] if i + 1 < len(self.all) and self.all[i + 1].t <= self.watched + _EPSILON else None

    def _repeats(self, a: _Txn, b: _Txn) -> bool:
        """``b`` asks ``a``'s failed request again (a retry or, for a master that polls it, its next poll)."""
        return a.status == "failed" and b.request == a.request

    def _polls(self, a: _Txn, b: _Txn) -> bool:
        """``b`` repeats ``a``'s failed request at the master's own rhythm, not sooner: its next poll, no retry.

        Only a master that asks one request in a row when all is well (:attr:`repeats_when_warm`) polls the same
        request again; it retries when the repeat comes sooner than :data:`POLL_SHARE` of its poll period (the
        warm-up's). Another master's repeat right after a failure is a retry, however late it comes."""
        return self.repeats_when_warm and b.t - a.t >= POLL_SHARE * self.learned.period - _EPSILON

    def _retries(self) -> list[tuple[_Txn, _Txn]]:
        """(failed request, its retry) pairs in the drill's span."""
        return [(a, b) for a, b in itertools.pairwise(self.span) if self._repeats(a, b) and not self._polls(a, b)]

    def retries(self) -> CheckResult:
        failed = [x for x in self.during if x.status == "failed"]
        if not failed:
            return _check("retries", False, "no request failed during the incident: the master sent nothing it hit", 0)
        moved: list[tuple[_Txn, _Txn | None]] = []
        for f in failed:
            n = self._next(f)
            if n is None or n.request != f.request:
                moved.append((f, n))
        if not moved:
            return _check(
                "retries", True, f"asked each of {len(failed)} failed requests again", len(failed), [failed[0].ref]
            )
        f, n = moved[0]
        if n is None:
            what = "sent nothing more within the watch"
        else:
            what = f"moved on to another request {1000 * (n.t - f.t):.0f} ms later without asking again"
        return _check(
            "retries",
            False,
            f"{len(moved)} of {len(failed)} failed requests not asked again; after frame {f.seq} it {what}",
            len(moved),
            [f.ref, *([n.ref] if n else [])],
        )

    def no_storm(self) -> CheckResult:
        fast = None
        for a, b in self._retries():
            need = self.line.time(a.request)
            if b.t - a.t < need - _EPSILON and (fast is None or b.t - a.t < fast[1].t - fast[0].t):
                fast = (a, b)
        length = max(self.end - self.start, self.learned.period)
        count = len([x for x in self.span if x.t <= self.end + self.learned.timeout + _EPSILON])
        rate = count / (length + self.learned.timeout)
        usual = self.learned.rate or (1.0 / self.learned.period)
        ratio = rate / usual if usual > 0 else 0.0
        if fast is not None:
            a, b = fast
            return _check(
                "no-storm",
                False,
                f"a retry {1000 * (b.t - a.t):.1f} ms after the request it repeats, sooner than the line can answer "
                f"({1000 * self.line.time(a.request):.1f} ms)",
                b.t - a.t,
                [a.ref, b.ref],
            )
        if ratio > STORM_RATE:
            return _check(
                "no-storm",
                False,
                f"{rate:.1f} requests/s during the incident, {ratio:.1f}x its usual {usual:.1f}/s",
                ratio,
                [x.ref for x in self.span[:2]],
            )
        return _check("no-storm", True, f"{rate:.1f} requests/s, {ratio:.1f}x its usual", ratio)

    def bounded(self) -> CheckResult:
        longest, run, where, polls = 0, 0, None, 0
        for a, b in itertools.pairwise(self.span):
            if self._repeats(a, b) and self._polls(a, b):
                polls += 1
                run = 0  # its next poll: the retries of the poll before it are over
            elif self._repeats(a, b):
                run += 1
                if run > longest:
                    longest, where = run, b
            else:
                run = 0
        passed = longest <= MAX_RETRIES
        figure = f"at most {longest} retries of one request in a row (limit {MAX_RETRIES})"
        if polls:
            figure += (
                f"; {polls} repeats of a failed request {1000 * POLL_SHARE * self.learned.period:.0f} ms or more "
                f"after it are polls at its own period ({1000 * self.learned.period:.0f} ms), not retries"
            )
        return _check("bounded", passed, figure, longest, [where.ref] if where else [])

    def takes_replies(self) -> CheckResult:
        # a master whose warm-up already asks a request again after its good reply (one request polled) cannot be
        # told taking a reply from not taking it
        if self.repeats_when_warm:
            return _check(
                "takes-replies", True, "cannot tell: the master asks the same request in a row when all is well", 0
            )
        limit = self.end + self.learned.timeout
        again = [
            (a, b)
            for a, b in itertools.pairwise(self.span)
            if a.status == "good" and b.request == a.request and b.t <= limit + _EPSILON
        ]
        if again:
            a, b = again[0]
            return _check(
                "takes-replies",
                False,
                f"{len(again)} requests asked again after a good reply; frame {b.seq} {1000 * (b.t - a.reply_t):.0f} ms "
                "after the reply to the same request",
                len(again),
                [a.ref, b.ref],
            )
        return _check("takes-replies", True, "took every reply: asked nothing again", 0)

    def waits_own_id(self) -> CheckResult:
        fraction = self.drill.values.get("fraction", 0.5)
        hold = float(fraction) * self.learned.timeout if isinstance(fraction, (int, float)) else 0.0
        early = []
        for a in self.during:
            n = self._next(a)
            if a.status == "good" and n is not None and n.request != a.request and n.t < a.reply_t + hold - _EPSILON:
                early.append((a, n))
        if early:
            a, n = early[0]
            return _check(
                "waits-own-id",
                False,
                f"{len(early)} of {len(self.during)} took the reply under another id: frame {n.seq}, a new request "
                f"{1000 * (n.t - a.reply_t):.0f} ms after it, before its own came ({1000 * hold:.0f} ms)",
                len(early),
                [a.ref, n.ref],
            )
        return _check("waits-own-id", True, f"waited for its own id each time ({1000 * hold:.0f} ms)", 0)

    def keeps_polling(self) -> CheckResult:
        length = self.end - self.start
        rate = len(self.during) / length if length > 0 else 0.0
        usual = self.learned.rate or (1.0 / self.learned.period)
        ratio = rate / usual if usual > 0 else 0.0
        retried = len(self._retries())
        return _check(
            "keeps-polling",
            ratio >= 0.5,
            f"{rate:.1f} requests/s during the incident, {100 * ratio:.0f} % of its usual {usual:.1f}/s"
            + (f"; {retried} retries" if retried else ""),
            ratio,
        )

    def backs_off(self) -> CheckResult:
        length = self.end - self.start
        rate = len(self.during) / length if length > 0 else 0.0
        usual = self.learned.rate or (1.0 / self.learned.period)
        ratio = rate / usual if usual > 0 else 0.0
        return _check(
            "backs-off",
            ratio <= 1.0,
            f"{rate:.1f} requests/s while the drive was silent, {100 * ratio:.0f} % of its usual {usual:.1f}/s",
            ratio,
            [x.ref for x in self.during[:2]],
        )

    def recovers(self) -> CheckResult:
        limit = self.learned.timeout + RECOVER_POLLS * self.learned.period
        back = next((x for x in self.span if x.t >= self.end - _EPSILON and x.status == "good"), None)
        if back is None:
            return _check(
                "recovers", False, f"no good reply within {self.watched - self.end:.2f} s after the incident", -1
            )
        after = back.reply_t - self.end
        return _check(
            "recovers",
            after <= limit + _EPSILON,
            f"a good reply {after:.2f} s after the incident (limit {limit:.2f} s)",
            after,
            [back.ref],
        )

    def notices(self) -> CheckResult:
        at = self.end if self.drill.incident.silent else self.start
        limit = self.learned.timeout + NOTICE_POLLS * self.learned.period
        read = next(
            (
                x
                for x in self.span
                if x.t >= at - _EPSILON and (x.reads(Reg.STATUS1) or x.reads(Reg.FAULT_CODE)) and x.status == "good"
            ),
            None,
        )
        since = "the link came back" if self.drill.incident.silent else "the trip"
        if read is None:
            return _check("notices", False, f"never read 2100H or 2102H after {since}", -1)
        after = read.reply_t - at
        which = "2102H" if read.reads(Reg.FAULT_CODE) else "2100H"
        return _check(
            "notices",
            after <= limit + _EPSILON,
            f"read {which} {after:.2f} s after {since} (limit {limit:.2f} s)",
            after,
            [read.ref],
        )

    def no_run_into_fault(self) -> CheckResult:
        refused = [
            x
            for x in self.span
            if (w := x.written()) is not None and w[0] == Reg.COMMAND and w[1] in _RUN and x.status == "refused"
        ]
        if refused:
            return _check(
                "no-run-into-fault",
                False,
                f"{len(refused)} run commands sent into the fault (refused 0x{refused[0].code:02X}), the first "
                f"{refused[0].t - self.start:.2f} s after the incident began",
                len(refused),
                [x.ref for x in refused],
            )
        return _check("no-run-into-fault", True, "no run command into the fault", 0)

    def resets_once(self) -> CheckResult:
        resets = [
            x for x in self.during if (w := x.written()) is not None and w[0] == Reg.COMMAND and w[1] == Command.RESET
        ]
        return _check(
            "resets-once",
            len(resets) <= 1,
            f"{len(resets)} fault resets while the cause was present ({self.end - self.start:.1f} s)",
            len(resets),
            [x.ref for x in resets],
        )

    def restores_ram(self) -> CheckResult:
        after = [x for x in self.span if x.t >= self.end - _EPSILON]
        setpoint = next(
            (x for x in after if (w := x.written()) is not None and w[0] == Reg.SPEED_SETPOINT and x.status == "good"),
            None,
        )
        run = next((x for x in after if (w := x.written()) is not None and w[0] == Reg.COMMAND and w[1] in _RUN), None)
        if run is None:
            return _check("restores-ram", True, "no run command after the power came back", 0)
        if setpoint is None or setpoint.t > run.t:
            return _check(
                "restores-ram",
                False,
                f"a run command {run.t - self.end:.2f} s after power-up, before any write of 2001H (its RAM value was lost)",
                run.t - self.end,
                [run.ref],
            )
        return _check(
            "restores-ram",
            True,
            f"2001H written {setpoint.t - self.end:.2f} s after power-up, before the run command",
            setpoint.t - self.end,
            [setpoint.ref, run.ref],
        )

    def _resets(self, since: float, until: float) -> list[_Txn]:
        return [
            x
            for x in self.span
            if since - _EPSILON <= x.t <= until + _EPSILON
            and (w := x.written()) is not None
            and w == (Reg.COMMAND, Command.RESET)
        ]

    def _interval(self) -> float:
        interval = self.drill.values.get("interval", 0.0)
        return float(interval) if isinstance(interval, (int, float)) else 0.0

    def waits_auto_reset(self) -> CheckResult:
        interval = self._interval()
        resets = self._resets(self.start, self.start + interval)
        if resets:
            return _check(
                "waits-auto-reset",
                False,
                f"{len(resets)} fault resets of its own while the drive's automatic reset counted down, the first "
                f"{resets[0].t - self.start:.2f} s after the trip (F08.29 = {interval:g} s)",
                len(resets),
                [x.ref for x in resets],
            )
        return _check("waits-auto-reset", True, f"no reset of its own within F08.29 = {interval:g} s", 0)

    def resumes(self) -> CheckResult:
        reset_at = self.start + self._interval()
        limit = self.learned.timeout + RECOVER_POLLS * self.learned.period
        runs = (x for x in self.span if x.t >= self.start - _EPSILON and x.status == "good")
        run = next((x for x in runs if (w := x.written()) is not None and w[0] == Reg.COMMAND and w[1] in _RUN), None)
        if run is None:
            return _check("resumes", False, "no run command the drive took after the trip", -1)
        after = run.t - reset_at
        when = f"{after:.2f} s after its automatic reset" if after >= 0 else "before its automatic reset was due"
        return _check(
            "resumes",
            after <= limit + _EPSILON,
            f"a run command the drive took {run.t - self.start:.2f} s after the trip, {when} (limit {limit:.2f} s)",
            after,
            [run.ref],
        )

    def reads_record(self) -> CheckResult:
        read = next((x for x in self.span if x.status == "good" and any(x.reads(r) for r in _RECORD)), None)
        reset = next(iter(self._resets(self.start, self.watched)), None)
        if read is None:
            what = (
                f"reset the fault {reset.t - self.start:.2f} s after the trip without reading"
                if reset
                else "never read"
            )
            return _check(
                "reads-record",
                False,
                f"{what} the fault record (F07.27-F07.40)",
                -1,
                [reset.ref] if reset else [],
            )
        if reset is not None and reset.t < read.t:
            return _check(
                "reads-record",
                False,
                f"reset the fault {reset.t - self.start:.2f} s after the trip, before it read the fault record "
                f"({read.t - self.start:.2f} s)",
                read.t - self.start,
                [reset.ref, read.ref],
            )
        return _check(
            "reads-record",
            True,
            f"read the fault record {read.reply_t - self.start:.2f} s after the trip"
            + (", before its reset" if reset else ""),
            read.reply_t - self.start,
            [read.ref],
        )


@dataclass(frozen=True, slots=True)
class Check:
    """A check a verdict can be made of: one row of :data:`CHECKS`."""

    name: str
    passes: str  #: when it passes, in words
    source: str  #: a key of :data:`~c20sim.drill.incidents.SOURCES`: where its limit comes from
    judge: Callable[[_Drill], CheckResult]  #: the check over a played drill's frames


#: Every check, by name: an incident's ``checks`` name them, the judge runs them, docs/drill.md has a row for
#: each. A dict, so that a test can add a throwaway row and take it out.
CHECKS: dict[str, Check] = {
    check.name: check
    for check in (
        Check(
            "retries",
            "asks a failed request again before moving on (a reply not its own is discarded)",
            "guide",
            _Drill.retries,
        ),
        Check(
            "no-storm",
            "no retry sooner than the line could answer; no more than 3x its usual request rate",
            "guide",
            _Drill.no_storm,
        ),
        Check(
            "bounded",
            "at most 3 retries of one request in a row (a repeat at the poll period of a master that polls one "
            "request is its next poll)",
            "assumed",
            _Drill.bounded,
        ),
        Check(
            "takes-replies",
            "asks no request again whose reply was good (a split or late reply is taken)",
            "guide",
            _Drill.takes_replies,
        ),
        Check(
            "waits-own-id",
            "sends nothing new before its own transaction id's reply comes (Modbus TCP)",
            "tcp",
            _Drill.waits_own_id,
        ),
        Check(
            "keeps-polling",
            "keeps at least half its usual request rate while the incident lasts",
            "assumed",
            _Drill.keeps_polling,
        ),
        Check("backs-off", "asks no faster than its usual rate while the drive is silent", "assumed", _Drill.backs_off),
        Check(
            "recovers",
            "a good reply again within its timeout plus 5 poll periods after the incident",
            "assumed",
            _Drill.recovers,
        ),
        Check(
            "notices",
            "reads 2100H or 2102H within its timeout plus 3 poll periods after the trip",
            "sheet",
            _Drill.notices,
        ),
        Check(
            "no-run-into-fault",
            "sends no run command (2000H = 1-4) that the faulted drive refuses",
            "sheet",
            _Drill.no_run_into_fault,
        ),
        Check(
            "resets-once", "at most one fault reset (2000H = 7) while the cause is present", "invt", _Drill.resets_once
        ),
        Check(
            "restores-ram",
            "writes 2001H (RAM, lost at power-off) before the first run command after power-up",
            "sheet",
            _Drill.restores_ram,
        ),
        Check(
            "waits-auto-reset",
            "no fault reset (2000H = 7) of its own while the drive's automatic reset counts down (F08.29)",
            "invt-auto",
            _Drill.waits_auto_reset,
        ),
        Check(
            "resumes",
            "a run command the drive takes within its timeout plus 5 poll periods after the drive's automatic reset",
            "assumed",
            _Drill.resumes,
        ),
        Check(
            "reads-record",
            "reads the fault record (F07.27 or F07.33-F07.40) after the trip, before its reset",
            "invt-record",
            _Drill.reads_record,
        ),
    )
}

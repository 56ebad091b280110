"""The auditor's shared window over one line's stream: what every rule reads and the one way they report.

A rule (:mod:`c20sim.audit.rules`) keeps nothing of the stream itself but what it alone judges by: it reads
the window (the last request and its reply, the drives' followed facts, the line-demand window, counters by
subject) and reports through :meth:`Window.report`. The :class:`~c20sim.audit.engine.Auditor` is a window
that is fed frames and calls the rules' hooks.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable

from ..drive.profile import Profile
from ..wire.protocol import BROADCAST, SHEET_CHAR_BITS, transaction_time
from ..wire.registers import BAUD_RATES, Reg, is_fcode
from .findings import Finding, FrameRef, Severity
from .limits import (
    _EPSILON,
    F_BAUD,
    F_COMM_TIMEOUT,
    F_MAX_SPEED,
    MAX_EVENTS,
    MAX_SUBJECTS,
    MAX_WINDOW,
    Limits,
    LineDemand,
)
from .state import _Count, _Drive, _Request

__all__ = ["Window"]


class Window:
    """What the rules share of one line's stream; :meth:`report` is how a rule says what it found."""

    def __init__(
        self,
        profile: Profile,
        *,
        baud: int | None = None,
        bits: int = SHEET_CHAR_BITS,
        comm_timeout: float | None = None,
        limits: Limits | None = None,
        ignore: Iterable[str] = (),
    ) -> None:
        self.profile = profile
        default_baud = profile.defaults.get(F_BAUD, 4)
        self.baud = baud if baud is not None else BAUD_RATES[default_baud if default_baud < len(BAUD_RATES) else 4]
        self.bits = bits
        self.limits = limits or Limits()
        self.ignore = frozenset(ignore)
        self.turnaround = profile.protocol.turnaround_ms / 1000.0
        self.endurance = profile.protocol.eeprom_endurance_writes
        self.broadcast_delay = profile.protocol.broadcast_delay_ms / 1000.0
        timeout_spec = profile.registers.get(F_COMM_TIMEOUT) if F_COMM_TIMEOUT in profile.defaults else None
        self._timeout_scale = timeout_spec.scale if timeout_spec is not None else 0.1
        self._timeout_override = comm_timeout
        self._default_timeout = (
            comm_timeout if comm_timeout is not None else profile.defaults.get(F_COMM_TIMEOUT, 0) * self._timeout_scale
        )
        self._default_max_speed = profile.defaults.get(F_MAX_SPEED, 3000)
        #: the function codes (EEPROM) and the registers that mirror them
        self.eeprom = frozenset(profile.mirrors) | frozenset(a for a in profile.defaults if is_fcode(a))
        self._timeout_cells = {F_COMM_TIMEOUT} | {r for r, f in profile.mirrors.items() if f == F_COMM_TIMEOUT}
        self._speed_cells = {F_MAX_SPEED} | {r for r, f in profile.mirrors.items() if f == F_MAX_SPEED}
        #: the registers whose write, once stored, changes what the rules follow (see Auditor._stored)
        self._followed = self.eeprom | {Reg.WRITE_ENABLE} | self._speed_cells
        if self._timeout_override is None:
            self._followed |= self._timeout_cells
        self.frames = 0
        self.enabled: set[int] = set()  #: drives with 200EH = 1
        # the last request (until the next one): what it means, its place, time and bytes, and its reply's time
        self.pending: _Request | None = None
        self.pending_seq = 0
        self.pending_t = 0.0
        self.pending_data = b""
        self.pending_reply: float | None = None
        #: the request before the pending one (CRC good), its place and time, and its reply's time (None: none came
        #: before the pending one was sent)
        self.previous: _Request | None = None
        self.previous_seq = 0
        self.previous_t = 0.0
        self.previous_reply: float | None = None
        #: a request sent too soon (the gap hooks): the seconds the last transaction needed before it
        self.need = 0.0
        self.drives: dict[int, _Drive] = {}
        self._counts: dict[tuple[str, int, int, int], _Count] = {}
        self._findings: dict[tuple[str, int | None, str], Finding] = {}
        self._events: deque[Finding] = deque(maxlen=MAX_EVENTS)
        # the line-demand window: (t, seq, cost) of the last transactions, and their sum
        self._window: deque[tuple[float, int, float]] = deque()
        self.window_sum = 0.0
        self._first_t: float | None = None
        self._last_t = 0.0
        self._last_cost = 0.0
        self._now = 0.0
        # the last request while it awaits its reply, (its place, its time, its bytes): the window is judged when
        # the reply says what the line carried (or at the next frame, if none came)
        self._awaited: tuple[int, float, int] | None = None
        # a transaction's line time by (request bytes, reply bytes, baud), at most MAX_SUBJECTS
        self._costs: dict[tuple[int, int, int], float] = {}
        #: what hears of a new peak of the line-demand window (the Auditor's demand hooks)
        self._peak_hooks: list[Callable[[Window, int, float, float], None]] = []
        self._peak = 0.0
        self._transactions = 0
        self._busy = 0.0

    def know(self, address: int, *, comm_timeout: float | None = None, max_speed: int | None = None) -> None:
        """What a live drive holds now (its F08.02 in seconds, its F00.03 in rpm), where it differs from the
        profile's defaults (a state file); the master's writes are followed from here on."""
        drive = self.drive(address)
        if comm_timeout is not None and self._timeout_override is None:
            drive.comm_timeout = comm_timeout
        if max_speed is not None:
            drive.max_speed = max_speed

    def drive(self, address: int) -> _Drive:
        """What the audit follows of the drive at ``address`` (made on first sight)."""
        found = self.drives.get(address)
        if found is None:
            found = self.drives[address] = _Drive(self._default_timeout, self._default_max_speed)
        return found

    def pending_ref(self) -> FrameRef:
        """The last request's place and time."""
        return FrameRef(self.pending_seq, self.pending_t)

    # -- the line-demand window

    def line_demand(self, t: float | None = None) -> LineDemand:
        """The line demand; ``now`` over the window before ``t`` (live: the clock's time, so that a master gone
        quiet reads 0 %), or before the last request."""
        now = self._now
        if t is not None and t > self._last_t and self._first_t is not None:
            self._expire(t - self.limits.window + _EPSILON)
            now = self._window_percent() if t - self._first_t >= self.limits.window else 0.0
        span = (self._last_t - self._first_t) if self._first_t is not None else 0.0
        # the stream's stretch of line: from the first request to the end of the last transaction
        mean = 100.0 * self._busy / (span + self._last_cost) if span >= self.limits.window else 0.0
        return LineDemand(self.baud, self.bits, now, self._peak, mean, self._transactions, self._busy)

    def window_first(self) -> FrameRef:
        """The oldest transaction in the line-demand window (the window holds one at least after a request)."""
        t, seq, _ = self._window[0]
        return FrameRef(seq, t)

    def window_count(self) -> int:
        """How many transactions the line-demand window holds."""
        return len(self._window)

    def _window_percent(self) -> float:
        """The window's transactions' line time, in percent of :meth:`window_stretch`."""
        return 100.0 * self.window_sum / self.window_stretch()

    def window_stretch(self) -> float:
        """The time the window's transactions take: the window, or longer, from the oldest one's request to the
        end of the newest. A line kept exactly full then reads 100 %: a window of 1 s holds the requests of 75
        back-to-back reads of 13.46 ms at 19200 baud, which take 1.01 s of line."""
        window = self._window
        stretch = self._last_t - window[0][0] + self._last_cost if window else 0.0
        return max(self.limits.window, stretch)

    def _expire(self, horizon: float) -> None:
        """Drop the window's transactions at or before ``horizon`` (and beyond its bound)."""
        window = self._window
        while window and (window[0][0] <= horizon or len(window) > MAX_WINDOW):
            self.window_sum -= window.popleft()[2]
        if not window:
            self.window_sum = 0.0  # no rounding left over

    def _demand(self, seq: int, t: float, cost: float) -> float:
        """Add a transaction to the window; the window's demand (percent) if it is a new peak, else 0.0.

        A request that awaits a reply (the last request, not a broadcast) is judged once its reply comes
        (:meth:`settle`), so that the window is never judged by a reply the drive did not send (a read of 126
        registers refused with a 5-byte exception); if none comes, at the next frame, charged the reply it asked
        for. Until then this returns 0.0."""
        awaited = self._awaited
        if awaited is not None:  # the last request got no reply: judged as charged
            self._awaited = None
            self._judge_at(awaited[0], awaited[1])
        if self._first_t is None:
            self._first_t = t
        self._last_t = t
        self._last_cost = cost
        self._transactions += 1
        self._busy += cost
        window = self._window
        window.append((t, seq, cost))
        self.window_sum += cost
        span = self.limits.window
        horizon = t - span + _EPSILON  # a frame log's times are rounded to the microsecond
        if window[0][0] <= horizon or len(window) > MAX_WINDOW:
            self._expire(horizon)
        pending = self.pending
        if seq == self.pending_seq and pending is not None and pending.slave != BROADCAST:
            self._awaited = (seq, t, len(self.pending_data))
            return 0.0
        return self._judge(t)

    def _judge(self, t: float) -> float:
        """The window's demand (percent) at ``t`` if it is a new peak, else 0.0 (also 0.0 before a whole window)."""
        if self._first_t is None or t - self._first_t < self.limits.window:
            return 0.0  # not yet a whole window seen
        percent = self._window_percent()
        self._now = percent
        if percent <= self._peak:
            return 0.0
        self._peak = percent
        return percent

    def _judge_at(self, seq: int, t: float) -> None:
        """Judge the window as it stands, the request ``seq`` at ``t`` newest; the demand hooks hear of a new peak
        (:meth:`_judge` inline, :meth:`window_stretch` too: this runs at every reply)."""
        first = self._first_t
        span = self.limits.window
        if first is None or t - first < span:
            return  # not yet a whole window seen
        window = self._window
        stretch = self._last_t - window[0][0] + self._last_cost if window else 0.0
        percent = self._now = 100.0 * self.window_sum / (stretch if stretch > span else span)
        if percent > self._peak:
            self._peak = percent
            for peak in self._peak_hooks:
                peak(self, seq, t, percent)

    def settle(self, reply: int) -> None:
        """The last request got its reply, ``reply`` bytes: charge its transaction the request, the turnaround
        and that reply, not the reply it asked for (a read of 126 registers refused with a 5-byte exception holds
        the line 12.4 ms at 19200 baud, not the 143.7 ms of a 257-byte reply); then judge the window."""
        awaited = self._awaited
        if awaited is None:
            return
        seq, t, n = awaited
        if seq != self.pending_seq:
            return  # noise came after the request: the request was judged then, charged what it asked
        self._awaited = None
        key = (n, reply, self.baud)
        cost = self._costs.get(key)
        if cost is None:  # a master's few request and reply lengths: remembered
            if len(self._costs) >= MAX_SUBJECTS:
                self._costs.clear()
            cost = self._costs[key] = transaction_time(n, reply, self.baud, self.bits, self.turnaround)
        charged = self._last_cost  # nothing came since the request: it is the newest transaction
        if cost != charged:
            window = self._window
            if window and window[-1][1] == seq:  # not let go by a live window's clock
                window[-1] = (window[-1][0], seq, cost)
                self.window_sum += cost - charged
            self._busy += cost - charged
            self._last_cost = cost
        self._judge_at(seq, t)

    # -- what the rules count and report

    def count(self, key: tuple[str, int, int, int]) -> _Count | None:
        """The counter of ``key`` (a rule's id, the drive, a register, a code); None once :data:`MAX_SUBJECTS`
        counters are kept (new subjects are not followed, the first ones are)."""
        found = self._counts.get(key)
        if found is None:
            if len(self._counts) >= MAX_SUBJECTS:
                return None
            found = self._counts[key] = _Count()
        return found

    def report(
        self,
        rule: str,
        source: str,
        severity: Severity,
        drive: int | None,
        subject: str,
        frames: tuple[FrameRef, ...],
        figure: str,
        value: float,
        advice: str,
        *,
        bump: bool = False,
    ) -> None:
        """A finding of ``rule`` (``source``: where its facts come from); a finding of the same rule, drive and
        subject is replaced, or with ``bump`` (a repeat of a one-off) counted with its first frames and figure."""
        if rule in self.ignore:
            return
        key = (rule, drive, subject)
        before = self._findings.get(key)
        count = before.count + 1 if before else 1
        if before is not None and bump:
            # a repeat of a one-off: keep the first frames and figure, count it
            finding = Finding(
                rule,
                max(severity, before.severity),
                drive,
                subject,
                (before.frames[0], frames[-1]),
                before.figure,
                before.value,
                count,
                before.advice,
                before.source,
            )
        else:
            finding = Finding(rule, severity, drive, subject, frames, figure, value, count, advice, source)
        self._findings[key] = finding
        self._events.append(finding)

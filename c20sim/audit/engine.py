"""The audit's engine: frames and their times in, findings out; no I/O, no clock.

Sans-I/O like the framer: :meth:`Auditor.feed` takes one frame (its time, its
direction, its bytes) and :meth:`Auditor.events` hands back the findings that
are new or whose figure grew since the last call; :meth:`Auditor.findings` is
the report so far. Live (every frame the bus records) and offline (a frame
log, a packet capture) go through the same engine, so a log recorded live
gives the same findings later.

The drive's facts come from its profile: the turnaround, the EEPROM's
endurance, the time it needs after a broadcast, the defaults of the
communication timeout (F08.02) and the maximum speed (F00.03). Writes the
master makes to those function codes are followed. The line's real time for
a transaction is :func:`c20sim.wire.protocol.transaction_time`, whatever
transport carried the frames. Every limit a rule judges by and that no
document gives is marked ``assumed`` here and in docs/audit.md.

Memory is bounded whatever the stream's length: a window of the line's last
transactions (at most :data:`MAX_WINDOW` entries), a few counters per drive
and subject (at most :data:`MAX_SUBJECTS` of them), and a bounded queue of
events.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Iterable

from ..drive.profile import Profile
from ..wire.protocol import (
    BROADCAST,
    SHEET_CHAR_BITS,
    ExceptionCode,
    FunctionCode,
    crc_ok,
    frame_time,
    transaction_time,
)
from ..wire.registers import BAUD_RATES, Command, Reg, address_label, is_fcode
from .findings import RULES, Finding, FrameRef, Severity
from .limits import (
    _EPSILON,
    _TIMER_SLACK,
    F_BAUD,
    F_COMM_TIMEOUT,
    F_MAX_SPEED,
    MAX_EVENTS,
    MAX_SUBJECTS,
    MAX_WINDOW,
    Limits,
    LineDemand,
    _format,
)
from .state import _NOT_A_REPLY, _Count, _Drive, _Request

__all__ = ["MAX_SUBJECTS", "MAX_WINDOW", "Auditor", "Limits", "LineDemand"]

_READ = FunctionCode.READ_REGISTERS
_WRITE1 = FunctionCode.WRITE_SINGLE
_WRITEN = FunctionCode.WRITE_MULTIPLE


class Auditor:
    """The rules over one line's frame stream. ``feed`` frames in order; read ``events`` or ``findings``."""

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
        unknown = sorted(self.ignore - set(RULES))
        if unknown:
            raise ValueError(f"unknown rule {unknown[0]!r}; the rules are {', '.join(RULES)}")
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
        self._eeprom = frozenset(profile.mirrors) | frozenset(a for a in profile.defaults if is_fcode(a))
        self._timeout_cells = {F_COMM_TIMEOUT} | {r for r, f in profile.mirrors.items() if f == F_COMM_TIMEOUT}
        self._speed_cells = {F_MAX_SPEED} | {r for r, f in profile.mirrors.items() if f == F_MAX_SPEED}
        #: the registers whose write, once stored, changes what the rules follow (see _stored)
        self._followed = self._eeprom | {Reg.WRITE_ENABLE} | self._speed_cells
        if self._timeout_override is None:
            self._followed |= self._timeout_cells
        self.frames = 0
        self._enabled: set[int] = set()  #: drives with 200EH = 1
        # the last request (until the next one): what it means, its place, time and bytes, and its reply's time
        self._pending: _Request | None = None
        self._pending_seq = 0
        self._pending_t = 0.0
        self._pending_data = b""
        self._pending_reply: float | None = None
        self._drives: dict[int, _Drive] = {}
        self._counts: dict[tuple[str, int, int, int], _Count] = {}
        self._findings: dict[tuple[str, int | None, str], Finding] = {}
        self._events: deque[Finding] = deque(maxlen=MAX_EVENTS)
        # what the frames seen mean, by their bytes (at most MAX_SUBJECTS each): requests, and replies as
        # (slave, function, exception code or -1)
        self._requests: dict[bytes, _Request] = {}
        self._replies: dict[bytes, tuple[int, int, int]] = {}
        # the line-demand window: (t, seq, cost) of the last transactions, and their sum
        self._window: deque[tuple[float, int, float]] = deque()
        self._window_sum = 0.0
        self._first_t: float | None = None
        self._last_t = 0.0
        self._last_cost = 0.0
        self._now = 0.0
        self._peak = 0.0
        # the line-demand finding as last reported: its peak and severity (it is reported again when the peak has
        # grown by more than half a point since, or its severity rises)
        self._reported_peak = -1.0
        self._reported_severity = Severity.NOTE
        self._transactions = 0
        self._busy = 0.0

    def know(self, address: int, *, comm_timeout: float | None = None, max_speed: int | None = None) -> None:
        """What a live drive holds now (its F08.02 in seconds, its F00.03 in rpm), where it differs from the
        profile's defaults (a state file); the master's writes are followed from here on."""
        drive = self._drive(address)
        if comm_timeout is not None and self._timeout_override is None:
            drive.comm_timeout = comm_timeout
        if max_speed is not None:
            drive.max_speed = max_speed

    def set_baud(self, baud: int) -> None:
        """The line's baud changed (a 2009H write the line followed): judge the next transactions at it."""
        if baud != self.baud:
            self.baud = baud
            self._requests.clear()  # their cost was at the old baud

    # -- the stream

    def feed(self, t: float, direction: str, data: bytes) -> None:
        """One frame: ``direction`` ``rx`` (master to drive) or ``tx`` (drive to master), at time ``t`` (seconds)."""
        if direction == "rx":
            self.request(t, data)
        elif direction == "tx":
            self.reply(t, data)
        else:
            self.frames += 1
            raise ValueError(f"direction {direction!r}: expected rx or tx")

    def feed_all(self, frames: Iterable[tuple[float, str, bytes]]) -> None:
        for t, direction, data in frames:
            self.feed(t, direction, data)

    def events(self) -> list[Finding]:
        """The findings new or grown since the last call, oldest first."""
        out = list(self._events)
        self._events.clear()
        return out

    def findings(self) -> list[Finding]:
        """Every finding so far, worst first, then by rule, drive and subject."""
        return sorted(
            self._findings.values(),
            key=lambda f: (-f.severity, f.rule, -1 if f.drive is None else f.drive, f.subject),
        )

    def worst(self) -> Severity | None:
        return max((f.severity for f in self._findings.values()), default=None)

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

    def _window_percent(self) -> float:
        """The window's transactions' line time, in percent of :meth:`_window_stretch`."""
        return 100.0 * self._window_sum / self._window_stretch()

    def _window_stretch(self) -> float:
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
            self._window_sum -= window.popleft()[2]
        if not window:
            self._window_sum = 0.0  # no rounding left over

    # -- requests

    def request(self, t: float, data: bytes) -> None:
        """A frame from the master to the drives (``feed`` with ``rx``)."""
        self.frames = seq = self.frames + 1
        meaning = self._requests.get(data)
        if meaning is None:
            meaning = self._meaning(data)
        if not meaning.good:
            self._demand(seq, t, meaning.cost)  # noise still holds the line
            return
        if self._pending is not None:
            self._timing(seq, t, data)
        self._pending, self._pending_seq, self._pending_t, self._pending_data = meaning, seq, t, data
        self._pending_reply = None
        self._demand(seq, t, meaning.cost)
        slave = meaning.slave
        if slave == BROADCAST:
            for address in list(self._drives):  # a broadcast feeds every drive's timer
                self._silence(self._drives[address], address, seq, t)
        else:
            self._silence(self._drive(slave), slave, seq, t)
            if meaning.judged:
                self._written(meaning, seq, t)
        if self._enabled:
            self.check_idle(t)

    def _meaning(self, data: bytes) -> _Request:
        """What the request ``data`` means, remembered: a master polls the same few frames over and over."""
        n = len(data)
        if n < 4 or not crc_ok(data):
            meaning = _Request(False, frame_time(n, self.baud, self.bits), -1, -1, -1, -1, False, False)
        else:
            slave, function = data[0], data[1]
            register, value, reply = -1, -1, 5
            writes: tuple[tuple[int, int], ...] = ()
            if function in (_READ, _WRITE1) and n == 8:
                register, value = struct.unpack_from(">HH", data, 2)
                if function == _READ:
                    reply, value = 5 + 2 * value, -1
                else:
                    reply = 8
                    writes = ((register, value),)
            elif function == _WRITEN and n >= 11 and n == 9 + data[6] and data[6] % 2 == 0:
                register, value = struct.unpack_from(">H", data, 2)[0], struct.unpack_from(">H", data, 7)[0]
                values = struct.unpack_from(f">{data[6] // 2}H", data, 7)
                writes = tuple(((register + i) & 0xFFFF, v) for i, v in enumerate(values))  # every register, in turn
                reply = 8
            if slave == BROADCAST:
                reply = 0
            cost = transaction_time(n, reply, self.baud, self.bits, self.turnaround)
            judged = slave != BROADCAST and any(
                r == Reg.SPEED_SETPOINT or (r == Reg.COMMAND and v == Command.RESET) for r, v in writes
            )
            stores = any(r in self._followed for r, _ in writes)
            meaning = _Request(True, cost, slave, function, register, value, judged, stores, writes)
        if len(self._requests) >= MAX_SUBJECTS:
            self._requests.clear()
        self._requests[data] = meaning
        return meaning

    def _drive(self, address: int) -> _Drive:
        found = self._drives.get(address)
        if found is None:
            found = self._drives[address] = _Drive(self._default_timeout, self._default_max_speed)
        return found

    def _pending_ref(self) -> FrameRef:
        return FrameRef(self._pending_seq, self._pending_t)

    def _timing(self, seq: int, t: float, data: bytes) -> None:
        """collision, early-retry, broadcast-turnaround: did this request leave too soon after the last one?"""
        last = self._pending
        if last is None:
            return
        last_t = self._pending_t
        gap = t - last_t
        if last.slave == BROADCAST:
            if gap < self.broadcast_delay:
                self._report(
                    "broadcast-turnaround",
                    Severity.WARNING,
                    None,
                    "",
                    (self._pending_ref(), FrameRef(seq, t)),
                    f"a request {gap * 1000:.1f} ms after a broadcast; the drive needs "
                    f"{self.broadcast_delay * 1000:.0f} ms (the profile's broadcast_delay_ms)",
                    gap,
                    "wait the turnaround delay after every broadcast before the next request",
                )
            return
        reply_t = self._pending_reply
        if reply_t is not None:
            early = t < reply_t - _TIMER_SLACK  # sent before the reply to the last one came out
            need = reply_t - last_t
        else:
            need = last.cost
            early = gap < need - _EPSILON  # no reply: sent before one could have finished on the line
        if not early:
            return
        retry = data == self._pending_data
        what = "a retry" if retry else "a request"
        rule = "early-retry" if retry else "collision"
        self._report(
            rule,
            Severity.ERROR,
            last.slave,
            "",
            (self._pending_ref(), FrameRef(seq, t)),
            f"{what} {gap * 1000:.1f} ms after the last, before its reply could have finished "
            f"({need * 1000:.1f} ms on {self.baud} {_format(self.bits)})",
            gap,
            "wait for the reply, or for a timeout longer than the transaction's line time, before the next request",
            bump=True,
        )

    def _demand(self, seq: int, t: float, cost: float) -> None:
        first = self._first_t
        if first is None:
            first = self._first_t = t
        self._last_t = t
        self._last_cost = cost
        self._transactions += 1
        self._busy += cost
        window = self._window
        window.append((t, seq, cost))
        self._window_sum += cost
        span = self.limits.window
        horizon = t - span + _EPSILON  # a frame log's times are rounded to the microsecond
        if window[0][0] <= horizon or len(window) > MAX_WINDOW:
            self._expire(horizon)
        if t - first < span:
            return  # not yet a whole window seen
        percent = self._window_percent()
        self._now = percent
        if percent <= self._peak:
            return
        self._peak = percent
        if percent < self.limits.demand_warning or "line-demand" in self.ignore:
            return
        severity = Severity.ERROR if percent >= self.limits.demand_error_at() else Severity.WARNING
        if percent <= self._reported_peak + 0.5 and severity <= self._reported_severity:
            return  # a peak a little higher, judged the same: not worth a new finding event
        self._reported_peak, self._reported_severity = percent, severity
        count = len(window)
        self._report(
            "line-demand",
            severity,
            None,
            "",
            (FrameRef(window[0][1], window[0][0]), FrameRef(seq, t)),
            f"line demand {percent:.0f} % of {self.baud} {_format(self.bits)}: {count} transactions in "
            f"{self._window_stretch():.3f} s need {self._window_sum:.3f} s of line",
            percent,
            "poll less often or fewer registers, split the drives over more lines, or raise the baud rate "
            "(F08.01); the replies of a real line would queue and time out",
        )

    def _silence(self, drive: _Drive, address: int, seq: int, t: float) -> None:
        """comm-watchdog: the longest silence towards the drive, against its communication timeout."""
        last = drive.last_t
        drive.last_t, last_seq, drive.last_seq = t, drive.last_seq, seq
        if last is None or drive.comm_timeout <= 0.0:
            return
        gap = t - last
        if gap <= drive.longest:
            return
        drive.longest = gap
        ratio = gap / drive.comm_timeout
        if ratio < self.limits.watchdog_margin:
            return
        tripped = ratio > 1.0
        self._report(
            "comm-watchdog",
            Severity.ERROR if tripped else Severity.WARNING,
            address,
            "",
            (FrameRef(last_seq, last), FrameRef(seq, t)),
            f"longest silence {gap:.2f} s is {100 * ratio:.0f} % of the communication timeout "
            f"F08.02 = {drive.comm_timeout:g} s" + (": the drive trips CE" if tripped else ""),
            100.0 * ratio,
            "talk to the drive well within its timeout (a poll at most half of F08.02 apart), or raise F08.02",
        )

    def _written(self, request: _Request, seq: int, t: float) -> None:
        """The request side of writes: speed-above-max, reset-loop (each register a 0x10 writes, in turn)."""
        for register, value in request.writes:
            self._written_one(request.slave, register, value, seq, t)

    def _written_one(self, slave: int, register: int, value: int, seq: int, t: float) -> None:
        drive = self._drive(slave)
        if register == Reg.SPEED_SETPOINT and value > drive.max_speed:
            self._report(
                "speed-above-max",
                Severity.WARNING,
                slave,
                "2001H",
                (FrameRef(seq, t),),
                f"speed reference 2001H = {value} rpm above the maximum speed F00.03 = {drive.max_speed} rpm",
                float(value),
                f"keep 2001H within F00.03 ({drive.max_speed} rpm): the drive limits it or refuses it (0x03)",
                bump=True,
            )
        elif register == Reg.COMMAND and value == Command.RESET:
            ref = FrameRef(seq, t)
            resets = drive.resets
            resets.append(ref)
            while resets and resets[0].t < ref.t - self.limits.reset_window:
                resets.popleft()
            if len(resets) >= self.limits.resets:
                span = ref.t - resets[0].t
                self._report(
                    "reset-loop",
                    Severity.WARNING,
                    slave,
                    "2000H",
                    (resets[0], ref),
                    f"fault reset 2000H = 7 sent {len(resets)} times in {span:.1f} s",
                    float(len(resets)),
                    "read the fault code (2102H) and remove its cause before one reset; a reset loop hides the fault",
                )

    # -- replies

    def reply(self, t: float, data: bytes) -> None:
        """A frame from a drive to the master (``feed`` with ``tx``)."""
        self.frames += 1
        pending = self._pending
        if pending is None or self._pending_reply is not None or pending.slave == BROADCAST:
            return
        meaning = self._replies.get(data)
        if meaning is None:
            meaning = self._reply_meaning(data)
        slave, function, code = meaning
        if slave != pending.slave or function != pending.function:
            return  # a dropped reply (no bytes), noise, or not the answer to the last request
        self._pending_reply = t
        if code >= 0:
            self._refused(pending, code, FrameRef(self.frames, t))
        elif pending.stores:
            self._stored(pending)

    def _reply_meaning(self, data: bytes) -> tuple[int, int, int]:
        """(slave, function, exception code or -1) of the reply ``data``, remembered like a request's meaning."""
        if len(data) < 5 or not crc_ok(data):
            meaning = _NOT_A_REPLY
        else:
            meaning = (data[0], data[1] & 0x7F, data[2] if data[1] & 0x80 else -1)
        if len(self._replies) >= MAX_SUBJECTS:
            self._replies.clear()
        self._replies[data] = meaning
        return meaning

    def _refused(self, request: _Request, code: int, ref: FrameRef) -> None:
        register = request.register
        if register == Reg.SPEED_SETPOINT and code == ExceptionCode.ILLEGAL_VALUE:
            return  # speed-above-max says it
        if code == ExceptionCode.NOT_WHILE_RUNNING:
            rule = "refused-while-running"
            advice = f"stop the drive before writing {address_label(register)} (W/R*: written only while stopped)"
        elif code == ExceptionCode.OPERATION_FAILED and register == Reg.COMMAND:
            rule = "run-channel"
            advice = "select the communication run channel (2006H = 2, F00.01) before sending run commands"
        elif code == ExceptionCode.OPERATION_FAILED and register in self._eeprom:
            rule = "fcode-locked"
            advice = "write 200EH = 1 before function-code writes, and 200EH = 0 after them"
        elif code == ExceptionCode.ILLEGAL_ADDRESS and request.function == _READ:
            rule = "absent-register"
            advice = f"drop {address_label(register)} from the poll list: the drive has no such register"
        else:
            rule = "refused-repeat"
            advice = "read the refusal: repeating the request gets the same answer"
        key = (rule, request.slave, register, code)
        count = self._count(key)
        if count is None:
            return
        count.n += 1
        count.first = count.first or self._pending_ref()
        count.last = ref
        if count.n < self.limits.repeats:
            return
        action = "read" if request.function == _READ else "write"
        label = address_label(register) if register >= 0 else f"function 0x{request.function:02X}"
        try:
            meaning = ExceptionCode(code).meaning
        except ValueError:
            meaning = "not a code of the sheet"
        self._report(
            rule,
            Severity.WARNING,
            request.slave,
            label,
            (count.first, ref),
            f"{action} of {label} refused 0x{code:02X} ({meaning}) {count.n} times",
            float(count.n),
            advice,
        )

    def _stored(self, request: _Request) -> None:
        """A write the drive took: follow the settings the rules use; eeprom-wear, write-enable-left-on. A 0x10
        stores each of its registers, as that many 0x06 would."""
        for register, value in request.writes:
            if register in self._followed:
                self._stored_one(request.slave, register, value)

    def _stored_one(self, slave: int, register: int, value: int) -> None:
        drive = self._drive(slave)
        if register == Reg.WRITE_ENABLE:
            drive.write_enable = value != 0
            if value:
                self._enabled.add(slave)
            else:
                self._enabled.discard(slave)
            drive.enable_ref = self._pending_ref() if value else None
            drive.last_fcode_write = None
            return
        if register in self._timeout_cells and self._timeout_override is None:
            drive.comm_timeout = value * self._timeout_scale
            drive.longest = 0.0
        elif register in self._speed_cells:
            drive.max_speed = value
        if register not in self._eeprom:
            return
        drive.last_fcode_write = self._pending_t
        count = self._count(("eeprom-wear", slave, register, 0))
        if count is None:
            return
        count.n += 1
        count.same_value = count.same_value and (count.value in (-1, value))
        count.value = value
        count.first = count.first or self._pending_ref()
        count.last = self._pending_ref()
        if count.n < self.limits.cyclic_writes:
            return
        span = count.last.t - count.first.t
        if span <= 0.0:
            return
        per_hour = (count.n - 1) / span * 3600.0
        hours = self.endurance / per_hour
        if hours >= self.limits.wear_warning_h:
            return
        label = address_label(register)
        ram = register | 0x8000
        same = "the same value each time; " if count.same_value else ""
        self._report(
            "eeprom-wear",
            Severity.ERROR if hours < self.limits.wear_error_h else Severity.WARNING,
            slave,
            label,
            (count.first, count.last),
            f"{label} stored {per_hour:,.0f} times an hour ({same}{count.n} writes): rated "
            f"{self.endurance:,} writes reached in {_duration(hours)}",
            per_hour,
            f"write {label} only when it changes; a value that changes all the time belongs in RAM: "
            f"2001H for the speed reference, or {ram:04X}H ({label}, RAM only) where the drive has the "
            "INVT family's RAM-only addresses",
        )

    def check_idle(self, t: float) -> None:
        """write-enable-left-on: 200EH still 1 ``enable_hold`` s after the last function-code write.

        :meth:`feed` calls it on every request while a drive has 200EH = 1; call it at the stream's end too
        (offline: with the last frame's time), or now and then live."""
        for address in sorted(self._enabled):
            drive = self._drives[address]
            if drive.enable_ref is None:
                continue
            since = drive.last_fcode_write if drive.last_fcode_write is not None else drive.enable_ref.t
            if t - since >= self.limits.enable_hold:
                self._report(
                    "write-enable-left-on",
                    Severity.WARNING,
                    address,
                    "200EH",
                    (drive.enable_ref,),
                    f"200EH = 1 (function codes writable) left on {t - since:.1f} s after the last function-code write",
                    t - since,
                    "write 200EH = 0 after the function-code writes, so that a stray write cannot change a parameter",
                )
                drive.enable_ref = None  # said once per enabling

    # -- findings

    def _count(self, key: tuple[str, int, int, int]) -> _Count | None:
        found = self._counts.get(key)
        if found is None:
            if len(self._counts) >= MAX_SUBJECTS:
                return None
            found = self._counts[key] = _Count()
        return found

    def _report(
        self,
        rule: str,
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
            finding = Finding(
                rule, severity, drive, subject, frames, figure, value, count, advice, _source(rule, self.profile)
            )
        self._findings[key] = finding
        self._events.append(finding)


def _duration(hours: float) -> str:
    if hours < 1.0:
        return f"{hours * 60:.0f} min"
    if hours < 48.0:
        return f"{hours:.1f} h"
    if hours < 24 * 365:
        return f"{hours / 24:.0f} days"
    return f"{hours / 8760:.1f} years"


def _source(rule: str, profile: Profile) -> str:
    base = RULES[rule].source
    if rule == "eeprom-wear":
        return f"{base} (eeprom_endurance_writes = {profile.protocol.eeprom_endurance_writes:,}, assumed)"
    if rule == "broadcast-turnaround":
        return f"{base} (broadcast_delay_ms = {profile.protocol.broadcast_delay_ms:g}, assumed)"
    if rule == "comm-watchdog":
        # an instance's: a compiled (mypyc) dataclass has no class-level default
        return f"{base} (its margin {Limits().watchdog_margin:g} assumed)"
    return base

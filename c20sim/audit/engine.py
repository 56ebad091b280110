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

The Auditor is the window the rules share (:class:`~c20sim.audit.window.Window`) and the dispatch: each rule
is an object in its own file under :mod:`c20sim.audit.rules`, made per stream from the table
:data:`~c20sim.audit.rules.RULES`, and the Auditor calls the hooks each defines (see
:mod:`c20sim.audit.rules.base`).

Memory is bounded whatever the stream's length: a window of the line's last
transactions (at most :data:`MAX_WINDOW` entries), a few counters per drive
and subject (at most :data:`MAX_SUBJECTS` of them), and a bounded queue of
events.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable

from ..drive.profile import Profile
from ..wire.protocol import BROADCAST, SHEET_CHAR_BITS, FunctionCode, crc_ok, frame_time, transaction_time
from ..wire.registers import Reg
from .findings import Finding, FrameRef, Severity
from .limits import _EPSILON, _TIMER_SLACK, F_COMM_TIMEOUT, F_MAX_SPEED, MAX_SUBJECTS, MAX_WINDOW, Limits, LineDemand
from .rules import RULES, Rule, hooked
from .state import _NOT_A_REPLY, _Request
from .window import Window

__all__ = ["F_COMM_TIMEOUT", "F_MAX_SPEED", "MAX_SUBJECTS", "MAX_WINDOW", "Auditor", "Limits", "LineDemand"]

_READ = FunctionCode.READ_REGISTERS
_WRITE1 = FunctionCode.WRITE_SINGLE
_WRITEN = FunctionCode.WRITE_MULTIPLE


class Auditor(Window):
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
        super().__init__(profile, baud=baud, bits=bits, comm_timeout=comm_timeout, limits=limits, ignore=ignore)
        unknown = sorted(self.ignore - set(RULES))
        if unknown:
            raise ValueError(f"unknown rule {unknown[0]!r}; the rules are {', '.join(RULES)}")
        #: this stream's rules, one of each row of RULES, in its order
        self.rules: list[Rule] = [make() for make in RULES.values()]
        rules = self.rules
        # each hook's rules (bound methods where a frame calls them all: a lookup less a call)
        self._gap: list[Callable[[Window, int, float, bytes], None]] = [r.gap for r in hooked(rules, "gap")]
        self._peak_hooks: list[Callable[[Window, int, float, float], None]] = [
            r.demand for r in hooked(rules, "demand")
        ]
        self._request_hooks: list[Callable[[Window, _Request, int, float], None]] = [
            r.request for r in hooked(rules, "request")
        ]
        self._writers = hooked(rules, "written")
        self._refusers = hooked(rules, "refused")
        self._storers = hooked(rules, "stored")
        self._readers = hooked(rules, "read")
        self._idlers = hooked(rules, "idle")
        # what the frames seen mean, by their bytes (at most MAX_SUBJECTS each): requests, and replies as
        # (slave, function, exception code or -1)
        self._requests: dict[bytes, _Request] = {}
        self._replies: dict[bytes, tuple[int, int, int]] = {}
        # the rule that takes a refusal, by the request's bytes and the exception code (at most MAX_SUBJECTS)
        self._claimed: dict[tuple[bytes, int], Callable[[Window, _Request, int, FrameRef], None]] = {}
        # the read hooks of the rules that watch a read request's registers, by its bytes (at most MAX_SUBJECTS)
        self._watching: dict[bytes, tuple[Callable[[Window, int, int, tuple[int, ...], int, float], None], ...]] = {}

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

    # -- requests

    def request(self, t: float, data: bytes) -> None:
        """A frame from the master to the drives (``feed`` with ``rx``): the rules' hooks gap, demand, request,
        written and idle, in that order."""
        self.frames = seq = self.frames + 1
        meaning = self._requests.get(data)
        if meaning is None:
            meaning = self._meaning(data)
        if not meaning.good:
            self._line(seq, t, meaning.cost)  # noise still holds the line
            return
        pending = self.pending
        if pending is not None and self._gap:
            self._too_soon(pending, seq, t, data)
        self.previous, self.previous_seq, self.previous_t = pending, self.pending_seq, self.pending_t
        self.previous_reply = self.pending_reply
        self.pending, self.pending_seq, self.pending_t, self.pending_data = meaning, seq, t, data
        self.pending_reply = None
        percent = self._demand(seq, t, meaning.cost)
        if percent > 0.0:
            for peak in self._peak_hooks:
                peak(self, seq, t, percent)
        for hook_request in self._request_hooks:
            hook_request(self, meaning, seq, t)
        for written, register, value in meaning.judged:  # each register a 0x10 writes, in turn
            written(self, meaning.slave, register, value, seq, t)
        if self.enabled:
            self.check_idle(t)

    def _line(self, seq: int, t: float, cost: float) -> None:
        """The transaction takes the line-demand window; the demand hooks hear of a new peak."""
        percent = self._demand(seq, t, cost)
        if percent > 0.0:
            for peak in self._peak_hooks:
                peak(self, seq, t, percent)

    def _too_soon(self, pending: _Request, seq: int, t: float, data: bytes) -> None:
        """The gap hooks, for a request sent after a broadcast, or before the reply to the last request came out
        (or, with no reply, before one could have finished on the line: :attr:`need` is the time it needed)."""
        if pending.slave != BROADCAST:
            last_t = self.pending_t
            reply_t = self.pending_reply
            if reply_t is not None:
                if t >= reply_t - _TIMER_SLACK:
                    return
                self.need = reply_t - last_t
            else:
                need = pending.cost
                if t - last_t >= need - _EPSILON:
                    return
                self.need = need
        for hook in self._gap:
            hook(self, seq, t, data)

    def _meaning(self, data: bytes) -> _Request:
        """What the request ``data`` means, remembered: a master polls the same few frames over and over."""
        n = len(data)
        if n < 4 or not crc_ok(data):
            meaning = _Request(False, frame_time(n, self.baud, self.bits), -1, -1, -1, -1, (), False)
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
            judged = tuple(
                (rule.written, r, v)
                for r, v in (writes if slave != BROADCAST else ())
                for rule in self._writers
                if rule.judges(r, v)
            )
            stores = any(r in self._followed for r, _ in writes)
            meaning = _Request(True, cost, slave, function, register, value, judged, stores, writes)
        if len(self._requests) >= MAX_SUBJECTS:
            self._requests.clear()
        self._requests[data] = meaning
        return meaning

    # -- replies

    def reply(self, t: float, data: bytes) -> None:
        """A frame from a drive to the master (``feed`` with ``tx``): the rules' hooks refused, stored or read."""
        self.frames += 1
        pending = self.pending
        if pending is None or self.pending_reply is not None or pending.slave == BROADCAST:
            return
        meaning = self._replies.get(data)
        if meaning is None:
            meaning = self._reply_meaning(data)
        slave, function, code = meaning
        if slave != pending.slave or function != pending.function:
            return  # a dropped reply (no bytes), noise, or not the answer to the last request
        self.pending_reply = t
        self.settle(len(data))  # the line held the reply it got, not the one asked for: judge its demand
        if code >= 0:
            refused = self._claimed.get((self.pending_data, code))
            if refused is None:
                refused = self._claimant(pending, code)
            refused(self, pending, code, FrameRef(self.frames, t))
        elif pending.stores:
            self._stored(pending)
        elif self._readers and function == _READ:
            watching = self._watching.get(self.pending_data)
            if watching is None:
                watching = self._watchers(pending)
            if watching and len(data) == 5 + data[2] and data[2] % 2 == 0:
                values = struct.unpack_from(f">{data[2] // 2}H", data, 3)
                for read in watching:
                    read(self, slave, pending.register, values, self.frames, t)

    def _claimant(self, request: _Request, code: int) -> Callable[[Window, _Request, int, FrameRef], None]:
        """The refused hook of the first rule that claims the refusal ``code`` of ``request`` (a fallback rule
        last), remembered by the request's bytes and the code; a refusal no rule claims goes nowhere."""
        refused: Callable[[Window, _Request, int, FrameRef], None] = _unclaimed
        for rule in self._refusers:
            if rule.claims(self, request, code):
                refused = rule.refused
                break
        if len(self._claimed) >= MAX_SUBJECTS:
            self._claimed.clear()
        self._claimed[(self.pending_data, code)] = refused
        return refused

    def _watchers(
        self, request: _Request
    ) -> tuple[Callable[[Window, int, int, tuple[int, ...], int, float], None], ...]:
        """The read hooks of the rules that watch the registers ``request`` reads, remembered by its bytes."""
        count = struct.unpack_from(">H", self.pending_data, 4)[0]
        watching = tuple(rule.read for rule in self._readers if rule.watches(request.register, count))
        if len(self._watching) >= MAX_SUBJECTS:
            self._watching.clear()
        self._watching[self.pending_data] = watching
        return watching

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

    def _stored(self, request: _Request) -> None:
        """A write the drive took: follow the settings the rules use; a function code's store goes to the stored
        hooks. A 0x10 stores each of its registers, as that many 0x06 would."""
        for register, value in request.writes:
            if register in self._followed:
                self._stored_one(request.slave, register, value)

    def _stored_one(self, slave: int, register: int, value: int) -> None:
        drive = self.drive(slave)
        if register == Reg.WRITE_ENABLE:
            drive.write_enable = value != 0
            if value:
                self.enabled.add(slave)
            else:
                self.enabled.discard(slave)
            drive.enable_ref = self.pending_ref() if value else None
            drive.last_fcode_write = None
            return
        if register in self._timeout_cells and self._timeout_override is None:
            drive.comm_timeout = value * self._timeout_scale
            drive.longest = 0.0
        elif register in self._speed_cells:
            drive.max_speed = value
        if register not in self.eeprom:
            return
        drive.last_fcode_write = self.pending_t
        for rule in self._storers:
            rule.stored(self, slave, register, value)

    def check_idle(self, t: float) -> None:
        """The rules' idle hooks (write-enable-left-on: 200EH still 1 ``enable_hold`` s after the last
        function-code write).

        :meth:`feed` calls it on every request while a drive has 200EH = 1; call it at the stream's end too
        (offline: with the last frame's time), or now and then live."""
        for rule in self._idlers:
            rule.idle(self, t)


def _unclaimed(audit: Window, request: _Request, code: int, ref: FrameRef) -> None:
    """A refusal no rule claims (none while the table has its fallback, refused-repeat)."""

"""Several drives on one RS485 line: addressing, broadcast, and the frame log.

The bus takes framing events (:class:`~c20sim.wire.protocol.FrameEvent`) and gives
back the reply to put on the line, if any. Address 0 is broadcast: a write
acts on every drive and is never answered, a read is ignored. Reserved
addresses (F8H-FFH) and absent drives get silence. A frame with a bad CRC or
length addressed to a drive gets exception 0x06, as the sheet says, unless
the profile says the model stays silent.

A write to 2008H (address) or 2009H (baud) takes effect after its reply,
which goes out at the old address and baud: the reply is built from the
request, and the new settings are read for the next frame. When the only
drive on the line changes its baud, by any write (broadcast, or one whose
reply is lost), the line follows: :attr:`Bus.line_baud` changes once the
request is served, and :attr:`Reply.baud` keeps the baud the reply goes out
at. With several drives, a drive set to another baud than the line's goes
deaf, as it would on a real multi-drop line.

The bus tells when the line changes, as it tells of frames: a listener of
:meth:`Bus.on_line` is called with the new :class:`LineSettings` (baud and
character size) whenever either changes, by a write the line followed (once
the request is served, its reply recorded at the old baud), a reset, or the
serial settings given to :attr:`Bus.char_bits`. Nobody polls the baud.

Every frame in and out becomes a :class:`FrameRecord` in a bounded ring
(:class:`~c20sim.core.framering.FrameRing`: kept as bytes and numbers, which
no garbage collection walks), and is passed to each listener (the JSON-lines
writer, the dashboard).

Every event also has its time on a real RS485 line
(:func:`~c20sim.wire.protocol.transaction_time` at the line's baud and
character size, :attr:`Bus.char_bits`): the request, the turnaround and the
reply, each frame after its t3.5. It is added to the line's busy time and the
addressed drive's (:class:`Counters`), whatever transport carried the frame,
and the line scheduler holds the line for it under bus timing.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import random
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from ..wire.protocol import (
    BROADCAST,
    SHEET_CHAR_BITS,
    ExceptionCode,
    ExceptionResponse,
    FrameEvent,
    FrameKind,
    MbapHeader,
    ReadRequest,
    Request,
    Response,
    crc_ok,
    decode_request,
    encode,
    frame_time,
    transaction_time,
)
from ..wire.registers import RegisterMap
from ..wire.values import quick_init
from .framering import FrameRing
from .linkfaults import LinkFaults
from .records import Direction, FrameRecord, RecordKind
from .slave import Slave

__all__ = ["Bus", "Counters", "Direction", "FrameRecord", "LineListener", "LineSettings", "RecordKind", "Reply"]

log = logging.getLogger(__name__)

#: Addresses the sheet reserves (1.a): no drive answers them.
RESERVED = range(0xF8, 0x100)


@dataclass
class Counters:
    """Traffic of one drive address, as a master's diagnostics would count it."""

    requests: int = 0  #: good frames addressed to it (broadcasts count at address 0)
    replies: int = 0  #: normal answers sent
    exceptions: dict[int, int] = field(default_factory=dict)  #: exception code -> answers sent
    crc_errors: int = 0  #: frames with its address and a bad CRC
    length_errors: int = 0  #: frames with its address and the wrong length
    silences: int = 0  #: requests left unanswered (absent, offline, reply dropped); not broadcasts
    injected: int = 0  #: requests and replies a link fault acted on
    #: seconds its transactions held an RS485 line at the line's settings (request, turnaround, reply)
    line_busy_s: float = 0.0
    #: the line's time (seconds) from the start of its first transaction to the end of its last
    first_t: float | None = None
    last_t: float | None = None

    @property
    def line_share(self) -> float:
        """Its share of the line's capacity: busy time over the time from its first transaction to its last."""
        if self.first_t is None or self.last_t is None or self.last_t <= self.first_t:
            return 0.0
        return min(1.0, self.line_busy_s / (self.last_t - self.first_t))

    def as_dict(self) -> dict[str, object]:
        return {
            "requests": self.requests,
            "replies": self.replies,
            "exceptions": {f"0x{code:02X}": n for code, n in sorted(self.exceptions.items())},
            "crc_errors": self.crc_errors,
            "length_errors": self.length_errors,
            "silences": self.silences,
            "injected": self.injected,
            "line_busy_s": round(self.line_busy_s, 6),
            "line_share": round(self.line_share, 4),
        }


@quick_init
@dataclass(frozen=True, slots=True)
class Reply:
    """Bytes to send back, after ``delay`` seconds of turnaround."""

    data: bytes
    delay: float
    slave: int
    baud: int  #: the line speed it goes out at (the old one, after a 2009H write)
    split: float = 0.0  #: seconds between its two pieces (a link fault; 0: in one piece)
    #: Modbus TCP: seconds the right reply waits behind a copy under another transaction id (a link fault)
    wrong_transaction: float = 0.0


@dataclass(frozen=True, slots=True)
class LineSettings:
    """What the line runs at: what a listener of :meth:`Bus.on_line` is told when it changes."""

    baud: int
    char_bits: int  #: bits per character: 10 for 8N1, 11 with parity or 2 stop bits


#: Called with the line's new settings when its baud or its character changes.
LineListener = Callable[[LineSettings], None]


class Bus:
    """Drives sharing one line. ``handle`` serves one framing event."""

    def __init__(self, slaves: Iterable[Slave], *, log_size: int = 2000, seed: int | None = None) -> None:
        self.slaves: list[Slave] = list(slaves)
        if not self.slaves:
            raise ValueError("a bus needs at least one drive")
        self._line_baud = self.slaves[0].baud
        #: who is told when the line's settings change (:meth:`on_line`)
        self._line_listening: tuple[LineListener, ...] = ()
        #: link faults of the whole line, and of each drive's interface (by position in ``slaves``)
        self.link = LinkFaults()
        self.drive_links: list[LinkFaults] = [LinkFaults() for _ in self.slaves]
        self._link_of = dict(zip(self.slaves, self.drive_links, strict=True))
        self._at: dict[int, Slave] = {}  #: address -> drive, a cache checked on every use
        self.rng = random.Random(seed)
        self.records: FrameRing[FrameRecord] = FrameRing(log_size, FrameRecord)
        #: the listeners, a tuple made anew when one comes or goes: a record calls each without a copy
        self._listening: tuple[Callable[[FrameRecord], None], ...] = ()
        #: traffic per address on the frames (at most 256 entries), and bytes that were no frame
        self.counters: dict[int, Counters] = {}
        self.noise = 0
        #: bits per character on the line (10 for 8N1, 11 with parity or 2 stop bits): the serial settings
        self._char_bits = SHEET_CHAR_BITS
        #: seconds the last event held the line (request, turnaround, reply), and its request's share of it
        self.last_line_time = 0.0
        self.last_request_time = 0.0
        #: seconds every event so far held the line
        self.line_busy_s = 0.0
        #: how the reply being made is stamped, set by the line before each request it serves: None (the reply is
        #: handed over whole, the turnaround after its request: its last byte leaves then), or, on a line that
        #: keeps each transaction's RS485 time (bus timing), when the transaction starts on the line and whether
        #: the request was on the wire already as its bytes came (a line-timed port): the reply's last byte
        #: leaves at the end of the transaction's time on the wire
        self.timed_from: tuple[float, bool] | None = None
        self._request_len = 0

    # -- the line's settings, told to whoever listens

    @property
    def line_baud(self) -> int:
        """The line's speed: the drives' F08.01 (with one drive, the line follows its writes)."""
        return self._line_baud

    @line_baud.setter
    def line_baud(self, baud: int) -> None:
        if baud != self._line_baud:
            self._line_baud = baud
            self._tell_line()

    @property
    def char_bits(self) -> int:
        """Bits per character on the line (10 for 8N1, 11 with parity or 2 stop bits): the serial settings."""
        return self._char_bits

    @char_bits.setter
    def char_bits(self, bits: int) -> None:
        if bits != self._char_bits:
            self._char_bits = bits
            self._tell_line()

    @property
    def line_settings(self) -> LineSettings:
        return LineSettings(self._line_baud, self._char_bits)

    def on_line(self, listener: LineListener) -> Callable[[], None]:
        """Call ``listener`` with the new :class:`LineSettings` whenever the baud or the character changes (after
        the request that changed it is served and its reply recorded); returns a function that unsubscribes."""
        self._line_listening = (*self._line_listening, listener)

        def drop() -> None:
            listening = list(self._line_listening)
            if listener in listening:
                listening.remove(listener)
                self._line_listening = tuple(listening)

        return drop

    def _tell_line(self) -> None:
        settings = self.line_settings
        for listener in self._line_listening:
            try:
                listener(settings)
            except Exception:
                log.exception("a line listener failed on %s; the bus keeps serving", settings)

    def counters_of(self, address: int) -> Counters:
        """The traffic counters of ``address`` (zeros until a frame names it)."""
        found = self.counters.get(address)
        if found is None:
            found = self.counters[address] = Counters()
        return found

    # -- the frame log

    def subscribe(self, listener: Callable[[FrameRecord], None]) -> Callable[[], None]:
        """Call ``listener`` with every new record; returns a function that unsubscribes."""
        self._listening = (*self._listening, listener)
        return functools.partial(self._drop, listener)

    def _drop(self, listener: Callable[[FrameRecord], None]) -> None:
        """Stop calling ``listener`` (once, if it subscribed twice); a failing listener may be gone already."""
        listening = list(self._listening)
        if listener in listening:
            listening.remove(listener)
            self._listening = tuple(listening)

    def record(self, entry: FrameRecord) -> None:
        self.records.append(entry)
        for listener in self._listening:
            try:
                listener(entry)
            except Exception:
                log.exception("frame log listener failed; removing it")
                self._drop(listener)

    # -- serving

    def link_of(self, slave: Slave) -> LinkFaults:
        """The link faults of one drive's interface."""
        return self._link_of[slave]

    def _links(self, slave: Slave) -> tuple[LinkFaults, LinkFaults]:
        return self._link_of[slave], self.link

    def _offline(self, slave: Slave) -> bool:
        """The drive hears nothing: its own link, or the whole line, is offline."""
        return self._link_of[slave].offline or self.link.offline

    def _forced(self, slave: Slave) -> ExceptionCode | None:
        """The exception forced on the drive's replies (its own link's first, then the line's)."""
        own = self._link_of[slave].forced_exception
        return own if own is not None else self.link.forced_exception

    def slave_at(self, address: int) -> Slave | None:
        """The drive answering ``address`` at the line's baud, if any."""
        # Addresses change (2008H, restore defaults, a state file): the cache is a guess, checked each time.
        cached = self._at.get(address)
        if cached is not None and cached.address == address and cached.baud == self._line_baud:
            return cached
        for slave in self.slaves:
            if slave.address == address and slave.baud == self._line_baud:
                self._at[address] = slave
                return slave
        self._at.pop(address, None)
        return None

    def handle(self, event: FrameEvent, now: float | None = None) -> Reply | None:
        """Serve one framing event; ``now`` is model time (default: the event's time).

        Sets :attr:`last_line_time`: the event's time on a real line at the line's settings, counted to the
        line and to the addressed drive."""
        baud = self._line_baud  # the request and its reply go at the baud before a 2009H write takes effect
        self._request_len = len(event.data)
        try:
            reply = self._handle(event, now)
        finally:
            if self._line_baud != baud:
                self._tell_line()  # the line followed its only drive: told once the transaction is recorded
        bits = self._char_bits
        request = frame_time(len(event.data), baud, bits)
        spent = request
        if reply is not None:
            spent = transaction_time(len(event.data), len(reply.data), baud, bits, reply.delay)
        self.last_line_time, self.last_request_time = spent, request
        self.line_busy_s += spent
        if event.kind is not FrameKind.NOISE and len(event.data) >= 2:  # an addressed frame (noise is the line's)
            counters = self.counters_of(reply.slave if reply is not None else event.data[0])
            counters.line_busy_s += spent
            if counters.first_t is None:
                counters.first_t = event.t - request
            counters.last_t = event.t + spent - request
        return reply

    def _handle(self, event: FrameEvent, now: float | None) -> Reply | None:
        t = event.t if now is None else now
        if event.kind is FrameKind.FRAME and self.link.noise_percent > 0 and self.link.noisy(self.rng):
            event = self._hit(event)
        if event.kind is FrameKind.FRAME:
            return self._handle_frame(event, t)
        slave_address = event.data[0] if event.data else None
        self.record(
            FrameRecord(
                event.t,
                Direction.RX,
                event.data,
                RecordKind(event.kind.value),
                slave_address,
                event.kind.value,
                event.note,
                t,
                mbap=event.mbap,
            )
        )
        if event.kind is FrameKind.NOISE or slave_address is None or len(event.data) < 2:
            self.noise += 1
            return None
        counters = self.counters_of(slave_address)
        if event.kind is FrameKind.CRC_ERROR:
            counters.crc_errors += 1
        else:
            counters.length_errors += 1
        slave = self.slave_at(slave_address)
        if slave is None or not slave.profile.protocol.reply_to_bad_crc:
            return None
        if self._offline(slave):
            return None
        return self._reply(
            slave, slave.frame_error(slave_address, event.data[1]), event.t, t, None, self._line_baud, event.mbap
        )

    def _hit(self, event: FrameEvent) -> FrameEvent:
        """A request that noise on the line hit: one bit flipped, so the drive sees a CRC error (the address byte
        is spared, so that the frame still names its drive)."""
        data = event.data
        bit = 8 + self.rng.randrange((len(data) - 1) * 8)
        hit = data[: bit // 8] + bytes((data[bit // 8] ^ (1 << (bit % 8)),)) + data[bit // 8 + 1 :]
        kind = FrameKind.FRAME if crc_ok(hit) else FrameKind.CRC_ERROR
        return dataclasses.replace(event, data=hit, kind=kind, note=f"bit {bit} flipped by noise (injected)")

    def _handle_frame(self, event: FrameEvent, t: float) -> Reply | None:
        request = decode_request(event.data, check_crc=False)  # the framer checked it
        address = request.slave

        def rx(note: str = "", registers: RegisterMap | None = self.slaves[0].registers) -> None:
            self.record(
                FrameRecord(
                    event.t,
                    Direction.RX,
                    event.data,
                    RecordKind.REQUEST,
                    address,
                    request,
                    note,
                    t,
                    registers,
                    mbap=event.mbap,
                )
            )

        counters = self.counters_of(address)
        counters.requests += 1
        if address == BROADCAST:
            if isinstance(request, ReadRequest):
                rx("broadcast read: ignored")
                return None
            rx("broadcast: no reply")
            for each in self.slaves:
                if each.baud != self._line_baud or self._offline(each):
                    continue
                if self._forced(each) is None:
                    each.handle(request, t)  # a forced exception means the drive never acts on the request
                self._follow_baud(each)
            return None
        slave = self.slave_at(address) if address not in RESERVED else None
        if slave is None:
            rx("reserved address: silence" if address in RESERVED else "no drive at this address: silence")
            counters.silences += 1
            return None
        if self._offline(slave):
            rx("drive offline (injected)", slave.registers)
            counters.silences += 1
            counters.injected += 1
            return None
        rx("", slave.registers)
        forced = self._forced(slave)
        spent: LinkFaults | None = None
        if forced is not None:
            counters.injected += 1
            response: Response = ExceptionResponse(address, request.function, forced)
            own = self._link_of[slave]
            spent = own if own.forced_exception is not None else self.link
            spent.spend()
        else:
            response = slave.handle(request, t)
        baud = self._line_baud
        self._follow_baud(slave)
        return self._reply(slave, response, event.t, t, request, baud, event.mbap, event.data, spent)

    def _follow_baud(self, slave: Slave) -> None:
        """The line follows the only drive on it to a new baud (on a multi-drop line, the drive goes deaf); the
        listeners are told when :meth:`handle` ends, after the reply at the old baud is recorded."""
        if len(self.slaves) == 1 and slave.baud != self._line_baud:
            self._line_baud = slave.baud

    def _reply(
        self,
        slave: Slave,
        response: Response,
        t: float,
        model_t: float,
        request: Request | None,
        baud: int,
        mbap: MbapHeader | None = None,
        raw: bytes = b"",
        spent: LinkFaults | None = None,
    ) -> Reply | None:
        """The reply to ``response`` with the links' reply faults on it; ``spent``: a link whose "next N replies"
        this reply has counted already (a forced exception), which is not counted again."""
        data: bytes | None = encode(response)
        kind = RecordKind.EXCEPTION if response.function & 0x80 else RecordKind.REPLY
        delay = slave.answer_delay
        notes: list[str] = []
        split = wrong_transaction = 0.0
        for link in self._links(slave):
            if not link.active_reply_faults:
                continue
            assert data is not None
            mangled = link.mangle(data, delay, self.rng, raw, t)
            if link is not spent:
                link.spend()
            data, delay = mangled.data, mangled.delay
            split = max(split, mangled.split)
            wrong_transaction = max(wrong_transaction, mangled.wrong_transaction)
            notes += mangled.notes
            if data is None:
                counters = self.counters_of(response.slave)
                counters.silences += 1
                counters.injected += 1
                self._tx(t + delay, b"", RecordKind.DROPPED, slave, response, notes, model_t, request, mbap)
                return None
        assert data is not None
        counters = self.counters_of(response.slave)
        if notes:
            counters.injected += 1
        if isinstance(response, ExceptionResponse):
            counters.exceptions[int(response.code)] = counters.exceptions.get(int(response.code), 0) + 1
        else:
            counters.replies += 1
        self._tx(
            self._reply_end(t, len(data), delay, baud, split),
            data,
            kind,
            slave,
            response,
            notes,
            model_t,
            request,
            mbap,
        )
        return Reply(data, delay, response.slave, baud, split, wrong_transaction)

    def _reply_end(self, t: float, size: int, delay: float, baud: int, split: float) -> float:
        """When a reply of ``size`` bytes to the request stamped ``t`` has its last byte out (a frame's time in the
        log): the turnaround after the request where the reply is handed over whole; with :attr:`timed_from`, the
        end of the transaction on the line (:func:`transaction_time` from its start, less the request's own time
        where it was on the wire as it came), a split reply's gap included."""
        timed = self.timed_from
        if timed is None:
            return t + delay
        start, on_wire = timed
        bits = self._char_bits
        spent = transaction_time(self._request_len, size, baud, bits, delay) + split
        return start + spent - (frame_time(self._request_len, baud, bits) if on_wire else 0.0)

    def _tx(
        self,
        t: float,
        data: bytes,
        kind: RecordKind,
        slave: Slave,
        response: Response,
        notes: list[str],
        model_t: float,
        request: Request | None,
        mbap: MbapHeader | None,
    ) -> None:
        note = "; ".join(notes)
        if mbap is not None and data and kind is not RecordKind.DROPPED and (not crc_ok(data) or data[0] != mbap.unit):
            note = "; ".join([*notes, "the gateway forwards no broken reply: it answers 0x0B after its timeout"])
        self.record(
            FrameRecord(
                t,
                Direction.TX,
                data,
                kind,
                response.slave,
                response,
                note,
                model_t,
                slave.registers,
                request,
                mbap=mbap,
            )
        )

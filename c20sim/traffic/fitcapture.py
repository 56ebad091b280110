"""The capture, read for a fit: its writes, marks and reads of physical quantities, in time order."""

from __future__ import annotations

import itertools
import statistics
from dataclasses import dataclass, field

from ..drive import face
from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.protocol import (
    SHEET_CHAR_BITS,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    WriteMultipleRequest,
    WriteSingleRequest,
    crc_ok,
    decode_request,
    decode_response,
)
from ..wire.registers import BAUD_RATES, FIXED_REGISTERS, Reg
from .capture import LogRecord, _read_text, parse_log
from .dialect import NOTE, Frame
from .fitlink import LINKS, PORT_LINKS, LinkModel, Timing, choose_link, format_bits, turnaround_of
from .programme import LOAD_OFF, LOAD_ON
from .replay import Exchange, exchanges

#: Registers whose reads are physical quantities or the drive's state: what a fit compares.
PHYSICAL = frozenset(range(0x3000, 0x3012)) | {Reg.STATUS1, Reg.STATUS2, Reg.FAULT_CODE}


@dataclass(frozen=True)
class Event:
    """What the model is given, in log time: a write, a load mark, or a read to compare."""

    t: float
    kind: str  #: "write", "load", "read"
    address: int = 0
    value: int = 0
    line: int = 0


@dataclass
class Capture:
    """A frame log, read for a fit."""

    path: str
    address: int
    events: list[Event]  #: writes, marks and physical reads, at the time the drive took or sampled each
    reads: dict[int, list[Event]]  #: register -> its reads
    timings: list[Timing]  #: each answered request's times and lengths (exceptions too)
    loads: int = 0  #: load marks (load-on)
    settings: dict[int, int] = field(default_factory=dict)  #: 20xxH settings read (pole pairs, ramps)
    duration: float = 0.0
    link: LinkModel = LINKS["bare"]  #: how the transactions were carried
    link_why: str = ""  #: how the link was told, in words
    baud: int = 19200
    bits: int = 10  #: of one character on the line
    turnaround: tuple[float, float, int] | None = None  #: (s, its uncertainty, late transactions); None: too few
    probes: list[tuple[str, Frame]] = field(default_factory=list)  #: the dialect probe's frames, with their notes
    port: str = ""  #: the header's word for the link (serial, pty, tcp, modbus-tcp, ...); "" without a header


# --- Reading the capture.


def _load_records(path: str) -> list[LogRecord]:
    text = _read_text(path)
    lines = text.splitlines()
    try:
        return parse_log(lines, path)
    except C20SimError as exc:
        last = len(lines)
        if f"line {last}:" in str(exc) and not text.endswith("\n"):
            raise C20SimError(
                f"{path}: truncated: its last line ({last}) is cut short; remove that line, or record again"
            ) from None
        raise


def _header(records: list[LogRecord], path: str) -> tuple[str, int, int] | None:
    """The capture's link header (``{"kind": "link", "note": "link PORT BAUD FORMAT"}``): port, baud, bits."""
    for record in records[:4]:
        if record.kind == "link" and not record.data:
            words = record.note.split()
            try:
                if len(words) != 4 or words[0] != "link" or words[1] not in PORT_LINKS:
                    raise ValueError(record.note)
                return words[1], int(words[2]), format_bits(words[3])
            except ValueError:
                raise C20SimError(
                    f"{path}: line {record.line}: key 'note': expected 'link PORT BAUD FORMAT' (PORT one of "
                    f"{', '.join(PORT_LINKS)}; FORMAT such as 8N1), not {record.note[:60]!r}"
                ) from None
    return None


def _timings(records: list[LogRecord], address: int) -> list[Timing]:
    """Each answered request to ``address`` (a good CRC: a reply or an exception), with its reply's time."""
    out = []
    for request, reply in itertools.pairwise(records):
        if (
            request.direction == "rx"
            and reply.direction == "tx"
            and len(request.data) >= 4
            and len(reply.data) >= 5
            and request.data[0] == address
            and crc_ok(reply.data)
            and not reply.note  # a late reply to an earlier request (exercise says so) is not this one's
        ):
            out.append(Timing(request.t, reply.t, len(request.data), len(reply.data)))
    return out


def load_capture(
    path: str, profile: Profile, address: int | None = None, *, link: str | None = None, baud: int | None = None
) -> Capture:
    """The events of a frame log for a fit; C20SimError in one line for a log that cannot be fitted.

    ``link`` (a name in :data:`LINKS`) overrides what the capture's header and its times say of the link;
    ``baud`` the header's (or, with no header, the profile's) baud."""
    records = _load_records(path)
    if not any(r.direction == "rx" for r in records):
        raise C20SimError(f"{path}: no frame from the master (dir rx): not a capture of a master and a drive")
    found, _ = exchanges(records)
    answered = _answered(found, profile, path)
    if address is None:
        address = max(answered, key=lambda a: answered[a]) if answered else 1
    header = _header(records, path)
    port, line_baud, bits = header if header is not None else ("", _profile_baud(profile), SHEET_CHAR_BITS)
    line_baud = baud or line_baud
    timings = _timings(records, address)
    if link is not None:
        model, why = LINKS[link], "as --link says"
    else:
        candidates = PORT_LINKS[port] if port else tuple(LINKS)
        model, why = choose_link(timings, candidates, line_baud, bits, path)
    turnaround = turnaround_of(timings, model, line_baud, bits) if len(timings) >= 5 else None
    net = turnaround[0] if turnaround is not None else 0.0
    replies = {id(r): n.t for r, n in itertools.pairwise(records) if r.direction == "rx" and n.direction == "tx"}
    capture = Capture(path, address, [], {}, timings, 0, {}, 0.0, model, why, line_baud, bits, turnaround, port=port)
    t0 = found[0].record.t
    for exchange in found:
        record = exchange.record
        t = record.t - t0
        reply_t = replies.get(id(record))
        if reply_t is not None and exchange.reply:
            # the drive took the request when the link had carried it: its record's time, and what the
            # transaction took beyond the link's arithmetic and the turnaround (a queue behind other masters, a
            # transaction held up); the link's own part is the same for every request, and left out
            fixed = model.fixed(len(record.data), len(exchange.reply), line_baud, bits)
            t += max(0.0, reply_t - record.t - fixed - net)
        mine = record.data[:1] in (bytes((address,)), b"\x00")  # the fitted drive's request, or a broadcast
        if record.note.startswith(NOTE) and mine:
            capture.probes.append((record.note, Frame(record.line, record.data, exchange.reply)))
            if record.data[1:2] != b"\x03":
                continue  # the probe's writes are refused, or change nothing: not the model's events
        _add_exchange(capture, exchange, t, record.t - t0)
    if not capture.reads:
        raise C20SimError(
            f"{path}: no answered reads of physical quantities (3000H-3011H, 2100H-2102H) from drive {address}: "
            "nothing to fit; make a capture with: c20sim exercise PORT --out FILE"
        )
    capture.events.sort(key=lambda e: e.t)  # stable: a request's reads stay in their order
    capture.duration = capture.events[-1].t if capture.events else 0.0
    return capture


def _answered(found: list[Exchange], profile: Profile, path: str) -> dict[int, int]:
    """The requests answered, by drive; C20SimError if most requests are nothing a C20 answers."""
    registers = profile.registers
    answered: dict[int, int] = {}
    foreign: list[str] = []
    requests = 0
    for exchange in found:
        if not exchange.record.data:
            continue
        requests += 1
        try:
            request = decode_request(exchange.record.data)
        except ValueError:
            foreign.append(f"line {exchange.record.line}: not a C20 request")
            continue
        if isinstance(request, ReadRequest | WriteSingleRequest | WriteMultipleRequest):
            start = request.start if isinstance(request, ReadRequest | WriteMultipleRequest) else request.register
            if start not in registers:
                foreign.append(f"line {exchange.record.line}: register {start:04X}H")
        else:
            foreign.append(f"line {exchange.record.line}: function 0x{request.function:02X}")
        if exchange.reply:
            answered[request.slave] = answered.get(request.slave, 0) + 1
    if requests and len(foreign) * 2 > requests:
        raise C20SimError(
            f"{path}: not a C20's traffic: {len(foreign)} of {requests} requests are nothing a C20 answers "
            f"(first: {foreign[0]}); is it another device's log?"
        )
    return answered


def _add_exchange(capture: Capture, exchange: Exchange, t: float, sent: float) -> None:
    """What one exchange adds to the capture's events: a load mark, the drive's writes, its reads. ``t``: when
    the drive took the request; ``sent``: when the master sent it (a mark's and an unanswered write's time)."""
    record = exchange.record
    if not record.data:
        if record.kind == "mark" and record.note in (LOAD_ON, LOAD_OFF):
            capture.events.append(Event(sent, "load", value=int(record.note == LOAD_ON), line=record.line))
            capture.loads += record.note == LOAD_ON
        return
    try:
        request = decode_request(record.data)
    except ValueError:
        return
    if request.slave == capture.address and not exchange.reply and isinstance(request, WriteSingleRequest):
        # its reply was lost, not always its request: the drive most likely took it (a master asks again with
        # the same value, which changes nothing); the baud is refused below, when answered
        if request.register != Reg.BAUD:
            capture.events.append(Event(sent, "write", request.register, request.value, record.line))
        return
    if request.slave != capture.address or not exchange.reply or not crc_ok(exchange.reply):
        return
    try:
        response = decode_response(exchange.reply)
    except ValueError:
        return
    if not isinstance(response, ExceptionResponse):
        _add_answered(capture, request, response, t, record.line)


def _add_answered(capture: Capture, request: Request, response: Response, t: float, line: int) -> None:
    """An answered request's writes and reads; a baud change or another device's ID refuses the capture."""
    path = capture.path
    if isinstance(request, WriteSingleRequest):
        if request.register == Reg.BAUD:
            baud = BAUD_RATES[request.value] if request.value < len(BAUD_RATES) else request.value
            raise C20SimError(
                f"{path}: line {line}: the master changes the baud (2009H = {baud} baud) mid-capture; "
                "a fit needs one baud all through: record again without the change"
            )
        capture.events.append(Event(t, "write", request.register, request.value, line))
    elif isinstance(request, WriteMultipleRequest):
        if request.start <= Reg.BAUD < request.start + len(request.values):
            raise C20SimError(
                f"{path}: line {line}: the master changes the baud (2009H) mid-capture; "
                "a fit needs one baud all through: record again without the change"
            )
        for offset, value in enumerate(request.values):
            capture.events.append(Event(t, "write", request.start + offset, value, line))
    elif isinstance(request, ReadRequest) and isinstance(response, ReadResponse):
        for offset, value in enumerate(response.values):
            where = request.start + offset
            if where == Reg.DRIVE_ID and value != face.DRIVE_ID:
                raise C20SimError(
                    f"{path}: line {line}: the drive ID (2103H) reads 0x{value:04X}, a C20 reads "
                    f"0x{face.DRIVE_ID:04X}: another device's log"
                )
            if where in PHYSICAL:
                event = Event(t, "read", where, value, line)
                capture.events.append(event)
                capture.reads.setdefault(where, []).append(event)
            elif where in (Reg.POLE_PAIRS, Reg.ACCEL_TIME, Reg.DECEL_TIME):
                capture.settings.setdefault(where, value)


def _profile_baud(profile: Profile) -> int:
    raw = profile.default(Reg.BAUD)
    return BAUD_RATES[raw] if raw < len(BAUD_RATES) else 19200


def _units(read: Event) -> float:
    """A read's value in its register's units (the temperature is signed)."""
    return FIXED_REGISTERS[read.address].engineering(read.value)


def _held_speeds(capture: Capture) -> set[int]:
    """The speeds the drive was held at: the set speeds written (2001H), or else the speeds read often
    (at least 10 reads within 50 rpm of each other)."""
    written = {e.value for e in capture.events if e.kind == "write" and e.address == Reg.SPEED_SETPOINT and e.value}
    if written:
        return written
    counts: dict[int, int] = {}
    for read in capture.reads.get(Reg.MOTOR_SPEED, ()):
        if read.value > 50:
            counts[round(read.value / 50.0)] = counts.get(round(read.value / 50.0), 0) + 1
    return {key * 50 for key, count in counts.items() if count >= 10}


def _consistency(capture: Capture) -> list[str]:
    """Pole pairs (2002H against 3001H / 3006H) and the Hall codes (3009H), in words."""
    notes: list[str] = []
    frequency = capture.reads.get(Reg.OUTPUT_FREQUENCY, [])
    speed = capture.reads.get(Reg.MOTOR_SPEED, [])
    ratios: list[float] = []
    j = 0
    for read in frequency:  # each output frequency with the speed read next to it
        while j + 1 < len(speed) and speed[j + 1].t <= read.t:
            j += 1
        if speed and read.value and speed[j].value > 200 and abs(speed[j].t - read.t) < 0.5:
            ratios.append(read.value / 100.0 * 60.0 / speed[j].value)
    if len(ratios) >= 3:
        found = statistics.median(ratios)
        read_pp = capture.settings.get(Reg.POLE_PAIRS)
        if read_pp is None:
            notes.append(f"pole pairs: output frequency against speed gives {found:.2f}; 2002H was not read")
        elif abs(found - read_pp) < 0.25:
            notes.append(f"pole pairs: output frequency against speed gives {found:.2f}, as 2002H reads ({read_pp})")
        else:
            notes.append(
                f"pole pairs: output frequency against speed gives {found:.2f}, but 2002H reads {read_pp}: "
                "the motor's pole pairs are set wrong on the drive, or its speed is measured another way"
            )
    halls = capture.reads.get(Reg.HALL, [])
    if halls:
        bad = sorted({e.value for e in halls if e.value in (0, 7)})
        seen = sorted({e.value for e in halls})
        if bad:
            notes.append(f"Hall codes (3009H): {seen}; {bad} is no healthy sensor's code: check the Hall wiring")
        else:
            notes.append(f"Hall codes (3009H): {seen}, each a healthy sensor's")
    return notes

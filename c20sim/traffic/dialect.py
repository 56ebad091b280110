"""The dialect probe of ``c20sim exercise --dialect``, and what ``c20sim fit`` learns from its frames.

A drive's dialect is how it speaks Modbus where the sheet leaves room: how many registers one read may ask for,
0x06 or silence on a bad CRC, which exception a malformed 0x10 gets, whether a function code has a RAM-only
address (code | 8000H), whether a password guards the codes, which registers answer, the order of its exception
checks, silence to a broadcast. Every request the probe sends is harmless on a real drive: a read; a write of the
value the register already holds (to a function code's RAM-only address, so nothing reaches the EEPROM); or a
write every drive refuses (to a read-only register). Each request is logged with the note ``dialect KEY``, so
that ``fit`` finds the frames of each quirk in the capture, learns the quirk from them and names them.

:data:`QUIRKS` is the one table: a row is a quirk, how to probe it and how to learn it. The probe sends each
row's frames in order; ``fit`` learns each row from its frames; the report has a line per row.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..drive.config import F_ANSWER_DELAY
from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.protocol import ExceptionCode, ReadRequest, WriteSingleRequest, encode, with_crc
from ..wire.registers import FIXED_REGISTERS, RAM_ONLY, Access, Reg, format_fcode, is_fcode

__all__ = ["QUIRKS", "Frame", "Learned", "Prober", "Quirk", "learn", "probe"]

NOTE = "dialect "
#: Requests a drive answers that may go unanswered in a row before the probe ends.
SILENT_LIMIT = 3
#: The block the read limit is probed on: 3000H-3011H answer on every C20 (sheet), 18 registers in a row.
BLOCK_START, BLOCK_RUN = 0x3000, 18
#: The read-only register the refused writes go to: status word 1 (sheet: R).
READ_ONLY = Reg.STATUS1
#: The function code whose RAM-only address is written with the value it holds: F00.10, keypad speed (W/R).
ALIAS_CODE = 0x000A


@dataclass(frozen=True)
class Frame:
    """One probe request in the capture and what came back (b"": silence)."""

    line: int
    request: bytes
    reply: bytes

    @property
    def code(self) -> int | None:
        """The exception code of the reply, or None (a normal reply, or silence)."""
        reply = self.reply
        return reply[2] if len(reply) == 5 and reply[1] & 0x80 else None


@dataclass(frozen=True)
class Learned:
    """What a quirk's frames showed: ``value`` (None: not learned) and in words how, or why not."""

    value: object | None
    why: str
    #: the base profile's function codes that answered 0x02: ``fit`` drops their [[parameter]] rows
    absent: tuple[int, ...] = ()
    #: function codes read, as (address, raw): ``fit`` writes each as its [[parameter]] row's default
    defaults: tuple[tuple[int, int], ...] = ()


class Prober:
    """The probe's side of the master: a frame out, its reply back, the request logged with the quirk's note."""

    def __init__(self, send: Callable[[bytes, str], bytes], address: int, profile: Profile, rtu: bool) -> None:
        self.send = send
        self.address = address
        self.profile = profile
        self.rtu = rtu  #: the link carries RTU frames as sent (a bad CRC reaches the drive); not Modbus TCP
        self.silent = 0  #: requests a drive answers that got no reply, in a row

    def frame(self, key: str, frame: bytes, *, answered: bool = True) -> bytes:
        """``frame`` sent, its reply returned; ``answered``: a drive answers it (not a bad frame, not a broadcast).
        Three of those in a row unanswered end the probe in one line (a drive that went away costs 1.5 s, not
        a timeout for each of the probe's hundred requests)."""
        reply = self.send(frame, NOTE + key)
        if answered:
            self.silent = 0 if reply else self.silent + 1
            if self.silent >= SILENT_LIMIT:
                raise C20SimError(
                    f"the drive stopped answering during the dialect probe ({key}): {SILENT_LIMIT} requests in a row "
                    "got no reply; the capture so far is kept"
                )
        return reply

    def read(self, key: str, start: int, count: int = 1) -> bytes:
        return self.frame(key, encode(ReadRequest(self.address, start, count)))


@dataclass(frozen=True)
class Quirk:
    """One row: the quirk's key in the profile's [protocol] table (None: the format has no key for it)."""

    name: str
    key: str | None
    send: Callable[[Prober], None]
    learn: Callable[[Sequence[Frame], Profile], Learned]
    doc: str
    #: why the probe sends nothing for it over Modbus TCP ("": it does)
    not_over_modbus_tcp: str = ""


# --- Each quirk: its probe and what its frames show.


def _bad_crc_send(p: Prober) -> None:
    if not p.rtu:
        return  # a Modbus TCP gateway computes the CRC itself: a bad one never reaches the drive
    good = encode(ReadRequest(p.address, BLOCK_START, 1))
    p.frame("reply_to_bad_crc", good[:-2] + bytes((good[-2] ^ 0xFF, good[-1])), answered=False)  # a bad CRC
    p.frame("reply_to_bad_crc", good[:-1], answered=False)  # a bad length: a read one byte short, then silence


def _bad_crc_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames:
        return Learned(None, "not probed")
    seen: dict[str, bool] = {}
    for frame in frames:
        what = "a bad length" if len(frame.request) < 8 else "a bad CRC"
        if not frame.reply:
            seen[what] = False
        elif frame.code == ExceptionCode.FRAME_ERROR:
            seen[what] = True
        else:
            return Learned(None, f"an unexpected answer to {what}: {frame.reply.hex(' ').upper()}")
    words = "; ".join(f"{'exception 0x06' if v else 'silence'} to {k}" for k, v in seen.items())
    if len(set(seen.values())) != 1:
        return Learned(None, f"{words}: the profile has one key for both")
    return Learned(next(iter(seen.values())), words)


def _limit_send(p: Prober) -> None:
    """Counts 2, 4, 8, ... until one is refused with 0x03, then halves the gap: at most 13 reads."""
    accepted, refused = 1, 126
    count = 2
    while accepted + 1 < refused:
        reply = p.read("max_read_registers", BLOCK_START, count)
        code = reply[2] if len(reply) == 5 and reply[1] & 0x80 else None
        if code == ExceptionCode.ILLEGAL_VALUE:
            refused = count
        elif reply and code in (None, ExceptionCode.ILLEGAL_ADDRESS):
            accepted = count  # answered, or past the count's check to the addresses'
        else:
            return  # silence or another refusal: the probe cannot tell; fit says so
        count = min(2 * count, 125) if refused == 126 else (accepted + refused) // 2


def _limit_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    accepted, refused = 1, 126
    for frame in frames:
        count = struct.unpack(">H", frame.request[4:6])[0]
        if frame.code == ExceptionCode.ILLEGAL_VALUE:
            refused = min(refused, count)
        elif frame.reply and frame.code in (None, ExceptionCode.ILLEGAL_ADDRESS):
            accepted = max(accepted, count)
        else:
            answer = f"exception 0x{frame.code:02X}" if frame.code is not None else "silence"
            return Learned(None, f"{answer} to a read of {count}: it does not tell")
    if not frames:
        return Learned(None, "not probed")
    if accepted + 1 != refused and refused != 126:
        return Learned(None, f"reads of {accepted} answered, of {refused} refused: the counts between not probed")
    if accepted + 1 != refused:
        return Learned(None, "no read was refused, and 125 was not probed")
    how = f"a read of {accepted} answered, of {refused} refused with 0x03" if refused <= 125 else "125 answered"
    if accepted == 1:
        how = "a read of 2 refused with 0x03: one register a read"
    if accepted > BLOCK_RUN:
        how += f" (counts above {BLOCK_RUN} reach past 3011H: learned if the drive checks the count first)"
    return Learned(accepted, how)


def _byte_count_send(p: Prober) -> None:
    # 0x10 of 2 registers at a read-only register with a byte count of 2 and one value: refused by any drive
    body = struct.pack(">BBHHBH", p.address, 0x10, READ_ONLY, 2, 2, 0)
    p.frame("byte_count_exception", with_crc(body))


def _byte_count_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames:
        return Learned(None, "not probed")
    code = frames[-1].code
    if code in (3, 6):
        return Learned(code, f"exception 0x{code:02X} to a 0x10 whose byte count is not 2 x N")
    answer = f"exception 0x{code:02X}" if code is not None else frames[-1].reply.hex(" ").upper() or "silence"
    return Learned(None, f"{answer} to a 0x10 whose byte count is not 2 x N: the format holds 3 or 6 only")


def _alias_code(p: Prober) -> int | None:
    """F00.10 if the base profile has it, else its first function code written in any state."""
    codes = [s for s in p.profile.registers.parameters() if s.access is Access.RW]
    codes = [s for s in codes if s.address != p.profile.password_address]
    chosen = next((s for s in codes if s.address == ALIAS_CODE), codes[0] if codes else None)
    return chosen.address if chosen is not None else None


def _alias_send(p: Prober) -> None:
    code = _alias_code(p)
    if code is None:
        return
    reply = p.read("ram_only_alias", code)
    if len(reply) != 7:
        return  # the code does not answer: nothing to write back
    value = struct.unpack(">H", reply[3:5])[0]
    p.frame("ram_only_alias", encode(WriteSingleRequest(p.address, code | RAM_ONLY, value)))


def _alias_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    writes = [f for f in frames if f.request[1] == 0x06]
    if not writes:
        return Learned(None, "not probed" if not frames else "the function code read did not answer")
    frame = writes[-1]
    where = f"{struct.unpack('>H', frame.request[2:4])[0]:04X}H"
    if frame.code == ExceptionCode.ILLEGAL_ADDRESS:
        return Learned(False, f"exception 0x02 to a write of the value it holds at {where}")
    if not frame.reply:
        return Learned(None, f"silence to a write at {where}")
    what = "its echo" if frame.code is None else f"exception 0x{frame.code:02X}"
    return Learned(True, f"{what} to a write of the value it holds at {where}: the address exists")


def _password_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    """From the RAM-only write: 0x05 means a password guards the codes (its value cannot be learned)."""
    writes = [f for f in frames if f.request[1] == 0x06 and f.reply]
    if not writes or writes[-1].code == ExceptionCode.ILLEGAL_ADDRESS:
        return Learned(None, "not probed: it is told by a write to a function code's RAM-only address, absent here")
    code = writes[-1].code
    if code is None:
        return Learned(0, "a write to a function code's RAM-only address was taken: no password locks the codes")
    if code == ExceptionCode.PASSWORD_ERROR:
        return Learned(None, "exception 0x05: a password is set; its value cannot be read from the drive")
    return Learned(None, f"exception 0x{code:02X} to the RAM-only write: it does not tell (200EH = 0 answers 0x04)")


def _gate_send(p: Prober) -> None:
    p.read("write_enable", Reg.WRITE_ENABLE)


def _gate_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames or not frames[-1].reply:
        return Learned(None, "not probed" if not frames else "silence to a read of 200EH")
    frame = frames[-1]
    if frame.code == ExceptionCode.ILLEGAL_ADDRESS:
        return Learned("absent", "exception 0x02 to a read of 200EH: the drive has no write-enable gate")
    if frame.code is None and len(frame.reply) == 7:
        value = struct.unpack(">H", frame.reply[3:5])[0]
        return Learned("present", f"200EH reads {value}: the gate exists ({'open' if value else 'closed'})")
    return Learned(None, f"exception 0x{frame.code:02X} to a read of 200EH")


def _delay_send(p: Prober) -> None:
    if F_ANSWER_DELAY in p.profile.registers:
        p.read("answer_delay", F_ANSWER_DELAY)


def _delay_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    spec = base.registers.get(F_ANSWER_DELAY)
    if not frames or spec is None:
        return Learned(
            None, "not probed" + ("" if spec is not None else f": the base has no {format_fcode(F_ANSWER_DELAY)}")
        )
    frame = frames[-1]
    if frame.code is None and len(frame.reply) == 7:
        raw = struct.unpack(">H", frame.reply[3:5])[0]
        ms: float = raw * spec.scale
        ms = int(ms) if float(ms).is_integer() else ms
        return Learned(ms, f"{spec.label} reads {ms:g} ms", defaults=((F_ANSWER_DELAY, raw),))
    answer = f"exception 0x{frame.code:02X}" if frame.code is not None else "silence"
    return Learned(None, f"{answer} to a read of {spec.label}")


#: The fixed ranges probed one register at a time, and the first address past each (which should not answer).
RANGES = ((0x2000, 0x2010), (0x2100, 0x2104), (0x3000, 0x3012))


def _absent_send(p: Prober) -> None:
    for start, end in RANGES:
        for address in range(start, end + 1):
            p.read("registers", address)
    for address in sorted(s.address for s in p.profile.registers.parameters()):
        p.read("registers", address)


def _ranges(addresses: Sequence[int]) -> str:
    out: list[str] = []
    run: list[int] = []
    for address in sorted(addresses):
        if run and address != run[-1] + 1:
            out.append(f"{run[0]:04X}H-{run[-1]:04X}H" if len(run) > 1 else f"{run[0]:04X}H")
            run = []
        run.append(address)
    if run:
        out.append(f"{run[0]:04X}H-{run[-1]:04X}H" if len(run) > 1 else f"{run[0]:04X}H")
    return ", ".join(out) or "none"


def _absent_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames:
        return Learned(None, "not probed")
    answered, absent = [], []
    for frame in frames:
        address = struct.unpack(">H", frame.request[2:4])[0]
        if frame.code == ExceptionCode.ILLEGAL_ADDRESS:
            absent.append(address)
        elif frame.reply and frame.code is None:
            answered.append(address)
    expected = [a for a in absent if a in base.registers or a in FIXED_REGISTERS]
    surprise = [a for a in answered if a not in base.registers]
    # a function code's [[parameter]] row can go; not a fixed register's, nor one a 20xxH register mirrors
    droppable = tuple(a for a in expected if is_fcode(a) and a not in base.registers.mirrored_by)
    value = "as the base" if not expected and not surprise else "differs"
    words = f"answer: {_ranges(answered)}; 0x02: {_ranges(absent)}"
    if expected:
        words += f"; the base has {_ranges(expected)}, which did not answer"
    if kept := [a for a in expected if a not in droppable]:
        words += f" ({_ranges(kept)}: the format cannot drop them)"
    if surprise:
        words += f"; the base lacks {_ranges(surprise)}, which answered"
    return Learned(value, words, droppable)


def _order_send(p: Prober) -> None:
    # a read-only register written with a value out of any range: 0x07 if read-only is checked first, else 0x03
    p.frame("exception_order", encode(WriteSingleRequest(p.address, READ_ONLY, 0xFFFF)))
    # a read of 126 registers (more than Modbus allows any drive) at an absent address: 0x03 if the count is
    # checked first, 0x02 if the address is
    p.read("exception_order", 0x3011 + 1, 126)


def _order_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames:
        return Learned(None, "not probed")
    seen = []
    for frame in frames:
        if frame.request[1] == 0x06:
            order = {0x07: "read-only before range", 0x03: "range before read-only"}
            seen.append(order.get(frame.code or 0, f"a read-only write answered {frame.reply.hex(' ') or 'nothing'}"))
        elif frame.code == ExceptionCode.ILLEGAL_VALUE:
            seen.append("read count before address")
        elif frame.code == ExceptionCode.ILLEGAL_ADDRESS:
            seen.append("address before read count")
    same = all(s in ("read-only before range", "read count before address") for s in seen)
    return Learned("as c20sim" if same else "differs", "; ".join(seen) or "nothing told")


def _broadcast_send(p: Prober) -> None:
    # every drive on the line refuses a write to a read-only register; none answers a broadcast
    p.frame("broadcast", encode(WriteSingleRequest(0, READ_ONLY, 0)), answered=False)


def _broadcast_learn(frames: Sequence[Frame], base: Profile) -> Learned:
    if not frames:
        return Learned(None, "not probed")
    reply = frames[-1].reply
    if not reply:
        return Learned("silent", "no reply to a broadcast write (as Modbus and the sheet say)")
    return Learned("answers", f"a reply to a broadcast: {reply.hex(' ').upper()}")


QUIRKS: tuple[Quirk, ...] = (
    Quirk(
        "reply_to_bad_crc",
        "reply_to_bad_crc",
        _bad_crc_send,
        _bad_crc_learn,
        "0x06 or silence on a bad CRC",
        "the gateway makes the CRC and the length: a bad frame cannot be sent",
    ),
    Quirk("max_read_registers", "max_read_registers", _limit_send, _limit_learn, "the most one 0x03 may read"),
    Quirk("byte_count_exception", "byte_count_exception", _byte_count_send, _byte_count_learn, "a bad 0x10 count"),
    Quirk("ram_only_alias", "ram_only_alias", _alias_send, _alias_learn, "a function code at its address | 8000H"),
    Quirk("password", "password", lambda p: None, _password_learn, "a password guarding the function codes"),
    Quirk("write_enable", None, _gate_send, _gate_learn, "the write-enable gate 200EH"),
    Quirk("answer_delay", None, _delay_send, _delay_learn, "the answer delay a master set (F08.04)"),
    Quirk("registers", None, _absent_send, _absent_learn, "which registers answer"),
    Quirk("exception_order", None, _order_send, _order_learn, "the order of exception checks"),
    Quirk("broadcast", None, _broadcast_send, _broadcast_learn, "no reply to a broadcast"),
)


def probe(prober: Prober) -> None:
    """Send every row's frames, in the table's order."""
    for quirk in QUIRKS:
        quirk.send(prober)


def learn(
    frames: Sequence[tuple[str, Frame]], base: Profile, *, modbus_tcp: bool = False
) -> list[tuple[Quirk, Learned, list[int]]]:
    """Each row learned from the capture's frames noted ``dialect NAME`` (the RAM-only write also tells the
    password), with the log lines that showed it; ``modbus_tcp``: the capture was carried by Modbus TCP, over
    which some rows send nothing (and say why)."""
    by_name: dict[str, list[Frame]] = {}
    for note, frame in frames:
        if note.startswith(NOTE):
            by_name.setdefault(note[len(NOTE) :], []).append(frame)
    out = []
    for quirk in QUIRKS:
        own = by_name.get("ram_only_alias" if quirk.name == "password" else quirk.name, [])
        learned = quirk.learn(own, base)
        if not own and frames and modbus_tcp and quirk.not_over_modbus_tcp:
            learned = Learned(None, f"not probed: over Modbus TCP {quirk.not_over_modbus_tcp}")
        out.append((quirk, learned, [f.line for f in own]))
    return out

"""Link faults: what a bad RS485 line, gateway or drive interface does to replies.

A :class:`LinkFaults` is a set of switches, one per drive and one per bus,
that the operations (:mod:`c20sim.control.ops`) flip for every front end;
each switch's :class:`Knob` says how a value is checked and shown. The bus consults them
around each request: an offline drive or a forced exception means the drive
never sees the request; the rest (drop, delay, corrupt, truncate, garbage,
wrong address) act on the reply the drive produced. Randomness comes from a
``random.Random`` the bus owns, so a seeded run repeats exactly.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field, fields
from typing import Any, TypeAlias

from mypy_extensions import mypyc_attr

from ..wire.protocol import ExceptionCode, crc16

__all__ = ["KNOBS", "Knob", "LinkFaults", "Mangled"]

#: ``object`` for a field's annotation: a compiled (mypyc) dataclass looks an annotation up by name in the
#: module, where ``object`` is not (KeyError at import); an alias is
_Object: TypeAlias = object


@dataclass(frozen=True, slots=True)
class Mangled:
    """A reply after the link faults: None if it never reaches the wire."""

    data: bytes | None
    delay: float
    notes: tuple[str, ...] = ()
    #: seconds between the reply's two pieces (0: in one piece); the transport splits it
    split: float = 0.0
    #: Modbus TCP: seconds the right reply is held back behind a copy under another transaction id (0: none)
    wrong_transaction: float = 0.0


@dataclass(frozen=True, slots=True)
class Knob:
    """How one link fault is set and shown: the one definition every front end reads.

    ``kind`` says what a value is (and so how the operations check one):
    ``flag``, ``count`` (0-1,000,000), ``percent`` (0-100), ``seconds``
    (0-60), ``bytes`` (hex such as ``"FF 00"``), ``address`` (0-255 or
    null) or ``exception`` (a code 0x01-0x08, its name, or null). ``key``,
    ``label`` and ``on`` are its dashboard switch: pressing it sets ``on``
    (a count goes up by ``on``, an exception steps through the codes) and
    pressing it again sets the default back. ``on_reply`` is False for the
    faults that act before the drive sees the request.
    """

    kind: str
    key: str
    label: str
    how: str
    on: _Object
    on_reply: bool = True


def _knob(default: object, kind: str, key: str, label: str, how: str, on: object, *, on_reply: bool = True) -> Any:
    return field(default=default, metadata={"knob": Knob(kind, key, label, how, on, on_reply)})


# A Python class where the core is compiled (tools/compile-core): it keeps _reply_armed in its __dict__.
@mypyc_attr(native_class=False)
@dataclass
class LinkFaults:
    """Switches for one drive's link, or the whole bus's. To add one: a field here, its effect in :meth:`mangle`."""

    offline: bool = _knob(False, "flag", "o", "offline", "hears nothing, says nothing", True, on_reply=False)
    drop_next: int = _knob(0, "count", "d", "drop next", "drop the next reply (press again for more)", 1)
    drop_percent: float = _knob(0.0, "percent", "a", "drop 50 %", "drop half the replies at random", 50.0)
    delay: float = _knob(0.0, "seconds", "y", "delay", "reply 500 ms late", 0.5)
    delay_jitter: float = _knob(0.0, "seconds", "i", "jitter", "up to 200 ms random extra delay", 0.2)
    corrupt_crc: bool = _knob(False, "flag", "c", "bad CRC", "corrupt the reply's CRC", True)
    truncate: bool = _knob(False, "flag", "u", "truncate", "send half the reply", True)
    garbage_before: bytes = _knob(b"", "bytes", "g", "garbage before", "two noise bytes before the reply", b"\x00\xff")
    garbage_after: bytes = _knob(b"", "bytes", "n", "garbage after", "two noise bytes after the reply", b"\x00\xff")
    #: answer from this address instead of the drive's own (the switch picks the next address)
    wrong_address: int | None = _knob(None, "address", "w", "wrong address", "answer from another address", 0x63)
    #: answer every request with this exception code, without acting on it
    forced_exception: ExceptionCode | None = _knob(  # noqa: RUF009 (a dataclasses.field, as the others)
        None, "exception", "e", "exception", "cycles: force exception 0x01 .. 0x08, off", None, on_reply=False
    )
    #: answer with another function code (0x03 -> 0x04, 0x06 -> 0x01, 0x10 -> 0x17: the code XOR 7), CRC good
    wrong_function: bool = _knob(False, "flag", "k", "wrong function", "answer with another function code", True)
    #: the master's own request before the reply: a two-wire RS485 adapter without echo suppression
    echo: bool = _knob(False, "flag", "h", "echo", "the request echoed before the reply (RS485 adapter)", True)
    #: replies handed over only at multiples of this many seconds (an FTDI adapter's latency timer, 16 ms)
    burst: float = _knob(0.0, "seconds", "l", "16 ms bursts", "replies in 16 ms bursts (USB adapter latency)", 0.016)
    #: one bit flipped in this percent of the frames, either way (a request hit is a CRC error at the drive)
    noise_percent: float = _knob(0.0, "percent", "v", "noise", "a bit error in 5 % of the frames, both ways", 5.0)
    #: the reply in two pieces this many seconds apart (two TCP segments; on a serial line a gap inside the frame)
    split: float = _knob(0.0, "seconds", "G", "split reply", "the reply in two pieces 20 ms apart", 0.02)
    #: Modbus TCP: a copy of the reply under another transaction id first, the right one this many seconds later
    wrong_transaction: float = _knob(
        0.0, "seconds", "W", "wrong transaction id", "Modbus TCP: a reply under another id first, 100 ms ahead", 0.1
    )
    #: the reply faults above act on the next N replies only, then switch off (0: on every reply until cleared)
    replies: int = _knob(
        0, "count", "N", "next N only", "the reply faults act on the next 3 replies only", 3, on_reply=False
    )

    def clear(self) -> None:
        """Switch every fault off."""
        for name in KNOBS:
            setattr(self, name, _DEFAULTS[name])

    @property
    def active(self) -> list[str]:
        """Names of the faults switched on, for display."""
        return [name for name in KNOBS if getattr(self, name) != _DEFAULTS[name]]

    def __setattr__(self, name: str, value: object) -> None:
        # Every reply asks whether a reply fault is armed: the answer is worked out when a switch moves
        # (seldom), not on every reply (15,000 times a second), and forgotten whenever one does.
        object.__setattr__(self, name, value)
        if name in KNOBS:
            object.__setattr__(self, "_reply_armed", None)

    @property
    def active_reply_faults(self) -> bool:
        """True if :meth:`mangle` would change anything (a cheap test on every reply)."""
        armed: bool | None = self.__dict__.get("_reply_armed")
        if armed is None:
            armed = any(getattr(self, name) != default for name, default in _REPLY_DEFAULTS)
            object.__setattr__(self, "_reply_armed", armed)
        return armed

    def spend(self) -> None:
        """One reply went through these faults: with :attr:`replies` set, count it, and at the last one switch the
        reply faults (and a forced exception) off."""
        if self.replies <= 0:
            return
        self.replies -= 1
        if self.replies == 0:
            for name, knob in KNOBS.items():
                if knob.on_reply or name == "forced_exception":
                    setattr(self, name, _DEFAULTS[name])

    def noisy(self, rng: random.Random) -> bool:
        """Whether noise hits the next frame (one draw of ``rng``, only while noise is on)."""
        return self.noise_percent > 0 and rng.random() * 100 < self.noise_percent

    def mangle(self, data: bytes, delay: float, rng: random.Random, request: bytes = b"", t: float = 0.0) -> Mangled:
        """Apply the reply faults to ``data`` sent after ``delay`` seconds, the answer to ``request`` that came at
        ``t`` on the line's clock (for the echo and the bursts)."""
        notes: list[str] = []
        if self.drop_next > 0:
            self.drop_next -= 1
            return Mangled(None, delay, ("reply dropped (injected)",))
        if self.drop_percent > 0 and rng.random() * 100 < self.drop_percent:
            return Mangled(None, delay, (f"reply dropped at random, {self.drop_percent:g} % (injected)",))
        if self.delay or self.delay_jitter:
            extra = self.delay + (rng.random() * self.delay_jitter if self.delay_jitter else 0.0)
            delay += extra
            notes.append(f"delayed {extra * 1000:.0f} ms (injected)")
        if self.wrong_function and len(data) >= 4:
            body = data[:1] + bytes((data[1] ^ 0x07,)) + data[2:-2]
            data = body + crc16(body).to_bytes(2, "little")
            notes.append(f"function 0x{body[1]:02X} instead of 0x{body[1] ^ 0x07:02X} (injected)")
        if self.wrong_address is not None:
            body = bytes((self.wrong_address & 0xFF,)) + data[1:-2]
            data = body + crc16(body).to_bytes(2, "little")
            notes.append(f"sent from address {self.wrong_address} (injected)")
        if self.corrupt_crc:
            data = data[:-2] + bytes((data[-2] ^ 0xFF, data[-1] ^ 0xFF))
            notes.append("CRC corrupted (injected)")
        if self.truncate:
            data = data[: max(1, len(data) // 2)]
            notes.append(f"truncated to {len(data)} bytes (injected)")
        if self.garbage_before or self.garbage_after:
            data = self.garbage_before + data + self.garbage_after
            notes.append("garbage added (injected)")
        if self.noisy(rng) and data:
            bit = rng.randrange(len(data) * 8)
            data = data[: bit // 8] + bytes((data[bit // 8] ^ (1 << (bit % 8)),)) + data[bit // 8 + 1 :]
            notes.append(f"bit {bit} flipped by noise (injected)")
        if self.echo and request:
            data = request + data
            notes.append("request echoed before the reply (injected)")
        if self.burst > 0:
            due = t + delay
            held = math.ceil(due / self.burst - 1e-9) * self.burst - due
            delay += held
            notes.append(f"held {held * 1000:.1f} ms to the next {self.burst * 1000:g} ms burst (injected)")
        if self.split > 0:
            notes.append(f"in two pieces {self.split * 1000:.0f} ms apart (injected)")
        if self.wrong_transaction > 0:
            notes.append(
                f"Modbus TCP: first under another transaction id, {self.wrong_transaction * 1000:.0f} ms ahead (injected)"
            )
        return Mangled(data, delay, tuple(notes), self.split, self.wrong_transaction)


#: Every link fault: field name -> its knob, in the order of the fields.
KNOBS: dict[str, Knob] = {f.name: f.metadata["knob"] for f in fields(LinkFaults)}
_DEFAULTS: dict[str, object] = {f.name: f.default for f in fields(LinkFaults)}
_REPLY_DEFAULTS: tuple[tuple[str, object], ...] = tuple((n, _DEFAULTS[n]) for n, k in KNOBS.items() if k.on_reply)

"""Link faults: what a bad RS485 line, gateway or drive interface does to replies.

A :class:`LinkFaults` is a set of switches, one per drive and one per bus,
that the dashboard, the control API and tests flip. The bus consults them
around each request: an offline drive or a forced exception means the drive
never sees the request; the rest (drop, delay, corrupt, truncate, garbage,
wrong address) act on the reply the drive produced. Randomness comes from a
``random.Random`` the bus owns, so a seeded run repeats exactly.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, fields

from .protocol import ExceptionCode, crc16

__all__ = ["LinkFaults", "Mangled"]


@dataclass(frozen=True, slots=True)
class Mangled:
    """A reply after the link faults: None if it never reaches the wire."""

    data: bytes | None
    delay: float
    notes: tuple[str, ...] = ()


@dataclass
class LinkFaults:
    """Switches for one drive's link, or the whole bus's."""

    #: the drive hears nothing and says nothing until cleared
    offline: bool = False
    #: drop the next N replies (the drive still acts on the requests)
    drop_next: int = 0
    #: drop this percentage of replies at random
    drop_percent: float = 0.0
    #: extra reply delay in seconds, plus a random 0..delay_jitter
    delay: float = 0.0
    delay_jitter: float = 0.0
    #: flip the reply's CRC
    corrupt_crc: bool = False
    #: cut the reply short (send only its first half)
    truncate: bool = False
    #: bytes sent before / after the reply
    garbage_before: bytes = b""
    garbage_after: bytes = b""
    #: answer from this address instead of the drive's own
    wrong_address: int | None = None
    #: answer every request with this exception code, without acting on it
    forced_exception: ExceptionCode | None = None

    def clear(self) -> None:
        """Switch every fault off."""
        for f in fields(self):
            setattr(self, f.name, f.default)

    @property
    def active(self) -> list[str]:
        """Names of the faults switched on, for display."""
        default = LinkFaults()
        return [f.name for f in fields(self) if getattr(self, f.name) != getattr(default, f.name)]

    @property
    def active_reply_faults(self) -> bool:
        """True if :meth:`mangle` would change anything (a cheap test on every reply)."""
        return bool(
            self.drop_next
            or self.drop_percent
            or self.delay
            or self.delay_jitter
            or self.corrupt_crc
            or self.truncate
            or self.garbage_before
            or self.garbage_after
            or self.wrong_address is not None
        )

    def mangle(self, data: bytes, delay: float, rng: random.Random) -> Mangled:
        """Apply the reply faults to ``data`` sent after ``delay`` seconds."""
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
        return Mangled(data, delay, tuple(notes))

"""RTU framing: a byte stream split into frames by silence (t3.5), and by length where the transport has no
line timing (moved out of protocol.py as it was)."""

from __future__ import annotations

from collections import deque

from .protocol import (
    _EPSILON,
    MAX_ADU,
    SHEET_CHAR_BITS,
    Direction,
    FrameEvent,
    FrameKind,
    _known_function,
    char_time,
    crc16,
    crc_ok,
    expected_length,
    silence_times,
)

__all__ = ["RtuFramer"]


class RtuFramer:
    """Splits a byte stream into RTU frames by silence, and by length where asked.

    ``feed(data, t)``: ``data`` arrived at time ``t`` (seconds, any origin),
    its bytes back to back. ``tick(t)``: tell the framer the time is now
    ``t``, so that silence can end a frame; call it at :meth:`deadline`.
    ``next_event()`` returns the next :class:`FrameEvent`, or None.

    ``complete_on_length``: for transports without line timing (TCP), emit a
    frame as soon as a known function code's length is reached with a good
    CRC, without waiting for silence. ``check_gaps``: enforce the sheet's
    1.5-character rule (only meaningful on a line with real byte timing).
    ``silence``: override t3.5, for transports whose timing is not the line's.
    ``bits``: bits of one character on the line (:func:`char_bits`; 10 for 8N1).
    ``strict``: a frame is exactly what lies between two silences of t3.5, as
    the sheet says ("if the time interval between two characters is more than
    3.5 times, it is considered that one frame of data has been transmitted");
    two requests with no silence between them, or garbage glued to a request,
    are one bad frame, never split apart. Strict framing cannot complete on
    length.
    """

    def __init__(
        self,
        baud: int = 19200,
        *,
        direction: Direction = "request",
        complete_on_length: bool = False,
        check_gaps: bool = True,
        silence: float | None = None,
        bits: int = SHEET_CHAR_BITS,
        strict: bool = False,
    ) -> None:
        if strict and complete_on_length:
            raise ValueError("a strict framer ends frames by silence only; it cannot complete on length")
        self.direction: Direction = direction
        self.bits = bits
        self.strict = strict
        self.complete_on_length = complete_on_length
        self.check_gaps = check_gaps
        self._silence_override = silence
        self.set_baud(baud)
        self._buffer = bytearray()
        self._last_t = 0.0
        self._broken = ""
        self._events: deque[FrameEvent] = deque()

    def set_baud(self, baud: int) -> None:
        """Change the line speed (after a 2009H write); the timing follows."""
        self.baud = baud
        self._char = char_time(baud, self.bits)
        self.t15, t35 = silence_times(baud, self.bits)
        self.t35 = self._silence_override if self._silence_override is not None else t35

    @property
    def pending(self) -> bool:
        """True while bytes of an unfinished frame are buffered."""
        return bool(self._buffer)

    def deadline(self) -> float | None:
        """Time at which silence ends the buffered frame, or None if nothing is buffered.

        Strict: t3.5 of silence is known only one character later, since a byte is seen when it has
        arrived whole: one that started within t3.5 of the last has arrived by then.
        """
        if not self._buffer:
            return None
        return self._last_t + self.t35 + (self._char if self.strict else 0.0)

    def feed(self, data: bytes, t: float) -> None:
        if not data:
            return
        if self._buffer:
            # Silence before this chunk: its bytes came back to back and its last one ended at t.
            gap = t - len(data) * self._char - self._last_t
            if gap >= self.t35 - _EPSILON:
                self._close()
            elif self.check_gaps and gap > self.t15 + _EPSILON and not self._broken:
                self._broken = f"gap of {gap * 1000:.2f} ms (> t1.5 = {self.t15 * 1000:.2f} ms) inside the frame"
        if self.complete_on_length and not self._buffer and not self._broken:
            # The common read on TCP: exactly one whole request. It is what _split would find, found without
            # copying it through the buffer.
            n = len(data)
            if n >= 4 and expected_length(data, self.direction) == n and crc_ok(data):
                self._last_t = t
                self._events.append(FrameEvent(FrameKind.FRAME, bytes(data), t))
                return
        self._last_t = t
        if self.strict:
            room = MAX_ADU - len(self._buffer)
            if len(data) > room and not self._broken:
                self._broken = f"more than {MAX_ADU} bytes without a silence of t3.5"
            self._buffer += data[: max(0, room)]  # bounded: the rest of a runaway stream is dropped
            return
        self._buffer += data
        if self.complete_on_length and not self._broken:
            self._split(final=False)
        if len(self._buffer) > MAX_ADU:
            self._close()

    def tick(self, t: float) -> None:
        deadline = self.deadline()
        if deadline is not None and t >= deadline - _EPSILON:
            self._close()

    def flush(self) -> None:
        """End the buffered frame now (the transport closed)."""
        if self._buffer:
            self._close()

    def next_event(self) -> FrameEvent | None:
        return self._events.popleft() if self._events else None

    def events(self) -> list[FrameEvent]:
        """All pending events, oldest first."""
        out = list(self._events)
        self._events.clear()
        return out

    # -- internals

    def _close(self) -> None:
        if self._broken:
            self._emit(FrameKind.NOISE, bytes(self._buffer), self._broken)
            self._buffer.clear()
        elif self.strict:
            # Sheet, section 1: bytes not separated by 3.5 character times are one frame. Two requests sent
            # back to back, or garbage glued to one, are one frame of the wrong length or CRC: the drive
            # answers it with 0x06 (or silence, where the profile says so), never with two replies.
            data = bytes(self._buffer)
            self._buffer.clear()
            if self._complete_at_all(data):
                self._emit(FrameKind.FRAME, data)
            else:
                self._emit(*_classify(data, self.direction))
        else:
            self._split(final=True)
        self._broken = ""

    def _complete_at_all(self, data: bytes) -> bool:
        """True if ``data`` is exactly one CRC-valid frame of a known function code."""
        return expected_length(data[:7], self.direction) == len(data) and crc_ok(data)

    def _emit(self, kind: FrameKind, data: bytes, note: str = "") -> None:
        self._events.append(FrameEvent(kind, data, self._last_t, note))

    def _complete_at(self, offset: int) -> int | None:
        """Length of a complete, CRC-valid frame of a known function code at ``offset``."""
        buf = self._buffer
        length = expected_length(bytes(buf[offset : offset + 7]), self.direction)
        if length is None or offset + length > len(buf):
            return None
        if crc16(bytes(buf[offset : offset + length - 2])) != int.from_bytes(
            buf[offset + length - 2 : offset + length], "little"
        ):
            return None
        return length

    def _split(self, *, final: bool) -> None:
        buf = self._buffer
        while buf:
            length = self._complete_at(0)
            if length is not None:
                self._emit(FrameKind.FRAME, bytes(buf[:length]))
                del buf[:length]
                continue
            if not final and self._may_still_complete():
                return
            # What is at offset 0 is broken: find the next valid frame behind it.
            for offset in range(1, len(buf)):
                if self._complete_at(offset) is not None:
                    self._emit_bad(bytes(buf[:offset]))
                    del buf[:offset]
                    break
            else:
                if final:
                    self._emit_bad(bytes(buf))
                    buf.clear()
                return

    def _may_still_complete(self) -> bool:
        """True if the bytes at offset 0 are the start of a valid frame still arriving."""
        buf = self._buffer
        if len(buf) < 2:
            return True
        if not _known_function(bytes(buf[:2]), self.direction):
            return False
        length = expected_length(bytes(buf[:7]), self.direction)
        return length is None or len(buf) < length

    def _emit_bad(self, data: bytes) -> None:
        self._emit(*_classify(data, self.direction))


def _classify(data: bytes, direction: Direction) -> tuple[FrameKind, bytes, str]:
    """Name what is wrong with bytes that do not form a valid frame of a known length."""
    if len(data) < 4:
        return FrameKind.NOISE, data, f"{len(data)} byte(s), too short for a frame"
    if not _known_function(data, direction):
        if crc_ok(data):
            return FrameKind.FRAME, data, ""
        return FrameKind.CRC_ERROR, data, f"bad CRC: got {data[-2:].hex(' ').upper()}, expected {_crc_hex(data)}"
    length = expected_length(data, direction)
    if length == len(data):
        return FrameKind.CRC_ERROR, data, f"bad CRC: got {data[-2:].hex(' ').upper()}, expected {_crc_hex(data)}"
    wanted = f"{length}" if length is not None else "at least 9"
    return FrameKind.LENGTH_ERROR, data, f"{len(data)} bytes, a function 0x{data[1]:02X} {direction} has {wanted}"


def _crc_hex(data: bytes) -> str:
    return crc16(data[:-2]).to_bytes(2, "little").hex(" ").upper()

"""What the audit keeps between frames: a request's meaning, a drive's followed facts, a counter."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from .findings import FrameRef


@dataclass(frozen=True, slots=True)
class _Request:
    """What a request's bytes mean on the line: worked out once per distinct frame (:meth:`Auditor._meaning`),
    since a master polls the same few frames over and over. It holds nothing that the stream changes, only
    what follows from the bytes and the line's baud (a baud change forgets them all)."""

    good: bool  #: a request (4 bytes or more, CRC good); else noise, which only holds the line
    cost: float  #: seconds of line: the transaction's (noise: its own frame's)
    slave: int
    function: int
    register: int  #: the register read or written (the first of a 0x10), else -1
    value: int  #: the value written (0x06, first of a 0x10), else -1
    #: the writes to one drive a rule judges, in turn: (the rule's ``written`` hook, register, value), as the
    #: rules' ``judges`` said once for this frame
    judged: tuple[tuple[Callable[..., None], int, int], ...]
    stores: bool  #: a write that :meth:`Auditor._stored` follows once the drive takes it
    #: every (register, value) a write carries: one for 0x06, each register of a 0x10 in turn
    writes: tuple[tuple[int, int], ...] = ()


#: A frame from a drive that answers no request: too short, or a bad CRC (slave -1 matches no request).
_NOT_A_REPLY = (-1, -1, -1)


@dataclass(slots=True)
class _Drive:
    """What the audit follows of one drive."""

    comm_timeout: float
    max_speed: int
    last_t: float | None = None
    last_seq: int = 0
    longest: float = 0.0
    write_enable: bool = False
    enable_ref: FrameRef | None = None
    last_fcode_write: float | None = None
    resets: deque[FrameRef] = field(default_factory=lambda: deque(maxlen=64))


@dataclass(slots=True)
class _Count:
    n: int = 0
    first: FrameRef | None = None
    last: FrameRef | None = None
    same_value: bool = True
    value: int = -1

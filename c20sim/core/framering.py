"""The frame log's ring: the newest frame records, kept as bytes and numbers in storage made once.

A serving process keeps every bus's last ``log_size`` frames (2000 by default) for the control API, the
dashboard and the tests. Kept as objects (a record, its decoded request or response), that is four to five
thousand objects a bus that the garbage collector tracks, and a full collection walks all of them while every
bus waits: 1,024,770 of them and 344 ms at 256 buses (bench/bench_plant.py part 4). The ring keeps each record
as the numbers and bytes it is made of, one tuple of them in a list made at start, which the collector stops
tracking the first time it sees it (bytes, str, floats and ints hold no references), and makes the record anew
when it is read. What reads it (GET /frames, a test, the dashboard's first look) is rare beside what writes it (two records
a request).

A record read back equals the one appended (dataclass equality, and every field the equality leaves out), for
the records :class:`~c20sim.core.bus.Bus` makes: a request decoded from its frame (an RX request record's
``words`` is ``decode_request(data)``, which the ring does not store twice), any other request or response
packed field by field (:func:`pack_message`), a text as its text. The few objects a record refers to (its
direction and kind, the drive's register map) are interned in tables of a few entries a ring.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from typing import Any, Generic, Protocol, TypeVar

from ..wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    MbapHeader,
    ReadRequest,
    ReadResponse,
    Request,
    Response,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    decode_request,
)

__all__ = ["FrameRing", "pack_message", "unpack_message"]

#: How ``words`` is kept: its text, nothing (decoded from the frame again), or packed (:func:`pack_message`)
_TEXT, _SAME_AS_DATA, _PACKED = 0, 1, 2
#: Distinct objects (directions, kinds, register maps) a ring interns before it renumbers what it holds.
MAX_INTERNED = 256
_FOUR = struct.Struct("<BBHH").pack
#: Request records an iteration remembers, so that a reply's request is the very object its request record holds
_RECENT = 16


class _Record(Protocol):
    """What the ring reads of a record (:class:`~c20sim.core.bus.FrameRecord`)."""

    @property
    def t(self) -> float: ...

    @property
    def direction(self) -> Any: ...

    @property
    def data(self) -> bytes: ...

    @property
    def kind(self) -> Any: ...

    @property
    def slave(self) -> int | None: ...

    @property
    def words(self) -> str | Request | Response: ...

    @property
    def note(self) -> str: ...

    @property
    def model_t(self) -> float | None: ...

    @property
    def registers(self) -> Any: ...

    @property
    def request(self) -> Request | None: ...

    @property
    def wall(self) -> float | None: ...

    @property
    def mbap(self) -> MbapHeader | None: ...

    @property
    def from_gateway(self) -> bool: ...


R = TypeVar("R", bound=_Record)


def pack_message(message: Request | Response) -> bytes:
    """A request or response as bytes (a tag, then its fields): :func:`unpack_message` gives it back equal,
    counts as sent included (an encoded frame would not: a 0x10 whose counts disagree)."""
    packed: bytes = _PACK[message.__class__](message)
    return packed


def _pack_multiple(m: WriteMultipleRequest) -> bytes:
    return struct.pack(f"<BBHHH{len(m.values)}H", 3, m.slave, m.start, m.count, m.byte_count, *m.values)


#: by class (a dict, not a match: this runs for every reply the ring keeps)
_PACK: dict[type, Any] = {
    ReadRequest: lambda m: _FOUR(1, m.slave, m.start, m.count),
    WriteSingleRequest: lambda m: _FOUR(2, m.slave, m.register, m.value),
    WriteMultipleRequest: _pack_multiple,
    UnsupportedRequest: lambda m: bytes((4, m.slave, m.function)) + m.data,
    ReadResponse: lambda m: struct.pack(f"<BB{len(m.values)}H", 5, m.slave, *m.values),
    WriteSingleResponse: lambda m: _FOUR(6, m.slave, m.register, m.value),
    WriteMultipleResponse: lambda m: _FOUR(7, m.slave, m.start, m.count),
    ExceptionResponse: lambda m: _FOUR(8, m.slave, m.request_function, int(m.code)),
}


def unpack_message(packed: bytes) -> Request | Response:
    """The message :func:`pack_message` packed."""
    tag, slave = packed[0], packed[1]
    if tag == 4:
        return UnsupportedRequest(slave, packed[2], packed[3:])
    if tag == 3:
        start, count, byte_count = struct.unpack_from("<HHH", packed, 2)
        values = struct.unpack_from(f"<{(len(packed) - 8) // 2}H", packed, 8)
        return WriteMultipleRequest(slave, start, values, count, byte_count)
    if tag == 5:
        return ReadResponse(slave, struct.unpack_from(f"<{(len(packed) - 2) // 2}H", packed, 2))
    a, b = struct.unpack_from("<HH", packed, 2)
    if tag == 1:
        return ReadRequest(slave, a, b)
    if tag == 2:
        return WriteSingleRequest(slave, a, b)
    if tag == 6:
        return WriteSingleResponse(slave, a, b)
    if tag == 7:
        return WriteMultipleResponse(slave, a, b)
    code: Any = ExceptionCode(b) if b in ExceptionCode._value2member_map_ else b
    return ExceptionResponse(slave, a, code)


class FrameRing(Generic[R]):
    """The newest ``maxlen`` records, as a ``deque(maxlen=...)`` of them reads: ``len``, iteration oldest first,
    an index (negative from the newest), ``append`` (the oldest goes when full), ``popleft`` and ``clear``.
    ``make`` builds a record from its fields (the record's class).

    A slot holds one tuple of the record's atoms (numbers, bytes, str, None; the objects it names are table
    indexes): the collector stops tracking such a tuple the first time it looks at it, and never walks it
    again. One tuple a record costs the request path half what writing each field to an array of its own did.
    """

    def __init__(self, maxlen: int, make: Any) -> None:
        if maxlen < 0:
            raise ValueError("maxlen must be at least 0")
        self._make = make
        self._maxlen = maxlen
        self._start = 0
        self._len = 0
        self._slots: list[tuple[Any, ...] | None] = [None] * maxlen
        #: interned objects (directions, kinds, register maps): their index, by identity
        self._table: list[Any] = []
        self._index: dict[int, int] = {}
        #: the newest request record's slot and decoded request (a reply names it as its own request)
        self._rx_slot = -1
        self._rx_words: object = None

    @property
    def maxlen(self) -> int:
        return self._maxlen

    def __len__(self) -> int:
        return self._len

    def __bool__(self) -> bool:
        return self._len > 0

    def _intern(self, obj: Any) -> int:
        found = self._index.get(id(obj))
        if found is not None:
            return found
        if len(self._table) >= MAX_INTERNED:
            self._renumber()
        self._index[id(obj)] = len(self._table)
        self._table.append(obj)
        return len(self._table) - 1

    def _renumber(self) -> None:
        """The table is full: keep only what the records held refer to, numbered anew."""
        held = [self._slots[slot] for slot in self._slot_numbers()]
        used = sorted({ix for kept in held if kept is not None for ix in (kept[1], kept[3], kept[9]) if ix is not None})
        new = {old: i for i, old in enumerate(used)}
        for slot in self._slot_numbers():
            kept = self._slots[slot]
            assert kept is not None
            registers = None if kept[9] is None else new[kept[9]]
            self._slots[slot] = (*kept[:1], new[kept[1]], kept[2], new[kept[3]], *kept[4:9], registers, *kept[10:])
        self._table = [self._table[old] for old in used]
        self._index = {id(obj): i for i, obj in enumerate(self._table)}

    def _slot_numbers(self) -> Iterator[int]:
        for i in range(self._len):
            yield (self._start + i) % self._maxlen

    def append(self, record: R) -> None:
        """Keep ``record`` (its fields), dropping the oldest when full."""
        maxlen = self._maxlen
        if not maxlen:
            return
        if self._len < maxlen:
            slot = (self._start + self._len) % maxlen
            self._len += 1
        else:
            slot = self._start
            self._start = (slot + 1) % maxlen
        words = record.words
        kept: bytes | str | None
        if words.__class__ is str:
            how, kept = _TEXT, words
        elif record.request is None and words.__class__ in _REQUESTS and record.direction == "rx":
            how, kept = _SAME_AS_DATA, None  # the bus decoded it from the frame: read back by decoding it again
            self._rx_slot, self._rx_words = slot, words
        else:
            how, kept = _PACKED, pack_message(words)  # type: ignore[arg-type]
        index = self._index
        direction, kind, registers = record.direction, record.kind, record.registers
        d = index.get(id(direction))
        if d is None:
            d = self._intern(direction)
        k = index.get(id(kind))
        if k is None:
            k = self._intern(kind)
        r = None
        if registers is not None:
            r = index.get(id(registers))
            if r is None:
                r = self._intern(registers)
        request = record.request
        back = 0
        packed: bytes | None = None
        if request is not None:
            if request is self._rx_words and self._rx_slot != slot:
                # its frame, which the request record holds already (bytes are shared, not copied); read back
                # as that very object in one pass, as the bus made it
                back = (slot - self._rx_slot) % maxlen
                kept_rx = self._slots[self._rx_slot]
                assert kept_rx is not None
                packed = kept_rx[2]
            else:
                packed = pack_message(request)
        mbap = record.mbap
        self._slots[slot] = (
            record.t,
            d,
            record.data,
            k,
            record.slave,
            how,
            kept,
            record.note,
            record.model_t,
            r,
            packed,
            back,
            record.wall,
            None if mbap is None else mbap.transaction,
            None if mbap is None else mbap.unit,
            record.from_gateway,
        )

    def _record(self, slot: int, recent: dict[int, Any] | None = None) -> R:
        """The record in ``slot``; ``recent``: the requests read so far by slot (a reply's request is then that
        same object, as it was on the bus), filled in as it goes."""
        kept = self._slots[slot]
        assert kept is not None
        t, d, data, k, slave, how, words_kept, note, model_t, r, packed, back, wall, transaction, unit, gateway = kept
        words: str | Request | Response
        if how == _TEXT:
            words = words_kept
        elif how == _SAME_AS_DATA:
            words = decode_request(data, check_crc=False)
            if recent is not None:
                recent[slot] = words
                if len(recent) > _RECENT:
                    del recent[next(iter(recent))]
        else:
            words = unpack_message(words_kept)
        request: Any = None
        if back:
            if back <= (slot - self._start) % self._maxlen:  # its request record is still held
                request = (recent or {}).get((slot - back) % self._maxlen)
            if request is None:
                request = decode_request(packed, check_crc=False)  # that record has gone, or is read alone
        elif packed is not None:
            request = unpack_message(packed)
        table = self._table
        record: R = self._make(
            t,
            table[d],
            data,
            table[k],
            slave,
            words,
            note,
            model_t,
            None if r is None else table[r],
            request,
            wall=wall,
            mbap=None if transaction is None else MbapHeader(transaction, unit),
            from_gateway=gateway,
        )
        return record

    def __getitem__(self, index: int) -> R:
        if index < 0:
            index += self._len
        if not 0 <= index < self._len:
            raise IndexError("frame ring index out of range")
        return self._record((self._start + index) % self._maxlen)

    def __iter__(self) -> Iterator[R]:
        recent: dict[int, Any] = {}
        for slot in self._slot_numbers():
            yield self._record(slot, recent)

    def popleft(self) -> R:
        """Take the oldest record out (IndexError when empty): a queue's end, for a consumer that drains it."""
        if not self._len:
            raise IndexError("pop from an empty frame ring")
        slot = self._start
        record = self._record(slot)
        self._slots[slot] = None
        self._start = (slot + 1) % self._maxlen
        self._len -= 1
        return record

    def clear(self) -> None:
        """Forget every record (the storage stays, for the next)."""
        self._start = self._len = 0
        self._slots = [None] * self._maxlen
        self._table.clear()
        self._index.clear()
        self._rx_slot, self._rx_words = -1, None


_REQUESTS = frozenset((ReadRequest, WriteSingleRequest, WriteMultipleRequest, UnsupportedRequest))

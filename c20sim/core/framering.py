"""The frame log's ring: the newest frame records, kept as bytes and numbers in storage made once.

A serving process keeps every bus's last ``log_size`` frames (2000 by default) for the control API, the
dashboard and the tests. Kept as objects (a record, its decoded request or response), that is four to five
thousand objects a bus that the garbage collector tracks, and a full collection walks all of them while every
bus waits: 1,024,770 of them and 344 ms at 256 buses (bench/bench_plant.py part 4). The ring keeps each record
as the numbers and bytes it is made of, in arrays and lists made at start and written in place, none of which
the collector tracks (bytes, str, floats and ints hold no references), and makes the record anew when it is
read. What reads it (GET /frames, a test, the dashboard's first look) is rare beside what writes it (two records
a request).

A record read back equals the one appended (dataclass equality, and every field the equality leaves out), for
the records :class:`~c20sim.core.bus.Bus` makes: a request decoded from its frame (an RX request record's
``words`` is ``decode_request(data)``, which the ring does not store twice), any other request or response
packed field by field (:func:`pack_message`), a text as its text. The few objects a record refers to (its
direction and kind, the drive's register map) are interned in tables of a few entries a ring.
"""

from __future__ import annotations

import math
import struct
from array import array
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

#: How ``words`` is kept (the low bits of a slot's flags)
_TEXT, _SAME_AS_DATA, _PACKED = 0, 1, 2
_WORDS = 3
_FROM_GATEWAY = 4
_MBAP = 16  #: the record has a Modbus TCP header: its transaction and unit are in their arrays (else stale there)
_WALL = 32  #: the record has a wall-clock time: in its array (else stale there)
_REQUEST_FRAME = 8  #: the request is kept as its frame (that of a request record), not packed
#: Distinct objects (directions, kinds, register maps) a ring interns before it renumbers what it holds.
MAX_INTERNED = 256
_NONE = -1
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


def _numbers(typecode: str, size: int, fill: float) -> array[Any]:
    return array(typecode, [fill]) * size if typecode == "d" else array(typecode, [int(fill)]) * size


class FrameRing(Generic[R]):
    """The newest ``maxlen`` records, as a ``deque(maxlen=...)`` of them reads: ``len``, iteration oldest first,
    an index (negative from the newest), ``append`` (the oldest goes when full) and ``clear``. ``make`` builds
    a record from its fields (the record's class)."""

    def __init__(self, maxlen: int, make: Any) -> None:
        if maxlen < 0:
            raise ValueError("maxlen must be at least 0")
        self._make = make
        self._maxlen = maxlen
        self._start = 0
        self._len = 0
        n = maxlen
        self._t = _numbers("d", n, 0.0)
        self._model_t = _numbers("d", n, math.nan)
        self._wall = _numbers("d", n, math.nan)
        self._slave = _numbers("h", n, _NONE)
        self._flags = _numbers("b", n, 0)
        self._direction = _numbers("h", n, 0)
        self._kind = _numbers("h", n, 0)
        self._registers = _numbers("h", n, _NONE)
        self._transaction = _numbers("l", n, _NONE)
        self._unit = _numbers("h", n, _NONE)
        #: a reply's request, when it is the words of a request record still held: how many records back
        self._back = _numbers("l", n, 0)
        self._data: list[bytes] = [b""] * n
        self._note: list[str] = [""] * n
        self._words: list[bytes | str] = [b""] * n
        self._request: list[bytes] = [b""] * n
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
        used = sorted(
            {ix for arr in (self._direction, self._kind, self._registers) for ix in self._slots(arr) if ix >= 0}
        )
        renumbered = {old: new for new, old in enumerate(used)}
        for arr in (self._direction, self._kind, self._registers):
            for slot in self._slot_numbers():
                if arr[slot] >= 0:
                    arr[slot] = renumbered[arr[slot]]
        self._table = [self._table[old] for old in used]
        self._index = {id(obj): i for i, obj in enumerate(self._table)}

    def _slot_numbers(self) -> Iterator[int]:
        for i in range(self._len):
            yield (self._start + i) % self._maxlen

    def _slots(self, arr: array[Any]) -> Iterator[int]:
        for slot in self._slot_numbers():
            yield arr[slot]

    def append(self, record: R) -> None:
        """Keep ``record`` (its fields), dropping the oldest when full."""
        if not self._maxlen:
            return
        if self._len < self._maxlen:
            slot = (self._start + self._len) % self._maxlen
            self._len += 1
        else:
            slot = self._start
            self._start = (self._start + 1) % self._maxlen
        if slot == self._rx_slot:  # the last request's slot is taken over: a reply can no longer share its frame
            self._rx_slot, self._rx_words = -1, None
        words = record.words
        kept: bytes | str
        if isinstance(words, str):
            flags, kept = _TEXT, words
        elif record.request is None and words.__class__ in _REQUESTS and record.direction == "rx":
            flags, kept = _SAME_AS_DATA, b""  # the bus decoded it from the frame: read back by decoding it again
        else:
            flags, kept = _PACKED, pack_message(words)
        if flags == _SAME_AS_DATA:
            self._rx_slot, self._rx_words = slot, words
        if record.from_gateway:
            flags |= _FROM_GATEWAY
        wall, mbap = record.wall, record.mbap
        if wall is not None:  # the rare fields are written only when there: a flag says which are
            flags |= _WALL
            self._wall[slot] = wall
        if mbap is not None:
            flags |= _MBAP
            self._transaction[slot] = mbap.transaction
            self._unit[slot] = mbap.unit
        self._flags[slot] = flags
        self._words[slot] = kept
        self._t[slot] = record.t
        model_t = record.model_t
        self._model_t[slot] = math.nan if model_t is None else model_t
        self._slave[slot] = _NONE if record.slave is None else record.slave
        index = self._index
        direction, kind = record.direction, record.kind
        found = index.get(id(direction))
        self._direction[slot] = self._intern(direction) if found is None else found
        found = index.get(id(kind))
        self._kind[slot] = self._intern(kind) if found is None else found
        registers = record.registers
        self._registers[slot] = _NONE if registers is None else self._intern(registers)
        self._data[slot] = record.data
        self._note[slot] = record.note
        request = record.request
        back = 0
        if request is not None and request is self._rx_words and self._rx_slot != slot:
            back = (slot - self._rx_slot) % self._maxlen  # read back as that very object, as the bus made it
        self._back[slot] = back
        if back:  # its frame, which the request record holds already (bytes are shared, not copied)
            self._flags[slot] = flags | _REQUEST_FRAME
            self._request[slot] = self._data[self._rx_slot]
        else:
            self._request[slot] = b"" if request is None else pack_message(request)

    def _record(self, slot: int, recent: dict[int, Any] | None = None) -> R:
        """The record in ``slot``; ``recent``: the requests read so far by slot (a reply's request is then that
        same object, as it was on the bus), filled in as it goes."""
        flags, kept, data = self._flags[slot], self._words[slot], self._data[slot]
        words: str | Request | Response
        how = flags & _WORDS
        if how == _TEXT:
            assert isinstance(kept, str)
            words = kept
        elif how == _SAME_AS_DATA:
            words = decode_request(data, check_crc=False)
            if recent is not None:
                recent[slot] = words
                if len(recent) > _RECENT:
                    del recent[next(iter(recent))]
        else:
            assert isinstance(kept, bytes)
            words = unpack_message(kept)
        model_t = self._model_t[slot]
        wall = self._wall[slot] if flags & _WALL else None
        transaction = self._transaction[slot] if flags & _MBAP else _NONE
        registers = self._registers[slot]
        packed = self._request[slot]
        request: Any = None
        if flags & _REQUEST_FRAME:
            back = self._back[slot]
            if back <= (slot - self._start) % self._maxlen:  # its request record is still held
                request = (recent or {}).get((slot - back) % self._maxlen)
            if request is None:
                request = decode_request(packed, check_crc=False)  # that record has gone, or is read alone
        elif packed:
            request = unpack_message(packed)
        record: R = self._make(
            self._t[slot],
            self._table[self._direction[slot]],
            data,
            self._table[self._kind[slot]],
            None if self._slave[slot] == _NONE else self._slave[slot],
            words,
            self._note[slot],
            None if model_t != model_t else model_t,
            None if registers == _NONE else self._table[registers],
            request,
            wall=wall,
            mbap=None if transaction == _NONE else MbapHeader(transaction, self._unit[slot]),
            from_gateway=bool(flags & _FROM_GATEWAY),
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
        if slot == self._rx_slot:  # the last request is gone: a reply appended next keeps a frame of its own
            self._rx_slot, self._rx_words = -1, None
        self._data[slot] = self._request[slot] = b""
        self._words[slot] = self._note[slot] = ""
        self._start = (slot + 1) % self._maxlen
        self._len -= 1
        return record

    def clear(self) -> None:
        """Forget every record (the storage stays, for the next)."""
        self._start = self._len = 0
        for i in range(self._maxlen):
            self._data[i] = self._request[i] = b""
            self._words[i] = b""
            self._note[i] = ""
        self._table.clear()
        self._index.clear()
        self._rx_slot, self._rx_words = -1, None


_REQUESTS = frozenset((ReadRequest, WriteSingleRequest, WriteMultipleRequest, UnsupportedRequest))

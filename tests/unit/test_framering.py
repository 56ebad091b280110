"""The frame log's ring: records kept as bytes and numbers read back equal, bounded, and tracking nothing per frame."""

from __future__ import annotations

import dataclasses
import gc
from typing import Any

import pytest

from c20sim.core.bus import Bus, FrameRecord
from c20sim.core.framering import MAX_INTERNED, FrameRing, pack_message, unpack_message
from c20sim.core.slave import Slave
from c20sim.drive.profile import Profile
from c20sim.drive.store import RegisterStoreDrive
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    FrameEvent,
    FrameKind,
    MbapHeader,
    ReadRequest,
    ReadResponse,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    encode,
    with_crc,
)
from c20sim.wire.registers import Reg
from tests.conftest import Line

FIELDS = [f.name for f in dataclasses.fields(FrameRecord)]


def frame_objects() -> int:
    """Objects a frame makes that the collector tracks (records, requests, responses), after a collection: counted
    by kind, not all objects of the process, which other tests' threads may be adding to meanwhile."""
    gc.collect()
    kinds = (FrameRecord, ReadRequest, ReadResponse, FrameEvent)
    return sum(1 for o in gc.get_objects() if isinstance(o, kinds))


def same(a: FrameRecord, b: FrameRecord) -> None:
    """Every field equal, those the equality leaves out too; the register map the very same object."""
    assert a == b
    for name in FIELDS:
        if name == "registers":
            assert getattr(a, name) is getattr(b, name)
        else:
            assert getattr(a, name) == getattr(b, name), name
            assert type(getattr(a, name)) is type(getattr(b, name)), name


def make_bus(profile: Profile, addresses: tuple[int, ...] = (1, 2)) -> Bus:
    slaves = []
    for address in addresses:
        drive = RegisterStoreDrive(profile)
        drive.parameters.set(Reg.ADDRESS, address)
        slaves.append(Slave(profile, drive))
    return Bus(slaves, log_size=500, seed=7)


@pytest.mark.parametrize(
    "message",
    [
        ReadRequest(1, 0x2100, 3),
        WriteSingleRequest(2, 0x2001, 0xFFFF),
        WriteMultipleRequest(3, 0x2000, (1, 2, 3)),
        WriteMultipleRequest(3, 0x2000, (1,), count=5, byte_count=3),  # counts as sent, disagreeing
        WriteMultipleRequest(3, 0x2000, ()),
        UnsupportedRequest(4, 0x2B, b"\x0e\x01\x00"),
        UnsupportedRequest(4, 0x85, b""),
        ReadResponse(1, (0, 0xFFFF, 7)),
        ReadResponse(1, ()),
        WriteSingleResponse(1, 0x2001, 5),
        WriteMultipleResponse(1, 0x2000, 2),
        ExceptionResponse(1, 0x03, ExceptionCode.ILLEGAL_ADDRESS),
        ExceptionResponse(1, 0x85, ExceptionCode.ILLEGAL_FUNCTION),  # a function code with its top bit set
    ],
)
def test_a_packed_message_unpacks_equal(message: Any) -> None:
    back = unpack_message(pack_message(message))
    assert back == message and type(back) is type(message)
    if isinstance(message, ExceptionResponse):
        assert type(back.code) is ExceptionCode


def test_every_record_the_bus_makes_reads_back_the_same(profile: Profile) -> None:
    bus = make_bus(profile)
    made: list[FrameRecord] = []
    bus.subscribe(made.append)
    line = Line(bus)
    line.send(encode(ReadRequest(1, Reg.STATUS1, 2)))
    line.send(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 300)))
    line.send(encode(WriteMultipleRequest(2, Reg.SPEED_SETPOINT, (100, 1))))
    line.send(with_crc(bytes((1, 0x10, 0x20, 0x01, 0x00, 0x03, 0x02, 0x00, 0x64))))  # counts disagree: 0x03
    line.send(with_crc(bytes((1, 0x2B, 0x0E, 0x01, 0x00))))  # a function the C20 lacks
    line.send(encode(ReadRequest(1, 0x7777, 1)))  # an address no drive has: exception
    line.send(encode(ReadRequest(0, Reg.STATUS1, 1)))  # broadcast read: ignored
    line.send(encode(WriteSingleRequest(0, Reg.SPEED_SETPOINT, 200)))  # broadcast write
    line.send(encode(ReadRequest(9, Reg.STATUS1, 1)))  # nobody there
    line.send(encode(ReadRequest(0xF9, Reg.STATUS1, 1)))  # reserved
    line.send(bytes.fromhex("01 03 21 00 00 01 00 00"))  # bad CRC
    line.send(b"\x01")  # noise
    bus.drive_links[0].forced_exception = ExceptionCode.OPERATION_FAILED
    line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))
    bus.drive_links[0].forced_exception = None
    bus.drive_links[0].corrupt_crc = True  # a mangled reply: its data is not the response's frame
    bus.drive_links[0].wrong_address = 0x63
    line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))
    bus.drive_links[0].clear()
    bus.drive_links[1].drop_next = 1  # a dropped reply: an empty frame
    line.send(encode(ReadRequest(2, Reg.STATUS1, 1)))
    # Modbus TCP through the gateway: the MBAP header on the records
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    bus.handle(FrameEvent(FrameKind.FRAME, frame, 10.0, mbap=MbapHeader(0xBEEF, 1)))
    bus.link.corrupt_crc = True
    bus.handle(FrameEvent(FrameKind.FRAME, frame, 11.0, mbap=MbapHeader(7, 1)))
    gateway = dataclasses.replace(made[-1], from_gateway=True, wall=1.7e9, t=12.0)
    bus.record(gateway)
    assert len(made) >= 30
    kept = list(bus.records)
    assert len(kept) == len(made) == len(bus.records)
    for original, back in zip(made, kept, strict=True):
        same(original, back)
        assert original.text == back.text and original.as_dict(5.0) == back.as_dict(5.0)
    assert {r.kind for r in kept} >= {"request", "reply", "exception", "crc error", "noise", "dropped"}
    assert any(r.mbap is not None for r in kept) and kept[-1].from_gateway and kept[-1].wall == 1.7e9
    same(bus.records[-1], gateway)
    same(bus.records[0], made[0])
    same(bus.records[-len(made)], made[0])
    with pytest.raises(IndexError):
        bus.records[len(made)]


def test_the_ring_keeps_the_newest_maxlen_and_clears(profile: Profile) -> None:
    bus = make_bus(profile, (1,))
    ring: FrameRing[FrameRecord] = FrameRing(7, FrameRecord)
    bus.subscribe(ring.append)
    made: list[FrameRecord] = []
    bus.subscribe(made.append)
    line = Line(bus)
    for v in range(10):
        line.send(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 100 + v)))
    assert len(made) == 20 and len(ring) == 7 and ring.maxlen == 7
    assert list(ring) == made[-7:]
    assert ring[-1] == made[-1] and ring[0] == made[-7]
    ring.clear()
    assert len(ring) == 0 and list(ring) == [] and not ring
    line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))
    assert list(ring) == made[-2:]
    empty: FrameRing[FrameRecord] = FrameRing(0, FrameRecord)
    empty.append(made[0])
    assert len(empty) == 0 and list(empty) == []


def test_a_full_ring_tracks_no_object_per_frame(profile: Profile) -> None:
    """What the collector walks does not grow with the frames kept: the ring's storage is made once."""
    bus = make_bus(profile, (1,))
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    bus.handle(FrameEvent(FrameKind.FRAME, frame, 0.0))
    before = frame_objects()
    for i in range(1500):  # 3000 records through a ring of 500
        bus.handle(FrameEvent(FrameKind.FRAME, frame, i * 0.01))
    after = frame_objects()
    assert len(bus.records) == 500
    assert after - before <= 2, (before, after)  # a deque of records kept 500 x (record, request or response)


def test_more_distinct_objects_than_the_table_holds_are_renumbered(profile: Profile) -> None:
    """Register maps come and go (a record refers to its drive's): the interned table stays bounded and every
    record kept still reads back its own map."""
    ring: FrameRing[FrameRecord] = FrameRing(40, FrameRecord)
    base = FrameRecord(1.0, "rx", b"\x01", "noise", 1, "noise")  # type: ignore[arg-type]
    maps = [object() for _ in range(MAX_INTERNED + 60)]
    for i, registers in enumerate(maps):
        ring.append(dataclasses.replace(base, t=float(i), registers=registers))  # type: ignore[arg-type]
    assert [r.registers for r in ring] == maps[-40:]
    assert [r.t for r in ring] == [float(i) for i in range(len(maps) - 40, len(maps))]
    assert len(ring._table) <= MAX_INTERNED


def test_a_reply_names_the_very_request_its_request_record_holds(profile: Profile) -> None:
    """As on the bus, a reply record's ``request`` is its request record's ``words`` (testing.assert_written
    pairs them so), read in one pass; once the request record has left the ring, an equal request."""
    bus = make_bus(profile, (1,))
    bus.records = FrameRing(5, FrameRecord)
    line = Line(bus)
    line.send(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 300)))
    line.send(encode(WriteMultipleRequest(1, Reg.SPEED_SETPOINT, (400, 1))))
    rx1, tx1, rx2, tx2 = list(bus.records)
    assert tx1.request is rx1.words and tx2.request is rx2.words and tx1.request != tx2.request
    line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))  # 6 records: the first request record leaves
    first_tx = next(iter(bus.records))
    assert first_tx.direction == "tx" and first_tx.request == WriteSingleRequest(1, Reg.SPEED_SETPOINT, 300)
    assert bus.records[-1].request == ReadRequest(1, Reg.STATUS1, 1)


def test_popleft_drains_oldest_first(profile: Profile) -> None:
    """The frame log's writer drains its buffer from the oldest end: each record once, equal, then empty."""
    bus = make_bus(profile, (1,))
    ring: FrameRing[FrameRecord] = FrameRing(6, FrameRecord)
    made: list[FrameRecord] = []
    bus.subscribe(made.append)
    bus.subscribe(ring.append)
    line = Line(bus)
    for v in range(2):
        line.send(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 100 + v)))
    first = ring.popleft()
    same(first, made[0])
    line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))  # wraps around the slot popped
    drained = [ring.popleft() for _ in range(len(ring))]
    assert drained == made[1:] and len(ring) == 0
    with pytest.raises(IndexError):
        ring.popleft()


def test_a_reply_appended_after_its_request_was_drained_keeps_its_request(profile: Profile) -> None:
    """The frame log's writer may drain a request before the bus appends its reply (a CI run's writer thread did,
    and the reply read back from the emptied slot broke the writer): the reply keeps a request of its own."""
    bus = make_bus(profile, (1,))
    ring: FrameRing[FrameRecord] = FrameRing(4, FrameRecord)
    made: list[FrameRecord] = []
    bus.subscribe(made.append)
    bus.subscribe(lambda record: ring.append(record) if record.direction == "rx" else None)
    line = Line(bus)
    line.send(encode(WriteSingleRequest(1, Reg.SPEED_SETPOINT, 300)))
    request = ring.popleft()  # drained before its reply reaches the ring
    assert request.direction == "rx" and len(ring) == 0
    ring.append(made[1])  # the reply
    reply = ring.popleft()
    same(reply, made[1])
    assert reply.request == WriteSingleRequest(1, Reg.SPEED_SETPOINT, 300)
    for _ in range(5):  # and a slot taken over by later records: each reply still reads its own request
        line.send(encode(ReadRequest(1, Reg.STATUS1, 1)))
        assert ring.popleft().direction == "rx"  # the request, drained first again
        ring.append(made[-1])
        assert ring.popleft().request == ReadRequest(1, Reg.STATUS1, 1)


def test_what_waits_for_the_frame_log_writer_is_no_tracked_object(profile: Profile, tmp_path: Any) -> None:
    """--log-frames: records queued for the writer thread (here not started: a sink that has not taken them)
    add nothing the collector walks, up to the buffer's bound and past it (the newest refused, counted)."""
    from c20sim.transport.framelog import FrameLog

    bus = make_bus(profile, (1,))
    frame_log = FrameLog(str(tmp_path / "frames.jsonl"), buffer_records=1000)
    bus.subscribe(frame_log.put)
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    bus.handle(FrameEvent(FrameKind.FRAME, frame, 0.0))
    before = frame_objects()
    for i in range(1000):  # 2000 records: 1000 wait, 1000 refused
        bus.handle(FrameEvent(FrameKind.FRAME, frame, i * 0.01))
    assert frame_objects() - before <= 2  # a deque of records: 2,000 more (1,000 records, their messages)
    assert (len(frame_log._buffer), frame_log.dropped) == (1000, 1002)

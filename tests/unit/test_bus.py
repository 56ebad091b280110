"""Several drives on one line: addressing, broadcast, silence, address and baud changes, the frame log."""

from __future__ import annotations

import dataclasses
import logging

import pytest

from c20sim.core.bus import Bus
from c20sim.core.slave import Slave
from c20sim.drive.profile import Profile
from c20sim.drive.store import RegisterStoreDrive
from c20sim.wire.protocol import (
    ExceptionCode,
    ReadRequest,
    ReadResponse,
    WriteMultipleRequest,
    WriteSingleRequest,
    encode,
    with_crc,
)
from c20sim.wire.registers import Reg
from tests.conftest import Line


def make_slave(profile: Profile, address: int) -> Slave:
    drive = RegisterStoreDrive(profile)
    drive.parameters.set(Reg.ADDRESS, address)
    return Slave(profile, drive)


@pytest.fixture
def three(profile: Profile) -> Line:
    return Line(Bus([make_slave(profile, a) for a in (1, 2, 5)]))


def read(address: int, register: int) -> bytes:
    return encode(ReadRequest(address, register, 1))


def write(address: int, register: int, value: int) -> bytes:
    return encode(WriteSingleRequest(address, register, value))


def test_each_drive_answers_only_its_own_address(three: Line) -> None:
    for address in (1, 2, 5):
        reply = three.send(write(address, 0x2001, 100 * address))
        assert reply == write(address, 0x2001, 100 * address)
    assert [s.drive.read(0x2001) for s in three.bus.slaves] == [100, 200, 500]
    assert three.send(read(3, 0x2001)) is None
    assert three.send(read(2, 0x2001)) == encode(ReadResponse(2, (200,)))


def test_broadcast_write_acts_on_every_drive_and_is_never_answered(three: Line) -> None:
    assert three.send(write(0, 0x2001, 1234)) is None
    assert [s.drive.read(0x2001) for s in three.bus.slaves] == [1234, 1234, 1234]
    assert three.send(encode(WriteMultipleRequest(0, 0x2000, (5, 42)))) is None
    assert [s.drive.read(0x2001) for s in three.bus.slaves] == [42, 42, 42]
    assert three.bus.records[-1].note == "broadcast: no reply"


def test_broadcast_read_is_ignored(three: Line) -> None:
    assert three.send(read(0, 0x2103)) is None
    assert three.bus.records[-1].note == "broadcast read: ignored"


@pytest.mark.parametrize("address", [0xF8, 0xFA, 0xFF])
def test_reserved_addresses_get_silence(profile: Profile, address: int) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    assert line.send(read(address, 0x2103)) is None
    assert line.bus.records[-1].note == "reserved address: silence"


def test_bad_crc_for_an_absent_drive_gets_silence(three: Line) -> None:
    frame = bytearray(read(9, 0x2100))
    frame[-1] ^= 0xFF
    assert three.send(bytes(frame)) is None


def test_bad_crc_silence_quirk(profile: Profile) -> None:
    quiet = dataclasses.replace(profile, protocol=dataclasses.replace(profile.protocol, reply_to_bad_crc=False))
    line = Line(Bus([make_slave(quiet, 1)]))
    assert line.send("01 03 21 00 00 01 8E 37") is None
    assert line.bus.records[-1].kind == "crc error"


def test_address_change_takes_effect_after_its_reply(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    # The reply to the write goes out from the old address.
    assert line.send(write(1, 0x2008, 7)) == write(1, 0x2008, 7)
    assert line.send(read(1, 0x2103)) is None
    assert line.send(read(7, 0x2008)) is not None
    assert line.bus.slaves[0].drive.read(0x0800) == 7  # F08.00 holds it


def test_baud_change_takes_effect_after_its_reply_on_a_single_drive_line(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    assert line.bus.line_baud == 19200
    assert line.send(write(1, 0x2009, 3)) == write(1, 0x2009, 3)
    assert line.replies[-1].baud == 19200  # the acknowledgement goes out at the old baud
    assert line.bus.line_baud == 9600
    assert line.send(read(1, 0x2009)) == encode(ReadResponse(1, (3,)))


def test_a_drive_set_to_another_baud_on_a_shared_line_goes_deaf(three: Line) -> None:
    assert three.send(write(2, 0x2009, 3)) == write(2, 0x2009, 3)
    assert three.replies[-1].baud == 19200
    assert three.bus.line_baud == 19200
    assert three.send(read(2, 0x2103)) is None
    assert three.send(read(1, 0x2103)) is not None


def test_frame_log_records_both_directions_in_words(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    seen = []
    unsubscribe = line.bus.subscribe(seen.append)
    line.send("01 06 20 00 00 01 43 CA")
    line.send("01 03 00 32 00 01 25 C5")
    unsubscribe()
    line.send("01 03 21 00 00 01 8E 36")
    assert [(r.direction, r.kind, r.text) for r in seen] == [
        ("rx", "request", "write 2000H = 0001: forward run"),
        ("tx", "reply", "write 2000H = 0001: forward run"),
        ("rx", "request", "read F00.50"),
        ("tx", "exception", "exception 0x02 to read: illegal data address"),
    ]
    assert len(line.bus.records) == 6
    last = line.bus.records[-1].as_dict()
    assert last["hex"] == "01 03 02 00 03 F8 45"
    assert last["text"] == "2100H = 0003: stopped"
    assert last["dir"] == "tx"
    # The line's time (reply due after the 2 ms turnaround) and the drives' time when it was served.
    assert (last["t"], last["model_t"]) == (pytest.approx(0.152), pytest.approx(0.15))


def test_frame_log_is_bounded(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)], log_size=10))
    for _ in range(20):
        line.send(read(1, 0x2103))
    assert len(line.bus.records) == 10


def test_noise_is_logged_and_not_answered(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    assert line.send("01 03") is None
    assert line.bus.records[-1].kind == "noise"


def test_unsupported_function_on_the_wire(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    assert line.hex(with_crc(bytes.fromhex("01 04 30 00 00 01"))) == "01 84 01 82 C0"


def test_a_broadcast_baud_change_moves_the_line_of_a_single_drive(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    assert line.send(write(0, 0x2009, 3)) is None  # broadcast: no reply, but the drive acts on it
    assert line.bus.line_baud == 9600
    assert line.send(read(1, 0x2009)) == encode(ReadResponse(1, (3,)))


def test_a_baud_change_whose_reply_is_dropped_still_moves_the_line(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    line.bus.drive_links[0].drop_next = 1
    assert line.send(write(1, 0x2009, 3)) is None
    assert line.bus.line_baud == 9600
    assert line.send(read(1, 0x2009)) == encode(ReadResponse(1, (3,)))


def test_a_forced_exception_keeps_a_broadcast_from_acting(profile: Profile) -> None:
    line = Line(Bus([make_slave(profile, 1)]))
    line.bus.link.forced_exception = ExceptionCode.OPERATION_FAILED
    assert line.send(write(0, 0x2001, 1234)) is None
    assert line.bus.slaves[0].drive.read(0x2001) == 0


def test_unsubscribing_twice_is_harmless(profile: Profile, caplog: pytest.LogCaptureFixture) -> None:
    bus = Bus([make_slave(profile, 1)])

    def failing(record: object) -> None:
        raise RuntimeError("listener bug")

    seen: list[object] = []
    unsubscribe = bus.subscribe(failing)
    unsubscribe_seen = bus.subscribe(seen.append)
    with caplog.at_level(logging.ERROR, logger="c20sim.core.bus"):
        assert Line(bus).send(read(1, 0x2103)) == encode(ReadResponse(1, (0x0020,)))  # the bus serves on
    # The failing listener is logged (once, with its exception) and removed; the other one gets every record.
    failures = [r for r in caplog.records if r.getMessage() == "frame log listener failed; removing it"]
    assert len(failures) == 1 and failures[0].exc_info is not None
    assert str(failures[0].exc_info[1]) == "listener bug"
    assert len(seen) == 2  # the request and its reply
    Line(bus).send(read(1, 0x2103))
    assert len(caplog.records) == 1 and len(seen) == 4  # removed: not called, not logged again
    unsubscribe()
    unsubscribe()  # already gone: harmless
    unsubscribe_seen()
    Line(bus).send(read(1, 0x2103))
    assert len(seen) == 4


@pytest.mark.parametrize("percent", [50.0, 10.0])
def test_drop_percent_drops_that_share_of_the_replies(profile: Profile, percent: float) -> None:
    line = Line(Bus([make_slave(profile, 1)], seed=7))
    line.bus.link.drop_percent = percent
    requests = 2000
    dropped = sum(line.send(read(1, 0x2103)) is None for _ in range(requests))
    # Binomial: within 5 sigma of the mean (50 %: 1000 +- 112; 10 %: 200 +- 67); half the rate is far outside.
    mean = requests * percent / 100
    sigma = (requests * percent / 100 * (1 - percent / 100)) ** 0.5
    assert abs(dropped - mean) <= 5 * sigma, f"{dropped} of {requests} dropped at {percent:g} %"
    assert line.bus.counters_of(1).silences == dropped


def test_a_fault_switched_between_replies_acts_on_the_next_one(profile: Profile) -> None:
    # Whether a reply fault is armed is remembered between replies, and forgotten whenever a switch moves.
    line = Line(Bus([make_slave(profile, 1)], seed=1))
    good = encode(ReadResponse(1, (0,)))
    link = line.bus.link_of(line.bus.slaves[0])
    assert line.send(read(1, 0x2001)) == good
    link.corrupt_crc = True
    assert line.send(read(1, 0x2001)) == good[:-2] + bytes((good[-2] ^ 0xFF, good[-1] ^ 0xFF))
    link.clear()
    assert line.send(read(1, 0x2001)) == good
    line.bus.link.drop_next = 2  # the whole line's: counted down by the replies it drops
    assert [line.send(read(1, 0x2001)) for _ in range(3)] == [None, None, good]
    assert line.bus.link.drop_next == 0 and not line.bus.link.active_reply_faults
    line.bus.link.garbage_after = b"\x00"
    assert line.send(read(1, 0x2001)) == good + b"\x00"

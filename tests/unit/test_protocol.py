"""CRC, frame encoding and the RTU framer, without a port and without waiting."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable

import fastcrc.crc16
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from c20sim.transport.endpoint import stream_framer
from c20sim.wire.framing import RtuFramer
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    FrameKind,
    ReadRequest,
    ReadResponse,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteMultipleResponse,
    WriteSingleRequest,
    WriteSingleResponse,
    char_bits,
    char_time,
    crc16,
    crc16_table,
    decode_request,
    decode_response,
    encode,
    silence_times,
    transaction_time,
    with_crc,
)

H = bytes.fromhex
T35 = 3.5 * 10 / 19200  # the sheet's 8N1: 10 bits a character
T15 = 1.5 * 10 / 19200
CHAR = 10 / 19200


def test_crc_of_the_sheets_frames() -> None:
    # Every CRC of the sheet's command table, low byte first (docs/protocol.md).
    assert with_crc(H("01 06 20 00 00 01")) == H("01 06 20 00 00 01 43 CA")
    assert with_crc(H("01 06 20 01 0B B8")) == H("01 06 20 01 0B B8 D4 88")
    assert with_crc(H("01 03 00 0A 00 01")) == H("01 03 00 0A 00 01 A4 08")
    assert with_crc(H("01 83 02")) == H("01 83 02 C0 F1")
    assert with_crc(H("01 86 03")) == H("01 86 03 02 61")


@pytest.mark.parametrize("crc", [crc16, crc16_table], ids=["crc16", "table"])
def test_crc_check_value(crc: Callable[[bytes], int]) -> None:
    # The catalogue check value of CRC-16/MODBUS, and the sheet's first frame.
    assert crc(b"123456789") == 0x4B37
    assert crc(b"") == 0xFFFF
    assert crc(H("01 06 20 00 00 01")).to_bytes(2, "little") == H("43 CA")


def test_the_compiled_crc_is_the_one_in_use_where_installed() -> None:
    # The test extra installs c20sim[fast]'s fastcrc: the suite runs on the compiled CRC, the table is checked
    # against it below and above (a plain install runs on the table).
    assert crc16 is fastcrc.crc16.modbus


@given(st.binary(max_size=300))
@settings(max_examples=300, deadline=None)
def test_the_compiled_crc_and_the_table_agree(data: bytes) -> None:
    assert fastcrc.crc16.modbus(data) == crc16_table(data) == crc16_table(bytearray(data))


@pytest.mark.parametrize(
    ("message", "frame"),
    [
        (ReadRequest(1, 0x2100, 1), "01 03 21 00 00 01 8E 36"),
        (WriteSingleRequest(1, 0x000A, 0x09C4), "01 06 00 0A 09 C4 AE 0B"),
        (ReadResponse(1, (0x1388,)), "01 03 02 13 88 B5 12"),
        (WriteSingleResponse(1, 0x2000, 5), "01 06 20 00 00 05 42 09"),
        (ExceptionResponse(1, 0x03, ExceptionCode.ILLEGAL_ADDRESS), "01 83 02 C0 F1"),
        (ExceptionResponse(1, 0x06, ExceptionCode.ILLEGAL_VALUE), "01 86 03 02 61"),
    ],
)
def test_encode_matches_the_sheet(message: object, frame: str) -> None:
    assert encode(message) == H(frame)  # type: ignore[arg-type]


def test_write_multiple_round_trip() -> None:
    request = WriteMultipleRequest(1, 0x2000, (1, 3000))
    frame = encode(request)
    assert frame[:7] == H("01 10 20 00 00 02 04")
    assert decode_request(frame) == request
    reply = encode(WriteMultipleResponse(1, 0x2000, 2))
    assert decode_response(reply) == WriteMultipleResponse(1, 0x2000, 2)


def test_decode_keeps_disagreeing_counts_for_the_slave_to_refuse() -> None:
    frame = with_crc(H("01 10 20 00 00 03 04 00 01 0B B8"))
    request = decode_request(frame)
    assert isinstance(request, WriteMultipleRequest)
    assert (request.count, request.byte_count, request.values) == (3, 4, (1, 3000))


def test_decode_unknown_function_is_unsupported() -> None:
    assert decode_request(with_crc(H("01 04 30 00 00 01"))) == UnsupportedRequest(1, 4, H("30 00 00 01"))


def test_decode_rejects_bad_crc_and_length() -> None:
    with pytest.raises(ValueError, match="bad CRC"):
        decode_request(H("01 06 20 00 00 01 43 CB"))
    with pytest.raises(ValueError, match="9 bytes"):
        decode_request(with_crc(H("01 03 21 00 00 01 00")))


def test_silence_times() -> None:
    assert silence_times(19200) == pytest.approx((T15, T35))
    assert silence_times(9600) == pytest.approx((1.5 * 10 / 9600, 3.5 * 10 / 9600))
    assert silence_times(1200) == pytest.approx((0.0125, 0.0291667), abs=1e-7)  # 8N1 at 1200: 12.5 ms, 29.2 ms
    assert silence_times(1200, char_bits(8, "E", 1)) == pytest.approx((1.5 * 11 / 1200, 3.5 * 11 / 1200))
    assert silence_times(38400) == (0.00075, 0.00175)
    assert silence_times(57600) == (0.00075, 0.00175)


@pytest.mark.parametrize("baud", [38400, 57600])
def test_a_line_timed_port_above_19200_ends_a_frame_after_a_fixed_1_75_ms(baud: int) -> None:
    """Through the framer a line-timed port uses (transport's stream_framer): garbage, a silence, a request. Above
    19200 baud t3.5 is a fixed 1.75 ms (3.5 characters would be 0.91 or 0.61 ms): 1.6 ms of silence leaves one
    bad frame, 1.9 ms splits off the request."""
    char = char_time(baud)

    def framed(silence: float) -> list[tuple[FrameKind, bytes]]:
        framer = stream_framer(baud, line_timing=True)
        framer.feed(H("FF 00"), 1.0)
        end = 1.0 + silence + len(READ) * char
        framer.feed(READ, end)
        framer.tick(end + 1.0)
        return frames(framer)

    assert [data for _, data in framed(0.0010)] == [H("FF 00") + READ]
    assert [data for _, data in framed(0.0016)] == [H("FF 00") + READ]
    assert framed(0.0019)[1:] == [(FrameKind.FRAME, READ)]
    assert [data for _, data in framed(0.0019)] == [H("FF 00"), READ]


# --- the framer


def frames(framer: RtuFramer) -> list[tuple[FrameKind, bytes]]:
    return [(e.kind, e.data) for e in framer.events()]


READ = H("01 03 21 00 00 01 8E 36")
WRITE = H("01 06 20 00 00 01 43 CA")


def test_frame_ends_only_after_t35_of_silence() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ, 1.0)
    framer.tick(1.0 + T35 * 0.99)
    assert framer.next_event() is None
    assert framer.deadline() == pytest.approx(1.0 + T35)
    framer.tick(1.0 + T35)
    event = framer.next_event()
    assert event is not None
    assert (event.kind, event.data, event.t) == (FrameKind.FRAME, READ, 1.0)
    assert framer.deadline() is None


def test_frame_split_into_chunks_is_joined() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ[:3], 1.0)
    framer.feed(READ[3:], 1.0 + 5 * CHAR)  # byte 4 follows byte 3 after one character time
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.FRAME, READ)]


def test_gap_over_t15_inside_a_frame_makes_it_invalid() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ[:3], 1.0)
    framer.feed(READ[3:], 1.0 + 5 * CHAR + T15 * 1.2)
    framer.tick(2.0)
    events = framer.events()
    assert [(e.kind, e.data) for e in events] == [(FrameKind.NOISE, READ)]
    assert "t1.5" in events[0].note


@pytest.mark.parametrize(
    ("silence_chars", "kinds"),
    [
        (0.0, [FrameKind.FRAME]),
        (1.0, [FrameKind.FRAME]),
        (1.4, [FrameKind.FRAME]),
        (1.6, [FrameKind.NOISE]),  # more than 1.5 characters inside a frame: invalid
        (3.0, [FrameKind.NOISE]),
        (3.5, [FrameKind.NOISE, FrameKind.CRC_ERROR]),  # 3.5 characters end the frame: two broken pieces
    ],
)
def test_silence_inside_a_frame_is_measured_between_bytes(silence_chars: float, kinds: list[FrameKind]) -> None:
    # At 9600 baud 8N1 (t1.5 = 1.56 ms, t3.5 = 3.65 ms): the first 3 bytes end at 1.0, then silence, then 5 bytes.
    char = 10 / 9600
    framer = RtuFramer(9600)
    framer.feed(READ[:3], 1.0)
    framer.feed(READ[3:], 1.0 + silence_chars * char + 5 * char)
    framer.tick(2.0)
    assert [e.kind for e in framer.events()] == kinds


def test_gap_between_t15_and_t35_is_tolerated_without_gap_checks() -> None:
    framer = RtuFramer(19200, check_gaps=False)
    framer.feed(READ[:3], 1.0)
    framer.feed(READ[3:], 1.0 + 5 * CHAR + T15 * 1.2)
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.FRAME, READ)]


def test_two_frames_separated_by_silence() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ, 1.0)
    framer.feed(WRITE, 1.0 + 8 * CHAR + T35)  # 8 bytes back to back after t3.5 of silence
    framer.tick(5.0)
    assert frames(framer) == [(FrameKind.FRAME, READ), (FrameKind.FRAME, WRITE)]


def test_back_to_back_frames_are_split() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ + WRITE + READ, 1.0)
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.FRAME, READ), (FrameKind.FRAME, WRITE), (FrameKind.FRAME, READ)]


def test_length_completion_emits_without_silence() -> None:
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(READ[:5], 1.0)
    assert framer.next_event() is None
    framer.feed(READ[5:] + WRITE[:2], 1.0)
    assert frames(framer) == [(FrameKind.FRAME, READ)]
    framer.feed(WRITE[2:], 1.0)
    assert frames(framer) == [(FrameKind.FRAME, WRITE)]


def test_length_completion_of_write_multiple_waits_for_its_byte_count() -> None:
    frame = encode(WriteMultipleRequest(1, 0x2000, (1, 3000)))
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    for i in range(len(frame) - 1):
        framer.feed(frame[i : i + 1], 1.0)
        assert framer.next_event() is None
    framer.feed(frame[-1:], 1.0)
    assert frames(framer) == [(FrameKind.FRAME, frame)]


def test_garbage_before_a_frame_costs_nothing() -> None:
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(H("FF 00 13") + READ, 1.0)
    assert frames(framer) == [(FrameKind.NOISE, H("FF 00 13")), (FrameKind.FRAME, READ)]


def test_bad_crc_frame_then_good_frame_back_to_back() -> None:
    bad = READ[:-1] + b"\x00"
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(bad + WRITE, 1.0)
    events = framer.events()
    assert [(e.kind, e.data) for e in events] == [(FrameKind.CRC_ERROR, bad), (FrameKind.FRAME, WRITE)]
    assert events[0].note == "bad CRC: got 8E 00, expected 8E 36"


def test_bad_crc_alone_waits_for_silence_then_is_reported() -> None:
    bad = READ[:-1] + b"\x00"
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(bad, 1.0)
    assert framer.next_event() is None
    framer.tick(1.0 + T35)
    assert frames(framer) == [(FrameKind.CRC_ERROR, bad)]


def test_truncated_frame_is_a_length_error_and_the_next_frame_survives() -> None:
    framer = RtuFramer(19200)
    framer.feed(READ[:6], 1.0)
    framer.feed(WRITE, 1.0 + 8 * CHAR + T35)
    framer.tick(5.0)
    events = framer.events()
    assert [(e.kind, e.data) for e in events] == [(FrameKind.LENGTH_ERROR, READ[:6]), (FrameKind.FRAME, WRITE)]
    assert events[0].note == "6 bytes, a function 0x03 request has 8"


def test_valid_crc_over_a_wrong_length_is_a_length_error() -> None:
    frame = with_crc(H("01 03 21 00 00 01 00"))
    framer = RtuFramer(19200)
    framer.feed(frame, 1.0)
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.LENGTH_ERROR, frame)]


def test_unknown_function_with_good_crc_is_a_frame_for_the_slave_to_refuse() -> None:
    frame = with_crc(H("01 04 30 00 00 01"))
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(frame, 1.0)
    assert framer.next_event() is None  # its length is unknown: silence ends it
    framer.tick(1.0 + T35)
    assert frames(framer) == [(FrameKind.FRAME, frame)]


def test_short_noise_is_noise() -> None:
    framer = RtuFramer(19200)
    framer.feed(H("00 FF"), 1.0)
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.NOISE, H("00 FF"))]


def test_a_runaway_stream_is_cut_at_the_longest_frame() -> None:
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False)
    framer.feed(bytes([0x01, 0x41]) + bytes(300), 1.0)
    events = framer.events()
    assert sum(len(e.data) for e in events) == 302
    assert all(e.kind is not FrameKind.FRAME for e in events)
    assert not framer.pending


def test_baud_change_changes_the_silence() -> None:
    framer = RtuFramer(19200)
    framer.set_baud(9600)
    framer.feed(READ, 1.0)
    framer.tick(1.0 + T35 * 1.5)  # enough at 19200, not at 9600
    assert framer.next_event() is None
    framer.tick(1.0 + 3.5 * 10 / 9600)
    assert frames(framer) == [(FrameKind.FRAME, READ)]


# --- properties


@settings(max_examples=300, deadline=None)
@given(
    chunks=st.lists(st.binary(min_size=0, max_size=40), max_size=12),
    gaps=st.lists(st.floats(min_value=0, max_value=0.01), min_size=12, max_size=12),
    on_length=st.booleans(),
)
def test_any_byte_stream_never_raises_and_accounts_for_every_byte(
    chunks: list[bytes], gaps: list[float], on_length: bool
) -> None:
    framer = RtuFramer(19200, complete_on_length=on_length, check_gaps=not on_length)
    t = 0.0
    for chunk, gap in zip(chunks, gaps, strict=False):
        t += gap
        framer.feed(chunk, t)
        framer.tick(t)
    framer.flush()
    events = framer.events()
    assert b"".join(e.data for e in events) == b"".join(chunks)
    assert all(e.data for e in events)


requests = st.one_of(
    st.builds(ReadRequest, st.integers(1, 247), st.integers(0, 0xFFFF), st.integers(1, 125)),
    st.builds(WriteSingleRequest, st.integers(1, 247), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF)),
    st.builds(
        WriteMultipleRequest,
        st.integers(1, 247),
        st.integers(0, 0xFFFF),
        st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=20).map(tuple),
    ),
)


@settings(max_examples=300, deadline=None)
@given(garbage=st.binary(max_size=300), request=requests, on_length=st.booleans())
def test_valid_frame_after_garbage_and_silence_is_recovered(garbage: bytes, request: object, on_length: bool) -> None:
    frame = encode(request)  # type: ignore[arg-type]
    framer = RtuFramer(19200, complete_on_length=on_length, check_gaps=not on_length)
    framer.feed(garbage, 1.0)
    start = 1.0 + T35 + len(frame) * CHAR
    framer.feed(frame, start)
    framer.tick(start + T35)
    events = framer.events()
    assert events[-1].kind is FrameKind.FRAME
    assert events[-1].data == frame
    assert decode_request(events[-1].data) == request


@settings(max_examples=200, deadline=None)
@given(request=requests, flip=st.integers(0, 10_000))
def test_a_bit_flip_is_never_taken_for_the_original_frame(request: object, flip: int) -> None:
    frame = bytearray(encode(request))  # type: ignore[arg-type]
    bit = flip % (len(frame) * 8)
    frame[bit // 8] ^= 1 << (bit % 8)
    framer = RtuFramer(19200)
    framer.feed(bytes(frame), 1.0)
    framer.tick(2.0)
    events = framer.events()
    assert b"".join(e.data for e in events) == bytes(frame)
    assert all(e.kind is not FrameKind.FRAME or e.data != encode(request) for e in events)  # type: ignore[arg-type]


# --- the character of the line's format, and strict framing (--line-timing)


def test_a_character_has_the_bits_of_the_lines_format() -> None:
    assert char_bits() == 10  # the sheet's 8N1
    assert (char_bits(8, "E", 1), char_bits(8, "O", 1), char_bits(8, "N", 2)) == (11, 11, 11)
    assert char_time(1200) == pytest.approx(0.0083333, abs=1e-7)  # 8.33 ms a byte at 1200 baud, not 9.17
    assert char_time(1200, char_bits(8, "E", 1)) == pytest.approx(11 / 1200)


@pytest.mark.parametrize(
    ("gap_ms", "kinds"),
    [
        (12.0, [FrameKind.FRAME]),  # under t1.5 = 12.5 ms at 1200 8N1
        (13.0, [FrameKind.NOISE]),  # over t1.5: the frame is invalid (11 bits made t1.5 13.75 ms)
        (26.5, [FrameKind.NOISE]),  # under t3.5 = 29.2 ms: still one (broken) frame, not two
        (30.0, [FrameKind.NOISE, FrameKind.CRC_ERROR]),  # over t3.5: two pieces
    ],
)
def test_gaps_at_1200_baud_are_judged_with_10_bit_characters(gap_ms: float, kinds: list[FrameKind]) -> None:
    char = 10 / 1200
    framer = RtuFramer(1200, strict=True)
    framer.feed(READ[:3], 1.0)
    framer.feed(READ[3:], 1.0 + gap_ms / 1000 + 5 * char)
    framer.tick(5.0)
    assert [e.kind for e in framer.events()] == kinds


def test_strict_back_to_back_requests_are_one_frame_of_the_wrong_length() -> None:
    framer = RtuFramer(19200, strict=True)
    framer.feed(READ + WRITE, 1.0)
    framer.tick(2.0)
    events = framer.events()
    assert [(e.kind, e.data) for e in events] == [(FrameKind.LENGTH_ERROR, READ + WRITE)]
    assert events[0].note == "16 bytes, a function 0x03 request has 8"


def test_strict_back_to_back_in_two_writes_is_still_one_frame() -> None:
    framer = RtuFramer(19200, strict=True)
    framer.feed(READ, 1.0)
    framer.feed(WRITE, 1.0 + 8 * CHAR)  # the second request's first byte right after the first's last
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.LENGTH_ERROR, READ + WRITE)]


def test_strict_garbage_glued_in_front_spoils_the_frame() -> None:
    framer = RtuFramer(19200, strict=True)
    framer.feed(H("FF 00") + READ, 1.0)
    framer.tick(2.0)
    assert frames(framer) == [(FrameKind.CRC_ERROR, H("FF 00") + READ)]


def test_strict_frame_and_unknown_function_frame_pass() -> None:
    unknown = with_crc(H("01 04 30 00 00 01"))
    framer = RtuFramer(19200, strict=True)
    framer.feed(READ, 1.0)
    framer.feed(unknown, 1.0 + 8 * CHAR + T35 + 8 * CHAR)
    framer.tick(5.0)
    assert frames(framer) == [(FrameKind.FRAME, READ), (FrameKind.FRAME, unknown)]


def test_strict_runaway_stream_is_bounded_and_reported_once() -> None:
    framer = RtuFramer(19200, strict=True)
    for i in range(10):
        framer.feed(bytes(100), 1.0 + i * 100 * CHAR)
    assert framer.next_event() is None  # no silence yet
    framer.tick(100.0)
    events = framer.events()
    assert [(e.kind, len(e.data)) for e in events] == [(FrameKind.NOISE, 256)]
    assert events[0].note == "more than 256 bytes without a silence of t3.5"


def test_strict_cannot_complete_on_length() -> None:
    with pytest.raises(ValueError, match="cannot complete on length"):
        RtuFramer(19200, strict=True, complete_on_length=True)


@settings(max_examples=200, deadline=None)
@given(
    chunks=st.lists(st.binary(min_size=0, max_size=80), max_size=12),
    gaps=st.lists(st.floats(0, 0.01), min_size=12, max_size=12),
)
def test_strict_framer_never_raises_and_never_splits_without_silence(chunks: list[bytes], gaps: list[float]) -> None:
    framer = RtuFramer(19200, strict=True)
    t = 0.0
    for chunk, gap in zip(chunks, gaps, strict=False):
        t += gap + len(chunk) * CHAR
        framer.feed(chunk, t)
        framer.tick(t)
    framer.flush()
    events = framer.events()
    assert all(0 < len(e.data) <= 256 for e in events)
    assert sum(len(e.data) for e in events) <= sum(len(c) for c in chunks)


def test_strict_silence_is_known_one_character_after_t35() -> None:
    # A byte that started just inside t3.5 arrives whole one character later: it still belongs to the frame.
    framer = RtuFramer(1200, strict=True)
    char, (_, t35) = 10 / 1200, silence_times(1200)
    framer.feed(H("FF 00"), 1.0)
    assert framer.deadline() == pytest.approx(1.0 + t35 + char)
    framer.tick(1.0 + t35 + 0.5 * char)
    assert framer.next_event() is None
    framer.feed(READ[:1], 1.0 + 0.0265 + char)  # 26.5 ms of silence, then a byte
    framer.feed(READ[1:], 1.0 + 0.0265 + 8 * char)
    framer.tick(5.0)
    assert [e.kind for e in framer.events()] == [FrameKind.NOISE]  # one frame, broken by a gap over t1.5


@pytest.mark.parametrize(
    ("request_len", "reply_len", "baud", "bits", "turnaround", "expected_us"),
    [
        # a one-register read at 19200 8N1: 8 + 7 characters of 10 bits, a t3.5 of 3.5 characters before each
        (8, 7, 19200, 10, 0.0, (8 + 3.5 + 7 + 3.5) * 10 / 19200 * 1e6),
        # the drive's turnaround sits between the request and the reply
        (8, 7, 19200, 10, 0.002, ((8 + 3.5 + 7 + 3.5) * 10 / 19200 + 0.002) * 1e6),
        # 8E1 is 11 bits a character
        (8, 7, 9600, 11, 0.0, (8 + 3.5 + 7 + 3.5) * 11 / 9600 * 1e6),
        # above 19200 baud t3.5 is fixed at 1.75 ms (Modbus over Serial Line V1.02, 2.5.1.1)
        (8, 7, 57600, 10, 0.0, ((8 + 7) * 10 / 57600 + 2 * 0.00175) * 1e6),
        # a broadcast has no reply: the request and its t3.5 only, no turnaround
        (8, 0, 19200, 10, 0.002, (8 + 3.5) * 10 / 19200 * 1e6),
    ],
)
def test_a_transaction_holds_the_line_for_its_characters_and_silences(
    request_len: int, reply_len: int, baud: int, bits: int, turnaround: float, expected_us: float
) -> None:
    got = transaction_time(request_len, reply_len, baud, bits, turnaround)
    assert got * 1e6 == pytest.approx(expected_us, abs=1e-6)


def test_a_19200_line_carries_about_86_single_register_reads_a_second() -> None:
    assert int(1 / transaction_time(8, 7, 19200)) == 87  # the "about 86": 87.27 with no turnaround


def _framed(chunks: list[bytes]) -> list[tuple[FrameKind, bytes, float]]:
    framer = stream_framer(19200)
    for chunk in chunks:
        framer.feed(chunk, 1.0)
    framer.flush()
    return [(e.kind, e.data, e.t) for e in framer.events()]


_WHOLE_READS = [
    encode(ReadRequest(1, 0x2001, 1)),
    encode(WriteSingleRequest(1, 0x2001, 1500)),
    encode(WriteMultipleRequest(1, 0x2000, (1, 1500))),
    H("01 03 20 01 00 01 DE 0B"),  # a bad CRC
    encode(ReadRequest(1, 0x2001, 1))[:-1],  # cut short
    encode(ReadRequest(1, 0x2001, 1)) + encode(ReadRequest(2, 0x2100, 1)),  # two in one read
    encode(ReadRequest(1, 0x2001, 1)) + b"\x00",  # a byte glued behind
    encode(UnsupportedRequest(1, 0x04, H("20 00 00 01"))),  # a function the C20 lacks
]


@pytest.mark.parametrize("data", _WHOLE_READS, ids=lambda d: d.hex(" "))
def test_a_whole_read_frames_as_the_same_bytes_through_the_buffer(data: bytes) -> None:
    # A read holding exactly one whole request skips the buffer (the common case on TCP); anything else takes
    # the buffer's way. Either way the events are those of the same bytes fed in two pieces (which always go
    # through the buffer).
    assert _framed([data]) == _framed([data[:1], data[1:]])
    if data == _WHOLE_READS[0]:
        assert _framed([data]) == [(FrameKind.FRAME, data, 1.0)]


_A_FRAME = st.one_of(
    st.builds(
        lambda s, r, c: encode(ReadRequest(s, r, c)), st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 130)
    ),
    st.builds(
        lambda s, r, v: encode(WriteSingleRequest(s, r, v)),
        st.integers(0, 255),
        st.integers(0, 0xFFFF),
        st.integers(0, 0xFFFF),
    ),
    st.builds(
        lambda s, r, v: encode(WriteMultipleRequest(s, r, tuple(v))),
        st.integers(0, 255),
        st.integers(0, 0xFFFF),
        st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=6),
    ),
)
#: whole frames (most reads on TCP), frames with a byte or two before or after, or cut, and random bytes
_A_READ = st.one_of(
    _A_FRAME,
    st.builds(lambda a, f, b: a + f + b, st.binary(max_size=2), _A_FRAME, st.binary(max_size=2)),
    st.builds(lambda f, n: f[:n], _A_FRAME, st.integers(1, 12)),
    st.binary(min_size=1, max_size=40),
)


@given(_A_READ)
@settings(max_examples=600, deadline=None)
def test_any_read_frames_as_the_same_bytes_through_the_buffer(data: bytes) -> None:
    assert _framed([data]) == _framed([data[:1], data[1:]])


def test_without_the_compiled_crc_the_table_is_used() -> None:
    # A plain install (no c20sim[fast]): the import of fastcrc fails and crc16 is the table, with no error.
    code = (
        "import sys; sys.modules['fastcrc'] = None\n"
        "from c20sim.wire.protocol import crc16, crc16_table, with_crc\n"
        "assert crc16 is crc16_table, crc16\n"
        "print(with_crc(bytes.fromhex('01 06 20 00 00 01')).hex())\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert (result.returncode, result.stdout, result.stderr) == (0, "01062000000143ca\n", "")

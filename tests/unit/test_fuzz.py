"""Fuzzing the pure core: framer, bus and slaves with real drive models, on virtual time.

Random, truncated, bit-flipped and concatenated frames go in, split at random
and fed with random gaps. Whatever arrives, no exception escapes the framer or
:meth:`Bus.handle`; every reply is a well-formed frame with a good CRC from the
drive that was addressed; a broadcast is never answered; and a valid request
after any garbage and a t3.5 silence gets exactly the reply a clean bus gives.

``bench/fuzz.py`` runs the same properties for longer. The properties live in
this module as plain functions so that both share them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from c20sim.core.bus import Reply
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.framing import RtuFramer
from c20sim.wire.protocol import (
    BROADCAST,
    FrameEvent,
    FrameKind,
    ReadRequest,
    ReadResponse,
    Request,
    UnsupportedRequest,
    WriteMultipleRequest,
    WriteSingleRequest,
    crc_ok,
    decode_request,
    decode_response,
    encode,
    silence_times,
)
from c20sim.wire.registers import Reg

#: The drives on the fuzzed bus.
ADDRESSES = (1, 2, 5)
BAUD = 19200
T15, T35 = silence_times(BAUD)
CHAR = 10 / BAUD  # 8N1
#: Silence that ends a frame on the TCP-style framer.
TCP_SILENCE = 0.02

_PROFILE: Profile | None = None


def profile() -> Profile:
    global _PROFILE
    if _PROFILE is None:
        _PROFILE = load_profile()
    return _PROFILE


def new_sim(seed: int = 1) -> Simulator:
    return Simulator(profile(), ADDRESSES, clock=VirtualClock(), seed=seed)


def new_framer(tcp: bool) -> RtuFramer:
    if tcp:
        return RtuFramer(BAUD, complete_on_length=True, check_gaps=False, silence=TCP_SILENCE)
    return RtuFramer(BAUD)


def silence(tcp: bool) -> float:
    return TCP_SILENCE if tcp else T35


# --- strategies

#: Registers worth hitting: the fixed map, a few function codes, and addresses not in the map.
_REGISTERS = st.one_of(
    st.sampled_from([int(r) for r in Reg]),
    st.sampled_from([0x0000, 0x0001, 0x000A, 0x000B, 0x0700, 0x0800, 0x0801]),
    st.integers(0, 0xFFFF),
)
_SLAVES = st.one_of(st.sampled_from([*ADDRESSES, BROADCAST]), st.integers(0, 255))

requests: st.SearchStrategy[Request] = st.one_of(
    st.builds(ReadRequest, _SLAVES, _REGISTERS, st.integers(0, 130)),
    st.builds(WriteSingleRequest, _SLAVES, _REGISTERS, st.integers(0, 0xFFFF)),
    st.builds(
        WriteMultipleRequest,
        _SLAVES,
        _REGISTERS,
        st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=8).map(tuple),
    ),
    st.builds(
        WriteMultipleRequest,
        _SLAVES,
        _REGISTERS,
        st.lists(st.integers(0, 0xFFFF), min_size=0, max_size=4).map(tuple),
        st.integers(0, 200),
        st.integers(0, 255),
    ),
    st.builds(UnsupportedRequest, _SLAVES, st.integers(0, 255), st.binary(max_size=8)),
)

#: Requests a drive answers normally: reads and writes of the fixed registers that do not move the bus.
_QUIET_REGISTERS = [int(r) for r in Reg if r not in (Reg.ADDRESS, Reg.BAUD)]
answered_requests: st.SearchStrategy[Request] = st.one_of(
    st.builds(ReadRequest, st.sampled_from(ADDRESSES), st.sampled_from(_QUIET_REGISTERS), st.just(1)),
    st.builds(
        WriteSingleRequest,
        st.sampled_from(ADDRESSES),
        st.sampled_from([Reg.SPEED_SETPOINT, Reg.ACCEL_TIME, Reg.DECEL_TIME, Reg.WRITE_ENABLE]),
        st.integers(0, 6000),
    ),
)


@st.composite
def mangled(draw: st.DrawFn) -> bytes:
    """One piece of a stream: a valid frame, or one truncated, bit-flipped, or random bytes."""
    kind = draw(st.sampled_from(["valid", "truncated", "flipped", "random", "extended"]))
    if kind == "random":
        return draw(st.binary(min_size=1, max_size=40))
    frame = bytearray(encode(draw(requests)))
    if kind == "truncated":
        return bytes(frame[: draw(st.integers(1, max(1, len(frame) - 1)))])
    if kind == "flipped":
        for _ in range(draw(st.integers(1, 3))):
            bit = draw(st.integers(0, len(frame) * 8 - 1))
            frame[bit // 8] ^= 1 << (bit % 8)
    if kind == "extended":
        frame += draw(st.binary(min_size=1, max_size=6))
    return bytes(frame)


@dataclass(frozen=True)
class Piece:
    data: bytes
    gap: float  #: silence before this piece, in seconds
    splits: tuple[int, ...]  #: where the piece is cut into separately fed chunks


@st.composite
def streams(draw: st.DrawFn) -> list[Piece]:
    pieces = draw(st.lists(mangled(), min_size=1, max_size=8))
    out = []
    for data in pieces:
        gap = draw(st.sampled_from([0.0, 0.0, T15 / 2, T15 * 1.2, T35, 0.03]))
        splits = tuple(sorted(draw(st.lists(st.integers(1, max(1, len(data) - 1)), max_size=3))))
        out.append(Piece(data, gap, splits))
    return out


# --- properties, shared with bench/fuzz.py


def addresses(sim: Simulator) -> set[int]:
    return {slave.address for slave in sim.bus.slaves}


def check_reply(event: FrameEvent, reply: Reply | None, before: set[int]) -> None:
    """A reply is a good frame from the addressed drive; a broadcast or noise gets none.

    ``before``: the drives' addresses before the event was served (a write to
    2008H is answered from the old address).
    """
    if reply is None:
        return
    assert event.data, "a reply to nothing"
    address = event.data[0]
    assert address != BROADCAST, f"broadcast answered: {event}"
    assert event.kind is not FrameKind.NOISE, f"noise answered: {event}"
    assert crc_ok(reply.data), f"reply with a bad CRC: {reply.data.hex(' ')}"
    assert reply.data[0] == address == reply.slave
    assert address in before, f"reply from {address}, drives at {sorted(before)}"
    response = decode_response(reply.data)  # raises if not a well-formed C20 reply
    assert response.function & 0x7F == event.data[1] & 0x7F
    if event.kind is FrameKind.FRAME:
        request = decode_request(event.data)
        assert response.slave == request.slave
    else:
        assert response.function == (event.data[1] & 0x7F) | 0x80  # exception 0x06 to a broken frame


def feed_stream(sim: Simulator, framer: RtuFramer, pieces: list[Piece], t: float) -> tuple[float, int]:
    """Feed ``pieces`` with their gaps and splits, serving every event; returns (time, replies)."""
    replies = 0

    def serve() -> None:
        nonlocal replies
        for event in framer.events():
            before = addresses(sim)
            reply = sim.bus.handle(event, event.t)
            check_reply(event, reply, before)
            replies += reply is not None

    for piece in pieces:
        t += piece.gap
        framer.tick(t)
        serve()
        bounds = (0, *piece.splits, len(piece.data))
        for start, end in itertools.pairwise(bounds):
            chunk = piece.data[start:end]
            if not chunk:
                continue
            t += len(chunk) * CHAR
            framer.feed(chunk, t)
            serve()
    t += 1.0
    framer.tick(t)
    serve()
    assert not framer.pending
    return t, replies


def check_stream(pieces: list[Piece], tcp: bool, seed: int = 1) -> None:
    """Property: a stream of anything is served without an exception, every reply well formed."""
    sim = new_sim(seed)
    feed_stream(sim, new_framer(tcp), pieces, 1.0)


def check_recovery(garbage: bytes, request: Request, tcp: bool) -> None:
    """Property: after garbage and silence, a valid request gets exactly the reply of a clean bus."""
    sim, clean = new_sim(), new_sim()
    framer = new_framer(tcp)
    valid_inside = 0
    t = 1.0
    framer.feed(garbage, t)
    framer.tick(t + silence(tcp))
    for event in framer.events():
        before = addresses(sim)
        check_reply(event, sim.bus.handle(event, event.t), before)
        if event.kind is FrameKind.FRAME:
            clean.bus.handle(event, event.t)  # a valid frame inside the garbage acts on both buses
            valid_inside += 1
    frame = encode(request)
    t += silence(tcp) + 0.01 + len(frame) * CHAR
    framer.feed(frame, t)
    framer.tick(t + silence(tcp))
    events = framer.events()
    assert [(e.kind, e.data) for e in events] == [(FrameKind.FRAME, frame)]
    before = addresses(sim)
    reply = sim.bus.handle(events[0], t)
    expected = clean.bus.handle(FrameEvent(FrameKind.FRAME, frame, t), t)
    assert reply == expected
    if valid_inside == 0:
        assert reply is not None  # a valid frame inside the garbage may have moved the drive (2008H)
    check_reply(events[0], reply, before)


# --- the tests: modest example counts for CI; bench/fuzz.py runs them for longer

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(pieces=streams(), tcp=st.booleans(), seed=st.integers(0, 2**16))
def test_any_stream_is_served_without_exception_and_replies_are_well_formed(
    pieces: list[Piece], tcp: bool, seed: int
) -> None:
    check_stream(pieces, tcp, seed)


@FAST
@given(garbage=st.binary(max_size=300), request=answered_requests, tcp=st.booleans())
def test_a_valid_request_after_garbage_gets_the_clean_reply(garbage: bytes, request: Request, tcp: bool) -> None:
    check_recovery(garbage, request, tcp)


@FAST
@given(pieces=st.lists(mangled(), min_size=1, max_size=6), request=answered_requests, tcp=st.booleans())
def test_a_valid_request_after_mangled_frames_gets_the_clean_reply(
    pieces: list[bytes], request: Request, tcp: bool
) -> None:
    check_recovery(b"".join(pieces), request, tcp)


@FAST
@given(request=requests, tcp=st.booleans())
def test_any_single_request_is_served_and_broadcast_is_silent(request: Request, tcp: bool) -> None:
    sim = new_sim()
    framer = new_framer(tcp)
    frame = encode(request)
    framer.feed(frame, 1.0)
    framer.tick(1.0 + silence(tcp))
    events = framer.events()
    assert b"".join(e.data for e in events) == frame
    before = addresses(sim)
    replies = [(e, sim.bus.handle(e, e.t)) for e in events]
    for event, reply in replies:
        check_reply(event, reply, before)
    if request.slave == BROADCAST:
        assert all(reply is None for _, reply in replies)


def test_the_reply_check_catches_a_wrong_address() -> None:
    # The property must be able to fail: a reply from another drive is refused.
    sim = new_sim()
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    event = FrameEvent(FrameKind.FRAME, frame, 1.0)
    reply = sim.bus.handle(event, 1.0)
    assert reply is not None
    forged = Reply(encode(ReadResponse(2, (3,))), reply.delay, 2, reply.baud)
    try:
        check_reply(event, forged, addresses(sim))
    except AssertionError:
        return
    raise AssertionError("check_reply accepted a reply from drive 2 to a request for drive 1")


def test_a_reply_to_an_address_change_comes_from_the_old_address() -> None:
    # Found by bench/fuzz.py: write 2008H = 4 to drive 1 is answered from address 1, which then no longer exists.
    sim = new_sim()
    frame = encode(WriteSingleRequest(1, Reg.ADDRESS, 4))
    before = addresses(sim)
    event = FrameEvent(FrameKind.FRAME, frame, 1.0)
    reply = sim.bus.handle(event, 1.0)
    assert reply is not None and reply.data == frame
    assert addresses(sim) == {4, 2, 5}
    check_reply(event, reply, before)


def test_recovery_after_garbage_holding_an_address_change() -> None:
    # Found by bench/fuzz.py: the garbage held a valid write 2008H = 2 to drive 1; both buses then stay silent.
    check_recovery(bytes.fromhex("01 06 20 08 00 02 82 09"), ReadRequest(1, Reg.COMMAND, 1), tcp=False)


def test_valid_frames_inside_a_stream_are_all_answered() -> None:
    # Concatenated valid frames with silences between them: every one is answered.
    sim = new_sim()
    frames = [encode(ReadRequest(a, Reg.STATUS1, 1)) for a in ADDRESSES]
    pieces = [Piece(b"\x01\x03\x21", 0.0, ()), *(Piece(f, 0.03, (3,)) for f in frames)]
    _, replies = feed_stream(sim, new_framer(tcp=False), pieces, 1.0)
    assert replies == len(frames)

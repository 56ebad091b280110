"""`c20sim serve --pty --line-timing`, held to the sheet's timing: behaviours that load cannot turn into failures.

The server runs as its own process (the real CLI). The master writes whole
pieces of a request at once (a piece written at once cannot be split by the
kernel, and its bytes reach the simulator together) and chooses the silences
between pieces so that a busy machine can only make a test slower, never fail
it:

- a silence that must split a request, or split a request off garbage, is
  200 ms at 1200 baud (t3.5 and a character: 37.5 ms): a master running late
  only lengthens it, and only the pty delivering the piece before it 160 ms
  late, together with the piece after, could join them (its lateness is
  milliseconds: up to 2 ms idle, p99 2-5 ms loaded, docs/line-timing.md; a
  silence between t1.5 and t3.5, 24 ms at most, was once joined so at load 5,
  and is left to the bench and the framer's unit tests);
- what must be answered is written whole;
- times are lower bounds: a reply never starts before t3.5 and one character
  (or the turnaround, if longer) after the request, and its k-th byte never
  comes before k characters more. Load only delays replies.

The fine figures (byte spacing within a fraction of a character, a reply's
start within 1 ms of its ideal, t1.5 judged at 0.64 and 1.28 x t1.5) are
measured and recorded by ``bench/bench_line_timing.py``, not asserted here.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    encode,
    expected_length,
)
from tests.conftest import wait_for_ready_file

pytestmark = pytest.mark.serial  # the pty's silences and gaps are real time: .ci/run runs it alone

READ = encode(ReadRequest(1, 0x2103, 1))  # read the drive ID
READ2 = encode(ReadRequest(2, 0x2103, 1))
ID_REPLY = encode(ReadResponse(1, (0x0020,)))
TURNAROUND = 0.002  # the default profile's
#: what a lower bound on a reply's time leaves for rounding (the master's clock and the server's are the same)
TOLERANCE = 0.0002
#: a reply not come this long after it is due is not coming (far beyond any reply's time at any baud)
REPLY_WAIT = 2.0
EXTRA: list[str] = []  # more serve options, for a diagnosis by hand


@dataclass
class Master:
    """A master on the pty of a line-timed server at ``baud`` (``bits`` a character: 10 for 8N1)."""

    fd: int
    baud: int
    bits: int = 10

    # The sheet's figures, written out here rather than taken from c20sim (which they check).

    @property
    def char(self) -> float:
        return self.bits / self.baud

    @property
    def t15(self) -> float:
        return 1.5 * self.char if self.baud <= 19200 else 0.00075

    @property
    def t35(self) -> float:
        return 3.5 * self.char if self.baud <= 19200 else 0.00175

    @property
    def earliest_start(self) -> float:
        """The least time from a request's last byte to its reply's first: t3.5 is known only once a character
        more has gone by with nothing (a byte is seen when it has arrived whole), and the turnaround runs from the
        frame's end; the later of the two."""
        return self.t35 + max(self.char, TURNAROUND)

    def send(self, *pieces: bytes, silence: float = 0.0) -> float:
        """Write each piece at once, with at least ``silence`` seconds of silence before each piece after the first,
        as the simulator counts it (from the previous piece's arrival to this piece's first byte, a piece taking its
        length in characters). Returns the time before the last piece was written: it cannot have arrived earlier."""
        self.drain()
        before = time.perf_counter()
        for i, piece in enumerate(pieces):
            if i:
                due = before + silence + len(piece) * self.char
                while (left := due - time.perf_counter()) > 0:
                    time.sleep(left)
                before = time.perf_counter()
            os.write(self.fd, piece)
        return before

    def receive(self, deadline: float) -> tuple[bytes, list[float]]:
        """One reply, as far as it came before ``deadline`` (perf_counter), with each byte's arrival time."""
        data = b""
        stamps: list[float] = []
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                return data, stamps
            ready, _, _ = select.select([self.fd], [], [], left)
            now = time.perf_counter()
            if not ready:
                return data, stamps
            chunk = os.read(self.fd, 1)
            data += chunk
            stamps.append(now)
            want = expected_length(data, "response")
            if want is not None and len(data) >= want:
                return data, stamps

    def ask(self, *pieces: bytes, silence: float = 0.0) -> tuple[bytes, list[float], float]:
        """Send the pieces and wait for a reply: (reply, byte times, when the last piece was written)."""
        end = self.send(*pieces, silence=silence)
        reply, stamps = self.receive(end + self.earliest_start + REPLY_WAIT)
        self.quiet()
        return reply, stamps, end

    def quiet(self) -> None:
        """Stay silent for t3.5 and a character, twice over, so that the next request is a frame of its own."""
        time.sleep(2 * (self.t35 + self.char))

    def drain(self) -> None:
        while select.select([self.fd], [], [], 0)[0]:
            if not os.read(self.fd, 4096):
                return


def _server(tmp: Path, baud: int, drives: str = "1") -> Iterator[Master]:
    ready = tmp / f"ready-{baud}.json"
    ready.unlink(missing_ok=True)
    command = [sys.executable, "-m", "c20sim", "serve", "--pty", "--line-timing", "--baud", str(baud)]
    proc = subprocess.Popen(
        [*command, "--drives", drives, "--ready-file", str(ready), *EXTRA],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        fd = os.open(wait_for_ready_file(ready, proc, 30)["pty"], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(fd)
        try:
            master = Master(fd, baud)
            # The first request of a fresh server is served late (imports, the model's first step): warm it up.
            reply, _ = master.receive(master.send(READ) + 10.0)
            assert reply == ID_REPLY, reply.hex(" ")
            master.quiet()
            yield master
        finally:
            os.close(fd)
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.fixture(scope="module")
def m1200(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Master]:
    yield from _server(tmp_path_factory.mktemp("lt"), 1200, "1,2")


@pytest.fixture(scope="module")
def m19200(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Master]:
    yield from _server(tmp_path_factory.mktemp("lt"), 19200)


# --- bytes not separated by t3.5 are one frame

FRAME_ERROR = encode(ExceptionResponse(1, 0x03, ExceptionCode.FRAME_ERROR))


@pytest.mark.parametrize(
    ("run", "why"),
    [(READ + READ, "twice to one drive"), (READ + READ2, "to drives 1 and 2")],
)
def test_two_requests_with_no_silence_between_are_one_frame_answered_0x06(m1200: Master, run: bytes, why: str) -> None:
    # Sheet: "if the time interval between two characters is more than 3.5 times, it is considered that one
    # frame of data has been transmitted". Without that silence the 16 bytes are one frame of the wrong length.
    replies = [m1200.ask(run)[0] for _ in range(5)]
    assert replies == [FRAME_ERROR] * 5, f"{why}: {[r.hex(' ') for r in replies]}"
    assert m1200.ask(READ)[0] == ID_REPLY  # and no second reply was waiting: the next answer is the next request's


def test_garbage_glued_in_front_of_a_frame_spoils_it(m1200: Master) -> None:
    # FF is a reserved address: the spoilt frame gets silence; 01 in front makes it drive 1's, with a bad CRC: 0x06.
    assert [m1200.ask(b"\xff\x00" + READ)[0] for _ in range(5)] == [b""] * 5
    spoilt = encode(ExceptionResponse(1, 0x01, ExceptionCode.FRAME_ERROR))  # 01 01 03 ...: function 01 as sent
    assert [m1200.ask(b"\x01" + READ)[0] for _ in range(5)] == [spoilt] * 5
    assert m1200.ask(READ)[0] == ID_REPLY


def test_a_frame_after_a_long_silence_is_a_frame_of_its_own(m1200: Master) -> None:
    # Garbage, then 200 ms of silence (five times t3.5 + a character: 37.5 ms), then a request.
    replies = [m1200.ask(b"\xff\x00", READ, silence=0.200)[0] for _ in range(5)]
    assert replies == [ID_REPLY] * 5, [r.hex(" ") for r in replies]


# --- a silence inside a request splits it: never served


def test_a_request_with_a_long_silence_inside_is_never_served(m1200: Master) -> None:
    # 200 ms before the last byte: two frames, the first 7 bytes answered 0x06 (a frame of drive 1 of the wrong
    # length), the last byte noise. A silence between t1.5 and t3.5 (a broken frame, discarded in silence) is
    # judged by the bench and the framer's unit tests, not here: a pty can deliver two pieces written up to
    # ~12 ms apart together on a loaded machine (seen once in 50 trials at load 5 on 2 cores), joining them.
    replies = [m1200.ask(READ[:-1], READ[-1:], silence=0.200)[0] for _ in range(5)]
    assert replies == [FRAME_ERROR] * 5, [r.hex(" ") for r in replies]
    assert m1200.ask(READ)[0] == ID_REPLY  # the line is not left broken


# --- replies: never before t3.5, never faster than the line


def _never_early(master: Master, trials: int) -> None:
    early: list[str] = []
    for trial in range(trials):
        reply, stamps, end = master.ask(READ)
        assert reply == ID_REPLY, f"trial {trial}: {reply.hex(' ')}"
        for k, stamp in enumerate(stamps):
            due = master.earliest_start + k * master.char
            if stamp - end < due - TOLERANCE:
                early.append(f"trial {trial} byte {k}: {(stamp - end) * 1000:.2f} ms, due {due * 1000:.2f} ms")
    assert not early, f"{len(early)} reply bytes came before their time: {early[:5]}"


def test_a_reply_at_1200_baud_is_never_early_nor_faster_than_the_line(m1200: Master) -> None:
    # The first byte at t3.5 (29.2 ms) + a character (8.33 ms) after the request, each next one a character later.
    # t3.5 counted as 3.0 characters would start it at 33.3 ms; 9-bit characters would bring the last byte early.
    _never_early(m1200, 10)


def test_a_reply_at_19200_baud_is_never_early_nor_faster_than_the_line(m19200: Master) -> None:
    _never_early(m19200, 20)


# --- a serial port: the character of its own format


def _serial_server(tmp: Path, parity: str) -> Iterator[Master]:
    """A line-timed simulator on a serial port, here the far end of a pty: this master holds the other end."""
    ours, theirs = os.openpty()
    tty.setraw(ours)
    tty.setraw(theirs)
    ready = tmp / "ready-serial.json"
    ready.unlink(missing_ok=True)
    device = os.ttyname(theirs)
    command = [sys.executable, "-m", "c20sim", "serve", "--serial", device, "--parity", parity, "--line-timing"]
    proc = subprocess.Popen(
        [*command, "--baud", "1200", "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        wait_for_ready_file(ready, proc, 30)
        os.set_blocking(ours, False)
        master = Master(ours, 1200, 10 if parity == "N" else 11)  # start, 8 data, parity, stop
        reply, _ = master.receive(master.send(READ) + 10.0)
        assert reply == ID_REPLY, reply.hex(" ")
        master.quiet()
        yield master
    finally:
        proc.terminate()
        proc.wait(10)
        os.close(ours)
        os.close(theirs)


@pytest.fixture(scope="module")
def serial_8e1(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Master]:
    yield from _serial_server(tmp_path_factory.mktemp("lt"), "E")


def test_a_serial_ports_t35_follows_its_parity(serial_8e1: Master) -> None:
    # 8E1 at 1200 baud: 11-bit characters (9.17 ms), t3.5 = 32.1 ms: a reply starts 41.3 ms after the request
    # at the earliest; with the sheet's 10-bit character it would start at 37.5 ms. (A pty here, not a UART:
    # the reply's bytes come at once, so only its start is bounded.)
    assert serial_8e1.bits == 11
    early: list[float] = []
    for _ in range(10):
        reply, stamps, end = serial_8e1.ask(READ)
        assert reply == ID_REPLY, reply.hex(" ")
        if stamps[0] - end < serial_8e1.earliest_start - TOLERANCE:
            early.append(stamps[0] - end)
    assert not early, f"replies started {[round(s * 1000, 2) for s in early]} ms after the request: before 41.25 ms"

"""The answer delay F08.04 (issue 42; INVT P14.03), written over the bus, on the line-timed pty.

`c20sim serve --pty --line-timing` as its own process; the master on the pty writes 200EH = 1 and F08.04,
then times its reads: a reply's first byte comes the request's time on the line, t3.5, the answer delay and
one character after the request's last byte is written (the profile's 2 ms turnaround while F08.04 is below
it). Each setting's reply starts within 1 ms of when
it is due, and the shift between two settings is their difference within 1 ms (the median of nine reads each, so one late
wake-up of a loaded machine does not decide it); every single reply is no earlier than its delay allows.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterator

import pytest

from c20sim.wire.protocol import WriteSingleRequest, encode
from tests.integration.test_line_timing import ID_REPLY, READ, TOLERANCE, Master, _server

pytestmark = pytest.mark.serial  # each reply's start within 1 ms of its due time: .ci/run runs it alone

F08_04 = 0x0804


@pytest.fixture(scope="module")
def master(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Master]:
    yield from _server(tmp_path_factory.mktemp("ad"), 19200)


def set_delay(m: Master, ms: int) -> None:
    for address, value in ((0x200E, 1), (F08_04, ms)):
        request = encode(WriteSingleRequest(1, address, value))
        reply, _, _ = m.ask(request)
        assert reply == request, reply.hex(" ")  # a 0x06 write is echoed


def start_offsets(m: Master, delay: float) -> list[float]:
    """Nine reads: from each request's last byte written to its reply's first byte."""
    out = []
    for _ in range(9):
        reply, stamps, end = m.ask(READ)
        assert reply == ID_REPLY
        offset = stamps[0] - end
        assert offset >= m.t35 + delay - TOLERANCE  # never early
        out.append(offset)
    return out


def test_the_answer_delay_written_over_the_bus_moves_the_reply_by_that_much(master: Master) -> None:
    # F08.04 = 0 as shipped: the 2 ms turnaround, and no earlier (how much later is the machine's load: the
    # reply is due before a loaded machine has it ready, so it is not the zero to measure shifts from).
    start_offsets(master, 0.002)
    medians = {}
    for ms in (20, 60, 150):
        set_delay(master, ms)
        medians[ms] = statistics.median(start_offsets(master, ms / 1000))
        # Due within 1 ms of: the request's own time on the line (the pty hands its bytes over at once; the
        # line-timed pty counts them as the wire would carry them), then t3.5, then the delay, then the reply's
        # first character (a byte is handed over when its character has ended, as a serial chip does).
        due = len(READ) * master.char + master.t35 + ms / 1000 + master.char
        assert medians[ms] == pytest.approx(due, abs=0.001), ms
    assert medians[150] - medians[20] == pytest.approx(0.130, abs=0.001)
    assert medians[60] - medians[20] == pytest.approx(0.040, abs=0.001)
    set_delay(master, 1)  # below the drive's own 2 ms turnaround: the turnaround
    start_offsets(master, 0.002)


def test_out_of_range_is_refused(master: Master) -> None:
    request = encode(WriteSingleRequest(1, 0x200E, 1))
    assert master.ask(request)[0] == request
    reply, _, _ = master.ask(encode(WriteSingleRequest(1, F08_04, 201)))
    assert reply[1] == 0x86, reply.hex(" ")  # an exception: beyond INVT's 0-200 ms

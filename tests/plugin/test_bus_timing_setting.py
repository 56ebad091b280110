"""The test handle's ``bus_timing`` setting: on by default, as ``c20sim serve``; off where asked; checked.

Judged by what a master meets on the wire: a Modbus TCP master that sends four requests at once (the gateway
takes up to four in flight) at 1200 baud, where one transaction holds an RS485 line for about 130 ms. With bus
timing each request waits for the line, and the frame log puts each one on the line after the last
transaction's time; without it they are served as they arrive.
"""

from __future__ import annotations

import itertools
import socket
import struct

import pytest

from c20sim.core.bus import Direction, RecordKind
from c20sim.testing import C20Sim, check_settings
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import SHEET_CHAR_BITS, transaction_time
from c20sim.wire.registers import Reg

#: one register read at 1200 8N1 (2009H = 0): the line's time, the drive's turnaround left out (a lower bound)
AT_1200 = transaction_time(8, 7, 1200, SHEET_CHAR_BITS)


def mbap(transaction: int, pdu: bytes, unit: int = 1) -> bytes:
    return struct.pack(">HHHB", transaction, 0, len(pdu) + 1, unit) + pdu


def receive(sock: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = sock.recv(size - len(data))
        assert chunk, "the gateway closed the connection"
        data += chunk
    return data


def four_at_once_at_1200_baud(sim: C20Sim) -> list[float]:
    """The frame log's times of four reads a Modbus TCP master sent in one segment, the drive at 1200 baud."""
    assert sim.host is not None and sim.port is not None  # the Modbus TCP endpoint (transport="modbus-tcp")
    with socket.create_connection((sim.host, sim.port), timeout=10) as sock:
        sock.sendall(mbap(1, struct.pack(">BHH", 0x06, Reg.BAUD, 0)))  # 2009H = 0: 1200 baud, after this reply
        assert receive(sock, 12) == mbap(1, struct.pack(">BHH", 0x06, Reg.BAUD, 0))
        sim.clear_frames()
        read = struct.pack(">BHH", 0x03, Reg.STATUS1, 1)
        sock.sendall(b"".join(mbap(n, read) for n in range(2, 6)))
        replies = receive(sock, 4 * 11)
    assert [struct.unpack_from(">H", replies, 11 * k)[0] for k in range(4)] == [2, 3, 4, 5]
    requests = [r for r in sim.frames() if r.direction is Direction.RX and r.kind is RecordKind.REQUEST]
    assert len(requests) == 4
    return [r.t for r in requests]


def test_the_handle_holds_the_line_by_default() -> None:
    assert check_settings({}).bus_timing is True
    with C20Sim.start(transport="modbus-tcp") as sim:
        times = four_at_once_at_1200_baud(sim)
    gaps = [later - earlier for earlier, later in itertools.pairwise(times)]
    assert all(gap >= AT_1200 for gap in gaps), (gaps, AT_1200)  # each waited for the last one's line time


def test_a_bad_bus_timing_says_what_is_wrong() -> None:
    with pytest.raises(C20SimError, match=r"^c20sim: bus_timing 'yes': give True or False$"):
        check_settings({"bus_timing": "yes"})


@pytest.mark.c20sim(bus_timing=False, transport="modbus-tcp")
def test_the_marker_turns_it_off(c20sim: C20Sim) -> None:
    times = four_at_once_at_1200_baud(c20sim)
    # served as they came, in one go: all four inside the time the line would have held for one of them
    assert times[-1] - times[0] < AT_1200, (times, AT_1200)

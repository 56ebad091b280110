"""The transports' own link faults: a reply in two pieces, and a Modbus TCP reply under another transaction id
before the right one."""

from __future__ import annotations

import socket
import struct
from collections.abc import Iterator

import pytest

from c20sim.testing import C20Sim
from c20sim.wire.protocol import crc16

pytestmark = pytest.mark.serial  # the split reply's two pieces 0.2 s apart in real time: .ci/run runs it alone


def _read(register: int) -> bytes:
    body = struct.pack(">BBHH", 1, 3, register, 1)
    return body + crc16(body).to_bytes(2, "little")


@pytest.fixture
def sim() -> Iterator[C20Sim]:
    handle = C20Sim.start(transport=("tcp", "modbus-tcp"), clock="realtime")
    yield handle
    handle.close()


def _connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def test_an_rtu_reply_split_in_two_comes_in_two_pieces(sim: C20Sim) -> None:
    assert sim.port is not None
    sim.link_faults(split=0.2, replies=1)
    with _connect(sim.port) as s:
        s.sendall(_read(0x2103))
        first = s.recv(64)
        rest = s.recv(64)
        assert len(first) == 3 and first + rest == bytes.fromhex("01 03 02 00 20") + crc16(
            bytes.fromhex("01 03 02 00 20")
        ).to_bytes(2, "little")
        s.sendall(_read(0x2103))  # the fault was for one reply: the next comes whole
        assert len(s.recv(64)) == 7


def test_a_modbus_tcp_reply_under_another_id_comes_first(sim: C20Sim) -> None:
    assert sim.modbus_tcp_port is not None
    sim.link_faults(wrong_transaction=0.2, replies=1)
    with _connect(sim.modbus_tcp_port) as s:
        s.sendall(struct.pack(">HHHBBHH", 0x0102, 0, 6, 1, 3, 0x2103, 1))
        got = b""
        while len(got) < 22:
            got += s.recv(64)
        (wrong, _, _, _), (right, _, _, _) = struct.unpack_from(">HHHB", got), struct.unpack_from(">HHHB", got, 11)
        assert (wrong, right) == (0x0102 ^ 0x5A5A, 0x0102)
        assert got[7:11] == got[18:22] == bytes.fromhex("03 02 00 20")


def test_a_modbus_tcp_reply_split_in_two_segments(sim: C20Sim) -> None:
    assert sim.modbus_tcp_port is not None
    sim.link_faults(split=0.2, replies=1)
    with _connect(sim.modbus_tcp_port) as s:
        s.sendall(struct.pack(">HHHBBHH", 7, 0, 6, 1, 3, 0x2103, 1))
        first = s.recv(64)
        rest = s.recv(64)
        assert first == struct.pack(">HHHB", 7, 0, 5, 1) and rest == bytes.fromhex("03 02 00 20")


def test_pipelined_modbus_tcp_replies_never_go_between_a_split_replys_two_segments(sim: C20Sim) -> None:
    """Three requests sent at once, the replies split: each reply's MBAP header is followed by its own PDU, the
    next reply after it (the second and third replies came between the first's two segments: header, header,
    header, then the PDUs: a corrupt stream)."""
    assert sim.modbus_tcp_port is not None
    sim.link_faults(split=0.05)
    requests = b"".join(struct.pack(">HHHBBHH", tid, 0, 6, 1, 3, 0x2103, 1) for tid in (1, 2, 3))
    with _connect(sim.modbus_tcp_port) as s:
        s.sendall(requests)
        data = b""
        while len(data) < 3 * 11:  # three ADUs of 11 bytes: a one-register read's reply
            chunk = s.recv(4096)
            assert chunk, data.hex(" ")
            data += chunk
    adus = [struct.unpack_from(">HHHBBB", data, i) for i in range(0, 33, 11)]
    assert [(tid, proto, length, unit, function, count) for tid, proto, length, unit, function, count in adus] == [
        (1, 0, 5, 1, 3, 2),
        (2, 0, 5, 1, 3, 2),
        (3, 0, 5, 1, 3, 2),
    ], data.hex(" ")

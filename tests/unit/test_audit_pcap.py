"""Packet captures read as frames: Modbus TCP and RTU over TCP, pcap and pcapng, retransmissions, frames split
and joined across segments, and one line for a capture c20sim cannot read."""

from __future__ import annotations

import io
import json
from pathlib import Path

import dpkt
import pytest

from c20sim.cli import main
from c20sim.traffic.pcap import read_capture
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import ReadRequest, ReadResponse, encode, with_crc
from c20sim.wire.registers import Reg

MASTER, DRIVE = (b"\x7f\x00\x00\x01", 40000), (b"\x7f\x00\x00\x01", 502)
REQUEST = encode(ReadRequest(1, Reg.STATUS1, 1))
REPLY = encode(ReadResponse(1, (5,)))


def segment(src: tuple[bytes, int], dst: tuple[bytes, int], seq: int, data: bytes = b"", flags: int = 0x18) -> bytes:
    tcp = dpkt.tcp.TCP(sport=src[1], dport=dst[1], seq=seq, ack=1, flags=flags, data=data)
    ip = dpkt.ip.IP(src=src[0], dst=dst[0], p=dpkt.ip.IP_PROTO_TCP, data=tcp)
    ip.len = len(bytes(ip))
    return bytes(dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x00" * 6, type=dpkt.ethernet.ETH_TYPE_IP, data=ip))


def mbap(transaction: int, rtu: bytes) -> bytes:
    """The Modbus TCP form of an RTU frame: the MBAP header, the unit id and the PDU (no CRC)."""
    body = rtu[:-2]
    return transaction.to_bytes(2, "big") + b"\x00\x00" + len(body).to_bytes(2, "big") + body


def capture(packets: list[tuple[float, bytes]], *, ng: bool = False) -> bytes:
    out = io.BytesIO()
    writer = dpkt.pcapng.Writer(out) if ng else dpkt.pcap.Writer(out)
    for ts, packet in packets:
        writer.writepkt(packet, ts=ts)
    return out.getvalue()


def handshake() -> list[tuple[float, bytes]]:
    return [
        (0.0, segment(MASTER, DRIVE, 99, flags=dpkt.tcp.TH_SYN)),
        (0.0001, segment(DRIVE, MASTER, 499, flags=dpkt.tcp.TH_SYN | dpkt.tcp.TH_ACK)),
    ]


def test_rtu_over_tcp_with_a_retransmission_and_frames_split_and_joined() -> None:
    packets = handshake()
    packets += [
        (1.0, segment(MASTER, DRIVE, 100, REQUEST[:3])),  # a frame split over two segments
        (1.0005, segment(MASTER, DRIVE, 103, REQUEST[3:])),
        (1.0005, segment(MASTER, DRIVE, 103, REQUEST[3:])),  # retransmitted: read once
        (1.003, segment(DRIVE, MASTER, 500, REPLY)),
        (1.1, segment(MASTER, DRIVE, 108, REQUEST + REQUEST)),  # two frames in one segment
    ]
    frames = list(read_capture(io.BytesIO(capture(packets)), "x.pcap"))
    assert frames == [(1.0005, "rx", REQUEST), (1.003, "tx", REPLY), (1.1, "rx", REQUEST), (1.1, "rx", REQUEST)]


def test_modbus_tcp_becomes_rtu_frames_in_pcapng() -> None:
    packets = handshake()
    packets += [
        (2.0, segment(MASTER, DRIVE, 100, mbap(7, REQUEST))),
        (2.002, segment(DRIVE, MASTER, 500, mbap(7, REPLY))),
    ]
    frames = list(read_capture(io.BytesIO(capture(packets, ng=True)), "x.pcapng"))
    assert frames == [(2.0, "rx", REQUEST), (2.002, "tx", with_crc(REPLY[:-2]))]


def test_a_capture_begun_mid_connection_needs_the_server_port(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "mid.pcap"
    path.write_bytes(
        capture([(1.0, segment(MASTER, DRIVE, 100, REQUEST)), (1.003, segment(DRIVE, MASTER, 500, REPLY))])
    )
    assert main(["audit", str(path)]) == 2
    assert capsys.readouterr().err == (
        f"c20sim: {path}: the capture starts after the connection 127.0.0.1:40000 - 127.0.0.1:502 was opened, so "
        "which side is the master is unknown; give --server-port (the drive's or the gateway's port)\n"
    )
    assert main(["audit", str(path), "--server-port", "502", "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == 2


def test_a_fast_poller_in_a_capture(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    packets = handshake()
    for k in range(300):
        t = 1.0 + k / 100
        packets += [
            (t, segment(MASTER, DRIVE, 100 + 8 * k, REQUEST)),
            (t + 0.002, segment(DRIVE, MASTER, 500 + 7 * k, REPLY)),
        ]
    path = tmp_path / "fast.pcap"
    path.write_bytes(capture(packets))
    assert main(["audit", str(path), "--format", "json"]) == 1
    (finding,) = json.loads(capsys.readouterr().out)["findings"]
    assert (finding["rule"], round(finding["value"])) == ("line-demand", 134)


def test_a_damaged_capture_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    packets = [*handshake(), (1.0, segment(MASTER, DRIVE, 100, REQUEST))]
    path = tmp_path / "cut.pcap"
    path.write_bytes(capture(packets)[:-5])
    assert main(["audit", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"c20sim: {path}: ")


def connection(port: int, seq: int, t: float) -> list[tuple[float, bytes]]:
    """The SYN and SYN-ACK of a master's connection from ``port``: its first byte is ``seq`` + 1."""
    master = (MASTER[0], port)
    return [
        (t, segment(master, DRIVE, seq, flags=dpkt.tcp.TH_SYN)),
        (t + 0.0001, segment(DRIVE, master, 499, flags=dpkt.tcp.TH_SYN | dpkt.tcp.TH_ACK)),
    ]


def test_a_master_stopped_with_a_reply_in_flight(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The capture of issue 45's user: an ``mbpoll -l 100`` loop stopped with ``kill`` (its FIN, the drive's reply
    of 11 bytes to its last request, then its RST as the socket is gone), then three one-shot mbpolls, each on its
    own connection closed by a FIN each way. Every reply is the drive's, the one after the master's FIN too."""
    loop = (MASTER[0], 40586)
    packets = connection(40586, 99, 0.0)
    frames: list[tuple[float, str, bytes]] = []
    reply = with_crc(REPLY[:-2])
    for k in range(20):
        t, answer = 1.0 + k / 10, 1.002 + k / 10
        packets += [(t, segment(loop, DRIVE, 100 + 12 * k, mbap(k, REQUEST)))]
        frames.append((t, "rx", REQUEST))
        if k < 19:
            packets += [(answer, segment(DRIVE, loop, 500 + 11 * k, mbap(k, REPLY)))]
            frames.append((answer, "tx", reply))
    assert len(mbap(19, REPLY)) == 11
    packets += [
        (2.9005, segment(loop, DRIVE, 100 + 12 * 20, flags=dpkt.tcp.TH_FIN | dpkt.tcp.TH_ACK)),
        (2.902, segment(DRIVE, loop, 500 + 11 * 19, mbap(19, REPLY))),
        (2.9021, segment(loop, DRIVE, 100 + 12 * 20 + 1, flags=dpkt.tcp.TH_RST)),
    ]
    frames.append((2.902, "tx", reply))
    for n, port in enumerate((40590, 40592, 40594)):
        start = 5.0 + n
        one = (MASTER[0], port)
        packets += connection(port, 999, start)
        packets += [
            (start + 0.001, segment(one, DRIVE, 1000, mbap(1, REQUEST))),
            (start + 0.003, segment(DRIVE, one, 500, mbap(1, REPLY))),
            (start + 0.004, segment(one, DRIVE, 1012, flags=dpkt.tcp.TH_FIN | dpkt.tcp.TH_ACK)),
            (start + 0.0041, segment(DRIVE, one, 511, flags=dpkt.tcp.TH_FIN | dpkt.tcp.TH_ACK)),
            (start + 0.0042, segment(one, DRIVE, 1013, flags=dpkt.tcp.TH_ACK)),
        ]
        frames += [(start + 0.001, "rx", REQUEST), (start + 0.003, "tx", reply)]
    path = tmp_path / "cap.pcap"
    path.write_bytes(capture(packets))
    with path.open("rb") as f:
        read = list(read_capture(f, str(path)))
    assert [(d, b) for _, d, b in read] == [(d, b) for _, d, b in frames]
    assert [t for t, _, _ in read] == pytest.approx([t for t, _, _ in frames], abs=1e-6)  # microseconds
    assert main(["audit", str(path), "--format", "json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["frames"], report["findings"]) == (46, [])


def test_bytes_after_a_reset_are_the_ended_connections_not_a_capture_begun_mid_connection(tmp_path: Path) -> None:
    """A master that resets its connection with a reply in flight: the reply after the RST is not read (the master
    never took it), and the capture is read on, not refused as begun after the connection was opened."""
    packets = [
        *handshake(),
        (1.0, segment(MASTER, DRIVE, 100, REQUEST)),
        (1.001, segment(MASTER, DRIVE, 108, flags=dpkt.tcp.TH_RST)),
        (1.003, segment(DRIVE, MASTER, 500, REPLY)),
        *connection(40002, 99, 2.0),
        (2.001, segment((MASTER[0], 40002), DRIVE, 100, REQUEST)),
        (2.003, segment(DRIVE, (MASTER[0], 40002), 500, REPLY)),
    ]
    path = tmp_path / "reset.pcap"
    path.write_bytes(capture(packets))
    with path.open("rb") as f:
        read = list(read_capture(f, str(path)))
    assert [(d, b) for _, d, b in read] == [("rx", REQUEST), ("rx", REQUEST), ("tx", REPLY)]
    assert [t for t, _, _ in read] == pytest.approx([1.0, 2.001, 2.003], abs=1e-6)


def test_a_connection_not_seen_to_open_is_still_refused_without_the_server_port(tmp_path: Path) -> None:
    """Only a connection seen to end is known: bytes of another, never opened in the capture, still need it."""
    packets = [
        *handshake(),
        (1.0, segment(MASTER, DRIVE, 100, REQUEST)),
        (1.001, segment(MASTER, DRIVE, 108, flags=dpkt.tcp.TH_RST)),
        (1.5, segment(DRIVE, (MASTER[0], 40004), 500, REPLY)),
    ]
    path = tmp_path / "other.pcap"
    path.write_bytes(capture(packets))
    with path.open("rb") as f, pytest.raises(C20SimError, match="the capture starts after the connection"):
        list(read_capture(f, str(path)))

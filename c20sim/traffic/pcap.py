"""Packet captures of Modbus on TCP, read as frames: pcap and pcapng from tcpdump or Wireshark.

The packets are parsed by dpkt (a well-kept parser of the capture formats and
of Ethernet, Linux cooked, loopback and IP headers); this module only follows
each TCP connection's bytes in order and cuts them into frames. A connection
is Modbus TCP (an MBAP header: transaction id, protocol 0, length, unit) or
RTU over TCP (RTU frames with their CRC), told apart by its first bytes; a
Modbus TCP frame is turned into the RTU frame the gateway hands the drives
(unit, PDU, CRC), so the audit judges both alike.

The master is the side that opened the connection (its SYN); a capture that
begins after the connection was opened needs ``server_port``. A connection is
followed until both sides have sent their FIN or one has reset it, so a reply
the drive sends after the master's FIN (a master stopped with a request in
flight) is still read as the drive's; bytes on a connection after it ended
(a reply to a master that reset it first) are not read, and the capture is
read on. The capture is
read a packet at a time and every buffer is bounded, so memory stays bounded
whatever the capture's length.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import IO, Any

from ..wire.errors import C20SimError
from ..wire.protocol import MAX_ADU, crc_ok, expected_length, with_crc

__all__ = ["MAGICS", "is_capture", "read_capture"]

#: The first four bytes of a pcap (either byte order, micro- or nanoseconds) and of a pcapng file.
MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d", b"\x0a\x0d\x0d\x0a")
#: The most TCP connections followed at once; beyond, new ones are not followed.
MAX_FLOWS = 1024
#: The most bytes a connection's direction holds waiting for the rest of a frame.
MAX_PENDING = 2 * MAX_ADU + 16
_MBAP = 7  # transaction id, protocol id, length, unit id


def is_capture(head: bytes) -> bool:
    """True if a file starting with ``head`` is a pcap or pcapng capture."""
    return head[:4] in MAGICS


@dataclass
class _Half:
    """One direction of a TCP connection: the next sequence number expected and the bytes not yet a frame."""

    next_seq: int | None = None
    pending: bytearray = field(default_factory=bytearray)
    finished: bool = False  #: this side sent its FIN: it sends no more, though the other side may


@dataclass
class _Flow:
    master_end: tuple[bytes, int]  #: the master's address and port
    kind: str = ""  #: "mbap" or "rtu", from the first bytes
    halves: dict[bool, _Half] = field(default_factory=lambda: {True: _Half(), False: _Half()})


def read_capture(stream: IO[bytes], where: str, server_port: int | None = None) -> Iterator[tuple[float, str, bytes]]:
    """The Modbus frames of a capture, one at a time: (time, ``rx`` from the master or ``tx`` to it, RTU bytes)."""
    import dpkt  # a dependency of c20sim; imported here, as only captures need it

    try:
        reader: Any = dpkt.pcap.UniversalReader(stream)
    except (ValueError, dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError) as exc:
        raise C20SimError(f"{where}: not a pcap or pcapng capture ({exc})") from None
    link = reader.datalink()
    decoders = {
        dpkt.pcap.DLT_EN10MB: dpkt.ethernet.Ethernet,
        dpkt.pcap.DLT_LINUX_SLL: dpkt.sll.SLL,
        dpkt.pcap.DLT_LINUX_SLL2: dpkt.sll2.SLL2,
        dpkt.pcap.DLT_NULL: dpkt.loopback.Loopback,
        dpkt.pcap.DLT_LOOP: dpkt.loopback.Loopback,
    }
    if link not in decoders and link not in (dpkt.pcap.DLT_RAW, 101):
        raise C20SimError(
            f"{where}: link type {link} is not one c20sim reads; capture on Ethernet, loopback or any (Linux cooked)"
        )
    decode = decoders.get(link)
    flows: dict[tuple[Any, ...], _Flow] = {}
    ended: dict[tuple[Any, ...], None] = {}  # the connections that ended, newest last (at most MAX_FLOWS)
    try:
        for ts, buf in reader:
            try:
                packet = decode(buf).data if decode is not None else dpkt.ip.IP(buf)
            except (dpkt.dpkt.UnpackError, dpkt.dpkt.NeedData, struct.error):
                continue  # a packet cut short by the snap length, or not IP
            segment = getattr(packet, "data", None)
            if not isinstance(segment, dpkt.tcp.TCP):
                continue
            yield from _segment(flows, ended, float(ts), packet, segment, server_port, where)
    except (dpkt.dpkt.NeedData, dpkt.dpkt.UnpackError, ValueError) as exc:
        raise C20SimError(f"{where}: the capture is cut short or damaged ({exc})") from None


def _segment(
    flows: dict[tuple[Any, ...], _Flow],
    ended: dict[tuple[Any, ...], None],
    t: float,
    packet: Any,
    segment: Any,
    server_port: int | None,
    where: str,
) -> Iterator[tuple[float, str, bytes]]:
    import dpkt

    if server_port is not None and server_port not in (segment.sport, segment.dport):
        return  # another conversation than the one asked for
    ends = ((bytes(packet.src), segment.sport), (bytes(packet.dst), segment.dport))
    key = tuple(sorted(ends))
    flags = segment.flags
    syn, ack = bool(flags & dpkt.tcp.TH_SYN), bool(flags & dpkt.tcp.TH_ACK)
    fin, rst = bool(flags & dpkt.tcp.TH_FIN), bool(flags & dpkt.tcp.TH_RST)
    flow = flows.get(key)
    if flow is None or (syn and not ack):
        if fin or rst or len(flows) >= MAX_FLOWS or (key in ended and not syn):
            return  # a connection's end, or bytes after it (a reply to a master that reset it): nothing to read
        if syn:
            master_end = ends[0] if not ack else ends[1]  # the SYN's sender opened the connection: the master
        elif server_port is not None:
            master_end = ends[1] if segment.sport == server_port else ends[0]
        elif not segment.data:
            return
        else:
            raise C20SimError(
                f"{where}: the capture starts after the connection {_end(ends[0])} - {_end(ends[1])} was opened, so "
                "which side is the master is unknown; give --server-port (the drive's or the gateway's port)"
            )
        ended.pop(key, None)  # a new connection on the same ports
        flow = flows[key] = _Flow(master_end)
    master = ends[0] == flow.master_end
    half = flow.halves[master]
    if syn:
        half.next_seq = (segment.seq + 1) & 0xFFFFFFFF
    data = bytes(segment.data)
    if data:
        if half.next_seq is not None:
            offset = (segment.seq - half.next_seq) & 0xFFFFFFFF
            if offset >= 0x80000000:  # a retransmission: skip the bytes had already
                behind = (half.next_seq - segment.seq) & 0xFFFFFFFF
                data = data[behind:] if behind < len(data) else b""
            elif offset:
                half.pending.clear()  # bytes the capture missed: start again at this segment
        if data:
            half.next_seq = (segment.seq + len(segment.data)) & 0xFFFFFFFF
            if not flow.kind:
                flow.kind = "mbap" if _looks_mbap(data) else "rtu"
            half.pending += data
            direction = "rx" if master else "tx"
            for frame in _frames(half, flow.kind, master):
                yield t, direction, frame
            if len(half.pending) > MAX_PENDING:
                half.pending.clear()  # not Modbus: drop it rather than hold it
    # a connection lives until both sides are done (a FIN each way) or it is reset: after the master's FIN
    # (a master stopped mid-poll) the drive's reply still in flight is the drive's, on this connection
    if fin:
        half.finished = True
    if rst or (flow.halves[True].finished and flow.halves[False].finished):
        del flows[key]
        ended[key] = None
        if len(ended) > MAX_FLOWS:
            del ended[next(iter(ended))]


def _end(end: tuple[bytes, int]) -> str:
    address, port = end
    if len(address) == 4:
        return f"{'.'.join(str(b) for b in address)}:{port}"
    return f"[{address.hex()}]:{port}"


def _looks_mbap(data: bytes) -> bool:
    """An MBAP header: protocol id 0 and a length that fits; and the bytes are not an RTU frame with its CRC."""
    if len(data) < 8 or data[2:4] != b"\x00\x00":
        return False
    length = struct.unpack_from(">H", data, 4)[0]
    if not 2 <= length <= 254:
        return False
    rtu = expected_length(data, "request")
    return not (rtu is not None and len(data) >= rtu and crc_ok(data[:rtu]))


def _frames(half: _Half, kind: str, master: bool) -> Iterator[bytes]:
    pending = half.pending
    while pending:
        if kind == "mbap":
            if len(pending) < _MBAP:
                return
            length = struct.unpack_from(">H", pending, 4)[0]
            if length < 2 or pending[2:4] != b"\x00\x00":
                pending.clear()
                return
            if len(pending) < 6 + length:
                return
            adu = bytes(pending[6 : 6 + length])  # unit id + PDU
            del pending[: 6 + length]
            yield with_crc(adu)
        else:
            size = expected_length(bytes(pending[:7]), "request" if master else "response")
            if size is None:
                if len(pending) >= 7 or (len(pending) >= 2 and not _known(pending[1], master)):
                    frame = bytes(pending)  # a function c20sim does not frame: the whole segment is one frame
                    pending.clear()
                    yield frame
                return
            if len(pending) < size:
                return
            frame = bytes(pending[:size])
            del pending[:size]
            yield frame


def _known(function: int, master: bool) -> bool:
    return function in (3, 6, 16) or (not master and bool(function & 0x80))

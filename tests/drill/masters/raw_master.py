"""A reference master for the drill's tests, on raw sockets (or a pty), in three styles.

    python raw_master.py careful|hasty|naive|stormy --tcp HOST:PORT | --modbus-tcp HOST:PORT | --pty PATH

Every style polls drive 1 every 100 ms with a 250 ms timeout and, at start, writes the speed reference
(2001H = 1500) and runs the drive (2000H = 1).

- careful: polls 2100H (status) and 3006H (speed); takes only a reply that checks (CRC, its address, its
  function, its own echo skipped, its own transaction id), retries a failed request after its timeout at most
  3 times, backs off (200 ms, 400 ms) while the drive is silent; on a fault reads 2102H, sends no run command,
  resets once (then not again for 3 s); a drive found stopped gets 2001H again, then the run command. On the
  first sight of a fault it reads the fault record (F07.27, and the frequency, current and bus voltage at the
  trip: F07.33, F07.36, F07.37) and the drive's automatic reset (F08.28, F08.29): while the drive will reset
  itself, its own reset waits for F08.29 and 0.5 s more.
- hasty: as careful, but on a fault it reads 2102H and the drive's F08.28/F08.29, not the record, and resets at
  once whatever the drive's automatic reset (the careful master of before the fault record and the automatic reset).
- naive: polls 3006H and writes 2000H = 1 every cycle (a run command kept asserted), takes whatever bytes come
  as the reply (no check at all, over Modbus TCP any transaction id), never retries, never reads the status or fault code, never writes 2001H again.
- stormy: polls like careful and checks replies, but retries a failed request at once (on a broken reply
  without waiting for its timeout) and without end, its retries waiting only 5 ms for an answer.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import socket
import struct
import sys
import termios
import time
import tty

PERIOD = 0.1
TIMEOUT = 0.25
SLAVE = 1
#: What a careful master reads on the first sight of a fault: the record (F07.27 the fault; F07.33, F07.36, F07.37
#: the running frequency, current and bus voltage at it), then F08.28 (automatic resets) and F08.29 (their interval).
RECORD = (0x071B, 0x0721, 0x0724, 0x0725)
AUTO_TRIALS, AUTO_INTERVAL = 0x081C, 0x081D


def crc16(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(body: bytes) -> bytes:
    return body + crc16(body).to_bytes(2, "little")


def read_request(register: int) -> bytes:
    return with_crc(struct.pack(">BBHH", SLAVE, 3, register, 1))


def write_request(register: int, value: int) -> bytes:
    return with_crc(struct.pack(">BBHH", SLAVE, 6, register, value))


class Link:
    """A byte stream to the drive: RTU frames over TCP or a pty, or Modbus TCP (MBAP) frames."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.mbap = args.modbus_tcp is not None
        self.tid = 0
        if args.pty:
            self.fd = os.open(args.pty, os.O_RDWR | os.O_NOCTTY)
            tty.setraw(self.fd)
            attrs = termios.tcgetattr(self.fd)
            attrs[4] = attrs[5] = termios.B19200
            termios.tcsetattr(self.fd, termios.TCSANOW, attrs)
            self.sock = None
        else:
            host, port = (args.tcp or args.modbus_tcp).rsplit(":", 1)
            self.sock = socket.create_connection((host, int(port)))
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.fd = self.sock.fileno()

    def send(self, frame: bytes) -> None:
        if self.mbap:
            self.tid = (self.tid + 1) & 0xFFFF
            pdu = frame[1:-2]
            frame = struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, frame[0]) + pdu
        os.write(self.fd, frame)

    def recv(self, deadline: float) -> bytes:
        """Bytes that come before ``deadline`` (b"" if none)."""
        wait = deadline - time.monotonic()
        if wait <= 0:
            return b""
        ready, _, _ = select.select([self.fd], [], [], wait)
        if not ready:
            return b""
        data = os.read(self.fd, 512)
        if not data and self.sock is not None:
            sys.exit("the drive closed the connection")
        return data

    def flush(self) -> None:
        while select.select([self.fd], [], [], 0)[0]:
            if not os.read(self.fd, 512):
                return

    def unwrap(self, buffer: bytes, any_id: bool = False) -> tuple[bytes | None, bytes]:
        """Modbus TCP: the RTU-like frame of the first whole MBAP frame with its own id (others dropped), or of
        any id (``any_id``: the naive master)."""
        while len(buffer) >= 7:
            tid, _, length, unit = struct.unpack_from(">HHHB", buffer)
            if len(buffer) < 6 + length:
                return None, buffer
            pdu, buffer = buffer[7 : 6 + length], buffer[6 + length :]
            if tid == self.tid or any_id:
                return with_crc(bytes((unit,)) + pdu), buffer
        return None, buffer


def expected_length(request: bytes) -> int:
    return 7 if request[1] == 3 else 8


class Master:
    def __init__(self, link: Link, style: str) -> None:
        self.link, self.style = link, style

    def ask(self, request: bytes, timeout: float = TIMEOUT) -> bytes | None:
        """One attempt: the checked reply (careful, stormy) or whatever came (naive); None if none."""
        link = self.link
        link.flush() if self.style != "naive" else None
        link.send(request)
        deadline = time.monotonic() + timeout
        buffer = b""
        while True:
            data = link.recv(deadline)
            if not data:
                return None if self.style != "naive" or len(buffer) < 5 else buffer
            buffer += data
            if link.mbap:
                frame, buffer = link.unwrap(buffer, self.style == "naive")
                if frame is None:
                    continue
                if self.style == "naive" or (frame[0] == SLAVE and frame[1] & 0x7F == request[1]):
                    return frame
                continue
            if self.style == "naive":
                if len(buffer) >= expected_length(request):
                    return buffer[: expected_length(request)]
                continue
            if len(buffer) > len(request) and buffer.startswith(request):  # our own echo, then the reply
                buffer = buffer[len(request) :]
            if len(buffer) >= 5 and buffer[1] & 0x80 and crc16(buffer[:5]) == 0 and buffer[0] == SLAVE:
                return buffer[:5]
            n = expected_length(request)
            if len(buffer) >= n:
                frame = buffer[:n]
                if crc16(frame) == 0 and frame[0] == SLAVE and frame[1] == request[1]:
                    return frame
                if self.style == "stormy":
                    return None  # broken or not ours: ask again at once
                buffer = b""  # not ours, or broken: discarded; wait on for our own

    def transact(self, request: bytes) -> bytes | None:
        if self.style == "naive":
            return self.ask(request)
        reply = self.ask(request)
        tries = 0
        while reply is None or (reply[1] & 0x80 and reply[2] == 0x06):
            if self.style == "careful":
                if tries >= 3:
                    return None
                if reply is not None:
                    time.sleep(0.02)  # a frame error: the line was answered; send it again after a breath
            tries += 1
            reply = self.ask(request, TIMEOUT if self.style == "careful" else 0.005)
        return reply


def value(reply: bytes | None) -> int | None:
    if reply is None or len(reply) < 5 or reply[1] & 0x80:
        return None
    return int(struct.unpack_from(">H", reply, 3)[0])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("style", choices=("careful", "hasty", "naive", "stormy"))
    parser.add_argument("--tcp")
    parser.add_argument("--modbus-tcp")
    parser.add_argument("--pty")
    args = parser.parse_args()
    master = Master(Link(args), "careful" if args.style == "hasty" else args.style)
    master.transact(write_request(0x2001, 1500))
    master.transact(write_request(0x2000, 1))
    next_reset = 0.0
    fault_seen = False
    silent = 0
    cycle = time.monotonic()
    while True:
        if args.style == "naive":
            master.transact(read_request(0x3006))
            master.transact(write_request(0x2000, 1))
        else:
            status = value(master.transact(read_request(0x2100)))
            speed = master.transact(read_request(0x3006))
            if status is None and speed is None:
                silent += 1
                if args.style == "careful":
                    time.sleep(min(0.4, 0.1 * 2**silent))  # back off while the drive is silent
            else:
                silent = 0
            if status == 4:  # fault
                master.transact(read_request(0x2102))
                if not fault_seen:  # the record for the alarm screen; wait for the drive's own reset if it has one
                    fault_seen = True
                    for register in RECORD if args.style != "hasty" else ():
                        master.transact(read_request(register))
                    trials = value(master.transact(read_request(AUTO_TRIALS)))
                    interval = value(master.transact(read_request(AUTO_INTERVAL)))
                    if trials and interval is not None and args.style != "hasty":
                        next_reset = max(next_reset, time.monotonic() + interval / 10 + 0.5)
                if time.monotonic() >= next_reset:
                    master.transact(write_request(0x2000, 7))
                    next_reset = time.monotonic() + 3.0
            elif status is not None:
                fault_seen = False
            if status == 3:  # stopped (a reset, a power cycle): the speed reference again, then run
                master.transact(write_request(0x2001, 1500))
                master.transact(write_request(0x2000, 1))
        cycle += PERIOD
        pause = cycle - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        else:
            cycle = time.monotonic()


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        main()

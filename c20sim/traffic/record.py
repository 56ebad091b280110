"""``c20sim record``: a pass-through sniffer between a master and a drive, writing the JSONL frame log.

The master talks to the sniffer (a serial port, a pty it creates, or raw RTU
over TCP); the sniffer talks to the drive (a serial port). Every byte is
passed on at once, unchanged, both ways; on the side, each direction is cut
into frames by the protocol (a request's length from its function code, a
reply's from its byte count, the CRC deciding, broken bytes ended by 20 ms of
silence) and written as one JSON line per frame, in the format of
``serve --log-frames``: ``t`` (seconds since the recording began, at the
frame's last byte), ``dir`` (``rx`` master to drive, ``tx`` drive to master),
``hex``, ``kind``, ``slave``, ``text`` (in words, with the profile's register
names) and ``note``. ``c20sim replay`` and ``c20sim decode`` read it.
Recording stops at SIGINT or SIGTERM (exit 0), or when a serial port or the
pty is lost (an adapter unplugged: exit 1, the log kept).

The serial settings are fixed for the session: a baud change by 2009H is
passed on, but the sniffer's ports keep the baud they were opened at.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import sys
from pathlib import Path
from typing import IO, Any, Literal

from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..transport.endpoint import UNTIMED_SILENCE
from ..transport.passthrough import PtySide, SerialSide, Side, TcpSide
from ..wire.decode import decode_frame, describe
from ..wire.errors import C20SimError
from ..wire.framing import RtuFramer
from ..wire.protocol import FrameEvent, FrameKind, Request, decode_request, decode_response
from ..wire.registers import BAUD_RATES, RegisterMap

__all__ = ["Recorder", "add_record_command"]

#: Records written before ``--max-records`` stops the log (the bytes are still passed on).
DEFAULT_MAX_RECORDS = 1_000_000

#: MiB of log written before ``--max-mb`` stops it (the bytes are still passed on): a day of a busy line.
DEFAULT_MAX_MB = 256.0

#: Noise no longer than this is one record as a frame is, its bytes spaced and described; longer noise, and
#: noise that goes on, is logged compactly: its bytes in one run of hex, up to :data:`NOISE_RUN` bytes a record
#: (about 2 bytes of log a byte of noise, where a record a broken piece took 3.4).
NOISE_SHORT = 16
NOISE_RUN = 4096


#: Each direction of the log, and how its frames are cut: the master sends requests, the drive replies.
_SIDES: tuple[tuple[str, Literal["request", "response"]], ...] = (("rx", "request"), ("tx", "response"))


class Recorder:
    """Frames both directions of a master-drive conversation and writes each frame as a JSON line."""

    def __init__(
        self,
        out: IO[str],
        registers: RegisterMap,
        baud: int,
        *,
        max_records: int = DEFAULT_MAX_RECORDS,
        max_mb: float = DEFAULT_MAX_MB,
    ):
        self.out = out
        self.registers = registers
        self.max_records = max_records
        self.max_mb = max_mb
        self.max_bytes = int(max_mb * 1024 * 1024)
        self.records = 0
        self.bytes = 0  #: bytes of log written
        self.full = False
        #: noise being gathered into one compact record, by direction: (its bytes, the time of its last byte)
        self._noise: dict[str, tuple[bytearray, float]] = {}
        self.t0 = 0.0
        self._last_request: Request | None = None
        self.framers = {
            direction: RtuFramer(
                baud, direction=side, complete_on_length=True, check_gaps=False, silence=UNTIMED_SILENCE
            )
            for direction, side in _SIDES
        }
        self._timers: dict[str, asyncio.TimerHandle] = {}

    def start(self) -> None:
        self.t0 = asyncio.get_running_loop().time()

    def heard(self, direction: str, data: bytes) -> None:
        """Bytes seen going ``direction`` (rx: from the master, tx: from the drive), arriving now."""
        loop = asyncio.get_running_loop()
        framer = self.framers[direction]
        framer.feed(data, loop.time() - self.t0)
        self._drain(direction)
        timer = self._timers.pop(direction, None)
        if timer is not None:
            timer.cancel()
        deadline = framer.deadline()
        if deadline is not None:
            self._timers[direction] = loop.call_at(deadline + self.t0, self._silence, direction)
        elif direction in self._noise:  # noise gathered, nothing half-framed: silence ends the noise too
            self._timers[direction] = loop.call_later(UNTIMED_SILENCE, self._silence, direction)

    def _silence(self, direction: str) -> None:
        self._timers.pop(direction, None)
        self.framers[direction].tick(asyncio.get_running_loop().time() - self.t0)
        self._drain(direction)
        self._end_noise(direction)

    def flush(self) -> None:
        for direction, framer in self.framers.items():
            framer.flush()
            self._drain(direction)
            self._end_noise(direction)
        for timer in self._timers.values():
            timer.cancel()
        self._timers.clear()

    def _drain(self, direction: str) -> None:
        for event in self.framers[direction].events():
            if event.kind is FrameKind.FRAME:
                self._end_noise(direction)
                self.write(direction, event)
            elif direction in self._noise or len(event.data) > NOISE_SHORT:
                self._gather_noise(direction, event)
            else:
                self.write(direction, event)

    def _gather_noise(self, direction: str, event: FrameEvent) -> None:
        data, _t = self._noise.get(direction, (bytearray(), 0.0))
        data += event.data
        self._noise[direction] = (data, event.t)
        while len(data) >= NOISE_RUN:
            self._write_noise(direction, bytes(data[:NOISE_RUN]), event.t)
            del data[:NOISE_RUN]

    def _end_noise(self, direction: str) -> None:
        """The noise gathered in ``direction`` ends (a frame, silence, the end): write what is left of it."""
        data, t = self._noise.pop(direction, (bytearray(), 0.0))
        if data:
            self._write_noise(direction, bytes(data), t)

    def _write_noise(self, direction: str, data: bytes, t: float) -> None:
        self._put(
            {
                "t": round(t, 6),
                "model_t": None,
                "dir": direction,
                "hex": data.hex().upper(),
                "kind": "noise",
                "slave": None,
                "text": f"{len(data)} bytes that are no frame",
                "note": "",
            }
        )

    def write(self, direction: str, event: FrameEvent) -> None:
        kind, text = self._words(direction, event)
        record = {
            "t": round(event.t, 6),
            "model_t": None,
            "dir": direction,
            "hex": event.data.hex(" ").upper(),
            "kind": kind,
            "slave": event.data[0] if event.data else None,
            "text": text,
            "note": event.note,
        }
        self._put(record)

    def _put(self, record: dict[str, Any]) -> None:
        """Write one record, unless the log has reached ``--max-records`` or ``--max-mb`` (said once)."""
        if self.full:
            return
        line = json.dumps(record) + "\n"
        size = len(line.encode())
        if self.records >= self.max_records or self.bytes + size > self.max_bytes:
            self.full = True
            limit = f"{self.max_records} records" if self.records >= self.max_records else f"{self.max_mb:g} MiB"
            print(
                f"c20sim record: {limit} written (the log's bound); the rest is passed on, not logged",
                file=sys.stderr,
                flush=True,
            )
            return
        self.out.write(line)
        self.out.flush()
        self.records += 1
        self.bytes += size

    def _words(self, direction: str, event: FrameEvent) -> tuple[str, str]:
        if event.kind is not FrameKind.FRAME:
            return event.kind.value, decode_frame(event.data, self.registers).text
        try:
            if direction == "rx":
                request = decode_request(event.data)
                self._last_request = request
                return "request", describe(request, self.registers)
            response = decode_response(event.data)
        except ValueError as exc:
            return "noise", str(exc)
        words = describe(response, self.registers, self._last_request)
        return ("exception" if response.function & 0x80 else "reply"), words


def _master_side(args: Any) -> Side:
    given = [x for x in (args.master_serial, args.master_tcp) if x] + (["pty"] if args.master_pty else [])
    if len(given) != 1:
        raise C20SimError("give the master's side once: --master-pty, --master-serial DEVICE or --master-tcp HOST:PORT")
    if args.master_pty:
        return PtySide(args.master_link)
    if args.master_serial:
        return SerialSide(args.master_serial, args.baud, args.parity, args.stopbits)
    return TcpSide(args.master_tcp)


def _write_ready(path: str, data: dict[str, str]) -> None:
    """The ready file, whole or not at all: written aside, then renamed (a reader never sees half of it)."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.tmp")
    try:
        tmp.write_text(json.dumps(data) + "\n")
        os.replace(tmp, target)
    except OSError as exc:
        raise C20SimError(f"--ready-file {path}: cannot write: {exc.strerror}") from None


async def record(args: Any, out: IO[str], registers: RegisterMap) -> tuple[Recorder, str | None]:
    """Sniff until SIGINT or SIGTERM, or a port is lost; the recorder (its count of records), and the loss."""
    master = _master_side(args)
    drive = SerialSide(args.drive_serial, args.baud, args.parity, args.stopbits)
    recorder = Recorder(out, registers, args.baud, max_records=args.max_records, max_mb=args.max_mb)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    losses: list[str] = []

    def lost(why: str) -> None:
        losses.append(why)
        stop.set()

    handled: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
            handled.append(sig)
        except NotImplementedError:  # Windows' loops: Ctrl-C raises KeyboardInterrupt, and the finally flushes
            pass
    opened: list[Side] = []
    try:
        for side in (drive, master):
            await side.open()
            opened.append(side)
        recorder.start()

        def from_master(data: bytes) -> None:
            drive.send(data)
            recorder.heard("rx", data)

        def from_drive(data: bytes) -> None:
            master.send(data)
            recorder.heard("tx", data)

        master.start(from_master, lost)
        drive.start(from_drive, lost)
        if args.ready_file:
            _write_ready(args.ready_file, {"master": master.name, "drive": drive.name, "log": args.out})
        print(f"c20sim record: master {master.name} <-> drive {drive.name}; frames to {args.out}", flush=True)
        await stop.wait()
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)
        recorder.flush()
        for side in opened:
            side.close()
    return recorder, (losses[0] if losses else None)


def cmd_record(args: Any) -> int:
    if args.baud not in BAUD_RATES:
        raise C20SimError(f"--baud {args.baud}: not one the C20 supports: {', '.join(map(str, BAUD_RATES))}")
    if args.max_records < 1:
        raise C20SimError(f"--max-records {args.max_records}: must be at least 1")
    if not 0.01 <= args.max_mb <= 1e6:  # also refuses nan
        raise C20SimError(f"--max-mb {args.max_mb:g}: give a size in MiB from 0.01 to 1000000")
    _master_side(args)  # the checks, before the log file is made
    registers = load_profile(args.profile).registers
    try:
        out = open(args.out, "w", encoding="utf-8")  # noqa: SIM115 - closed below, after the loop
    except OSError as exc:
        raise C20SimError(f"--out {args.out}: cannot write: {exc.strerror}") from None
    with contextlib.closing(out):
        recorder, loss = asyncio.run(record(args, out, registers))
    print(f"c20sim record: {recorder.records} frame(s) written to {args.out}", flush=True)
    if loss is not None:
        print(f"c20sim record: stopped: the port was lost ({loss})", file=sys.stderr, flush=True)
        return 1
    return 0


def add_record_command(sub: Any) -> None:
    parser = sub.add_parser(
        "record",
        help="sniff a master and a drive, passing every byte on, and write the JSONL frame log",
        description="A pass-through sniffer: the master connects here (--master-pty, --master-serial or "
        "--master-tcp), the drive is on --drive-serial; every byte is passed on and every frame logged "
        "as a JSON line with its time. Stop with Ctrl-C or SIGTERM. Replay the log with c20sim replay.",
    )
    master = parser.add_argument_group("the master's side (one of)")
    master.add_argument("--master-pty", action="store_true", help="create a pty for the master and print its path")
    master.add_argument("--master-link", metavar="PATH", help="a stable symlink to that pty, such as /tmp/ttyMaster")
    master.add_argument("--master-serial", metavar="DEVICE", help="a serial port the master is wired to")
    master.add_argument("--master-tcp", metavar="HOST:PORT", help="listen for the master's raw RTU over TCP")
    parser.add_argument("--drive-serial", metavar="DEVICE", required=True, help="the serial port the drive is on")
    parser.add_argument("--baud", type=int, default=19200, help="both ports' baud rate (default 19200)")
    parser.add_argument("--parity", default="N", choices=["N", "E", "O"], help="serial parity (default N)")
    parser.add_argument("--stopbits", type=int, default=1, choices=[1, 2], help="serial stop bits (default 1)")
    parser.add_argument("--out", "-o", metavar="LOG", required=True, help="the JSONL frame log to write")
    parser.add_argument("--profile", default=DEFAULT_PROFILE, help="profile whose register names the log uses")
    parser.add_argument(
        "--max-records", type=int, default=DEFAULT_MAX_RECORDS, metavar="N", help="stop logging after N frames"
    )
    parser.add_argument(
        "--max-mb",
        type=float,
        default=DEFAULT_MAX_MB,
        metavar="MB",
        help=f"stop logging when the log reaches this size in MiB (default {DEFAULT_MAX_MB:g})",
    )
    parser.add_argument("--ready-file", metavar="PATH", help="write the master's address as JSON when ready")
    parser.set_defaults(func=cmd_record)

"""Captured traffic, read: hex dumps and JSONL frame logs, and ``c20sim decode`` over them.

A capture is bytes in hex (``01 03 21 00 ...``, ``010321...``, ``0x01,0x03``),
a ``hexdump -C`` or ``xxd`` dump (offsets and the text column are skipped),
or a JSONL frame log as ``serve --log-frames`` and ``c20sim record`` write
(one JSON object a line: ``t`` seconds, ``dir`` ``rx`` from the master or
``tx`` from the drive, ``hex`` the bytes). :func:`c20sim.wire.decode.split_frames`
cuts the bytes into frames by the protocol.

A Modbus TCP exchange is logged as the TCP connection carried it: ``hex`` is
the MBAP frame, ``modbus_tcp`` its ``transaction`` and ``unit``, and ``rtu`` the
frame on the line behind the gateway (null for the gateway's own answer,
exception 0x0B, which never was on the line). Decode shows both; replay plays
and compares the line.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

from ..drive.files import MAX_DEPTH, FileReadError, json_depth, read_bytes
from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..wire.decode import Piece, decode_frame, split_frames
from ..wire.errors import C20SimError
from ..wire.protocol import MbapHeader, Request, mbap_adus, with_crc
from ..wire.registers import RegisterMap

__all__ = [
    "LogRecord",
    "add_decode_command",
    "load_frame_log",
    "on_the_line",
    "parse_dump",
    "parse_hex",
    "parse_log",
    "rtu_of_mbap",
]

#: The most input ``decode`` and ``replay`` read (bytes of text): a capture, not a disk.
MAX_INPUT = 64 * 1024 * 1024
#: The most records of a frame log.
MAX_RECORDS = 1_000_000

_EXAMPLE = "give a frame such as '01 06 20 00 00 01 43 CA'"


def parse_hex(words: Sequence[str]) -> bytes:
    """``01 06 20 00``, ``01:06:20:00``, ``0x01,0x06`` or ``01062000`` -> bytes."""
    text = " ".join(words)
    for sep in (":", ",", "-", "\n", "\t"):
        text = text.replace(sep, " ")
    tokens = [t[2:] if t.lower().startswith("0x") else t for t in text.split()]
    joined = (
        "".join(t if len(t) % 2 == 0 else "0" + t for t in tokens)
        if all(len(t) <= 2 for t in tokens)
        else "".join(tokens)
    )
    try:
        return bytes.fromhex(joined)
    except ValueError:
        hint = ""
        if len(words) == 1 and os.path.exists(words[0]):  # a capture's path given as if it were its bytes
            hint = f"; to read the file, give --file {words[0]} (or - for stdin)"
        raise C20SimError(f"not hex bytes: {text.strip()!r}; {_EXAMPLE}{hint}") from None


_XXD = re.compile(r"^\s*[0-9a-fA-F]{4,16}:\s")  # xxd: "00000000: 0103 2100 ...  ..!."
_OFFSET = re.compile(r"^[0-9a-fA-F]{6,16}$")  # hexdump -C, od: "00000000  01 03 21 ...", and the closing offset


def parse_dump(text: str) -> bytes:
    """The bytes of a hex dump: plain hex, ``hexdump -C``, ``od -A x -t x1`` or ``xxd``.

    Offsets and text columns are skipped; a line starting with ``#`` is a comment.
    """
    lines = text.splitlines()
    # hexdump -C and od end with a line holding only the offset; in plain hex such a line is bytes
    offsets = any("|" in line for line in lines) or any(
        _OFFSET.match(t[0]) and len(t) > 1 and all(len(x) <= 2 for x in t[1:]) for t in map(str.split, lines) if t
    )
    out = bytearray()
    for number, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#") or line.strip() == "*":
            continue
        if _XXD.match(line):
            body = re.split(r"\s{2,}", line.split(":", 1)[1].strip(), maxsplit=1)[0]  # the text column
        else:
            body = line.split("|", 1)[0]  # hexdump -C's text column
            tokens = body.split()
            if offsets and tokens and _OFFSET.match(tokens[0]):
                body = " ".join(tokens[1:])
        try:
            out += parse_hex([body])
        except C20SimError:
            raise C20SimError(f"line {number}: not hex bytes: {line.strip()!r}") from None
    return bytes(out)


@dataclass(frozen=True)
class LogRecord:
    """One line of a JSONL frame log."""

    line: int
    t: float
    direction: str  #: "rx" (master to drive) or "tx" (drive to master)
    data: bytes
    kind: str = ""
    note: str = ""
    #: a Modbus TCP record: its MBAP header (``data`` is then the MBAP frame), else None
    mbap: MbapHeader | None = None
    #: a Modbus TCP record: the RTU frame on the line (None: the gateway's own answer, never on the line)
    rtu: bytes | None = None

    @property
    def line_data(self) -> bytes | None:
        """The bytes on the RTU line: ``data``, or for Modbus TCP the RTU frame behind the gateway (None if none)."""
        return self.data if self.mbap is None else self.rtu


def rtu_of_mbap(adu: bytes) -> bytes:
    """The RTU frame of a Modbus TCP frame: unit, PDU, CRC (empty for fewer than 8 bytes)."""
    return with_crc(adu[6:]) if len(adu) >= 8 else b""


def on_the_line(records: Sequence[LogRecord]) -> list[LogRecord]:
    """The records as the RTU line saw them: a Modbus TCP record's RTU frame in ``data``; the gateway's own answers
    (never on the line) left out. RTU records are kept as they are."""
    out = []
    for record in records:
        if record.mbap is None:
            out.append(record)
        elif record.rtu is not None:
            out.append(dataclasses.replace(record, data=record.rtu, mbap=None, rtu=None))
    return out


def _modbus_tcp(
    item: dict[str, object], data: bytes, bad: Callable[[str], C20SimError]
) -> tuple[MbapHeader, bytes | None]:
    """The MBAP header and the RTU frame of a Modbus TCP record (``modbus_tcp`` and ``rtu`` keys)."""
    header = item["modbus_tcp"]
    fields = header if isinstance(header, dict) else {}
    transaction, unit = fields.get("transaction"), fields.get("unit")
    if (
        not isinstance(transaction, int)
        or isinstance(transaction, bool)
        or not 0 <= transaction <= 0xFFFF
        or not isinstance(unit, int)
        or isinstance(unit, bool)
        or not 0 <= unit <= 0xFF
    ):
        raise bad('key \'modbus_tcp\': expected {"transaction": 0-65535, "unit": 0-255}')
    if "rtu" not in item:
        return MbapHeader(transaction, unit), rtu_of_mbap(data)  # the line's frame, from the TCP one
    rtu = item["rtu"]
    if rtu is None:
        return MbapHeader(transaction, unit), None
    if not isinstance(rtu, str):
        raise bad("key 'rtu': expected the RTU frame on the line in hex, or null for the gateway's own answer")
    try:
        return MbapHeader(transaction, unit), bytes.fromhex(rtu)
    except ValueError:
        raise bad(f"key 'rtu': not hex bytes: {rtu[:60]!r}") from None


Bad = Callable[[str], C20SimError]


def log_item(line: str, bad: Bad, not_json: str = "not JSON; a frame log has one JSON object a line") -> dict[str, Any]:
    """A frame log line's JSON object; its nesting is measured before json reads it (``bad`` makes the error)."""
    if json_depth(line) > MAX_DEPTH:  # before json.loads could recurse
        raise bad(f"nested deeper than {MAX_DEPTH} levels; a frame log has one flat JSON object a line")
    try:
        item = json.loads(line)
    except json.JSONDecodeError:
        raise bad(not_json) from None
    if not isinstance(item, dict):
        raise bad("expected a JSON object with t, dir and hex")
    return item


def time_and_direction(item: Mapping[str, Any], bad: Bad) -> tuple[float, str]:
    """A frame record's ``t`` (seconds, finite, >= 0) and ``dir`` (rx or tx), checked."""
    t = item.get("t")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t < 0:
        raise bad("key 't': expected the frame's time in seconds, a finite number >= 0")
    direction = item.get("dir")
    if direction not in ("rx", "tx"):
        raise bad('key \'dir\': expected "rx" (master to drive) or "tx" (drive to master)')
    return float(t), str(direction)


def frame_bytes(text: object, bad: Bad) -> bytes:
    """A frame record's ``hex``, as bytes."""
    if not isinstance(text, str):
        raise bad("key 'hex': expected the frame's bytes in hex, such as \"01 03 21 00 00 01 8E 36\"")
    try:
        return bytes.fromhex(text)
    except ValueError:
        raise bad(f"key 'hex': not hex bytes: {text[:60]!r}") from None


def parse_log(lines: Iterable[str], where: str = "<log>") -> list[LogRecord]:
    """Frame-log records; raises C20SimError naming the file, line and key of a bad one."""
    records: list[LogRecord] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        if len(records) >= MAX_RECORDS:
            raise C20SimError(f"{where}: more than {MAX_RECORDS} records; split the log")

        def bad(message: str, n: int = number) -> C20SimError:
            return C20SimError(f"{where}: line {n}: {message}")

        item = log_item(line, bad)
        t, direction = time_and_direction(item, bad)
        data = frame_bytes(item.get("hex"), bad)
        kind, note = item.get("kind", ""), item.get("note", "")
        mbap, rtu = _modbus_tcp(item, data, bad) if "modbus_tcp" in item else (None, None)
        records.append(
            LogRecord(
                number,
                float(t),
                direction,
                data,
                kind if isinstance(kind, str) else "",
                note if isinstance(note, str) else "",
                mbap,
                rtu,
            )
        )
    return records


def _read_text(path: str) -> str:
    if path != "-":  # a file: bounded, and never a FIFO or a device (stdin is the way to pipe a capture in)
        try:
            return read_bytes(path, "capture", MAX_INPUT).decode("utf-8", errors="replace")
        except FileReadError as exc:
            if exc.reason.startswith("bigger than"):
                raise C20SimError(f"{path}: more than {MAX_INPUT // (1024 * 1024)} MiB; split the capture") from None
            if exc.reason.startswith("is a FIFO"):
                raise C20SimError(f"{exc}; to read a pipe, give - and pipe it to stdin") from None
            raise
    text = sys.stdin.read(MAX_INPUT + 1)
    if len(text) > MAX_INPUT:
        raise C20SimError(f"stdin: more than {MAX_INPUT // (1024 * 1024)} MiB; split the capture")
    return text


def load_frame_log(path: str) -> list[LogRecord]:
    """The records of a JSONL frame log file (``-``: stdin)."""
    return parse_log(_read_text(path).splitlines(), "stdin" if path == "-" else path)


def _is_log(text: str) -> bool:
    return text.lstrip().startswith("{")


def _render(pieces: list[Piece]) -> list[str]:
    lines = []
    for piece in pieces:
        lines.append(piece.data.hex(" ").upper())
        lines.append(f"  {piece.kind}: {piece.text}")
    return lines


def decode_stream(data: bytes, registers: RegisterMap) -> tuple[list[str], bool]:
    """A stream's frames in words (two lines each), and whether every byte belonged to a frame."""
    pieces = split_frames(data, registers)
    if len(pieces) == 1:  # one frame, or none: say all there is to say of it, CRC and length included
        decoded = decode_frame(data, registers)
        return [data.hex(" ").upper(), f"  {decoded.kind}: {decoded.text}"], decoded.ok
    return _render(pieces), all(p.kind != "noise" for p in pieces)


def decode_log(records: list[LogRecord], registers: RegisterMap) -> tuple[list[str], bool]:
    """A frame log in words: each record's time, direction and bytes, then what they are."""
    lines: list[str] = []
    ok = True
    last: Request | None = None
    for record in records:
        lines.append(f"{record.t:>12.6f} {record.direction} {record.data.hex(' ').upper()}".rstrip())
        if record.mbap is not None:
            on_line = "not on the line: the gateway's own answer" if record.rtu is None else "on the line: "
            lines.append(
                f"  modbus tcp: transaction {record.mbap.transaction}, unit {record.mbap.unit}; {on_line}"
                + ("" if record.rtu is None else record.rtu.hex(" ").upper() or "nothing")
            )
        if not record.data:
            lines.append(
                f"  {record.kind or 'empty'}: no bytes on the wire" + (f" ({record.note})" if record.note else "")
            )
            continue
        if record.mbap is not None and record.rtu is None and len(record.data) == 9 and record.data[7] & 0x80:
            lines.append(
                f"  gateway: exception 0x{record.data[8]:02X} to function 0x{record.data[7] & 0x7F:02X}"
                + (": gateway target device failed to respond" if record.data[8] == 0x0B else "")
            )
            continue
        frame = record.data if record.mbap is None else rtu_of_mbap(record.data)  # in words as RTU: unit, PDU
        pieces = split_frames(frame, registers, after=last if record.direction == "tx" else None)
        wanted = ("request",) if record.direction == "rx" else ("reply", "exception")
        if len(pieces) == 1 and pieces[0].kind in wanted:
            lines.append(f"  {pieces[0].kind}: {pieces[0].text}")
            if record.direction == "rx":
                last = cast(Request, pieces[0].message)
            continue
        ok = False
        headers = mbap_adus(record.data) if record.mbap is None else None
        if headers:
            lines.append(
                f"  this looks like Modbus TCP (transaction {headers[0].transaction}, unit {headers[0].unit}) "
                "sent to an RTU port"
            )
        if len(pieces) <= 1:
            decoded = decode_frame(frame, registers)
            lines.append(f"  {decoded.kind}: {decoded.text}")
        else:
            lines += ["  " + line for line in _render(pieces)]
    return lines, ok


def _dump(text: str, where: str) -> bytes:
    try:
        data = parse_dump(text)
    except C20SimError as exc:
        raise C20SimError(f"{where}: {exc}") from None
    if not data:
        raise C20SimError(f"{where}: no bytes; give hex, a hex dump or a JSONL frame log")
    return data


def cmd_decode(args: argparse.Namespace) -> int:
    registers = load_profile(args.profile).registers
    if args.file is not None:
        if args.hex:
            raise C20SimError("give the bytes or --file, not both")
        text = _read_text(args.file)
        where = "stdin" if args.file == "-" else args.file
        if _is_log(text):
            lines, ok = decode_log(parse_log(text.splitlines(), where), registers)
        else:
            lines, ok = decode_stream(_dump(text, where), registers)
    elif args.hex and args.hex != ["-"]:
        data = parse_hex(args.hex)
        if not data:
            raise C20SimError(f"no bytes given; {_EXAMPLE}")
        lines, ok = decode_stream(data, registers)
    else:
        if sys.stdin.isatty():
            raise C20SimError(f"no bytes given; {_EXAMPLE}, or pipe a capture: hex, a hex dump or a JSONL frame log")
        text = _read_text("-")
        if _is_log(text):
            lines, ok = decode_log(parse_log(text.splitlines(), "stdin"), registers)
        else:
            lines, ok = decode_stream(_dump(text, "stdin"), registers)
    sys.stdout.write("\n".join(lines) + "\n")
    return 0 if ok else 1


def add_decode_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    decode = sub.add_parser(
        "decode",
        help="print captured frames in words, or say what is wrong with them",
        description="Decode a frame, or a captured stream cut into frames by the protocol (request, then its "
        "reply). With no bytes (or -), read stdin: hex, a hexdump -C or xxd dump, or a JSONL frame log. "
        "Exit 0 if every byte belongs to a good frame, 1 if not.",
    )
    decode.add_argument("hex", nargs="*", help="bytes in hex, e.g. 01 06 20 00 00 01 43 CA (none or -: stdin)")
    decode.add_argument(
        "--file", "-f", metavar="PATH", help="read a capture from this file (hex, a dump or a JSONL frame log)"
    )
    decode.add_argument("--profile", default=DEFAULT_PROFILE, help="profile whose register names to use")
    decode.set_defaults(func=cmd_decode)

"""Captured traffic, read: hex dumps and JSONL frame logs, and ``c20sim decode`` over them.

A capture is bytes in hex (``01 03 21 00 ...``, ``010321...``, ``0x01,0x03``),
a ``hexdump -C`` or ``xxd`` dump (offsets and the text column are skipped),
or a JSONL frame log as ``serve --log-frames`` and ``c20sim record`` write
(one JSON object a line: ``t`` seconds, ``dir`` ``rx`` from the master or
``tx`` from the drive, ``hex`` the bytes). :func:`c20sim.wire.decode.split_frames`
cuts the bytes into frames by the protocol.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import cast

from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..wire.decode import Piece, decode_frame, split_frames
from ..wire.errors import C20SimError
from ..wire.protocol import Request
from ..wire.registers import RegisterMap

__all__ = ["LogRecord", "add_decode_command", "load_frame_log", "parse_dump", "parse_hex", "parse_log"]

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

        try:
            item = json.loads(line)
        except json.JSONDecodeError:
            raise bad("not JSON; a frame log has one JSON object a line") from None
        if not isinstance(item, dict):
            raise bad("expected a JSON object with t, dir and hex")
        t = item.get("t")
        if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t < 0:
            raise bad("key 't': expected the frame's time in seconds, a finite number >= 0")
        direction = item.get("dir")
        if direction not in ("rx", "tx"):
            raise bad('key \'dir\': expected "rx" (master to drive) or "tx" (drive to master)')
        text = item.get("hex")
        if not isinstance(text, str):
            raise bad("key 'hex': expected the frame's bytes in hex, such as \"01 03 21 00 00 01 8E 36\"")
        try:
            data = bytes.fromhex(text)
        except ValueError:
            raise bad(f"key 'hex': not hex bytes: {text[:60]!r}") from None
        kind, note = item.get("kind", ""), item.get("note", "")
        records.append(
            LogRecord(
                number,
                float(t),
                direction,
                data,
                kind if isinstance(kind, str) else "",
                note if isinstance(note, str) else "",
            )
        )
    return records


def _read_text(path: str) -> str:
    if path == "-":
        text = sys.stdin.read(MAX_INPUT + 1)
        where = "stdin"
    else:
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                text = f.read(MAX_INPUT + 1)
        except OSError as exc:
            raise C20SimError(f"{path}: cannot read: {exc.strerror}") from None
        where = path
    if len(text) > MAX_INPUT:
        raise C20SimError(f"{where}: more than {MAX_INPUT // (1024 * 1024)} MiB; split the capture")
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
        if not record.data:
            lines.append(
                f"  {record.kind or 'empty'}: no bytes on the wire" + (f" ({record.note})" if record.note else "")
            )
            continue
        pieces = split_frames(record.data, registers, after=last if record.direction == "tx" else None)
        wanted = ("request",) if record.direction == "rx" else ("reply", "exception")
        if len(pieces) == 1 and pieces[0].kind in wanted:
            lines.append(f"  {pieces[0].kind}: {pieces[0].text}")
            if record.direction == "rx":
                last = cast(Request, pieces[0].message)
            continue
        ok = False
        if len(pieces) <= 1:
            decoded = decode_frame(record.data, registers)
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

"""``c20sim audit LOG``: the audit's rules over a recorded frame log, streamed.

A frame log is one JSON object a line, as ``serve --log-frames`` and ``c20sim record``
write it; only ``t`` (seconds), ``dir`` (``rx`` master to drive, ``tx`` drive to master) and
``hex`` (the bytes) are read (for a Modbus TCP frame, ``rtu``: the frame on the line behind the
gateway, where ``hex`` is the MBAP frame on the connection), so a log from any tool that writes those three keys will do.
The log is read a line at a time (a line longer than :data:`MAX_LINE` is an error), so
memory stays bounded whatever its length. A line that is not a frame (the frame log's own
``{"kind": "log-dropped"}`` notices) is skipped; a line that is not JSON, or a frame with a bad
``t``, ``dir`` or ``hex``, stops the audit with one line naming the file, the line and the key
(exit 2).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import re
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from typing import IO

from ..audit import RULES, Auditor, Finding, Severity
from ..audit.engine import LineDemand
from ..drive.files import FileReadError, open_stream
from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..wire.errors import C20SimError
from ..wire.registers import BAUD_RATES
from .capture import frame_bytes, log_item, time_and_direction
from .pcap import is_capture, read_capture

__all__ = ["MAX_LINE", "add_audit_command", "audit_log", "junit_xml", "read_frames"]

#: The longest line of a frame log read (characters): a frame is at most 256 bytes, its words a few hundred.
MAX_LINE = 64 * 1024

# The three keys, as serve and record write them ("t": 1.5, ... "dir": "rx", "hex": "01 03 ..."): read
# without a JSON parse when the line has exactly this shape; anything else goes through json.loads.
_FAST = re.compile(r'^\{"t": ([0-9.e+-]+),.*?"dir": "(rx|tx)", "hex": "([0-9A-Fa-f ]*)"')


def read_frames(stream: IO[str], where: str) -> Iterator[tuple[float, str, bytes]]:
    """The frames of a JSONL frame log, one at a time: (t, dir, bytes)."""
    number = 0
    fast = _FAST.match
    while True:
        line = stream.readline(MAX_LINE + 1)
        if not line:
            return
        number += 1
        if len(line) > MAX_LINE and not line.endswith("\n"):
            raise C20SimError(f"{where}: line {number}: longer than {MAX_LINE} characters; not a frame log")
        found = fast(line) if '"rtu": ' not in line else None  # Modbus TCP: the RTU frame is under "rtu"
        if found is not None:
            try:
                t = float(found.group(1))
                data = bytes.fromhex(found.group(3))
            except ValueError:
                pass  # let the full parse name what is wrong
            else:
                if math.isfinite(t) and t >= 0:
                    yield t, found.group(2), data
                    continue
        if not line.strip():
            continue
        yield from _slow(line, number, where)


def _slow(line: str, number: int, where: str) -> Iterator[tuple[float, str, bytes]]:
    def bad(message: str) -> C20SimError:
        return C20SimError(f"{where}: line {number}: {message}")

    item = log_item(line, bad, "not JSON; a frame log has one JSON object a line with t, dir and hex")
    if "hex" not in item and "dir" not in item:
        return  # a notice of the log itself (log-dropped), not a frame
    t, direction = time_and_direction(item, bad)
    text = item.get("hex")
    if "rtu" in item:  # a Modbus TCP frame: "hex" is its MBAP frame, "rtu" the frame on the line behind the gateway
        text = item["rtu"]
        if text is None:
            return  # the gateway's own answer (0x0B after silence): never on the line
    yield t, direction, frame_bytes(text, bad)


def audit_log(path: str, auditor: Auditor, *, server_port: int | None = None) -> Auditor:
    """Feed the frame log or packet capture at ``path`` (``-``: stdin) through ``auditor``; C20SimError for a
    file it cannot read. A capture (pcap, pcapng) is told by its first bytes; ``server_port`` picks its
    conversation (and says which side is the master when the capture starts mid-connection)."""
    where = "stdin" if path == "-" else path
    last = 0.0
    try:  # a file: never a FIFO or a device, as replay and decode (stdin is the way to pipe a log in)
        raw = sys.stdin.buffer if path == "-" else open_stream(path, "frame log or capture")
    except FileReadError as exc:
        if exc.reason.startswith("is a FIFO"):
            raise C20SimError(f"{exc}; to read a pipe, give - and pipe it to stdin") from None
        raise
    try:
        head = raw.peek(4)[:4] if isinstance(raw, io.BufferedReader) else b""
        frames = (
            read_capture(raw, where, server_port)
            if is_capture(head)
            else read_frames(io.TextIOWrapper(raw, encoding="utf-8", errors="replace"), where)
        )
        feed = auditor.feed
        for t, direction, data in frames:
            feed(t, direction, data)
            last = t
    except OSError as exc:
        raise C20SimError(f"{where}: cannot read: {exc.strerror}") from None
    finally:
        if path != "-":
            raw.close()
    if auditor.frames == 0:
        raise C20SimError(
            f"{where}: no frames; give a frame log (one JSON object a line with t, dir and hex) or a capture of "
            "Modbus on TCP"
        )
    auditor.check_idle(last)
    return auditor


def junit_xml(findings: Sequence[Finding], fail_on: Severity, suite: str = "c20sim audit") -> bytes:
    """JUnit XML: a testcase per rule, failed by its findings at or above ``fail_on``."""
    by_rule: dict[str, list[Finding]] = {rule: [] for rule in RULES}
    for finding in findings:
        by_rule[finding.rule].append(finding)
    failures = sum(any(f.severity >= fail_on for f in found) for found in by_rule.values())
    root = ET.Element("testsuites", tests=str(len(by_rule)), failures=str(failures), errors="0")
    node = ET.SubElement(root, "testsuite", name=suite, tests=str(len(by_rule)), failures=str(failures))
    node.set("errors", "0")
    node.set("skipped", "0")
    for rule, found in by_rule.items():
        case = ET.SubElement(node, "testcase", name=rule, classname="audit")
        failing = [f for f in found if f.severity >= fail_on]
        if failing:
            failure = ET.SubElement(case, "failure", message=failing[0].figure, type=failing[0].severity.label)
            failure.text = "\n".join(f.line() for f in failing)
        if len(failing) < len(found):
            ET.SubElement(case, "system-out").text = "\n".join(f.line() for f in found if f not in failing)
    ET.indent(root)
    text: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return text + b"\n"


def _report(findings: Sequence[Finding], demand: LineDemand, frames: int) -> str:
    lines = [f.line() for f in findings]
    lines.append(
        f"{frames} frames, {demand.transactions} requests; line demand peak {demand.peak:.0f} %, "
        f"mean {demand.mean:.0f} % of {demand.baud} {demand.as_dict()['format']}; "
        f"{len(findings)} finding{'' if len(findings) == 1 else 's'}"
    )
    return "\n".join(lines) + "\n"


def cmd_audit(args: argparse.Namespace) -> int:
    try:
        fail_on = Severity.parse(args.fail_on)
    except ValueError as exc:
        raise C20SimError(f"--fail-on: {exc}") from None
    profile = load_profile(args.profile)
    if args.baud is not None and args.baud not in BAUD_RATES:
        raise C20SimError(f"--baud {args.baud}: not one the C20 supports: {', '.join(map(str, BAUD_RATES))}")
    if args.comm_timeout is not None and not 0.0 <= args.comm_timeout <= 6000.0:
        raise C20SimError(f"--comm-timeout {args.comm_timeout:g}: expected 0 (off) to 6000 s")
    try:
        auditor = Auditor(
            profile, baud=args.baud, bits=args.char_bits, comm_timeout=args.comm_timeout, ignore=args.ignore or ()
        )
    except ValueError as exc:
        raise C20SimError(f"--ignore: {exc}") from None
    audit_log(args.log, auditor, server_port=args.server_port)
    findings = auditor.findings()
    if args.junit:
        try:
            with open(args.junit, "wb") as out:
                out.write(junit_xml(findings, fail_on))
        except OSError as exc:
            raise C20SimError(f"--junit {args.junit}: cannot write: {exc.strerror}") from None
    if args.format == "json":
        sys.stdout.write(
            json.dumps(
                {
                    "frames": auditor.frames,
                    "line_demand": auditor.line_demand().as_dict(),
                    "findings": [f.as_dict() for f in findings],
                },
                indent=2,
            )
            + "\n"
        )
    else:
        sys.stdout.write(_report(findings, auditor.line_demand(), auditor.frames))
    return 1 if any(f.severity >= fail_on for f in findings) else 0


def _char_bits(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value not in (10, 11, 12):
        raise argparse.ArgumentTypeError(f"{value}: expected 10 (8N1), 11 (8E1, 8O1, 8N2) or 12 (8E2)")
    return value


def add_audit_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "audit",
        help="report what a master would do wrong on a real line, from a frame log or a packet capture",
        description="Run the audit's rules (docs/audit.md) over a JSONL frame log, from serve --log-frames or "
        "c20sim record (only t, dir and hex are read), or over a pcap or pcapng capture of Modbus TCP or RTU "
        "over TCP (tcpdump, Wireshark). Exit 0 if no finding is at or above --fail-on, 1 if one is, "
        "2 if the log cannot be read.",
    )
    parser.add_argument("log", help="the frame log or packet capture (- for stdin)")
    parser.add_argument("--profile", default=DEFAULT_PROFILE, help="the drive's profile (its facts the rules use)")
    parser.add_argument("--format", choices=("text", "json"), default="text", help="the report's format")
    parser.add_argument("--junit", metavar="FILE", help="write a JUnit XML report here: a test case per rule")
    parser.add_argument(
        "--fail-on",
        default="error",
        metavar="SEVERITY",
        help="exit 1 when a finding is at or above this: note, warning or error (default)",
    )
    parser.add_argument("--ignore", action="append", metavar="RULE", help="silence a rule (repeatable)")
    parser.add_argument("--baud", type=int, help="the real line's baud rate (default: the profile's F08.01)")
    parser.add_argument(
        "--char-bits", type=_char_bits, default=10, help="bits a character takes on the line: 10 (8N1, default)"
    )
    parser.add_argument(
        "--comm-timeout", type=float, metavar="S", help="the drives' communication timeout (default: F08.02)"
    )
    parser.add_argument(
        "--server-port",
        type=int,
        metavar="PORT",
        help="a packet capture: the drive's or the gateway's TCP port (only its conversations are read)",
    )
    parser.set_defaults(func=cmd_audit)

"""``c20sim replay LOG``: play the master's side of a frame log against a simulated drive, and compare.

The log is JSONL as ``c20sim record`` and ``serve --log-frames`` write it
(:mod:`c20sim.traffic.capture`); of a Modbus TCP exchange, the RTU frames on the
line behind the gateway are played and compared (``rtu``). Each frame the master sent (``rx``) is framed and
handed to a simulator with a virtual clock, at the log's time for it (the
first frame at model time 0): the drive's model runs exactly as long between
two requests as the real drive did. The simulator's reply is compared, byte
for byte, with what the log says came back (``tx`` records up to the next
request; none, or a dropped reply, is silence). Every reply that differs is
reported in words, both sides decoded with the profile's register names.
Exit 0 when every reply matches, 1 when one differs, 2 for a bad log.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from ..core.clock import VirtualClock
from ..core.simulator import Simulator, parse_addresses
from ..drive.profile import DEFAULT_PROFILE, load_profile
from ..wire.decode import decode_frame, describe, split_frames
from ..wire.errors import C20SimError
from ..wire.framing import RtuFramer
from ..wire.protocol import Request, decode_request
from ..wire.registers import RegisterMap
from .capture import LogRecord, load_frame_log, on_the_line

__all__ = ["Difference", "Exchange", "ReplayResult", "add_replay_command", "exchanges", "replay"]


@dataclass(frozen=True)
class Exchange:
    """One frame from the master in the log, and the bytes the drive sent back (empty: silence)."""

    record: LogRecord
    reply: bytes


@dataclass(frozen=True)
class Difference:
    exchange: Exchange
    simulated: bytes
    text: str  #: in words: the request, what was recorded, what the simulator says


@dataclass(frozen=True)
class ReplayResult:
    exchanges: int
    differences: tuple[Difference, ...]
    skipped: int  #: drive frames before the first master frame (a capture that starts mid-exchange)

    @property
    def ok(self) -> bool:
        return not self.differences


def exchanges(records: Sequence[LogRecord]) -> tuple[list[Exchange], int]:
    """The log as the master's frames, each with the reply after it; and how many drive frames came first."""
    out: list[Exchange] = []
    skipped = 0
    current: LogRecord | None = None
    reply = b""
    for record in records:
        if record.direction == "rx":
            if current is not None:
                out.append(Exchange(current, reply))
            current, reply = record, b""
        elif current is None:
            skipped += 1
        else:
            reply += record.data
    if current is not None:
        out.append(Exchange(current, reply))
    return out, skipped


def _request(data: bytes) -> Request | None:
    try:
        return decode_request(data)
    except ValueError:
        return None


def _words(data: bytes, registers: RegisterMap, request: Request | None) -> str:
    """A reply in words: ``no reply``, its decoded frames, or what is wrong with its bytes."""
    if not data:
        return "no reply"
    pieces = split_frames(data, registers, after=request)
    if len(pieces) == 1 and pieces[0].message is not None:
        words = describe(pieces[0].message, registers, pieces[0].request)
    elif len(pieces) == 1:
        words = decode_frame(data, registers).text
    else:
        words = "; ".join(p.text for p in pieces)
    return f"{words} [{data.hex(' ').upper()}]"


def _asked(record: LogRecord, registers: RegisterMap, request: Request | None) -> str:
    if request is not None:
        return describe(request, registers)
    return f"a broken frame ({decode_frame(record.data, registers).text})" if record.data else "an empty frame"


def default_drives(found: Sequence[Exchange]) -> list[int]:
    """The addresses that answered in the log (1 if none did)."""
    addresses: list[int] = []
    for exchange in found:
        data = exchange.record.data
        if exchange.reply and data and 1 <= data[0] <= 247 and data[0] not in addresses:
            addresses.append(data[0])
    return addresses or [1]


def replay(records: Sequence[LogRecord], sim: Simulator) -> ReplayResult:
    """Play the master's frames of ``records`` on ``sim`` (virtual clock) at the log's times, and compare."""
    if not isinstance(sim.clock, VirtualClock):
        raise C20SimError("replay needs a simulator with a virtual clock")
    found, skipped = exchanges(on_the_line(records))  # a Modbus TCP log: the line behind the gateway
    registers = sim.profile.registers
    differences: list[Difference] = []
    start = sim.now()
    t0 = found[0].record.t if found else 0.0
    for exchange in found:
        record = exchange.record
        sim.run_until(max(sim.now(), start + record.t - t0))
        framer = RtuFramer(sim.bus.line_baud, complete_on_length=True, check_gaps=False)
        framer.feed(record.data, sim.now())
        framer.flush()
        simulated = b""
        for event in framer.events():
            answer = sim.handle(event)
            if answer is not None:
                simulated += answer.data
        if simulated == exchange.reply:
            continue
        request = _request(record.data) if record.data else None
        text = (
            f"line {record.line} (t {record.t:.6f} s): {_asked(record, registers, request)}: "
            f"recorded {_words(exchange.reply, registers, request)}; "
            f"simulated {_words(simulated, registers, request)}"
        )
        differences.append(Difference(exchange, simulated, text))
    return ReplayResult(len(found), tuple(differences), skipped)


def cmd_replay(args: argparse.Namespace) -> int:
    records = load_frame_log(args.log)
    if not any(r.direction == "rx" for r in records):
        raise C20SimError(f"{args.log}: no frame from the master (dir rx) to replay")
    profile = load_profile(args.profile)
    found, _ = exchanges(on_the_line(records))
    addresses = parse_addresses(args.drives) if args.drives else default_drives(found)
    sim = Simulator(profile, addresses, clock=VirtualClock(), seed=args.seed, baud=args.baud)
    result = replay(records, sim)
    out = sys.stdout
    drives = ",".join(map(str, addresses))
    print(f"replay {args.log} against {profile.name}, drives {drives}: {result.exchanges} frame(s) from the master")
    for difference in result.differences:
        print(f"  DIFF {difference.text}", file=out)
    if result.skipped:
        print(f"  ({result.skipped} drive frame(s) before the first master frame: not compared)")
    if result.ok:
        print(f"{result.exchanges} replayed: every reply matches")
        return 0
    print(
        f"{result.exchanges} replayed: {len(result.differences)} "
        + ("reply differs" if len(result.differences) == 1 else "replies differ")
    )
    return 1


def add_replay_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "replay",
        help="play the master's side of a frame log against a simulated drive; report every reply that differs",
        description="Replay a JSONL frame log (c20sim record, serve --log-frames) against a simulated drive in "
        "virtual time paced by the log. Exit 0 if every reply matches, 1 if one differs, 2 for a bad log.",
    )
    parser.add_argument("log", help="the JSONL frame log (- for stdin)")
    parser.add_argument(
        "--profile", default=DEFAULT_PROFILE, help=f"the drive to compare with (default {DEFAULT_PROFILE})"
    )
    parser.add_argument("--drives", metavar="LIST", help="drive addresses (default: those that answered in the log)")
    parser.add_argument("--baud", type=int, help="the drives' baud rate (default: the profile's)")
    parser.add_argument("--seed", type=int, default=1, help="seed for random link faults (default 1)")
    parser.set_defaults(func=cmd_replay)

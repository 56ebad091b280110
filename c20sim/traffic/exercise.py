"""``c20sim exercise PORT``: a C20 master for a person at a bench, and the identification programme.

The same master does two jobs. ``c20sim exercise PORT read speed status fault``
reads single registers by name and prints them in units; ``c20sim exercise
PORT write setpoint 1500`` writes one, saying what it writes (and saying so
loudly when it is a function code, which the drive keeps in EEPROM). With
``--out FILE`` and no action it runs the short identification programme
(:func:`programme`): a hold at rest, a run, speed steps with holds, optionally
a load change the user makes by hand when told, and a stop, polling the
physical registers (:data:`POLL`) at a steady rate all along. The capture is
the JSONL frame log ``c20sim record`` and ``serve --log-frames`` write
(``t``, ``dir``, ``hex``, ``kind``, ``slave``, ``text``), which ``c20sim fit``
and ``c20sim replay`` read.

With ``--dialect`` (or ``--dialect-only``) the dialect probe (:mod:`c20sim.traffic.dialect`) comes first, in the
same capture: reads, a write of the value a function code holds to its RAM-only address, writes every drive
refuses; ``c20sim fit`` learns the drive's Modbus dialect from its frames.

Safety: the programme refuses to start a drive that is not stopped, faulted,
or not under communication control with the Modbus speed reference; a drive
that answers an exception or stays silent, or trips, is told to stop and the
programme ends with one line saying why; Ctrl-C stops the drive first.

PORT is a serial device or a pty (opened by :func:`c20sim.transport.device.open_serial`),
``tcp://HOST:PORT`` (raw RTU frames over TCP: a serial device server, ``serve --tcp``)
or ``modbus-tcp://HOST:PORT`` (Modbus TCP, MBAP; ``serve --modbus-tcp``). The
bytes are made and checked by :mod:`c20sim.wire.protocol`: its encoder, CRC and
frame lengths.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import TypeVar

from ..drive.profile import DEFAULT_PROFILE, Profile, load_profile
from ..wire.errors import C20SimError
from ..wire.registers import BAUD_RATES, Reg, RegisterMap
from ..wire.vocabulary import SHORT_NAMES
from .dialect import Prober, probe
from .master import Interrupted, Master, NoReply, is_function_code, parse_value, register_of
from .masterlinks import Link, MbapLink, link_port, open_link
from .programme import Step, check_ready, programme, run_programme, time_the_link

__all__ = ["NAMES", "add_exercise_command", "cmd_exercise"]

#: The short names of the one register vocabulary (kept here for those who import them from exercise).
NAMES = SHORT_NAMES

T = TypeVar("T")

# --- The command.


def _bar(
    index: int, count: int, step: Step, held: float, hold: float, last: dict[int, int], registers: RegisterMap
) -> str:
    done = (index + min(held / hold, 1.0) if hold else index + 1) / count
    bar = "#" * round(done * 20)
    shown = []
    for address in (Reg.MOTOR_SPEED, Reg.OUTPUT_CURRENT, Reg.BUS_VOLTAGE):
        if address in last:
            shown.append(registers[address].describe(last[address]))
    return f"[{bar:<20}] {done * 100:3.0f}% step {index + 1}/{count}: {step.say} | {'  '.join(shown)}"


def cmd_exercise(args: argparse.Namespace) -> int:
    profile = load_profile(args.profile)
    registers = profile.registers
    action = args.action
    if (args.dialect or args.dialect_only) and (action is not None or not args.out):
        raise C20SimError("--dialect: give --out FILE for the capture, and no action")
    if action is None:
        if not args.out:
            raise C20SimError("give --out FILE for the capture, or an action: read NAME..., write NAME VALUE")
    elif action == "read":
        if not args.words:
            raise C20SimError("read what? give register names, such as: read speed status fault")
        specs = [register_of(word, registers, f"the profile {profile.name}") for word in args.words]
    elif action == "write":
        if len(args.words) != 2:
            raise C20SimError("write needs a register and a value, such as: write setpoint 1500")
        spec = register_of(args.words[0], registers, f"the profile {profile.name}")
        if not spec.access.writable:
            raise C20SimError(f"{spec.label} {spec.name} is read-only")
        value = parse_value(spec, args.words[1])
    else:
        raise C20SimError(f"unknown action {action!r}: read, write, or none for the identification programme")
    if not 0 < args.rate <= 100:
        raise C20SimError(f"--rate {args.rate:g}: give reads a second, above 0 and at most 100")
    if not 0 <= args.hold <= 86400:
        raise C20SimError(f"--hold {args.hold:g}: give seconds, from 0 to 86400 (a day)")
    if not 0 < args.timeout <= 60:
        raise C20SimError(f"--timeout {args.timeout:g}: give seconds, above 0 and at most 60")
    if not 1 <= args.address <= 247:
        raise C20SimError(f"--address {args.address}: give the drive's address, 1-247 (2008H)")
    speeds = _speeds(args.speeds, profile.motor.rated_speed_rpm) if action is None else []
    baud = _baud(args, profile)
    link = open_link(args.port, baud, args.parity, args.stopbits)
    try:
        if action == "read":
            master = Master(link, registers, args.address, timeout=args.timeout)
            for index, spec in enumerate(specs):
                raw = _first(master.read, spec.address, args, baud) if index == 0 else master.read(spec.address)
                print(f"{spec.label} {spec.name}: {spec.describe(raw)}")
            return 0
        if action == "write":
            master = Master(link, registers, args.address, timeout=args.timeout)
            words = f"{spec.label} {spec.name} = {spec.describe(value)} (raw {value})"
            if is_function_code(registers, spec.address):
                print(f"writing a function code, kept in the drive's EEPROM: {words}")
            else:
                print(f"writing {words}")
            _first(master.write, spec.address, args, baud, value)
            return 0
        return _run(args, link, profile, speeds, baud)
    finally:
        link.close()


def _first(act: Callable[..., T], address: int, args: argparse.Namespace, baud: int, *more: int) -> T:
    """The first exchange with the drive: silence there is the address's or the link's, not the action's."""
    try:
        return act(address, *more)
    except NoReply:
        serial = "" if args.port.startswith(("tcp://", "modbus-tcp://")) else f", {baud} baud {args.parity}"
        raise C20SimError(
            f"{args.port}: no drive answered at address {args.address} within {args.timeout:g} s; check --address "
            f"(the drive's 2008H, 1 as shipped) and the link (the port{serial})"
        ) from None


def _speeds(text: str | None, rated: float) -> list[float]:
    """--speeds: rpm, each above 0 and at most the rated speed; one line for anything else."""
    if text is None:
        return [rated * f for f in (0.3, 0.6, 0.9, 0.5)]
    out = []
    for word in text.split(","):
        try:
            speed = float(word)
        except ValueError:
            raise C20SimError(f"--speeds {text}: {word.strip()!r} is not a number; give rpm such as 900,1800") from None
        if not (math.isfinite(speed) and 0 < speed <= rated):
            raise C20SimError(f"--speeds {text}: each speed above 0 and at most {rated:g} rpm (the profile's rated)")
        out.append(speed)
    return out


def _probe_dialect(args: argparse.Namespace, master: Master, link: Link, profile: Profile) -> None:
    """The dialect probe (:mod:`c20sim.traffic.dialect`): reads, writes of held values, writes every drive refuses."""
    print(
        f"exercise {args.port}: probing the dialect: reads, a write of the value F00.10 holds to its RAM-only "
        "address, writes to a read-only register (refused), one frame with a bad CRC, one broadcast",
        flush=True,
    )
    _first(master.read, Reg.STATUS1, args, _baud(args, profile))
    probe(Prober(master.probe, args.address, profile, rtu=not isinstance(link, MbapLink)))


def _baud(args: argparse.Namespace, profile: Profile) -> int:
    return int(args.baud or BAUD_RATES[min(profile.default(Reg.BAUD), len(BAUD_RATES) - 1)])


def _run(args: argparse.Namespace, link: Link, profile: Profile, speeds: list[float], link_baud: int) -> int:
    registers, rated = profile.registers, profile.motor.rated_speed_rpm
    try:
        out = open(args.out, "w", encoding="utf-8")  # noqa: SIM115 - closed below, after the stop
    except OSError as exc:
        raise C20SimError(f"--out {args.out}: cannot write: {exc.strerror}") from None
    tty = sys.stdout.isatty()
    with out:
        master = Master(link, registers, args.address, timeout=args.timeout, log=out)
        master.header(link_port(link), link_baud, f"8{args.parity}{args.stopbits}")
        if args.dialect or args.dialect_only:
            _probe_dialect(args, master, link, profile)
            if args.dialect_only:
                print(f"done: {master.frames} frames written to {args.out}; fit it: c20sim fit {args.out}")
                return 0
        settings = check_ready(master)
        time_the_link(master)
        accel = settings[Reg.ACCEL_TIME] * registers[Reg.ACCEL_TIME].scale
        decel = settings[Reg.DECEL_TIME] * registers[Reg.DECEL_TIME].scale
        steps = programme(speeds, args.hold, accel, decel, rated, args.load_change)
        total = sum(s.hold for s in steps)
        print(
            f"exercise {args.port}: {len(steps)} steps, about {total:.0f} s, polling {args.rate:g} reads/s; "
            f"writes 2001H (speed setting) and 2000H (run, stop) only, no function code; Ctrl-C stops the drive"
        )
        shown = [-1]

        def progress(index: int, count: int, step: Step, held: float, hold: float, last: dict[int, int]) -> None:
            if tty:
                line = _bar(index, count, step, held, hold, last, registers)
                print("\r" + line[:150].ljust(150), end="", flush=True)
            elif shown[0] != index:
                shown[0] = index
                print(f"step {index + 1}/{count}: {step.say}", flush=True)

        def confirm(prompt: str) -> None:
            print(("\n" if tty else "") + f"{prompt}, then press Enter (Ctrl-C stops the drive)", flush=True)
            if sys.stdin.readline() == "":
                raise C20SimError(f"no answer to '{prompt}' (stdin closed)")

        try:
            reads = run_programme(master, steps, rate=args.rate, progress=progress, confirm=confirm)
        except Interrupted as exc:
            print(f"\ninterrupted: {exc}; {master.frames} frames in {args.out}", file=sys.stderr)
            return 130
        finally:
            if tty:
                print()
    print(f"done: {reads} reads, {master.frames} frames written to {args.out}; fit it: c20sim fit {args.out}")
    return 0


def add_exercise_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "exercise",
        help="a C20 master: read or write registers by name, or run the identification programme (--out)",
        description="Talk to a C20 (or c20sim) as a master. 'read NAME...' and 'write NAME VALUE' for a person at "
        "a bench (values in units); with no action and --out FILE, the short identification programme (rest, run, "
        "speed steps, optionally a load change, stop), polling the physical registers and writing the capture as "
        "a JSONL frame log for c20sim fit.",
    )
    parser.add_argument("port", help="a serial device or pty, tcp://HOST:PORT (RTU over TCP) or modbus-tcp://HOST:PORT")
    parser.add_argument("action", nargs="?", help="read or write (none: the identification programme)")
    parser.add_argument("words", nargs="*", help="registers to read; or the register and value to write")
    parser.add_argument("--address", type=int, default=1, help="the drive's address (default 1)")
    parser.add_argument(
        "--baud", type=int, choices=BAUD_RATES, help="the serial line's baud (default: the profile's, 19200 as shipped)"
    )
    parser.add_argument("--parity", default="N", choices=["N", "E", "O"], help="serial parity (default N)")
    parser.add_argument("--stopbits", type=int, default=1, choices=[1, 2], help="serial stop bits (default 1)")
    parser.add_argument("--timeout", type=float, default=0.5, help="seconds to wait for a reply (default 0.5)")
    parser.add_argument(
        "--profile", default=DEFAULT_PROFILE, help=f"register names and rated speed (default {DEFAULT_PROFILE})"
    )
    parser.add_argument("--out", metavar="FILE", help="write the programme's capture here (JSONL frame log)")
    parser.add_argument("--rate", type=float, default=10.0, help="reads a second while polling (default 10)")
    parser.add_argument("--hold", type=float, default=8.0, help="seconds each speed is held past its ramp (default 8)")
    parser.add_argument(
        "--speeds", metavar="LIST", help="speeds to step through, rpm (default 30,60,90,50 %% of rated)"
    )
    parser.add_argument(
        "--dialect",
        action="store_true",
        help="probe the drive's Modbus dialect first (harmless: docs/fit.md, 'The dialect probe'), then the programme",
    )
    parser.add_argument("--dialect-only", action="store_true", help="probe the dialect only, no programme")
    parser.add_argument("--load-change", action="store_true", help="ask for a load change by hand, and hold with it")
    parser.set_defaults(func=cmd_exercise, trailing_words=_trailing_words)


def _trailing_words(args: argparse.Namespace, extras: list[str]) -> list[str]:
    """``exercise PORT --address 7 read speed``: argparse leaves the words after an option over; take them as the
    action and its words. Options among them stay over, for argparse's one-line error."""
    if any(word.startswith("-") and not _is_number(word) for word in extras):
        return extras
    words = list(extras)
    if args.action is None:
        args.action = words.pop(0)
    args.words = [*args.words, *words]
    return []


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True

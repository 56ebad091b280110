"""The ``c20sim`` command: argument parsing, and one function per subcommand.

Every user error ends in one line on stderr saying what is wrong and what to
do, and exit code 2; no traceback.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import NoReturn, cast

from .control.ctl import add_ctl_command
from .core.simulator import Simulator, make_clock
from .drive.profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile
from .plant import add_plant_commands, drive_addresses
from .scenario.schema import add_schema_command
from .scenario.suite import add_run_scenario_command
from .serve import ServeOptions, pty_supported, run, run_server
from .traffic.capture import add_decode_command
from .traffic.exercise import add_exercise_command
from .traffic.fit import add_fit_command
from .traffic.record import add_record_command
from .traffic.replay import add_replay_command
from .wire.errors import C20SimError
from .wire.registers import BAUD_RATES, format_fcode

__all__ = ["main"]


class UsageError(C20SimError):
    """A bad command line: printed as one line, exit code 2."""


def cmd_profiles(args: argparse.Namespace) -> int:
    if args.action == "show":
        if not args.name:
            raise UsageError("profiles show needs a profile name or path, such as: c20sim profiles show c20-400hr")
        print(render_profile(load_profile(args.name)), end="")
        return 0
    for name, path in available_profiles().items():
        profile = load_profile(str(path))
        default = " (default)" if name == DEFAULT_PROFILE else ""
        print(f"{name:<14} {profile.description}{default}")
    return 0


def add_endpoint_options(parser: argparse.ArgumentParser) -> None:
    """The options ``serve`` and ``dashboard`` share: where the drive is, and what it is."""
    where = parser.add_argument_group(
        "endpoints (with none: --pty and --tcp 127.0.0.1:5020; --tcp alone where there are no ptys)"
    )
    where.add_argument("--pty", action="store_true", help="create a virtual serial port and print its path")
    where.add_argument(
        "--link", metavar="PATH", help="a stable symlink to the pty, such as /tmp/ttyC20 (implies --pty)"
    )
    where.add_argument("--serial", metavar="DEVICE", help="a real serial port, such as /dev/ttyUSB0")
    where.add_argument(
        "--baud",
        type=int,
        choices=BAUD_RATES,
        help="the drives' baud rate, F08.01 (default: the profile's or the state file's, 19200 as shipped)",
    )
    where.add_argument("--parity", default="N", choices=["N", "E", "O"], help="serial parity (default N)")
    where.add_argument("--stopbits", type=int, default=1, choices=[1, 2], help="serial stop bits (default 1)")
    where.add_argument("--tcp", metavar="HOST:PORT", help="raw RTU frames over TCP, as a serial device server")
    where.add_argument("--modbus-tcp", metavar="HOST:PORT", help="Modbus TCP (MBAP), as an Ethernet gateway")
    where.add_argument("--line-timing", action="store_true", help="pace replies at the baud and enforce t1.5/t3.5")
    where.add_argument(
        "--control", metavar="HOST:PORT", help="HTTP JSON control API, such as 127.0.0.1:8020 (see c20sim ctl)"
    )
    where.add_argument(
        "--control-token",
        metavar="TOKEN",
        help="the token the control API asks for (beyond loopback one is generated and written to the ready file)",
    )
    what = parser.add_argument_group("the simulated drives")
    what.add_argument(
        "--profile", default=DEFAULT_PROFILE, help=f"profile name or TOML path (default {DEFAULT_PROFILE})"
    )
    what.add_argument(
        "--drives",
        # without it, $C20SIM_DRIVES: a container's drives come from a ConfigMap (c20sim.plant)
        metavar="LIST",
        help="drive addresses on the bus, such as 1,2,5 (default $C20SIM_DRIVES, or 1)",
    )
    what.add_argument(
        "--clock", default="realtime", choices=["realtime", "virtual"], help="time source (default realtime)"
    )
    what.add_argument("--speed", type=float, default=1.0, help="realtime clock speed factor (default 1)")
    what.add_argument("--state", metavar="PATH", help="keep function codes (EEPROM) in this file across runs")
    what.add_argument("--seed", type=int, help="seed for random link faults, for repeatable runs")
    what.add_argument("--log-frames", metavar="PATH", help="append every frame as a JSON line to this file")
    what.add_argument(
        "--log-frames-max-mb",
        type=float,
        metavar="MB",
        help="rotate the frame log at this size, keeping 3 old files (PATH.1 to PATH.3)",
    )
    what.add_argument("--ready-file", metavar="PATH", help="write the real endpoint addresses as JSON when ready")


def build_simulator(args: argparse.Namespace) -> Simulator:
    profile = load_profile(args.profile)
    return Simulator(
        profile,
        drive_addresses(args.drives),
        clock=make_clock(args.clock, args.speed),
        state=Path(args.state) if args.state else None,
        seed=args.seed,
        baud=args.baud,
    )


def serve_options(args: argparse.Namespace) -> ServeOptions:
    options = ServeOptions(
        pty=args.pty,
        link=args.link,
        serial=args.serial,
        parity=args.parity,
        stopbits=args.stopbits,
        tcp=args.tcp,
        modbus_tcp=args.modbus_tcp,
        line_timing=args.line_timing,
        log_frames=args.log_frames,
        log_frames_max_mb=args.log_frames_max_mb,
        ready_file=args.ready_file,
        control=args.control,
        control_token=args.control_token,
        scenario=getattr(args, "scenario", None),
    )
    if not options.any_endpoint:
        options.pty = pty_supported()  # no pty on Windows: TCP alone
        options.tcp = "127.0.0.1:5020"
    return options


def cmd_serve(args: argparse.Namespace) -> int:
    options = serve_options(args)
    sim = build_simulator(args)
    return run(run_server(sim, options))  # 1 if a --scenario failed: CI sees it in the exit code


def cmd_dashboard(args: argparse.Namespace) -> int:
    from .tui.session import run_dashboard  # textual loads only for the dashboard

    return run_dashboard(args, args.serve_defaults)


def cmd_web(args: argparse.Namespace) -> int:
    from .tui.web import run_web  # textual-serve loads only for the browser view

    return run_web(args, args.serve_defaults)


def render_profile(profile: Profile) -> str:
    """A profile as a SCADA developer wants to read it: quirks, physics, faults, function codes."""
    lines = [f"{profile.name}: {profile.description}", f"  file: {profile.path}", ""]
    proto = profile.protocol
    lines += [
        "protocol",
        f"  bad CRC or length:      {'exception 0x06' if proto.reply_to_bad_crc else 'silence'}",
        f"  registers per read:     up to {proto.max_read_registers}",
        f"  turnaround delay:       {proto.turnaround_ms:g} ms",
        f"  user password:          {'set, written at ' + proto.password_register if proto.password else 'none'}",
        f"  software version 300AH: {profile.software_version / 100:.2f}",
        "",
    ]
    for title, section in (
        ("motor", profile.motor),
        ("supply", profile.supply),
        ("protection", profile.protection),
        ("thermal", profile.thermal),
        ("control", profile.control),
    ):
        lines.append(title)
        lines += [
            f"  {key:<24} {value}" if isinstance(value, tuple) else f"  {key:<24} {value:g}"
            for key, value in vars(section).items()
        ]
        lines.append("")
    lines.append("faults (code, name, meaning, source)")
    for fault in profile.faults.values():
        lines.append(f"  0x{fault.code:02X} {fault.name:<6} {fault.meaning} [{fault.source}]")
    lines += ["", "function codes (code, address, name, default, range, access, mirror, source)"]
    for spec in profile.parameters:
        mirror = profile.registers.mirrored_by.get(spec.address)
        mirror_text = f"<-> {mirror:04X}H" if mirror is not None else ""
        default = spec.describe(profile.defaults[spec.address])
        # the range in the value's own units (0.1-600.0 s), or raw where values have names (0-4: keypad ...)
        span = (
            f"{spec.minimum}-{spec.maximum}"
            if spec.values
            else f"{spec.describe(spec.minimum)} - {spec.describe(spec.maximum)}"
        )
        lines.append(
            f"  {format_fcode(spec.address)} {spec.address:04X}H  {spec.name:<26} {default:<18} "
            f"{span:<22} {spec.access.value:<4} {mirror_text:<9} [{spec.source}]"
        )
    return "\n".join(lines) + "\n"


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a bad option is one line (what is wrong, and where the usage is) and exit 2, as every other
    error of c20sim; ``--help`` still prints the whole usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"c20sim: {self.prog}: {message} (see: {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="c20sim",
        description="A virtual ZBLD.C20 brushless DC drive behind a Modbus RTU slave.",
    )
    sub = cast(
        "argparse._SubParsersAction[argparse.ArgumentParser]", parser.add_subparsers(dest="command", metavar="COMMAND")
    )

    add_decode_command(sub)

    profiles = sub.add_parser("profiles", help="list the shipped profiles, or show one")
    profiles.add_argument("action", nargs="?", choices=["list", "show"], default="list")
    profiles.add_argument("name", nargs="?", help="profile name or path (for show)")
    profiles.set_defaults(func=cmd_profiles)

    serve = sub.add_parser("serve", help="run the simulator headless until SIGINT or SIGTERM")
    add_endpoint_options(serve)
    serve.add_argument(
        "--scenario",
        metavar="FILE",
        help="play a TOML scenario against the served drives once ready (c20sim.scenario.timeline)",
    )
    serve.set_defaults(func=cmd_serve)

    dashboard = sub.add_parser("dashboard", help="the simulator with its terminal dashboard (the default command)")
    add_endpoint_options(dashboard)
    dashboard.add_argument(
        "--attach",
        metavar="READY_FILE|URL",
        help="attach to a running serve (its ready file, or http://HOST:PORT of its --control) instead of starting one",
    )
    dashboard.set_defaults(func=cmd_dashboard, serve_defaults={a.dest: a.default for a in dashboard._actions})

    web = sub.add_parser("web", help="the dashboard in a browser (textual-serve), on a serve it starts or attaches to")
    add_endpoint_options(web)
    web.add_argument("--attach", metavar="READY_FILE|URL", help="attach to a running serve instead of starting one")
    web.add_argument(
        "--web", default="127.0.0.1:8000", metavar="HOST:PORT", help="the page's address (default 127.0.0.1:8000)"
    )
    web.add_argument("--web-token", metavar="TOKEN", help="the page's token (beyond loopback one is generated)")
    web.set_defaults(func=cmd_web, serve_defaults={a.dest: a.default for a in web._actions})

    add_ctl_command(sub)
    add_run_scenario_command(sub)
    add_schema_command(sub)
    add_plant_commands(sub)
    add_record_command(sub)
    add_replay_command(sub)
    add_exercise_command(sub)
    add_fit_command(sub)
    return parser


def with_default_command(argv: Sequence[str], commands: Iterable[str]) -> list[str]:
    """Bare ``c20sim`` and ``c20sim --pty --link /tmp/ttyC20`` mean the dashboard: its options need no command word.

    ``-h``/``--help`` alone still asks for the command list.
    """
    words = list(argv)
    if not words:
        return ["dashboard"]
    if words[0] in commands or words[0] in ("-h", "--help"):
        return words
    return ["dashboard", *words]


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    commands = next(a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    args = parser.parse_args(with_default_command(sys.argv[1:] if argv is None else argv, commands or ()))
    try:
        result: int = args.func(args)
        return result
    except C20SimError as exc:
        print(f"c20sim: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        if not _stdout_gone():
            raise
        # a reader that stopped early (`c20sim decode -f log | head -1`): end quietly, and let the
        # interpreter's last flush at exit go to /dev/null rather than print a second traceback
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return 0


def _stdout_gone() -> bool:
    """True when stdout is a pipe whose reader has closed it (POLLERR), so a BrokenPipeError was ours."""
    try:
        import select

        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll (Windows), or no stdout to ask
        return True

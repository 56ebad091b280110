"""The ``c20sim`` command: argument parsing, and one function per subcommand.

Every user error ends in one line on stderr saying what is wrong and what to
do, and exit code 2; no traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import logging
import os
import re
import stat
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import NoReturn, cast

from .browser.site import add_site_command
from .control.client import TOKEN_ENV
from .control.ctl import add_ctl_command
from .core.simulator import Simulator, make_clock
from .drillcli import add_drill_command
from .drive.files import FileReadError, read_text
from .drive.profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile
from .plant import add_plant_commands, drive_addresses
from .scenario.schema import add_schema_command
from .scenario.suite import add_run_scenario_command
from .serve import ServeOptions, endpoint_dests, run, run_server
from .traffic.auditlog import add_audit_command
from .traffic.capture import add_decode_command
from .traffic.exercise import add_exercise_command
from .traffic.fit import add_fit_command
from .traffic.record import add_record_command
from .traffic.replay import add_replay_command
from .transport.rows import find, rows
from .wire.errors import C20SimError
from .wire.registers import BAUD_RATES, format_fcode

__all__ = ["main"]


def _default(name: str) -> str:
    row = find(name)
    return str(row.default) if row is not None else ""


#: The endpoints of a bare ``c20sim`` or ``c20sim serve`` on TCP (the rows' defaults: RTU over TCP and Modbus TCP,
#: on unprivileged ports).
DEFAULT_TCP = _default("tcp")
DEFAULT_MODBUS_TCP = _default("modbus-tcp")


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
    add_transport_options(parser)
    add_drive_options(parser)


def add_transport_options(parser: argparse.ArgumentParser) -> None:
    """Where the drive is: each transport's options (one row each, c20sim.transport.rows), then the line's."""
    defaults = [
        row.options[0].flag + ("" if row.default is True else f" {row.default}")
        for row in rows()
        if row.default is not None
    ]
    posix = [row.options[0].flag for row in rows() if row.default is not None and row.posix_only is not None]
    where = parser.add_argument_group(
        f"endpoints (with none: {', '.join(defaults)}"
        + "".join(f"; no {flag} where there is no POSIX" for flag in posix)
        + ")",
        "The transports: " + "; ".join(f"{row.options[0].flag}, {row.help}" for row in rows()) + ".",
    )
    for row in rows():
        for option in row.options:
            if option.metavar is None:
                where.add_argument(option.flag, action="store_true", help=option.help)
            else:
                where.add_argument(option.flag, metavar=option.metavar, help=option.help)
    where.add_argument(
        "--baud",
        type=int,
        choices=BAUD_RATES,
        help="the drives' baud rate, F08.01 (default: the profile's or the state file's, 19200 as shipped)",
    )
    where.add_argument("--parity", default="N", choices=["N", "E", "O"], help="serial parity (default N)")
    where.add_argument("--stopbits", type=int, default=1, choices=[1, 2], help="serial stop bits (default 1)")
    where.add_argument("--line-timing", action="store_true", help="pace replies at the baud and enforce t1.5/t3.5")
    where.add_argument(
        "--bus-timing",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="each transaction holds the shared line for its RS485 time at the drives' baud and --parity/--stopbits, "
        "on every transport, as behind a serial device server (default on; --no-bus-timing: only the turnaround)",
    )
    where.add_argument(
        "--max-connections",
        metavar="N",
        type=int,
        help="connections each TCP port takes at once; the next is closed with one log line (default: 4 on --tcp, "
        "as a Moxa NPort's most; 32 on --modbus-tcp, as an MGate; docs/line-timing.md)",
    )
    where.add_argument(
        "--gateway-timeout",
        metavar="SECONDS",
        type=float,
        help="a TCP request that waited this long for the line, or got no reply on it, is answered 0x0B on "
        "--modbus-tcp and dropped on --tcp (default 1.0, an MGate's response timeout)",
    )
    add_control_options(where)


def add_control_options(where: argparse._ArgumentGroup) -> None:
    """The control API's and the metrics' listeners, and the API's token."""
    where.add_argument(
        "--control", metavar="HOST:PORT", help="HTTP JSON control API, such as 127.0.0.1:8020 (see c20sim ctl)"
    )
    where.add_argument(
        "--metrics",
        metavar="HOST:PORT",
        help="serve GET /metrics alone (Prometheus, read-only, no token), such as 0.0.0.0:9120",
    )
    where.add_argument(
        "--control-token",
        metavar="TOKEN",
        help="the token the control API asks for (beyond loopback one is generated and written to the ready file); "
        f"visible to every local user in the process list: prefer --control-token-file or ${TOKEN_ENV}",
    )
    where.add_argument(
        "--control-token-file",
        metavar="PATH",
        help=f"read the control API's token from this file (or give it in ${TOKEN_ENV})",
    )


def add_drive_options(parser: argparse.ArgumentParser) -> None:
    """What the drives are, and what serve keeps of them."""
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
        help="rotate the frame log at this size, keeping 3 old files (PATH.1 to PATH.3); default 100, 0 for no bound",
    )
    what.add_argument("--ready-file", metavar="PATH", help="write the real endpoint addresses as JSON when ready")
    what.add_argument(
        "--no-audit",
        dest="audit",
        action="store_false",
        help="do not audit the masters live (GET /audit; docs/audit.md); c20sim audit reads a frame log later",
    )


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
        **{dest: getattr(args, dest, None) for dest in endpoint_dests()},
        parity=args.parity,
        stopbits=args.stopbits,
        line_timing=args.line_timing,
        bus_timing=args.bus_timing,
        max_connections=getattr(args, "max_connections", None),
        gateway_timeout=1.0 if getattr(args, "gateway_timeout", None) is None else args.gateway_timeout,
        log_frames=args.log_frames,
        log_frames_max_mb=args.log_frames_max_mb,
        ready_file=args.ready_file,
        control=args.control,
        control_token=args.control_token,
        metrics=args.metrics,
        scenario=getattr(args, "scenario", None),
        audit=getattr(args, "audit", True),
        then=getattr(args, "then", None) or "exit",
    )
    if not options.any_endpoint:
        # each transport's default where it runs (no pty on Windows); most SCADA masters speak Modbus TCP: it has
        # a port of its own by default
        options.give_defaults()
    return options


def control_token(args: argparse.Namespace) -> str | None:
    """The control API's token: ``--control-token`` (warned: the process list shows it to every local user),
    ``--control-token-file``, or ``$C20SIM_CONTROL_TOKEN``; None for none."""
    given, path = args.control_token, args.control_token_file
    if given is not None and path is not None:
        raise UsageError("give --control-token or --control-token-file, not both")
    if given is not None:
        if not given.strip():
            raise C20SimError("--control-token: empty; give a token, or leave the option out")
        print(
            "c20sim: warning: --control-token: every user of this machine can read the token in the process list; "
            f"give it in a file (--control-token-file PATH) or in the environment (${TOKEN_ENV})",
            file=sys.stderr,
            flush=True,
        )
        return str(given)
    if path is not None:
        try:
            token = read_text(path, "token file").strip()
        except FileReadError as exc:
            raise C20SimError(f"--control-token-file {exc}") from None
        if not token:
            raise C20SimError(f"--control-token-file {path}: empty; put the token in it")
        if any(c.isspace() for c in token) or not token.isprintable():
            raise C20SimError(f"--control-token-file {path}: the token is one line of printable text, no spaces")
        _warn_if_readable(path)
        return token
    return os.environ.get(TOKEN_ENV) or None


def _warn_if_readable(path: str) -> None:
    """One line on stderr when the token file is readable by other users: taken, as ssh would not."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # read a moment ago: gone since, nothing to warn about
    who = [name for bit, name in ((stat.S_IRGRP, "its group"), (stat.S_IROTH, "every user")) if mode & bit]
    if who:
        print(
            f"c20sim: warning: --control-token-file {path}: readable by {' and '.join(who)} "
            f"(mode {stat.S_IMODE(mode):04o}); chmod 600 {path}",
            file=sys.stderr,
            flush=True,
        )


def cmd_serve(args: argparse.Namespace) -> int:
    args.control_token = control_token(args)
    options = serve_options(args)
    if args.then is not None and not options.scenario:
        raise UsageError("--then: it says what follows a --scenario; give --scenario FILE too, or leave --then out")
    if args.clock == "virtual" and options.control is None and (not options.scenario or options.then == "serve"):
        print(
            "c20sim: warning: --clock virtual without --control: nothing can advance the time, so the drives never "
            "move (ramps, trips, timeouts); add --control 127.0.0.1:0 and advance it with ctl advance, or use "
            "--clock realtime",
            file=sys.stderr,
            flush=True,
        )
    sim = build_simulator(args)
    return run(run_server(sim, options))  # 1 if a --scenario failed: CI sees it in the exit code


def cmd_dashboard(args: argparse.Namespace) -> int:
    from .tui.session import run_dashboard  # textual loads only for the dashboard

    args.control_token = control_token(args)
    return run_dashboard(args, args.serve_defaults)


def cmd_web(args: argparse.Namespace) -> int:
    from .tui.web import run_web  # textual-serve loads only for the browser view

    args.control_token = control_token(args)
    return run_web(args, args.serve_defaults)


#: What ``c20sim mcp`` says when the MCP SDK is not installed.
MCP_INSTALL = (
    "c20sim mcp needs the MCP SDK, an optional extra: pip install 'c20sim[mcp]' (in a clone: pip install -e '.[mcp]')"
)


def cmd_mcp(args: argparse.Namespace) -> int:
    args.control_token = control_token(args)
    try:
        from .mcpserver import run_mcp  # the mcp SDK loads only for this command
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != "mcp":
            raise
        raise C20SimError(MCP_INSTALL) from None
    return run_mcp(args, args.serve_defaults)


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
    if profile.levels:  # the cause rows' own keys (c20sim.drive.trips.Level)
        lines.append("the fault causes' own keys")
        lines += [f"  {key:<24} {value}" for key, value in profile.levels.items()]
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
    """argparse, but a bad option is one line (what is wrong, a "did you mean" where one is close, and the help of
    the command it was given to) and exit 2, as every other error of c20sim; ``--help`` still prints the whole
    usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message}{self._suggestion(message)} (see: {self.prog} --help)\n")

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        """As argparse's, but an unknown option is reported by the (sub)command it was given to, not the top."""
        parsed, extras = self.parse_known_args(args, namespace)
        trailing = getattr(parsed, "trailing_words", None)  # a command whose words may follow its options
        if extras and trailing is not None:
            extras = trailing(parsed, extras)
        if extras:
            chosen = self._chosen(parsed)
            chosen.error(f"unrecognized arguments: {' '.join(extras)}{chosen._did_you_mean(extras)}")
        return parsed

    def _chosen(self, parsed: argparse.Namespace) -> OneLineParser:
        """The deepest subcommand's parser that ``parsed`` went through (``c20sim ctl frames``)."""
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                name = getattr(parsed, action.dest, None) if action.dest != argparse.SUPPRESS else None
                found = action.choices.get(name) if isinstance(name, str) else None
                if isinstance(found, OneLineParser):
                    return found._chosen(parsed)
        return self

    def _did_you_mean(self, extras: Sequence[str]) -> str:
        known = [option for action in self._actions for option in action.option_strings]
        for word in extras:
            if word.startswith("-"):
                close = difflib.get_close_matches(word.split("=", 1)[0], known, n=1, cutoff=0.6)
                if close:
                    return f"; did you mean {close[0]}?"
        return ""

    @staticmethod
    def _suggestion(message: str) -> str:
        """A "did you mean" for a mistyped value of a choice (a command, a profile kind, a clock)."""
        found = _INVALID_CHOICE.search(message)
        if found is None:
            return ""
        choices = [c.strip().strip("'") for c in found.group(2).split(",")]
        close = difflib.get_close_matches(found.group(1), choices, n=1, cutoff=0.6)
        return f"; did you mean {close[0]}?" if close else ""


_INVALID_CHOICE = re.compile(r"invalid choice: '(.*?)' \(choose from (.*)\)$")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="c20sim",
        description="A virtual ZBLD.C20 brushless DC drive behind a Modbus RTU slave.",
    )
    sub = cast(
        "argparse._SubParsersAction[argparse.ArgumentParser]", parser.add_subparsers(dest="command", metavar="COMMAND")
    )

    add_decode_command(sub)
    add_audit_command(sub)
    add_drill_command(sub)

    profiles = sub.add_parser("profiles", help="list the shipped profiles, or show one")
    profiles.add_argument("action", nargs="?", choices=["list", "show"], default="list")
    profiles.add_argument("name", nargs="?", help="profile name or path (for show)")
    profiles.set_defaults(func=cmd_profiles)

    serve = sub.add_parser("serve", help="run the simulator headless until SIGINT or SIGTERM")
    add_endpoint_options(serve)
    serve.add_argument(
        "--scenario",
        metavar="FILE",
        help="play a TOML scenario against the served drives once ready, then stop with its exit code "
        "(0 passed, 1 failed) unless --then serve",
    )
    serve.add_argument(
        "--then",
        choices=["exit", "serve"],
        help="after --scenario: exit (the default: a CI job's serve ends) or serve on until SIGINT or SIGTERM",
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

    mcp = sub.add_parser(
        "mcp",
        help="the control API as Model Context Protocol tools on stdio, for an AI assistant (docs/mcp.md)",
        description="An MCP server on stdin/stdout: every operation of the control API is a tool; telemetry, "
        "frames and the audit are resources. It starts a serve with the options given, or attaches to one.",
    )
    add_endpoint_options(mcp)
    mcp.add_argument("--attach", metavar="READY_FILE|URL", help="attach to a running serve instead of starting one")
    mcp.set_defaults(func=cmd_mcp, serve_defaults={a.dest: a.default for a in mcp._actions})

    add_ctl_command(sub)
    add_run_scenario_command(sub)
    add_schema_command(sub)
    add_plant_commands(sub)
    add_record_command(sub)
    add_replay_command(sub)
    add_exercise_command(sub)
    add_fit_command(sub)
    add_site_command(sub)
    return parser


def with_default_command(argv: Sequence[str], commands: Iterable[str]) -> list[str]:
    """Bare ``c20sim`` and ``c20sim --pty --link /tmp/ttyC20`` mean the dashboard: its options need no command word.

    ``-h``/``--help`` alone still asks for the command list.
    A first word that is no option and no command is left where it is: a mistyped command (``c20sim serv``)
    is said as one, with a "did you mean", rather than as an argument the dashboard does not take.
    """
    words = list(argv)
    if not words:
        return ["dashboard"]
    if words[0] in commands or words[0] in ("-h", "--help") or not words[0].startswith("-"):
        return words
    return ["dashboard", *words]


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    commands = next(a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    args = parser.parse_args(with_default_command(sys.argv[1:] if argv is None else argv, commands or ()))
    try:
        result: int = args.func(args)
        if argv is None and args.func is cmd_serve:
            _leave(result)  # a process of its own (the c20sim command, python -m c20sim): nothing else runs after
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


def _leave(code: int) -> NoReturn:
    """End a ``serve`` process now that it has closed everything it opened, skipping the interpreter's teardown.

    By the time serve returns, its ports and link are closed, the ready file and the link are removed, the frame
    log's writer has written what it had and stopped, and the state file was saved at each write (c20sim registers
    no atexit handler and no finalizer). What the interpreter would do next is tear down some 400 modules, which
    took 0.1-0.3 s after a SIGTERM on an idle server (more on a loaded machine): a service manager, the dashboard
    and CI wait for that. Buffered output is written first.
    """
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a reader that has gone: nothing more to say to it
            stream.flush()
    os._exit(code)


def _stdout_gone() -> bool:
    """True when stdout is a pipe whose reader has closed it (POLLERR), so a BrokenPipeError was ours."""
    try:
        import select

        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):  # no poll (Windows), or no stdout to ask
        return True

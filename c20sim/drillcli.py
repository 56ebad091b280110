"""``c20sim drill``, the command: serves one drive, starts the master (or waits for one), plays the plan with
:func:`c20sim.drillrun.play`, and writes the reports; ``--judge LOG --plan PLAN`` judges a run's frame log
offline. Bad input is one line and exit 2 (:mod:`c20sim.cli` prints it); the master is always stopped.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import tempfile

from .drill import INCIDENTS
from .drill.judge import Judgement
from .drillrun import (
    RunOptions,
    drill_transports,
    json_report,
    judge_log,
    junit_xml,
    load_plan,
    markdown,
    marks_in,
    play,
    plot_timeline,
    text_report,
    write_file,
)
from .drive.profile import DEFAULT_PROFILE, available_profiles, load_profile
from .testing import C20Sim
from .wire.errors import C20SimError

__all__ = ["add_drill_command", "judge_command", "run_drill"]


def _endpoints(sim: C20Sim) -> dict[str, str]:
    """The master command's placeholders: each served transport's address by its ready-file key (``{tcp}``,
    ``{pty}``, ``{modbus_tcp}``, a new row's own), ``{KEY_port}`` of a HOST:PORT, and ``{host}``/``{port}`` of the
    first listener."""
    out: dict[str, str] = {}
    for key, address in sim.endpoints.items():
        out[key] = address
        host, colon, port = address.rpartition(":")
        if colon and port.isdigit():
            out[f"{key}_port"] = port
            out.setdefault("host", host)
    if sim.port is not None:
        out.update(host=str(sim.host), port=str(sim.port))
    return out


def run_drill(options: RunOptions) -> tuple[Judgement, str]:
    """Serve one drive for ``options`` and play its plan there; (the judgement, why it ended early or "")."""
    sim = C20Sim.start(
        options.profile, transport=options.transport, clock="realtime", seed=options.plan.seed, bus_timing=True
    )
    try:
        return play(sim, options, _endpoints(sim))
    finally:
        sim.close()


def judge_command(args: argparse.Namespace, log_path: str) -> str:
    """The ``c20sim drill --judge`` command that judges the frame log of the run ``args`` asked for exactly as the
    run did: the same plan (the file given, or the built-in standard plan of the same transport), seed and
    profile; paths made absolute, so that it works from any directory."""
    words = ["c20sim", "drill", "--judge", os.path.abspath(log_path)]
    if args.plan is not None:
        words += ["--plan", os.path.abspath(args.plan)]
    else:
        words += ["--transport", args.transport]  # the standard plan is the transport's: what it can carry
    if args.seed is not None:
        words += ["--seed", str(args.seed)]
    if args.profile != DEFAULT_PROFILE:
        shipped = args.profile in available_profiles()
        words += ["--profile", args.profile if shipped else os.path.abspath(args.profile)]
    return shlex.join(words)


def cmd_drill(args: argparse.Namespace) -> int:
    if args.list:
        for incident in INCIDENTS.values():
            print(f"{incident.name:<17} {incident.group:<6} {incident.does}")
        return 0
    profile = load_profile(args.profile)
    if args.wait is not None and not 0.1 <= args.wait <= 3600:
        raise C20SimError(f"--wait {args.wait:g}: expected 0.1 to 3600 seconds")
    early = ""
    if args.judge:
        if args.master is not None:
            raise C20SimError("--judge takes a frame log and --plan, not --master")
        plan = load_plan(args.plan, args.seed, args.transport if args.plan is None else None)
        judgement = judge_log(args.judge, plan, profile)
        log_path = args.judge
    else:
        plan = load_plan(args.plan, args.seed, args.transport)
        log_path = args.log or os.path.join(tempfile.gettempdir(), f"c20sim-drill-{os.getpid()}.jsonl")
        options = RunOptions(
            plan,
            transport=args.transport,
            master=args.master,
            profile=profile,
            wait=args.wait if args.wait is not None else (10.0 if args.master else 60.0),
            log=log_path,
            echo=(lambda line: print(line, file=sys.stderr)) if not args.quiet else (lambda line: None),
        )
        judgement, early = run_drill(options)
    if args.junit:
        write_file(args.junit, junit_xml(judgement), "--junit")
    if args.report:
        plot = None
        if args.plot is not False:
            png = os.path.splitext(args.report)[0] + ".png"
            frames, marks = marks_in(log_path)
            if plot_timeline(frames, marks, png):
                plot = os.path.basename(png)
        write_file(args.report, markdown(judgement, plan, plot, early).encode(), "--report")
    sys.stdout.write(json_report(judgement, early) if args.format == "json" else text_report(judgement, early))
    if not args.judge and not args.quiet:
        print(f"drill: frame log {log_path}; judged again by: {judge_command(args, log_path)}", file=sys.stderr)
    return 0 if judgement.passed and not early else 1


def add_drill_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "drill",
        help="play incidents on a running master and judge how it survives them, from the wire",
        description="Play a plan of incidents (docs/drill.md) on a master: reply faults, the line and the "
        "adapter, the drive's trips and power cycle; judge each from the frames. Exit 0 if every drill passed, "
        "1 if one failed, 2 on bad input.",
    )
    parser.add_argument("--plan", metavar="PLAN", help="a TOML plan (default: the built-in standard plan)")
    parser.add_argument(
        "--master",
        metavar="CMD",
        help="the master to start, with placeholders {host} {port} and the served transport's ready-file key: "
        "{tcp} {pty} {modbus_tcp} {modbus_tcp_port}; without it, wait for a master already running",
    )
    parser.add_argument(
        "--transport",
        choices=drill_transports(),
        default="tcp",
        help="where the drive is served (default tcp: RTU over TCP); the transports the test handle opens",
    )
    parser.add_argument("--profile", default=DEFAULT_PROFILE, help="the drive's profile")
    parser.add_argument("--seed", type=int, help="the faults' randomness (default: the plan's)")
    parser.add_argument(
        "--wait", type=float, help="seconds to wait for the master's first request (10 with --master, else 60)"
    )
    parser.add_argument(
        "--log", metavar="PATH", help="write the run's frame log here (default: a file in the temp directory)"
    )
    parser.add_argument(
        "--judge",
        metavar="LOG",
        help="judge a drill's frame log offline instead of running, against --plan (default: the standard plan "
        "for --transport)",
    )
    parser.add_argument("--format", choices=("text", "json"), default="text", help="the report's format")
    parser.add_argument("--junit", metavar="FILE", help="write a JUnit XML report: one test case per drill")
    parser.add_argument(
        "--report",
        metavar="FILE.md",
        help="write a Markdown report (and FILE.png, a timeline, where matplotlib is installed)",
    )
    parser.add_argument("--no-plot", dest="plot", action="store_false", default=None, help="no timeline plot")
    parser.add_argument("--list", action="store_true", help="list the incidents and exit")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    parser.set_defaults(func=cmd_drill)

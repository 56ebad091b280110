"""``c20sim fit LOG``: a profile fitted to a capture of a real drive.

The master's side of the log is played into the pure model in virtual time,
as ``c20sim replay`` plays it (:func:`c20sim.traffic.replay.exchanges` pairs
each request with its reply; the first frame is model time 0, and the model
runs exactly as long between two requests as the drive did). Each recorded
read of a physical quantity is compared with the model's value at the same
time, and bounded nonlinear least squares (:func:`scipy.optimize.least_squares`,
trust-region reflective, scaled by the Jacobian; a plain squared loss, since
the few reads taken in a ramp are the ones that carry the inertia) moves the
parameters the capture can reveal, within the ranges the profile format
allows, until model and drive agree:

========================  ===================================================
parameter                 what in the capture reveals it
========================  ===================================================
motor.kt_nm_per_a         output voltage 3003H against speed (Ke = Kt)
motor.inertia_kg_m2       current 3004H during ramps against constant speed
motor.friction_nm         current at constant speed (with viscous: >= 2 speeds)
motor.viscous_nm_per_krpm current at several constant speeds
supply.voltage_v          the bus 3008H at rest
supply.source_resistance  the bus sagging with the current drawn (a load)
thermal.time_constant_s   temperature 300CH rising (a long capture, a load)
thermal.resistance_k_per_w the temperature it rises to
protocol.turnaround_ms    the time from each request to its reply
========================  ===================================================

The model is compared by its values before they are rounded to a register's
resolution (so the fit sees a smooth function); the recorded value carries the
rounding, which is within the noise. A parameter whose fitted uncertainty (from
the Jacobian at the solution) is large against its value, or which nothing in
the capture moves, is "not identifiable from this capture" and is kept from
the base profile; the report says why. Status words and fault codes are
compared too (a state the model does not reach is reported, not fitted).

The new profile is the base profile's file with each fitted value replaced and
commented with its source (``fitted from LOG, +-x``); it is loaded with
c20sim's own loader before it is written. A load change the user made by hand
(``c20sim exercise --load-change``) is in the log as a ``mark``; its torque is
fitted too and reported, not written (it belongs to the bench, not the drive).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..core.clock import VirtualClock
from ..core.simulator import Simulator
from ..drive.profile import DEFAULT_PROFILE, Profile, load_profile
from ..wire.errors import C20SimError
from ..wire.registers import BAUD_RATES, FIXED_REGISTERS
from .fitcapture import Capture, _consistency, _load_records, load_capture
from .fitdialect import QuirkResult, learn_dialect, quirk_values
from .fitlink import LINKS
from .fitmodel import FitResult, Fitted, given_settings, simulate, with_values
from .fitreport import summary, write_profile, write_report
from .fitsolve import Problem, compared_reads, solve, turnaround, unrevealed
from .replay import replay

__all__ = ["Capture", "FitResult", "Fitted", "add_fit_command", "fit", "load_capture", "write_profile"]


def fit(capture: Capture, base: Profile, *, progress: Callable[[str], None] | None = None) -> FitResult:
    """Fit the parameters the capture reveals; the rest stay as in ``base``. The pipeline: the capture (read by
    :func:`load_capture`, with its link model) -> the compared reads and what they can reveal -> the drive model
    played along them -> the least squares -> the fitted profile and the report's figures."""
    try:
        import numpy  # noqa: F401 - the solve's
        import scipy.optimize  # noqa: F401
    except ImportError:
        raise C20SimError(
            "c20sim fit needs scipy, which the simulator itself does not: pip install 'c20sim[fit]'"
        ) from None
    started = time.perf_counter()
    compared, events = compared_reads(capture)
    problem = Problem.of(capture, base, compared, events)
    solution = solve(problem, unrevealed(capture, compared), progress or (lambda text: None))
    # the fitted profile holds only the identified values and the link's turnaround; it is what "after" shows
    final = with_values(problem.base, {f.parameter.name: f.value for f in solution.fitted if f.identified})
    dialect = learn_dialect(capture.probes, problem.base, modbus_tcp=capture.port == "modbus-tcp")
    found = masked_turnaround(turnaround(capture, problem.base), dialect)
    if found is not None and found.identified:
        final = with_values(final, {"protocol.turnaround_ms": found.value})
    final = with_values(final, quirk_values(dialect))
    after, states = solution.after, solution.states
    if final != solution.profile:
        after, states = simulate(final, capture, events, solution.load)
        problem.evaluations += 1
    notes = solution.notes
    if capture.settings:
        words = ", ".join(
            f"{FIXED_REGISTERS[a].name} {FIXED_REGISTERS[a].describe(v)}" for a, v in sorted(capture.settings.items())
        )
        notes.append(f"the drive's settings, read at the start and given to the model: {words}")
    notes += _consistency(capture)
    return FitResult(
        capture,
        problem.base,
        solution.fitted,
        found,
        solution.load_fit,
        problem.series(solution.before),
        problem.series(after),
        sum(1 for event, value in states if value != event.value),
        len(states),
        problem.evaluations,
        time.perf_counter() - started,
        notes,
        final,
        dialect,
    )


def masked_turnaround(found: Fitted | None, results: Sequence[QuirkResult]) -> Fitted | None:
    """The turnaround fitted, or not identified where the answer delay read (F08.04) is as long: the drive then
    answers after the delay it was told to keep, which hides its own processing time."""
    delay = next((r.learned.value for r in results if r.quirk.name == "answer_delay"), None)
    if found is None or not isinstance(delay, int | float) or not delay:
        return found
    if found.value > delay + 3 * found.sigma:
        return found
    why = (
        f"the drive answers after its answer delay ({delay:g} ms, read from F08.04), which hides its own "
        "turnaround: set F08.04 to 0 on the drive for a capture that shows it"
    )
    return dataclasses.replace(found, identified=False, why=why)


def cmd_fit(args: argparse.Namespace) -> int:
    base = load_profile(args.profile)
    out = Path(args.out)
    if out.suffix != ".toml":
        raise C20SimError(f"--out {out}: a profile is a .toml file, such as mydrive.toml")
    link = args.link or {"included": "sniffer", "excluded": "bare"}.get(args.wire_time)
    capture = load_capture(args.log, base, args.address, link=link, baud=args.baud)
    result = fit(capture, base, progress=lambda s: print(s, file=sys.stderr))
    log_name = Path(args.log).name
    profile = write_profile(result, out, log_name)
    for line in summary(result):
        print(line)
    print(f"wrote {out} ({profile.name}); compare: c20sim replay {args.log} --profile {out}")
    if args.report:
        written = write_report(result, Path(args.report), out)
        print(f"report: {written[0]} ({len(written) - 1} plot file(s))")
    # the replay against the fitted profile: the byte-for-byte view of what remains
    sim = given_settings(Simulator(profile, [capture.address], clock=VirtualClock()), capture)
    records = _load_records(args.log)
    replayed = replay(records, sim)
    print(
        f"replay against {out}: {replayed.exchanges - len(replayed.differences)} of {replayed.exchanges} replies "
        "match byte for byte; the rms differences above say by how much the rest differ"
    )
    return 0


def add_fit_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "fit",
        help="fit a profile to a capture of a real drive (c20sim exercise --out, record, serve --log-frames)",
        description="Play the master's side of a frame log into the model in virtual time, compare every read of a "
        "physical quantity, and fit what the capture reveals (Kt, inertia, friction, supply, thermal, turnaround) "
        "with bounded least squares; write a profile with each fitted value and its source.",
    )
    parser.add_argument("log", help="the JSONL frame log")
    parser.add_argument("--profile", default=DEFAULT_PROFILE, help=f"the base profile (default {DEFAULT_PROFILE})")
    parser.add_argument("--out", required=True, metavar="FILE.toml", help="the fitted profile to write")
    parser.add_argument("--report", metavar="DIR", help="write report.md and residual plots (PNG, SVG) here")
    parser.add_argument("--address", type=int, help="the drive to fit (default: the one answering most)")
    parser.add_argument(
        "--baud", type=int, choices=BAUD_RATES, help="the line's baud (default: the capture's header, or the profile's)"
    )
    parser.add_argument(
        "--link",
        choices=list(LINKS),
        help="how the capture was carried, where its header and times cannot tell (docs/fit.md, 'What each link adds')",
    )
    parser.add_argument(
        "--wire-time",
        default="auto",
        choices=["auto", "included", "excluded"],
        help="older spelling of --link: included is --link sniffer, excluded --link bare",
    )
    parser.set_defaults(func=cmd_fit)

"""``c20sim run-scenario``: scenario files in virtual time, many at once, with a JUnit report for CI.

Each file is played in its own simulator, in worker processes (``--jobs``),
instantly in virtual time (:func:`c20sim.scenario.timeline.run`). One file prints its
full report; several print one line per scenario, in the order given, then a
summary. Exit 0 if every expectation holds, 1 if one fails, 2 if a file cannot
be loaded or played (its line says which file, step and key).

``--junit PATH`` writes JUnit XML: one ``testsuite`` with one ``testcase``
per scenario; a failed expectation is a ``failure`` (its message the first
failed check, its text the full report), a bad file an ``error``.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from ..wire.errors import C20SimError

__all__ = ["Result", "add_run_scenario_command", "expand", "junit_xml", "run_file"]

#: The most worker processes ``--jobs`` may ask for.
MAX_JOBS = 64


@dataclass(frozen=True)
class Result:
    """What became of one scenario file."""

    path: str
    name: str
    status: str  #: "passed", "failed" or "error"
    checks: int
    failed: int
    seconds: float  #: wall seconds to load and play it (the JUnit time)
    report: str  #: the full report, or the error line
    first_failure: str = ""

    @property
    def line(self) -> str:
        """The one line ``run-scenario`` prints for this scenario."""
        if self.status == "error":  # the error names its file already, as ScenarioError does
            return f"ERROR {self.report}" if self.report.startswith(self.path) else f"ERROR {self.path}: {self.report}"
        head = f"{'PASS ' if self.status == 'passed' else 'FAIL '} {self.name} ({self.path})"
        if self.status == "passed":
            return f"{head}: {self.checks} check(s)"
        return f"{head}: {self.failed} of {self.checks} check(s) failed; first: {self.first_failure}"


def expand(patterns: Sequence[str]) -> list[str]:
    """Files, directories (their ``*.toml``) and globs (``**`` included) -> the files, in order, each once.

    Raises C20SimError for a pattern that matches nothing.
    """
    found: list[str] = []
    for pattern in patterns:
        if os.path.isdir(pattern):
            matches = sorted(str(p) for p in Path(pattern).glob("*.toml"))
        elif glob.has_magic(pattern):
            matches = sorted(glob.glob(pattern, recursive=True))
        else:
            matches = [pattern]  # a plain name: its own line says if it cannot be read
        if not matches:
            raise C20SimError(f"{pattern}: no scenario file matches")
        found += [m for m in matches if m not in found]
    return found


def run_file(path: str, profile: str | None = None, drives: str | None = None, seed: int = 1) -> Result:
    """Load and play one scenario file; never raises for a bad file (its Result says what is wrong)."""
    from ..core.simulator import Simulator, parse_addresses
    from ..drive.profile import DEFAULT_PROFILE, load_profile
    from .timeline import load_scenario, run

    started = time.perf_counter()
    name = Path(path).stem
    try:
        scenario = load_scenario(path)
        name = scenario.name
        loaded = load_profile(profile or scenario.profile or DEFAULT_PROFILE)
        addresses = parse_addresses(drives) if drives else list(scenario.drives or (1,))
        report = run(scenario, Simulator(loaded, addresses, seed=seed))
    except C20SimError as exc:
        return Result(path, name, "error", 0, 0, time.perf_counter() - started, str(exc))
    failures = report.failures
    first = f"{failures[0].step.label}: {failures[0].text}" if failures else ""
    return Result(
        path,
        scenario.name,
        "passed" if report.ok else "failed",
        len(report.outcomes),
        len(failures),
        time.perf_counter() - started,
        report.render(),
        first,
    )


def _run_args(item: tuple[str, str | None, str | None, int]) -> Result:
    return run_file(*item)


def run_files(
    paths: Sequence[str], *, profile: str | None = None, drives: str | None = None, seed: int = 1, jobs: int = 1
) -> Iterator[Result]:
    """Each file's Result, in the order given; with ``jobs`` > 1, played in that many worker processes."""
    items = [(path, profile, drives, seed) for path in paths]
    if jobs <= 1 or len(items) <= 1:
        yield from map(_run_args, items)
        return
    with ProcessPoolExecutor(max_workers=min(jobs, len(items))) as pool:
        yield from pool.map(_run_args, items, chunksize=max(1, len(items) // (4 * jobs)))


def junit_xml(results: Sequence[Result], suite: str = "c20sim scenarios") -> bytes:
    """JUnit XML for ``results``: one testsuite, a testcase per scenario, failures and errors counted."""
    failures = sum(r.status == "failed" for r in results)
    errors = sum(r.status == "error" for r in results)
    total = sum(r.seconds for r in results)
    root = ET.Element("testsuites", tests=str(len(results)), failures=str(failures), errors=str(errors))
    root.set("time", f"{total:.3f}")
    node = ET.SubElement(
        root, "testsuite", name=suite, tests=str(len(results)), failures=str(failures), errors=str(errors)
    )
    node.set("skipped", "0")
    node.set("time", f"{total:.3f}")
    for result in results:
        case = ET.SubElement(
            node, "testcase", name=result.name, classname=f"scenarios.{Path(result.path).stem}", file=result.path
        )
        case.set("time", f"{result.seconds:.3f}")
        if result.status == "failed":
            failure = ET.SubElement(case, "failure", message=result.first_failure, type="ScenarioFailure")
            failure.text = result.report
        elif result.status == "error":
            error = ET.SubElement(case, "error", message=result.report, type="ScenarioError")
            error.text = result.report
        else:
            ET.SubElement(case, "system-out").text = result.report
    ET.indent(root)
    text: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return text + b"\n"


def _jobs(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 1 <= value <= MAX_JOBS:
        raise argparse.ArgumentTypeError(f"{value} is outside 1-{MAX_JOBS}")
    return value


def cmd_run_scenario(args: argparse.Namespace) -> int:
    paths = expand(args.files)
    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, MAX_JOBS)
    results: list[Result] = []
    single = len(paths) == 1  # one file: its full report, or its error as one line on stderr, as before
    for result in run_files(paths, profile=args.profile, drives=args.drives, seed=args.seed, jobs=jobs):
        results.append(result)
        if single:
            if result.status != "error":
                sys.stdout.write(result.report)
            continue
        print(result.line, flush=True)
        if args.verbose and result.status != "error":
            sys.stdout.write(result.report)
    if args.junit:
        try:
            Path(args.junit).write_bytes(junit_xml(results))
        except OSError as exc:
            raise C20SimError(f"--junit {args.junit}: cannot write: {exc.strerror}") from None
    if single and results[0].status == "error":
        raise C20SimError(results[0].report)
    passed = sum(r.status == "passed" for r in results)
    failed = sum(r.status == "failed" for r in results)
    errors = sum(r.status == "error" for r in results)
    if not single:
        print(f"{len(results)} scenario(s): {passed} passed, {failed} failed, {errors} error(s)")
    return 2 if errors else 1 if failed else 0


def add_run_scenario_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    run_parser = sub.add_parser(
        "run-scenario",
        help="play scenario files in virtual time; exit 1 if an expectation fails",
        description="Play TOML scenarios in virtual time, instantly, in parallel processes. One file prints "
        "every check; several print one line per scenario. Exit 0 if all hold, 1 if one fails, 2 if a file is bad.",
    )
    run_parser.add_argument(
        "files", nargs="+", metavar="FILE", help="scenario files, directories or globs, such as 'scenarios/*.toml'"
    )
    run_parser.add_argument("--profile", help="profile name or path (default: each scenario's, or c20-400hr)")
    run_parser.add_argument("--drives", metavar="LIST", help="drive addresses (default: the scenario's, or 1)")
    run_parser.add_argument("--seed", type=int, default=1, help="seed for random link faults (default 1)")
    run_parser.add_argument(
        "--jobs", "-j", type=_jobs, metavar="N", help="worker processes (default: the number of CPUs)"
    )
    run_parser.add_argument("--junit", metavar="PATH", help="write a JUnit XML report here, for CI")
    run_parser.add_argument(
        "--verbose", "-v", action="store_true", help="with several files, print each full report too"
    )
    run_parser.set_defaults(func=cmd_run_scenario)

"""Scenarios at scale: 100 scenario files through ``c20sim run-scenario`` in parallel, time per scenario.

Writes 100 scenario files into a temporary directory: the three shipped
scenarios (undervoltage, overload, communication timeout) and one using the
new expectations (a refusal, a silence, an eventual state), in turn, each
under its own name. Then runs ``python -m c20sim run-scenario DIR/*.toml
--junit F --jobs N`` as a fresh process for each N, several times,
interleaved, and prints the wall time of the whole command (median, min,
max) and per scenario (median / 100); one file alone is the command's fixed
cost (interpreter, imports, one profile). The JUnit file of each run is parsed
and must count 100 tests and no failure. ``python -c pass`` is timed in the
same run as the floor of any Python process on this machine. The CPU time to
load and play one scenario in this process (``time.process_time``, which
other processes' load does not inflate) is printed first: the work the
worker processes share out.

    .venv/bin/python bench/bench_scenarios.py [--runs 5] [--count 100] [--jobs 1,2]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

EXPECTATIONS = """\
name = "expectations {n}"
[[step]]
at = 0
write = {{ "2001H" = 1500, "2000H" = 1 }}
[[step]]
at = 0.1
write = {{ "2002H" = 4 }}
expect_exception = 8
[[step]]
at = 0.1
within = 2.0
expect = {{ motor_speed = 1500, status1 = 1 }}
[[step]]
at = 3
link = {{ offline = true }}
expect_silence = true
"""


def make_suite(directory: Path, count: int) -> None:
    shipped = sorted((ROOT / "scenarios").glob("*.toml"))
    for n in range(count):
        kind = n % (len(shipped) + 1)
        target = directory / f"s{n:03d}.toml"
        if kind < len(shipped):
            shutil.copy(shipped[kind], target)
        else:
            target.write_text(EXPECTATIONS.format(n=n))


def run_suite(files: list[str], jobs: int, junit: Path) -> float:
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "run-scenario", *files, "--junit", str(junit), "--jobs", str(jobs)],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
    )
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise SystemExit(f"run-scenario exited {result.returncode}:\n{result.stdout[-2000:]}{result.stderr}")
    suite = ET.parse(junit).getroot().find("testsuite")
    assert suite is not None
    counts = (suite.get("tests"), suite.get("failures"), suite.get("errors"))
    if counts != (str(len(files)), "0", "0"):
        raise SystemExit(f"JUnit counts {counts}, expected ({len(files)}, 0, 0)")
    return elapsed


def cpu_per_scenario(files: list[str]) -> float:
    """Mean CPU seconds (process_time: not inflated by other processes' load) of run_file, in this process."""
    sys.path.insert(0, str(ROOT))
    from c20sim.scenario.suite import run_file

    run_file(files[0])  # imports and caches first
    start = time.process_time()
    for path in files:
        assert run_file(path).status == "passed", path
    return (time.process_time() - start) / len(files)


def time_pass() -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--count", type=int, default=100)
    parser.add_argument("--jobs", default="1,2", help="comma-separated worker counts to compare")
    args = parser.parse_args()
    jobs = [int(j) for j in args.jobs.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp)
        make_suite(directory, args.count)
        files = sorted(str(p) for p in directory.glob("*.toml"))
        times: dict[str, list[float]] = {"python -c pass": [], "one file": []} | {f"--jobs {j}": [] for j in jobs}
        for _ in range(args.runs):
            times["python -c pass"].append(time_pass())
            times["one file"].append(run_suite(files[:1], 1, directory / "one.xml"))
            for j in jobs:
                times[f"--jobs {j}"].append(run_suite(files, j, directory / "junit.xml"))
        cpu = cpu_per_scenario(files)
    print(f"{args.count} scenarios, {args.runs} runs each, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}")
    print(f"CPU to load and play one scenario, in this process: {cpu * 1000:.1f} ms (mean of {len(files)})")
    print(f"{'case':<16} {'median':>8} {'min':>8} {'max':>8} (s)   per scenario (ms, median)")
    for case, values in times.items():
        per = "" if not case.startswith("--jobs") else f"{statistics.median(values) / args.count * 1000:8.1f}"
        print(f"{case:<16} {statistics.median(values):8.3f} {min(values):8.3f} {max(values):8.3f}       {per}")


if __name__ == "__main__":
    main()

"""Start-up: time from process start to the ready file of ``c20sim serve``, over several runs.

Each run starts ``python -m c20sim serve --tcp 127.0.0.1:0 --ready-file F`` (and
variants) as a fresh process, waits for the ready file to appear, then stops
the server with SIGTERM. ``python -c pass`` is timed the same way (to its exit)
as the floor of any Python process on this machine, in the same run, because
the machine is noisy. Prints median, min and max in milliseconds.

    .venv/bin/python bench/bench_startup.py [--runs 15]
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES: dict[str, list[str]] = {
    "serve --tcp": ["--tcp", "127.0.0.1:0"],
    "serve --tcp --pty": ["--tcp", "127.0.0.1:0", "--pty"],
    "serve --tcp --control": ["--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"],
    "serve --clock virtual --tcp --control": ["--clock", "virtual", "--tcp", "127.0.0.1:0", "--control", "127.0.0.1:0"],
}


def time_pass() -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - start


def time_serve(options: list[str], ready: Path) -> float:
    ready.unlink(missing_ok=True)
    start = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", "serve", *options, "--ready-file", str(ready)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        while not ready.exists():
            if proc.poll() is not None:
                raise SystemExit(
                    f"serve {' '.join(options)} exited: {proc.stderr.read().decode() if proc.stderr else ''}"
                )
            time.sleep(0.001)
        return time.perf_counter() - start
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / "ready.json"
        time_serve(CASES["serve --tcp"], ready)  # warm the file cache, compile .pyc
        results: dict[str, list[float]] = {"python -c pass": [], **{name: [] for name in CASES}}
        for _ in range(args.runs):  # interleaved, so that noise hits every case alike
            results["python -c pass"].append(time_pass())
            for name, options in CASES.items():
                results[name].append(time_serve(options, ready))
    print(f"Python {sys.version.split()[0]}, {os.cpu_count()} CPUs, {args.runs} runs each\n")
    print(f"{'case':<40} {'median':>8} {'min':>8} {'max':>8}  (ms)")
    for name, times in results.items():
        ms = [t * 1000 for t in times]
        print(f"{name:<40} {statistics.median(ms):8.0f} {min(ms):8.0f} {max(ms):8.0f}")


if __name__ == "__main__":
    main()

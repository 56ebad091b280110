"""What one ``c20sim ctl`` call costs since ctl calls through the API's one client (``ControlClient``, one kept-alive
connection per action), beside urllib with a connection per call (what ctl did before, rebuilt here as the baseline).

One ``c20sim serve --clock virtual --control`` process. Rounds alternate: ``--calls`` calls by the baseline
(``urllib.request.urlopen``, a connection each, as ``c20sim.control.ctl.call`` was), then the same calls by
``ctl.call`` over one :class:`~c20sim.control.client.ControlClient`. The figure is the client's p50 and p99 as a
ratio of the baseline's, from the same run. ``ctl clear`` makes four calls, ``ctl state`` two: a ctl process pays
the saving that many times (its interpreter's start dwarfs both; bench_startup.py has that).

    .venv/bin/python bench/bench_ctl.py --calls 500 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from _common import machine, percentile

from c20sim.control.client import ControlClient
from c20sim.control.ctl import call

#: (method, path, body): a reading, a reading of a drive, a change
CALLS = (("GET", "/time", None), ("GET", "/drives/1", None), ("POST", "/time/advance", {"seconds": 0.01}))


def start_serve(tmp: Path) -> tuple[subprocess.Popen[bytes], Path]:
    ready = tmp / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--clock", "virtual", "--tcp", "127.0.0.1:0"]
    proc = subprocess.Popen([*command, "--control", "127.0.0.1:0", "--ready-file", str(ready)])
    deadline = time.monotonic() + 30
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("serve did not become ready")
        time.sleep(0.05)
    return proc, ready


def urllib_call(url: str, method: str, path: str, data: object) -> Any:
    """The baseline: one request with urllib, a connection of its own (ctl's client before)."""
    request = urllib.request.Request(
        url + path, data=None if data is None else json.dumps(data).encode(), method=method
    )
    if method != "GET":
        request.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(request, timeout=10.0) as response:
        return json.loads(response.read() or b"null")


def row(label: str, samples: list[float], base: list[float] | None = None) -> str:
    values = sorted(samples)
    p50, p99 = percentile(values, 50) * 1e6, percentile(values, 99) * 1e6
    text = f"{label:<34}{len(values):>7}{p50:>10.0f}{p99:>10.0f}"
    if base is not None:
        b = sorted(base)
        text += f"    p50 {p50 / (percentile(b, 50) * 1e6):.2f}x, p99 {p99 / (percentile(b, 99) * 1e6):.2f}x"
    return text


def main(calls: int, rounds: int) -> None:
    with tempfile.TemporaryDirectory(prefix="c20sim-bench-") as tmp:
        serve, ready = start_serve(Path(tmp))
        try:
            url = json.loads(ready.read_text())["control"]
            client = ControlClient(url, timeout=10.0)
            print(machine())
            print(f"{rounds} rounds x {calls} calls of each; microseconds a call")
            print(f"{'':<34}{'calls':>7}{'p50 us':>10}{'p99 us':>10}")
            for method, path, body in CALLS:
                before: list[float] = []
                now: list[float] = []
                for _ in range(rounds):
                    for _ in range(calls):
                        t = time.perf_counter()
                        urllib_call(url, method, path, body)
                        before.append(time.perf_counter() - t)
                    for _ in range(calls):
                        t = time.perf_counter()
                        call(url, method, path, body, client=client)
                        now.append(time.perf_counter() - t)
                print(f"{method} {path}:")
                print(row("  urllib, a connection a call", before))
                print(row("  ctl.call over one ControlClient", now, before))
            client.close()
        finally:
            serve.terminate()
            serve.wait(10)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    main(args.calls, args.rounds)

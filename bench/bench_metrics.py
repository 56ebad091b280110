"""What a Prometheus scrape costs the wire: reply latency with ``GET /metrics`` scraped, against without.

One ``c20sim serve`` process (RTU over TCP, a ``--metrics`` listener, the
default profile with its turnaround set to 0 and ``--no-bus-timing``, so that
the server's own time is what is measured; ``--bus-timing`` for the line's) and one lean blocking master (bench/_common.py) reading
2100H in a loop. Rounds alternate: quiet (no scrape) and scraped (a thread
fetching /metrics every ``--every`` seconds, 1 s by default, as a Prometheus
would; ``--every 0.01`` is a hundred times that). The figure is the ratio of
the scraped rounds' p50 and p99 to the quiet rounds', from the same process
in the same run; the machine's noise falls on both alike.

    .venv/bin/python bench/bench_metrics.py --seconds 10 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

from _common import RawRtuClient, machine, percentile

from c20sim.drive.profile import profile_path
from c20sim.wire.protocol import ReadRequest, encode
from c20sim.wire.registers import Reg


def start_server(tmp: Path, bus_timing: bool) -> tuple[subprocess.Popen[bytes], int, str]:
    profile = tmp / "fast.toml"
    text = profile_path("c20-400hr").read_text(encoding="utf-8")
    profile.write_text(text.replace("turnaround_ms = 2.0", "turnaround_ms = 0.0", 1), encoding="utf-8")
    ready = tmp / "ready.json"
    command = [sys.executable, "-m", "c20sim", "serve", "--profile", str(profile), "--tcp", "127.0.0.1:0"]
    if not bus_timing:
        command.append("--no-bus-timing")  # the server's own time, not the RS485 line's 11.5 ms a read
    proc = subprocess.Popen([*command, "--metrics", "127.0.0.1:0", "--ready-file", str(ready)])
    deadline = time.monotonic() + 20
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("serve did not become ready")
        time.sleep(0.05)
    info = json.loads(ready.read_text())
    return proc, int(info["tcp"].rsplit(":", 1)[1]), info["metrics"]


def poll(client: RawRtuClient, seconds: float) -> list[float]:
    frame = encode(ReadRequest(1, Reg.STATUS1, 1))
    latencies: list[float] = []
    perf = time.perf_counter
    end = perf() + seconds
    while (t := perf()) < end:
        client.transact(frame)
        latencies.append(perf() - t)
    return latencies


def scraper(url: str, every: float, stop: threading.Event, count: list[int]) -> None:
    while not stop.wait(every):
        with urllib.request.urlopen(url, timeout=5) as response:
            response.read()
        count[0] += 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="each round's length")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of each kind, alternating")
    parser.add_argument("--every", type=float, default=1.0, help="seconds between scrapes")
    parser.add_argument("--bus-timing", action="store_true", help="serve with bus timing (the line's real time)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        proc, port, url = start_server(Path(tmp), args.bus_timing)
        try:
            client = RawRtuClient("127.0.0.1", port)
            poll(client, 1.0)  # warm up
            quiet: list[float] = []
            scraped: list[float] = []
            scrapes = [0]
            for _ in range(args.rounds):
                quiet += poll(client, args.seconds)
                stop = threading.Event()
                thread = threading.Thread(target=scraper, args=(url, args.every, stop, scrapes), daemon=True)
                thread.start()
                scraped += poll(client, args.seconds)
                stop.set()
                thread.join()
            client.close()
        finally:
            proc.terminate()
            proc.wait(10)
    timing = "bus timing on" if args.bus_timing else "--no-bus-timing"
    print(
        f"# {machine()}; {args.rounds} x {args.seconds:g} s rounds of each kind; a scrape every {args.every:g} s; {timing}"
    )
    print(f"{'':<22} {'requests':>9} {'p50 us':>8} {'p99 us':>8} {'max us':>8}")
    figures = {}
    for name, latencies in (("quiet", quiet), (f"scraped ({scrapes[0]} scrapes)", scraped)):
        latencies.sort()
        p50, p99 = percentile(latencies, 50) * 1e6, percentile(latencies, 99) * 1e6
        figures[name.split()[0]] = (p50, p99)
        print(f"{name:<22} {len(latencies):>9} {p50:>8.1f} {p99:>8.1f} {latencies[-1] * 1e6:>8.0f}")
    (q50, q99), (s50, s99) = figures["quiet"], figures["scraped"]
    print(f"scraped / quiet: p50 {s50 / q50:.3f}x, p99 {s99 / q99:.3f}x")


if __name__ == "__main__":
    main()

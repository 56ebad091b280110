"""The turnaround ``c20sim fit`` finds over each link a plant uses, against the drive's own, and serve's timer.

A drive with a 3.2 ms turnaround, Kt 0.140, inertia 4.5e-4 and friction 0.030 (the shipped profile: 2 ms,
0.127, 3e-4, 0.02) is
served by ``c20sim serve --pty --line-timing --tcp --modbus-tcp`` (bus timing
on, the default); ``c20sim exercise`` runs the identification programme over
each endpoint (``--hold 2 --rate 10 --speeds 1000,2000``); ``fit`` reads each
capture. Printed per link: the link fit told, the turnaround it found, its
error against 3.2 ms in ms and in its own quoted uncertainties, the late
transactions; then, alone, how late the event loop's timer that serve hands
TCP replies over with (:class:`c20sim.transport.line.DueTimer`) fires for a
14.66 ms wait (a one-register read's transaction at 19200 8N1).

Run alone: .venv/bin/python bench/bench_fit_links.py
"""

from __future__ import annotations

import asyncio
import json
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from c20sim.drive.profile import load_profile  # noqa: E402
from c20sim.traffic.fit import fit, load_capture  # noqa: E402
from c20sim.transport.line import DueTimer  # noqa: E402

TRUTH_MS = 3.2
#: the served drive's physics, changed from the shipped (0.127, 0.0003, 0.02)
PHYSICS = {"kt_nm_per_a": 0.140, "inertia_kg_m2": 4.5e-4, "friction_nm": 0.030}


def timer_lateness(rounds: int = 100) -> list[float]:
    async def measure() -> list[float]:
        loop = asyncio.get_running_loop()
        late: list[float] = []
        for _ in range(rounds):
            done: asyncio.Future[float] = loop.create_future()
            due = time.perf_counter() + 0.01466
            DueTimer(loop, due, lambda d=due, f=done: f.set_result(time.perf_counter() - d))
            late.append(await done)
            await asyncio.sleep(0.02)
        return sorted(late)

    try:
        import uvloop

        return uvloop.run(measure())
    except ImportError:
        return asyncio.run(measure())


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        truth = folder / "truth.toml"
        text = Path(load_profile().path).read_text().replace("turnaround_ms = 2.0", f"turnaround_ms = {TRUTH_MS}", 1)
        for key, value in PHYSICS.items():
            text = re.sub(rf"(?m)^{key} = [0-9.e-]+", f"{key} = {value}", text, count=1)
        truth.write_text(text)
        ready = folder / "ready.json"
        args = ["--pty", "--line-timing", "--tcp", "127.0.0.1:0", "--modbus-tcp", "127.0.0.1:0", "--no-audit"]
        serve = subprocess.Popen(
            [sys.executable, "-m", "c20sim", "serve", *args, "--profile", str(truth), "--ready-file", str(ready)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            while not ready.exists():
                if serve.poll() is not None:
                    raise SystemExit("serve ended before it was ready")
                time.sleep(0.05)
            time.sleep(0.2)
            ports = json.loads(ready.read_text())
            base = load_profile()
            for key, scheme in (("pty", ""), ("tcp", "tcp://"), ("modbus_tcp", "modbus-tcp://")):
                out = folder / f"{key}.jsonl"
                cmd = [sys.executable, "-m", "c20sim", "exercise", scheme + ports[key], "--out", str(out)]
                subprocess.run(
                    [*cmd, "--hold", "2", "--rate", "10", "--speeds", "1000,2000"], capture_output=True, check=True
                )
                capture = load_capture(str(out), base)
                result = fit(capture, base)
                assert result.turnaround is not None
                t = result.turnaround
                delayed = capture.turnaround[2] if capture.turnaround else 0
                print(
                    f"{key:<11} link {capture.link.name:<14} turnaround {t.value:5.2f} ms +-{t.sigma:.2f}  error "
                    f"{t.value - TRUTH_MS:+.2f} ms = {(t.value - TRUTH_MS) / t.sigma:+.1f} sigma; "
                    f"{delayed} of {len(capture.timings)} transactions over 1 ms later"
                )
                for f in result.fitted:
                    if f.parameter.key in PHYSICS:
                        true = PHYSICS[f.parameter.key]
                        words = (
                            f"{f.value:.4g} +-{f.sigma:.2g}: {100 * (f.value - true) / true:+.2f} % "
                            f"= {(f.value - true) / f.sigma:+.1f} sigma"
                            if f.identified
                            else f"not written ({f.why[:60]})"
                        )
                        print(f"            {f.parameter.key:<14} (true {true:g}) {words}")
        finally:
            serve.kill()
            serve.wait()
    late = timer_lateness()
    print(
        f"DueTimer, a 14.66 ms wait, {len(late)} times: late by {late[0] * 1e3:.2f} ms at least, "
        f"{statistics.median(late) * 1e3:.2f} median, {late[int(0.9 * len(late))] * 1e3:.2f} at the 90th percentile"
    )


if __name__ == "__main__":
    main()

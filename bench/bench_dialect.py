"""What ``c20sim exercise --dialect-only`` costs on each link, and whether ``fit`` learns the dialect from it.

A drive whose dialect differs from the shipped profile's (reply_to_bad_crc false, max_read_registers 8,
byte_count_exception 3, ram_only_alias false) is served by ``c20sim serve --pty --line-timing --tcp
--modbus-tcp``; the probe runs over each endpoint, and ``fit`` reads each capture from the shipped profile.
Printed per link: the probe's requests, those unanswered (a bad CRC, a short frame, a broadcast: the master's
0.5 s timeout each), its time in the capture and with the process's start, the answered requests' time from
request to reply against what the link's arithmetic (fitlink.py, 19200 8N1) and the 2 ms turnaround make it (the
ratio), fit's time, the quirks learned right of the four changed, and the replies replay finds different against
the fitted profile.

Run alone: .venv/bin/python bench/bench_dialect.py
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from c20sim.core.clock import VirtualClock  # noqa: E402
from c20sim.core.simulator import Simulator  # noqa: E402
from c20sim.drive.profile import load_profile  # noqa: E402
from c20sim.traffic.capture import load_frame_log  # noqa: E402
from c20sim.traffic.fit import fit, load_capture  # noqa: E402
from c20sim.traffic.fitreport import write_profile  # noqa: E402
from c20sim.traffic.replay import replay  # noqa: E402

TRUTH = {"reply_to_bad_crc": False, "max_read_registers": 8, "byte_count_exception": 3, "ram_only_alias": False}
TURNAROUND_S = 0.002  #: the served drive's (the shipped profile's)


def main() -> None:
    shipped = load_profile()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        text = Path(shipped.path).read_text()
        for key, value in TRUTH.items():
            text = text.replace(f"{key} = {str(getattr(shipped.protocol, key)).lower()}", f"{key} = {value}", 1)
        truth = folder / "truth.toml"
        truth.write_text(text.replace("= False", "= false").replace("= True", "= true"))
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
            ports = json.loads(ready.read_text())
            for key, scheme, link in (
                ("pty", "", None),
                ("tcp", "tcp://", "device-server"),
                ("modbus_tcp", "modbus-tcp://", "gateway"),
            ):
                out = folder / f"{key}.jsonl"
                cmd = [
                    sys.executable,
                    "-m",
                    "c20sim",
                    "exercise",
                    scheme + ports[key],
                    "--dialect-only",
                    "--out",
                    str(out),
                ]
                started = time.perf_counter()
                subprocess.run(cmd, capture_output=True, check=True)
                wall = time.perf_counter() - started
                records = load_frame_log(str(out))
                requests = [r for r in records if r.direction == "rx" and r.data]
                span = records[-1].t - requests[0].t
                started = time.perf_counter()
                capture = load_capture(str(out), shipped, link=link)
                result = fit(capture, shipped)
                fit_s = time.perf_counter() - started
                taken = sum(t.reply_t - t.request_t for t in capture.timings)
                model = capture.link
                line = sum(model.fixed(t.request_len, t.reply_len, 19200, 10) + TURNAROUND_S for t in capture.timings)
                silent = len(requests) - len(capture.timings)
                fitted = write_profile(result, folder / f"{key}.toml", out.name)
                right = sum(getattr(fitted.protocol, k) == v for k, v in TRUTH.items())
                differ = len(replay(records, Simulator(fitted, [1], clock=VirtualClock())).differences)
                print(
                    f"{key:<11} {len(requests)} requests, {silent} unanswered, in {span:.2f} s ({wall:.2f} s with "
                    f"the process's start); the answered, request to reply: {taken:.2f} s = {taken / line:.2f} x the "
                    f"link's arithmetic ({model.name}, 2 ms turnaround); fit {fit_s:.2f} s; learned {right} of 4; "
                    f"replay against the fitted profile: {differ} differ"
                )
        finally:
            serve.kill()
            serve.wait()


if __name__ == "__main__":
    main()

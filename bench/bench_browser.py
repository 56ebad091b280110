"""The drive in a browser tab: the site's size, its first load on localhost, and the model's speed in the browser.

1. Builds the site (``c20sim site build``) and prints its size: every file, and the bytes a host that gzips
   sends.
2. Loads it in headless Chromium (Debian's), each time with a fresh profile (nothing cached), from a static
   server on 127.0.0.1: the time from navigation to the page's ready (Pyodide, c20sim imported, the drive
   made), the median of ``--loads``.
3. Runs one Python workload in the page's Pyodide and in CPython on the same machine, with the same files
   (the site's zip, unpacked, imported by ``python -I -S``: no compiled CRC, nothing but the standard
   library), and prints each figure and the ratio browser / CPython: the request path (a read framed and
   served by the simulator, as the terminal and the serial port hand requests over) and the model (a running
   drive advanced in 1 ms steps through its acceleration).
4. The stand-in Web Serial port's reply time in the page: from the last chunk of a request to the reply's
   write (the page's share of a reply's start; a real adapter adds its USB latency, not measured here).

Run: .venv/bin/python bench/bench_browser.py [--loads 3]   (needs tools/site-deps and Debian's chromium)
"""

from __future__ import annotations

import argparse
import asyncio
import gzip
import json
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from c20sim.browser import site  # noqa: E402
from tests.browser.chromium import CHROMIUM, PYODIDE, Browser, serve_site  # noqa: E402

#: The workload, the same source in both interpreters; ``bench()`` returns its figures as JSON.
WORKLOAD = r"""
import json, time
from c20sim.browser.page import start
from c20sim.wire.framing import RtuFramer

def bench():
    out = {}
    page = start()
    sim = page.sim
    frame = bytes.fromhex("0103300600016B0B")  # read 3006H, motor speed
    framer = RtuFramer(19200, complete_on_length=True, check_gaps=False, silence=0.02)
    n = 3000
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for i in range(n):
            framer.feed(frame, i * 0.01)
            for event in framer.events():
                sim.handle(event)
        best = min(best, time.perf_counter() - t0)
    out["request_us"] = best / n * 1e6
    page.call("write_register", '{"register": "2001H"}', '{"value": 3000}')
    page.call("set_conditions", "{}", '{"load_torque_nm": 0.5}')
    page.call("write_register", '{"register": "2000H"}', '{"value": 1}')
    steps = 2000
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.advance(0.001)
    out["model_step_us"] = (time.perf_counter() - t0) / steps * 1e6
    out["model_t"] = sim.now()
    page.close()
    return json.dumps(out)
"""

STAND_IN = """
(async () => {
  class Port {
    constructor() { this.written = []; }
    async open() {
      this.readable = new ReadableStream({ start: (c) => { this.ctrl = c; } });
      this.writable = new WritableStream({ write: () => { this.written.push(performance.now()); } });
    }
    async close() {}
  }
  const port = new Port();
  const served = await c20.serveOn(port);
  const bytes = Uint8Array.from([1, 3, 0x30, 6, 0, 1, 0x6B, 0x0B]);
  const times = [];
  for (let i = 0; i < 50; i++) {
    const before = port.written.length;
    port.ctrl.enqueue(bytes);
    const t0 = performance.now();
    while (port.written.length === before) await new Promise((r) => setTimeout(r, 0));
    times.push(port.written[before] - t0);
    await new Promise((r) => setTimeout(r, 5));
  }
  await served.close();
  return times;
})()
"""


async def load_once(base: str) -> tuple[float, float]:
    """(seconds from navigation to ready, the page's own load figure) in a fresh browser."""
    async with Browser(timeout=180) as browser:
        t0 = time.perf_counter()
        await browser.goto(base)
        await browser.eval("window.c20.ready.then(() => true)", timeout=180)
        wall = time.perf_counter() - t0
        page_ms = await browser.eval("window.c20.loadMs")
        return wall, page_ms / 1000


async def in_browser(base: str) -> tuple[dict[str, float], list[float]]:
    async with Browser(timeout=300) as browser:
        await browser.goto(base)
        await browser.eval("window.c20.ready.then(() => true)", timeout=180)
        source = json.dumps(WORKLOAD + "\nbench()")
        figures = json.loads(await browser.eval(f"c20.python().runPython({source})", timeout=300))
        replies = await browser.eval(STAND_IN, timeout=120)
        return figures, replies


def in_cpython(zipped: Path, tmp: Path) -> dict[str, float]:
    unpacked = tmp / "unpacked"
    with zipfile.ZipFile(zipped) as zf:
        zf.extractall(unpacked)
    script = f"import sys; sys.path.insert(0, {str(unpacked)!r})\n{WORKLOAD}\nprint(bench())"
    result = subprocess.run([sys.executable, "-I", "-S", "-c", script], capture_output=True, text=True, check=True)
    figures: dict[str, float] = json.loads(result.stdout)
    return figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=3, help="fresh-browser loads to take the median of")
    args = parser.parse_args()
    if CHROMIUM is None or not (PYODIDE / "pyodide.asm.wasm").is_file():
        print("bench_browser: needs Debian's chromium and tools/site-deps (the pyodide npm package)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        out = tmp / "site"
        manifest = site.build(out, str(PYODIDE))
        files = manifest["files"]
        assert isinstance(files, dict)
        total = sum(files.values())
        gz = sum(len(gzip.compress((out / name).read_bytes(), 6)) for name in files)
        print(
            f"site: {total / 1e6:.2f} MB in {len(files)} files, {gz / 1e6:.2f} MB gzipped (pyodide {manifest['pyodide']})"
        )
        for name, size in sorted(files.items(), key=lambda item: -item[1]):
            print(f"  {name:32s} {size / 1e3:9.1f} kB")
        with serve_site(out) as base:
            loads = [asyncio.run(load_once(base)) for _ in range(args.loads)]
            walls = [w for w, _ in loads]
            print(
                f"first load on localhost (fresh profile, navigation to ready), median of {len(walls)}: "
                f"{statistics.median(walls):.2f} s (each: {', '.join(f'{w:.2f}' for w in walls)}; the page's own "
                f"figure, from its script's start: {statistics.median(p for _, p in loads):.2f} s)"
            )
            browser, replies = asyncio.run(in_browser(base))
        cpython = in_cpython(out / "c20sim.zip", tmp)
        for key, label in (("request_us", "a read framed and served"), ("model_step_us", "a 1 ms model step")):
            print(
                f"{label}: browser {browser[key]:.1f} us, CPython {cpython[key]:.1f} us "
                f"(Python {sys.version.split()[0]}), ratio {browser[key] / cpython[key]:.2f}"
            )
        replies.sort()
        print(
            f"stand-in Web Serial port, request's last chunk to the reply's write, {len(replies)} reads: "
            f"median {statistics.median(replies):.1f} ms, max {replies[-1]:.1f} ms"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

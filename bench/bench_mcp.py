"""What an MCP tool call costs beside the same call made on the control API directly.

One ``c20sim serve --clock virtual --control`` process; one ``c20sim mcp --attach`` process on it, driven
over stdio by the ``mcp`` SDK's own client (as an assistant drives it). Rounds alternate: the operation
called on the API with :class:`~c20sim.control.client.ControlClient` (one kept-alive connection), and the
same operation called as a tool. The figure is the tool call's p50 and p99 as a ratio of the direct call's,
from the same run; also how long ``c20sim mcp --attach`` takes to answer ``initialize`` and ``tools/list``.

    .venv/bin/python bench/bench_mcp.py --calls 500 --rounds 3
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import machine, percentile
from mcp import ClientSession, StdioServerParameters
from mcp.client.stdio import stdio_client

from c20sim.control.client import ControlClient

#: (tool, its arguments, the same request on the API)
CALLS = (
    ("time", {}, ("GET", "/time", None)),
    ("drive", {"address": 1}, ("GET", "/drives/1", None)),
    ("advance", {"seconds": 0.01}, ("POST", "/time/advance", {"seconds": 0.01})),
)


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


def row(label: str, samples: list[float], base: list[float] | None = None) -> str:
    values = sorted(samples)
    p50, p99 = percentile(values, 50) * 1e6, percentile(values, 99) * 1e6
    text = f"{label:<28}{len(values):>7}{p50:>10.0f}{p99:>10.0f}"
    if base is not None:
        b = sorted(base)
        text += f"    p50 {p50 / (percentile(b, 50) * 1e6):.2f}x, p99 {p99 / (percentile(b, 99) * 1e6):.2f}x"
    return text


async def main(calls: int, rounds: int) -> None:
    with tempfile.TemporaryDirectory(prefix="c20sim-bench-") as tmp:
        serve, ready = start_serve(Path(tmp))
        try:
            info = json.loads(ready.read_text())
            client = ControlClient(info["control"], info.get("token"))
            params = StdioServerParameters(
                command=sys.executable, args=["-m", "c20sim", "mcp", "--attach", str(ready)], env=dict(os.environ)
            )
            started = time.perf_counter()
            async with stdio_client(params) as (read, write), ClientSession(read, write) as session:
                await session.initialize()
                initialised = time.perf_counter() - started
                t = time.perf_counter()
                tools = (await session.list_tools()).tools
                listed = time.perf_counter() - t
                print(machine())
                print(
                    f"c20sim mcp --attach: initialize answered {initialised:.2f} s after the start (process, imports)"
                )
                print(f"tools/list: {len(tools)} tools in {listed * 1e3:.1f} ms")
                print(f"{rounds} rounds x {calls} calls of each; microseconds a call")
                print(f"{'':<28}{'calls':>7}{'p50 us':>10}{'p99 us':>10}")
                for name, arguments, (method, path, body) in CALLS:
                    direct: list[float] = []
                    tool: list[float] = []
                    for _ in range(rounds):
                        for _ in range(calls):
                            t = time.perf_counter()
                            client.call(method, path, body)
                            direct.append(time.perf_counter() - t)
                        for _ in range(calls):
                            t = time.perf_counter()
                            result = await session.call_tool(name, arguments)
                            tool.append(time.perf_counter() - t)
                            assert not result.isError, result
                    print(f"{name}:")
                    print(row("  the API (ControlClient)", direct))
                    print(row("  the tool (c20sim mcp)", tool, direct))
            client.close()
        finally:
            serve.terminate()
            serve.wait(10)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=500)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    asyncio.run(main(args.calls, args.rounds))

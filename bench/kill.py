"""Kill test, many times: SIGKILL ``c20sim serve --state`` during a stream of EEPROM writes.

Each iteration runs :func:`tests.integration.test_kill.kill_once` with its own
seed (a kill between writes or with a write in flight, 0-3 ms after sending
it) and checks that the state file loads and holds the last acknowledged
write, or the one in flight.

    .venv/bin/python bench/kill.py --iterations 200
"""

from __future__ import annotations

import argparse
import collections
import sys
import tempfile
import time
from pathlib import Path

from _common import machine

from tests.integration.test_kill import FIRST, kill_once


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iterations", type=int, default=200)
    parser.add_argument("--seconds", type=float, default=900, help="stop after this long")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--max-writes", type=int, default=200, help="most acknowledged writes before a kill")
    args = parser.parse_args()
    t0 = time.monotonic()
    results: collections.Counter[str] = collections.Counter()
    failures: list[str] = []
    writes = leftovers = done = 0
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.iterations):
            if time.monotonic() - t0 > args.seconds:
                break
            try:
                outcome = kill_once(Path(tmp) / str(i), args.seed + i, max_writes=args.max_writes)
            except Exception as exc:  # a state file that does not load is a failure
                failures.append(f"seed {args.seed + i}: {exc!r}")
                continue
            done += 1
            writes += outcome.acknowledged - FIRST + 1
            leftovers += outcome.leftovers
            if outcome.stored == outcome.acknowledged:
                results["kept the last acknowledged write"] += 1
            elif outcome.stored == outcome.sent:
                results["kept the write in flight too"] += 1
            else:
                failures.append(f"seed {args.seed + i}: {outcome}")
    print(f"kill test: {done} kills in {time.monotonic() - t0:.0f} s on {machine()}")
    print(f"  acknowledged writes before the kills: {writes}")
    for what, n in results.items():
        print(f"  {what}: {n}")
    print(f"  temporary files left behind by kills: {leftovers} (ignored by the loader)")
    print(f"  failures: {len(failures)}")
    for failure in failures[:20]:
        print("   ", failure)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

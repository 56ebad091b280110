"""The fuzz properties of tests/unit/test_fuzz.py, run for longer: bounded by --seconds.

Runs each property with hypothesis in batches of ``--batch`` examples, with a
fresh random seed per batch, until the time is up; prints the examples run and
any failure (hypothesis shrinks it and prints the falsifying example).

    .venv/bin/python bench/fuzz.py --seconds 300
"""

from __future__ import annotations

import argparse
import random
import sys
import time
import traceback
from collections.abc import Callable

from _common import machine
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from c20sim.wire.protocol import Request, encode
from tests.unit.test_fuzz import (
    Piece,
    answered_requests,
    check_recovery,
    check_stream,
    mangled,
    requests,
    streams,
)


def properties(batch: int) -> dict[str, Callable[[], None]]:
    s = settings(max_examples=batch, deadline=None, database=None, suppress_health_check=list(HealthCheck))

    @s
    @given(pieces=streams(), tcp=st.booleans(), bus_seed=st.integers(0, 2**16))
    def stream(pieces: list[Piece], tcp: bool, bus_seed: int) -> None:
        check_stream(pieces, tcp, bus_seed)

    @s
    @given(garbage=st.binary(max_size=600), request=answered_requests, tcp=st.booleans())
    def garbage_then_request(garbage: bytes, request: Request, tcp: bool) -> None:
        check_recovery(garbage, request, tcp)

    @s
    @given(pieces=st.lists(mangled(), min_size=1, max_size=12), request=answered_requests, tcp=st.booleans())
    def mangled_then_request(pieces: list[bytes], request: Request, tcp: bool) -> None:
        check_recovery(b"".join(pieces), request, tcp)

    @s
    @given(burst=st.lists(requests, min_size=1, max_size=10), tcp=st.booleans())
    def concatenated_requests(burst: list[Request], tcp: bool) -> None:
        check_stream([Piece(b"".join(encode(r) for r in burst), 0.0, ())], tcp)

    return {
        "stream": stream,
        "garbage_then_request": garbage_then_request,
        "mangled_then_request": mangled_then_request,
        "concatenated_requests": concatenated_requests,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=300)
    parser.add_argument("--batch", type=int, default=500)
    parser.add_argument("--seed", type=int, default=None, help="seed of the batch seeds (default: random)")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    tests = properties(args.batch)
    runs = dict.fromkeys(tests, 0)
    failures = 0
    t0 = time.monotonic()
    while time.monotonic() - t0 < args.seconds and not failures:
        for name, test in tests.items():
            try:
                seed(rng.getrandbits(64))(test)()
                runs[name] += args.batch
            except Exception:
                failures += 1
                print(f"FAILED {name}:")
                traceback.print_exc()
                break
            if time.monotonic() - t0 >= args.seconds:
                break
    elapsed = time.monotonic() - t0
    print(f"fuzz: {sum(runs.values())} examples in {elapsed:.0f} s on {machine()}; failures: {failures}")
    for name, n in runs.items():
        print(f"  {name}: {n} examples")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())

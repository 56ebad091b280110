"""What condition generators cost in virtual time.

A generator applies its value every 10 ms of model time; a value that changes
takes the drive out of its steady-state skip, so it is integrated step by step
(1 ms steps) while the generator runs. Prints CPU seconds (``time.process_time``,
best of 3) for one simulated minute of a running, loaded drive on a Simulator:
no generator, a ramp that ends after 5 s, seeded noise resampled every 0.1 s and
every 1 s, and a sine; and each as a ratio to a reference loop timed in the
same process (a plain Python loop of one million float multiply-adds), since
the machines are noisy.

Run: .venv/bin/python bench/bench_generators.py
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from c20sim.control import ops
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile

MINUTE = 60.0


def cpu(work: Callable[[], object], repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.process_time()
        work()
        best = min(best, time.process_time() - start)
    return best


def reference_loop() -> float:
    x = 0.0
    for i in range(1_000_000):
        x = x * 0.999 + i
    return x


def minute(generator: dict[str, object] | None) -> Callable[[], object]:
    def run() -> object:
        sim = Simulator(load_profile(), (1,))
        ops.set_conditions(sim, 1, {"load_torque_nm": 0.8})
        ops.set_run_channel(sim, 1, "keypad")
        ops.press_key(sim, 1, "forward")
        if generator is not None:
            ops.set_conditions(sim, 1, {"supply_v": generator})
        return sim.run_until(MINUTE)

    return run


def main() -> None:
    reference = cpu(reference_loop)
    print(f"reference loop (1e6 float multiply-adds): {reference * 1000:.1f} ms CPU\n")
    print(f"{'one simulated minute, running and loaded':<48} {'CPU':>10} {'x reference':>12}")
    cases: list[tuple[str, dict[str, object] | None]] = [
        ("no generator", None),
        ("supply ramp 48 -> 40 V over 5 s, then held", {"ramp": 40, "over": 5}),
        ("supply noise 0.5 V, every 1 s", {"noise": 0.5, "seed": 1, "every": 1.0}),
        ("supply noise 0.5 V, every 0.1 s", {"noise": 0.5, "seed": 1, "every": 0.1}),
        ("supply sine 2 V, period 0.1 s", {"sine": 2, "period": 0.1}),
    ]
    for name, generator in cases:
        seconds = cpu(minute(generator))
        print(f"{name:<48} {seconds * 1000:8.1f} ms {seconds / reference:12.3f}")


if __name__ == "__main__":
    main()

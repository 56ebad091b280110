"""How long ``c20sim fit`` takes on the default programme's capture, and on one of an hour at 10 reads a second.

The capture is the identification programme (speed steps, a load change, a
stop) run on c20sim in virtual time by the same master ``c20sim exercise``
uses (:func:`c20sim.traffic.programme.simulated_capture`), with each hold long
enough that the whole lasts an hour, on a drive the fit does not see (inertia,
friction, Kt, supply resistance, turnaround, the thermal constants changed,
read noise on). The fit
starts from the shipped profile. Printed: the capture's size, the wall and CPU
seconds of loading and fitting it, the same figures for one ``c20sim replay``
of it in the same process (a reference), and what the fit found.

Run alone, on an idle machine: .venv/bin/python bench/bench_fit.py
"""

from __future__ import annotations

import dataclasses
import itertools
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from c20sim.core.clock import VirtualClock  # noqa: E402
from c20sim.core.simulator import Simulator  # noqa: E402
from c20sim.drive.profile import Profile, load_profile  # noqa: E402
from c20sim.traffic.capture import load_frame_log  # noqa: E402
from c20sim.traffic.fit import fit, load_capture  # noqa: E402
from c20sim.traffic.fitmodel import COMPARED, FitResult  # noqa: E402
from c20sim.traffic.fitreport import summary, write_profile  # noqa: E402
from c20sim.traffic.programme import simulated_capture  # noqa: E402
from c20sim.traffic.replay import replay  # noqa: E402
from c20sim.wire.registers import FIXED_REGISTERS, Reg  # noqa: E402

T = TypeVar("T")

SPEEDS = (900.0, 1800.0, 2700.0, 1500.0)
HOLD = 595.0  # s: 4 speeds and the load on and off, each held this long: an hour in all


def bench_drive() -> Profile:
    base = load_profile()
    return dataclasses.replace(
        base,
        motor=dataclasses.replace(base.motor, kt_nm_per_a=0.140, inertia_kg_m2=4.5e-4, friction_nm=0.030),
        supply=dataclasses.replace(base.supply, source_resistance_ohm=0.30),
        protocol=dataclasses.replace(base.protocol, turnaround_ms=3.5),
        control=dataclasses.replace(base.control, speed_noise_rpm=5.0, noise_seed=11),
        thermal=dataclasses.replace(base.thermal, time_constant_s=300.0, resistance_k_per_w=1.5),
    )


def timed(work: Callable[[], T]) -> tuple[T, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    result = work()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def default_programme(tmp: str) -> None:
    """``c20sim exercise PORT --out FILE --load-change`` with its defaults (30, 60, 90, 50 % of rated, 8 s holds,
    10 reads a second): the capture docs/fit.md starts from; the target is a fit under 20 s."""
    path = Path(tmp) / "default.jsonl"
    sim = Simulator(bench_drive(), [1], clock=VirtualClock())
    rated = sim.profile.motor.rated_speed_rpm
    with path.open("w") as out:
        simulated_capture(sim, out, speeds=[rated * f for f in (0.3, 0.6, 0.9, 0.5)], hold=8.0, rate=10.0, load_nm=0.6)
    base = load_profile()
    capture, load_wall, _ = timed(lambda: load_capture(str(path), base))
    result, fit_wall, fit_cpu = timed(lambda: fit(capture, base))
    print(
        f"default programme: {sim.now():.0f} s of model time; fit {load_wall + fit_wall:.2f} s wall, "
        f"{fit_cpu:.2f} s CPU ({result.evaluations} model runs); the target is under 20 s"
    )
    print("\n".join(summary(result)))
    again(path, result, Path(tmp))
    print()


def _reads(path: Path) -> dict[int, list[float]]:
    """Each compared register's reads, in order, in units."""
    records = load_frame_log(str(path))
    out: dict[int, list[float]] = {}
    for request, reply in itertools.pairwise(records):
        if request.direction == "rx" and reply.direction == "tx" and request.data[1:2] == b"\x03":
            register = int.from_bytes(request.data[2:4], "big")
            if register in COMPARED and len(reply.data) == 7:
                value = FIXED_REGISTERS[register].engineering(int.from_bytes(reply.data[3:5], "big"))
                out.setdefault(register, []).append(value)
    return out


def again(truth_path: Path, result: FitResult, tmp: Path) -> None:
    """The fitted profile served (in virtual time) and the same programme run on it: each compared register's
    reads against the truth drive's capture, read for read."""
    fitted = write_profile(result, tmp / "fitted.toml", truth_path.name)
    sim = Simulator(fitted, [1], clock=VirtualClock())
    path = tmp / "fitted.jsonl"
    rated = sim.profile.motor.rated_speed_rpm
    with path.open("w") as out:
        simulated_capture(sim, out, speeds=[rated * f for f in (0.3, 0.6, 0.9, 0.5)], hold=8.0, rate=10.0, load_nm=0.6)
    truth, ours = _reads(truth_path), _reads(path)
    for register, (name, unit, resolution) in COMPARED.items():
        a, b = truth.get(register, []), ours.get(register, [])
        n = min(len(a), len(b))
        if not n:
            continue
        gaps = [abs(x - y) for x, y in zip(a[:n], b[:n], strict=True)]
        rms = (sum(g * g for g in gaps) / n) ** 0.5
        print(
            f"  the fitted profile re-run, {name:<15} {n:4d} reads: rms {rms:.3g} {unit}, worst {max(gaps):.3g} "
            f"(resolution {resolution:g}{'; the truth has 5 rpm read noise' if register == Reg.MOTOR_SPEED else ''})"
        )


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        default_programme(tmp)
        path = Path(tmp) / "hour.jsonl"
        sim = Simulator(bench_drive(), [1], clock=VirtualClock())
        with path.open("w") as out:
            reads, wall, _ = timed(
                lambda: simulated_capture(sim, out, speeds=SPEEDS, hold=HOLD, rate=10.0, load_nm=0.6)
            )
        lines = path.read_text().count("\n")
        print(
            f"capture: {sim.now():.0f} s of model time, {reads} reads, {lines} lines, "
            f"{path.stat().st_size / 1e6:.1f} MB (made in {wall:.1f} s)"
        )
        base = load_profile()
        _, replay_wall, replay_cpu = timed(
            lambda: replay(load_frame_log(str(path)), Simulator(base, [1], clock=VirtualClock()))
        )
        capture, load_wall, load_cpu = timed(lambda: load_capture(str(path), base))
        result, fit_wall, fit_cpu = timed(lambda: fit(capture, base))
        print(f"reference, one replay of the capture:  {replay_wall:6.2f} s wall  {replay_cpu:6.2f} s CPU")
        print(f"fit: reading the capture              {load_wall:6.2f} s wall  {load_cpu:6.2f} s CPU")
        print(
            f"fit: least squares                    {fit_wall:6.2f} s wall  {fit_cpu:6.2f} s CPU "
            f"({result.evaluations} model runs)"
        )
        total = load_wall + fit_wall
        print(f"fit in all: {total:.2f} s wall = {total / replay_wall:.2f} x one replay; the target is under 60 s")
        print("\n".join(summary(result)))


if __name__ == "__main__":
    main()

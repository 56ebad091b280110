"""How fast the behavioural drive model runs in virtual time.

Prints CPU seconds (``time.process_time``) for one simulated hour of a running,
loaded drive: advanced in one call, polled every second and every 100 ms, and
stepped without the steady-state skip (extrapolated from a shorter run). The
machines are noisy, so it also prints each figure as a ratio to a reference
loop timed in the same process: a plain Python loop of one million float
multiply-adds.

Run: .venv/bin/python bench/bench_model.py
"""

from __future__ import annotations

import time
from collections.abc import Callable

from c20sim.drive.model import Drive
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.registers import Reg

HOUR = 3600.0


class NoSkipDrive(Drive):
    """The same model that never enters a steady segment: every step integrated."""

    def _try_segment(self) -> None:
        return None


def loaded(profile: Profile, cls: type[Drive] = Drive) -> Drive:
    drive = cls(profile)
    drive.set_load_torque(0.8)  # about 7 A of 10 A rated: warm, not overloaded
    drive.write(Reg.SPEED_SETPOINT, 3000)
    drive.write(Reg.COMMAND, 1)
    return drive


def cpu(work: Callable[[], object], repeat: int = 5) -> float:
    """Best of ``repeat`` CPU times of ``work()``."""
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


def hour_in_one_call(profile: Profile) -> Drive:
    drive = loaded(profile)
    drive.advance_to(HOUR)
    return drive


def hour_polled(profile: Profile, every: float) -> Drive:
    drive = loaded(profile)
    for i in range(1, round(HOUR / every) + 1):
        drive.advance_to(i * every)
        drive.read(Reg.MOTOR_SPEED)
        drive.read(Reg.OUTPUT_CURRENT)
        drive.read(Reg.TEMPERATURE)
    return drive


def no_skip(profile: Profile, seconds: float) -> Drive:
    drive = loaded(profile, NoSkipDrive)
    drive.advance_to(seconds)
    return drive


def main() -> None:
    profile = load_profile("c20-400hr")
    check = hour_in_one_call(profile)
    tel = check.telemetry()
    assert tel.status == 1 and tel.speed_rpm == 3000.0, tel
    reference = cpu(reference_loop)
    rows = [
        ("1 h running, loaded, one advance_to", cpu(lambda: hour_in_one_call(profile))),
        ("1 h running, loaded, polled every 1 s", cpu(lambda: hour_polled(profile, 1.0), 3)),
        ("1 h running, loaded, polled every 100 ms", cpu(lambda: hour_polled(profile, 0.1), 1)),
        ("1 day stopped, one advance_to", cpu(lambda: Drive(profile).advance_to(86400.0))),
    ]
    stepped = cpu(lambda: no_skip(profile, 20.0), 3)
    rows.append(("1 h without the steady skip (from 20 s)", stepped * HOUR / 20.0))
    print(f"state after 1 h: {tel.speed_rpm:.0f} rpm, {tel.current_a:.2f} A, {tel.temperature_c:.1f} degC")
    print(f"reference loop (1e6 float multiply-adds): {reference * 1e3:.1f} ms CPU\n")
    print(f"{'case':<44} {'CPU':>12} {'x reference':>12}")
    for name, seconds in rows:
        print(f"{name:<44} {seconds * 1e3:>9.2f} ms {seconds / reference:>12.4f}")
    print(f"\none internal step (1 ms of model time): {stepped / 20_000 * 1e6:.1f} us CPU")


if __name__ == "__main__":
    main()

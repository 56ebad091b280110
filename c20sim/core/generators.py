"""Condition generators: a numeric condition as a function of the model's time.

Real supplies sag and ripple, loads vary. A generator gives a condition
(``supply_v``, ``load_torque_nm``, ``ambient_c``, ``ai1_v`` ...) a value for
every moment of model time:

- :class:`Ramp`: from the value it starts at to ``to`` over ``over`` seconds, then held there;
- :class:`Sine`: ``center + amplitude * sin(2 pi (t - start) / period)``; the centre is the value it
  starts at unless given;
- :class:`Noise`: ``center + sigma * N(0, 1)``, a new sample every ``every`` seconds, each drawn from
  its own ``random.Random`` seeded with ``(seed, sample index)``: the same seed gives the same values
  at the same model times however time is stepped.

Values are clamped to the condition's range. The simulator applies them at
fixed ticks of model time (:data:`TICK` apart, from the simulator's start),
as the drives are advanced; between ticks a value is held. Pure: a function of
time, no clock, no I/O.
"""

from __future__ import annotations

import math
import random
import sys
from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["TICK", "Generator", "GeneratorError", "Noise", "Ramp", "Sine", "parse_generator"]

#: Model seconds between two applications of generator values (and behaviours' steps): 100 per second.
#: Fine enough for ripple down to a 20 ms period; assumed, as no source fixes it.
TICK = 0.01
#: The shortest sine period and noise interval: two ticks.
MIN_PERIOD = 2 * TICK
#: The longest ramp, period or interval: a year of model time.
MAX_SECONDS = 365 * 86400.0


class GeneratorError(ValueError):
    """A generator given wrongly: the message says which key and what is allowed."""


@dataclass(frozen=True)
class Ramp:
    """From ``start_value`` at ``start`` to ``to`` at ``start + over``, linearly; then ``to``."""

    start: float
    start_value: float
    to: float
    over: float

    def value(self, t: float) -> float:
        if self.over <= 0 or t >= self.start + self.over:
            return self.to
        fraction = max(0.0, (t - self.start) / self.over)
        return self.start_value + (self.to - self.start_value) * fraction

    def done(self, t: float) -> bool:
        """True once the ramp has reached ``to``: it may be dropped, its condition stays there."""
        return t >= self.start + self.over

    def describe(self) -> dict[str, float | str]:
        return {"kind": "ramp", "from": self.start_value, "to": self.to, "over": self.over, "start": self.start}


@dataclass(frozen=True)
class Sine:
    start: float
    center: float
    amplitude: float
    period: float

    def value(self, t: float) -> float:
        return self.center + self.amplitude * math.sin(2 * math.pi * (t - self.start) / self.period)

    def done(self, t: float) -> bool:
        return False

    def describe(self) -> dict[str, float | str]:
        return {
            "kind": "sine",
            "center": self.center,
            "amplitude": self.amplitude,
            "period": self.period,
            "start": self.start,
        }


@dataclass(frozen=True)
class Noise:
    start: float
    center: float
    sigma: float
    every: float
    seed: int

    def value(self, t: float) -> float:
        index = max(0, math.floor((t - self.start) / self.every + 1e-9))
        return self.center + self.sigma * random.Random(f"{self.seed}/{index}").gauss(0.0, 1.0)

    def done(self, t: float) -> bool:
        return False

    def describe(self) -> dict[str, float | str]:
        return {
            "kind": "noise",
            "center": self.center,
            "sigma": self.sigma,
            "every": self.every,
            "seed": self.seed,
            "start": self.start,
        }


Generator = Ramp | Sine | Noise

#: The keys of each kind of generator: the kind's own key first (its value), then the others.
FORMS: Mapping[str, tuple[str, ...]] = {
    "ramp": ("ramp", "over"),
    "sine": ("sine", "period", "center"),
    "noise": ("noise", "seed", "every", "center"),
}
#: How each form is written, for error messages and docs.
EXAMPLES = "{ ramp = 30, over = 5 }, { sine = 2, period = 0.5 } or { noise = 0.5, seed = 1 }"


def _number(key: str, value: object, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise GeneratorError(f"{key}: expected a finite number, got {value!r}")
    if isinstance(value, int) and abs(value) >= 10**30:  # beyond a float: said by its length, not printed
        try:
            length = f"{len(str(abs(value)))} digits"
        except ValueError:  # past the interpreter's limit on printing a whole number
            length = f"more than {sys.get_int_max_str_digits()} digits"
        raise GeneratorError(f"{key}: a number of {length} is outside {low:g}-{high:g}")
    if not math.isfinite(value):
        raise GeneratorError(f"{key}: expected a finite number, got {value!r}")
    if not low <= value <= high:
        raise GeneratorError(f"{key}: {value:g} is outside {low:g}-{high:g}")
    return float(value)


def parse_generator(
    name: str, spec: Mapping[str, object], low: float, high: float, now: float, current: float
) -> Generator:
    """A generator for condition ``name`` (range ``low``-``high``) from ``spec``, starting at ``now``
    from the condition's ``current`` value; raises GeneratorError saying what is wrong."""
    kinds = [k for k in FORMS if k in spec]
    if len(kinds) != 1:
        raise GeneratorError(f"{name}: give one generator, such as {EXAMPLES}")
    kind = kinds[0]
    for key in spec:
        if key not in FORMS[kind]:
            raise GeneratorError(f"{name}: unknown key {key!r} for a {kind}; its keys: {', '.join(FORMS[kind])}")
    span = high - low
    if kind == "ramp":
        if "over" not in spec:
            raise GeneratorError(f"{name}: a ramp needs over = SECONDS, such as {{ ramp = 30, over = 5 }}")
        return Ramp(
            now,
            current,
            _number(f"{name}.ramp", spec["ramp"], low, high),
            _number(f"{name}.over", spec["over"], 0, MAX_SECONDS),
        )
    center = _number(f"{name}.center", spec["center"], low, high) if "center" in spec else current
    if kind == "sine":
        if "period" not in spec:
            raise GeneratorError(f"{name}: a sine needs period = SECONDS, such as {{ sine = 2, period = 0.5 }}")
        return Sine(
            now,
            center,
            _number(f"{name}.sine", spec["sine"], 0, span),
            _number(f"{name}.period", spec["period"], MIN_PERIOD, MAX_SECONDS),
        )
    seed = spec.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise GeneratorError(f"{name}.seed: expected a whole number, got {seed!r}")
    every = _number(f"{name}.every", spec["every"], MIN_PERIOD, MAX_SECONDS) if "every" in spec else 0.1
    return Noise(now, center, _number(f"{name}.noise", spec["noise"], 0, span), every, seed)


def clamp(value: float, low: float, high: float) -> float:
    return min(max(value, low), high)

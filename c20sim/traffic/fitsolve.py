"""The fit's solve: which reads are compared and how much each weighs, which parameters the capture can
reveal, and the bounded least squares that move them until model and drive agree (docs/fit.md)."""

from __future__ import annotations

import bisect
import functools
import itertools
import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from ..drive.profile import Profile
from ..wire.registers import Reg
from .fitcapture import Capture, Event, _held_speeds, _units
from .fitmodel import COMPARED, PARAMETERS, STATES, Fitted, Parameter, simulate, with_values

__all__ = [
    "IDENTIFIABLE",
    "MAX_FIT_READS",
    "MIN_RAMP_READS",
    "THERMAL_RISE",
    "TRANSIENT",
    "Problem",
    "Solution",
    "compared_reads",
    "solve",
    "turnaround",
    "unrevealed",
]


#: Reads the least squares look at, at most, per quantity: a long capture is thinned evenly (an hour at 10
#: reads a second keeps its transients, the seconds after each change; what is dropped are reads of a steady drive).
MAX_FIT_READS = 2500

#: Seconds after a write or a load change whose reads are always kept when a long capture is thinned.
TRANSIENT = 5.0

#: A fitted value is kept when its standard uncertainty is below this fraction of it.
IDENTIFIABLE = 0.25

#: Current reads in speed ramps a fit needs before it fits the inertia.
MIN_RAMP_READS = 3

#: The temperature must move this much (K) over the capture for the thermal parameters to be fitted.
THERMAL_RISE = 1.5


# --- The fit.


def _thin(reads: list[Event], limit: int, changes: Sequence[float]) -> list[Event]:
    """At most ``limit`` of ``reads``: first those in the :data:`TRANSIENT` seconds after a change (a write, a
    load mark: the ramps, where inertia shows), then the steady ones, evenly."""
    if len(reads) <= limit:
        return reads
    moving: list[Event] = []
    steady: list[Event] = []
    i = 0
    for read in reads:
        while i + 1 < len(changes) and changes[i + 1] <= read.t:
            i += 1
        near = bool(changes) and changes[i] <= read.t < changes[i] + TRANSIENT
        (moving if near else steady).append(read)
    moving = _evenly(moving, max(limit * 3 // 4, limit - len(steady)))  # a long capture's holds keep a quarter
    kept = {id(e) for e in moving} | {id(e) for e in _evenly(steady, limit - len(moving))}
    return [e for e in reads if id(e) in kept]


def _evenly(reads: list[Event], count: int) -> list[Event]:
    if count <= 0:
        return []
    if len(reads) <= count:
        return reads
    stride = len(reads) / count
    return [reads[int(i * stride)] for i in range(count)]


def _current_reads_in_ramps(capture: Capture) -> int:
    """Current reads (3004H) taken inside a speed ramp: after the write that set the speed going, with the speed
    read before and after it still short of the speed asked (by 3 % of it, 50 rpm at least) and changing. A read
    at a ramp's very end, where the current falls from the ramp's to the hold's within a step, is no inertia's."""
    speed = capture.reads.get(Reg.MOTOR_SPEED, [])
    times = [e.t for e in speed]
    asked: list[tuple[float, float]] = []  #: (time, the speed the drive is to reach)
    setpoint, running = 0.0, False
    for event in capture.events:
        if event.kind != "write":
            continue
        if event.address == Reg.SPEED_SETPOINT:
            setpoint = float(event.value)
        elif event.address == Reg.COMMAND:
            running = event.value in (1, 2)
        else:
            continue
        asked.append((event.t, setpoint if running else 0.0))
    starts = [t for t, _ in asked]
    count = 0
    for read in capture.reads.get(Reg.OUTPUT_CURRENT, []):
        i = bisect.bisect_right(starts, read.t) - 1
        j = bisect.bisect_left(times, read.t)
        if i < 0 or not 0 < j < len(speed) or speed[j - 1].t < starts[i]:
            continue
        target = asked[i][1]
        before, after = speed[j - 1].value, speed[j].value
        short = max(50.0, 0.03 * target)
        if abs(target - before) > short and abs(target - after) > short and abs(after - before) > 30:
            count += 1
    return count


def _sigma(address: int, capture: Capture) -> float:
    """A compared quantity's read uncertainty: its resolution, and for the speed the spread of steady reads."""
    resolution = COMPARED[address][2]
    sigma = resolution / math.sqrt(12.0)
    if address == Reg.MOTOR_SPEED:
        values = [e.value for e in capture.reads.get(address, ()) if e.value]
        steps = [abs(b - a) for a, b in itertools.pairwise(values) if abs(b - a) < 50]
        if len(steps) > 10:
            sigma = max(sigma, statistics.median(steps) / math.sqrt(2.0))
    return sigma


# --- The compared reads, and what the capture can reveal.


def compared_reads(capture: Capture) -> tuple[dict[int, list[Event]], list[Event]]:
    """The reads of each compared quantity the fit uses (a long capture thinned to :data:`MAX_FIT_READS`), and
    the events the model plays: every write and mark, those reads, and every state read."""
    changes = [e.t for e in capture.events if e.kind != "read"]
    compared = {a: _thin(capture.reads[a], MAX_FIT_READS, changes) for a in COMPARED if a in capture.reads}
    chosen = {id(e) for reads in compared.values() for e in reads}
    events = [e for e in capture.events if e.kind != "read" or id(e) in chosen or e.address in STATES]
    return compared, events


def unrevealed(capture: Capture, compared: dict[int, list[Event]]) -> dict[str, str]:
    """The parameters nothing in the capture can reveal, each with why: they are kept from the base profile."""
    running = any(e.value in (1, 2) for e in capture.reads.get(Reg.STATUS1, ())) or any(
        e.value for e in capture.reads.get(Reg.MOTOR_SPEED, ())
    )
    temps = [_units(e) for e in capture.reads.get(Reg.TEMPERATURE, [])]
    rise = (max(temps) - min(temps)) if temps else 0.0
    reasons: dict[str, str] = {}
    if Reg.OUTPUT_VOLTAGE not in compared or not running:
        reasons["motor.kt_nm_per_a"] = "no reads of the output voltage (3003H) while running"
    if Reg.OUTPUT_CURRENT not in compared or not running:
        for key in ("inertia_kg_m2", "friction_nm", "viscous_nm_per_krpm"):
            reasons[f"motor.{key}"] = "no reads of the current (3004H) while running"
    elif len(_held_speeds(capture)) < 2:
        reasons["motor.viscous_nm_per_krpm"] = "the capture holds one speed only: friction and viscous are one sum"
    if Reg.BUS_VOLTAGE not in compared:
        reasons["supply.voltage_v"] = reasons["supply.source_resistance_ohm"] = "no reads of the bus voltage (3008H)"
    elif not capture.loads:
        reasons["supply.source_resistance_ohm"] = (
            "no load change in the capture: the bus sags too little to measure (exercise --load-change)"
        )
    if rise < THERMAL_RISE:
        why = f"the temperature moved {rise:.1f} K only: a longer capture with a load is needed"
        reasons["thermal.time_constant_s"] = reasons["thermal.resistance_k_per_w"] = why
    in_ramps = _current_reads_in_ramps(capture)
    if "motor.inertia_kg_m2" not in reasons and in_ramps < MIN_RAMP_READS:
        reasons["motor.inertia_kg_m2"] = (
            f"{in_ramps} current read(s) (3004H) fell in a speed ramp, and inertia shows only there: the programme "
            f"must read the current while the speed changes (at least {MIN_RAMP_READS}; c20sim exercise times its "
            "reads into the ramps: a higher --rate, or longer ramps, 2003H/2004H)"
        )
    return reasons


# --- The problem the least squares solve.

Played = tuple[Profile, float, dict[int, list[float]], list[tuple[Event, int]]]


@dataclass
class Problem:
    """The model against the capture: the compared reads in units, their weights, and a counter of model runs.

    ``base`` is the base profile at the drive's temperature when the capture began; ``start`` holds each
    parameter's value in the base as given.
    """

    capture: Capture
    base: Profile
    start: dict[str, float]
    compared: dict[int, list[Event]]
    events: list[Event]
    recorded: dict[int, Any]  #: numpy arrays of the recorded values, in units
    weights: dict[int, float]
    f_scale: float  #: the robust loss's scale: three standard deviations of one read, in the residuals' units
    fit_load: bool  #: a load change by hand is in the capture: its torque is fitted too
    load_scale: float
    evaluations: int = 0

    @classmethod
    def of(cls, capture: Capture, base: Profile, compared: dict[int, list[Event]], events: list[Event]) -> Problem:
        import numpy as np

        start = {p.name: p.get(base) for p in PARAMETERS}
        temps = capture.reads.get(Reg.TEMPERATURE, [])
        if temps:
            base = with_values(base, {"thermal.ambient_c": _units(temps[0])})  # the drive's when the capture began
        sigmas = {a: _sigma(a, capture) for a in compared}
        return cls(
            capture,
            base,
            start,
            compared,
            events,
            {a: np.array([_units(e) for e in reads]) for a, reads in compared.items()},
            {a: 1.0 / (sigmas[a] * math.sqrt(len(reads))) for a, reads in compared.items()},
            3.0 / math.sqrt(statistics.median(len(reads) for reads in compared.values())),
            capture.loads > 0,
            0.25 * base.motor.kt_nm_per_a * base.motor.rated_current_a,
        )

    @property
    def reads(self) -> int:
        return sum(len(reads) for reads in self.compared.values())

    def play(self, names: Sequence[str], scales: Sequence[float], x: Sequence[float]) -> Played:
        """The model with the scaled parameters ``x`` (and the load, last, where fitted), played along the capture."""
        values = {n: float(v) * s for n, v, s in zip(names, x, scales, strict=False)}
        profile = with_values(self.base, values)
        load = float(x[-1]) * self.load_scale if self.fit_load else 0.0
        self.evaluations += 1
        got, states = simulate(profile, self.capture, self.events, load)
        return profile, load, got, states

    def residuals(self, names: Sequence[str], scales: Sequence[float], x: Sequence[float]) -> Any:
        import numpy as np

        try:
            _, _, got, _ = self.play(names, scales, x)
            parts = [(np.array(got[a]) - self.recorded[a]) * self.weights[a] for a in self.compared]
            out = np.concatenate(parts)
        except (ArithmeticError, ValueError):  # a trial value the model cannot run with (a NaN in its state)
            out = np.full(self.reads, np.nan)
        return np.where(np.isfinite(out), out, 1e3)  # far from any fit: the least squares step back

    def series(self, values: dict[int, list[float]]) -> dict[int, tuple[list[float], list[float], list[float]]]:
        """Each compared quantity's times, recorded values and model values, for the report."""
        return {
            a: ([e.t for e in self.compared[a]], [float(v) for v in self.recorded[a]], [float(v) for v in values[a]])
            for a in self.compared
        }


# --- The solve.


@dataclass
class Solution:
    fitted: list[Fitted]  #: every parameter, in PARAMETERS' order: fitted, or kept with why
    load: float
    load_fit: tuple[float, float] | None
    before: dict[int, list[float]]  #: the compared values of the base model
    profile: Profile  #: the last model the least squares ran
    after: dict[int, list[float]]
    states: list[tuple[Event, int]]
    notes: list[str]


def _scaled(free: Sequence[Parameter], problem: Problem) -> tuple[list[float], list[float], list[float], list[float]]:
    """Each parameter moves as a multiple of its base value (1 = the base), within the profile format's range and
    a factor of 50 either way; a base value of 0 (no viscous friction) starts at 0 on a scale of its range.
    Returns the start, the scales and the bounds (the load's last, where fitted)."""
    x0: list[float] = []
    scales: list[float] = []
    lower: list[float] = []
    upper: list[float] = []
    for p in free:
        low, high = p.bounds(problem.base)
        start = problem.start[p.name]
        if start > 0:
            scale, low, high = start, max(low, start / 50.0), min(high, start * 50.0)
        else:
            scale = (high - low) / 1000.0 or 1.0
        x0.append(start / scale)
        scales.append(scale)
        lower.append(low / scale)
        upper.append(high / scale)
    if problem.fit_load:
        x0.append(1.0)
        lower.append(0.0)
        upper.append(20.0)
    return x0, scales, lower, upper


def _uncertainties(problem: Problem, fun: Any, jac: Any, size: int) -> Any:
    """Standard uncertainties from the Jacobian at the solution. Each quantity's residuals are weighted by
    1 / (sigma sqrt(n)): its reads count as one read's worth of information, not n. Averaging many reads does not
    take away the rounding of a steady value (a bus that sits at 47.43 V reads 47.4 every time), so the honest
    uncertainty is what one read at the register's resolution allows, times the misfit where worse. The misfit
    as the robust loss weighs it (scipy's jac is the loss's too): a read far off (late, an outlier) counts as one
    read 3 sigma off, not as its square, and cannot make every parameter too uncertain."""
    import numpy as np

    f_scale = problem.f_scale
    robust = f_scale**2 * 2.0 * (np.sqrt(1.0 + (np.asarray(fun) / f_scale) ** 2) - 1.0)  # soft_l1's rho
    spread = max(1.0, float(np.sum(robust)) / max(1, len(problem.compared)))
    try:
        covariance = np.linalg.pinv(jac.T @ jac) * spread if size else np.zeros((0, 0))
        return np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    except np.linalg.LinAlgError:
        return np.full(size, np.inf)


def _judged(
    free: Sequence[Parameter], problem: Problem, x: Any, sigma_x: Any, scales: list[float], jac: Any
) -> dict[str, Fitted]:
    """Each free parameter's fitted value, or its base where nothing moves it or it is too uncertain."""
    import numpy as np

    found: dict[str, Fitted] = {}
    for i, parameter in enumerate(free):
        base_value = problem.start[parameter.name]
        value, sigma = float(x[i]) * scales[i], float(sigma_x[i]) * scales[i]
        column = float(np.abs(jac[:, i]).max()) if jac.size else 0.0
        if column == 0.0:
            why = "nothing in the capture moves it"
            found[parameter.name] = Fitted(parameter, base_value, base_value, math.inf, False, why)
        elif not sigma < IDENTIFIABLE * abs(value):
            why = f"fitted {value:.4g} +-{sigma:.2g}: too uncertain; it needs {parameter.needs}"
            found[parameter.name] = Fitted(parameter, base_value, base_value, sigma, False, why)
        else:
            found[parameter.name] = Fitted(parameter, base_value, value, sigma, True)
    return found


def _least_squares(
    problem: Problem,
    x0: list[float],
    bounds: tuple[list[float], list[float]],
    residuals: Callable[..., Any],
    notes: list[str],
) -> tuple[Any, Any, Any]:
    """The solution, its residuals and Jacobian: the squared loss from the base first (far from the drive, every
    read is "off": a robust loss there flattens the very differences that lead to it), then a robust loss from
    where that ended (a read that is late, lost or an outlier weighs as one, and rejects no parameter)."""
    import numpy as np
    from scipy.optimize import least_squares

    if not x0:  # nothing to fit: the comparison and the turnaround only
        return np.array([]), residuals(x0), np.zeros((0, 0))
    solve = functools.partial(least_squares, residuals, bounds=bounds, method="trf", x_scale="jac", diff_step=1e-3)
    start = solve(x0, max_nfev=60).x
    result = solve(start, max_nfev=40, loss="soft_l1", f_scale=problem.f_scale)
    if result.status == 0:
        notes.append("the least squares stopped at their limit of model runs before they converged")
    return result.x, result.fun, result.jac


def solve(problem: Problem, reasons: dict[str, str], say: Callable[[str], None]) -> Solution:
    """Fit the parameters not in ``reasons``; one found too uncertain is fixed at its base, and the rest fitted
    again without it (three rounds at most)."""
    notes: list[str] = []
    rejected: dict[str, Fitted] = {}
    before: dict[int, list[float]] | None = None
    for _ in range(3):
        free = [p for p in PARAMETERS if p.name not in reasons and p.name not in rejected]
        names = [p.name for p in free]
        x0, scales, lower, upper = _scaled(free, problem)
        if before is None:
            load = " and the load" if problem.fit_load else ""
            say(f"fitting {len(names)} parameter(s){load} to {problem.reads} reads")
            _, _, before, _ = problem.play(names, scales, x0)
        residuals = functools.partial(problem.residuals, names, scales)
        x, fun, jac = _least_squares(problem, x0, (lower, upper), residuals, notes)
        profile, load_nm, after, states = problem.play(names, scales, x)
        sigma_x = _uncertainties(problem, fun, jac, len(x))
        found = _judged(free, problem, x, sigma_x, scales, jac)
        dropped = {name: f for name, f in found.items() if not f.identified}
        if not dropped:
            break
        rejected |= dropped
    fitted: list[Fitted] = []
    for parameter in PARAMETERS:
        base_value = problem.start[parameter.name]
        if parameter.name in reasons:
            fitted.append(Fitted(parameter, base_value, base_value, math.inf, False, reasons[parameter.name]))
        else:
            fitted.append(found.get(parameter.name) or rejected[parameter.name])
    assert before is not None
    load_fit = (load_nm, float(sigma_x[-1]) * problem.load_scale) if problem.fit_load else None
    return Solution(fitted, load_nm, load_fit, before, profile, after, states, notes)


def turnaround(capture: Capture, base: Profile) -> Fitted | None:
    """protocol.turnaround_ms: what the capture's link leaves of each transaction's time (:mod:`.fitlink`)."""
    if capture.turnaround is None:
        return None
    value, sigma, _ = capture.turnaround
    param = Parameter("protocol", "turnaround_ms", "ms", "answered requests with their times")
    return Fitted(param, base.protocol.turnaround_ms, max(0.0, value * 1000.0), sigma * 1000.0, True, "")

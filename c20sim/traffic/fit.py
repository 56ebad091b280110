"""``c20sim fit LOG``: a profile fitted to a capture of a real drive.

The master's side of the log is played into the pure model in virtual time,
as ``c20sim replay`` plays it (:func:`c20sim.traffic.replay.exchanges` pairs
each request with its reply; the first frame is model time 0, and the model
runs exactly as long between two requests as the drive did). Each recorded
read of a physical quantity is compared with the model's value at the same
time, and bounded nonlinear least squares (:func:`scipy.optimize.least_squares`,
trust-region reflective, scaled by the Jacobian; a plain squared loss, since
the few reads taken in a ramp are the ones that carry the inertia) moves the
parameters the capture can reveal, within the ranges the profile format
allows, until model and drive agree:

========================  ===================================================
parameter                 what in the capture reveals it
========================  ===================================================
motor.kt_nm_per_a         output voltage 3003H against speed (Ke = Kt)
motor.inertia_kg_m2       current 3004H during ramps against constant speed
motor.friction_nm         current at constant speed (with viscous: >= 2 speeds)
motor.viscous_nm_per_krpm current at several constant speeds
supply.voltage_v          the bus 3008H at rest
supply.source_resistance  the bus sagging with the current drawn (a load)
thermal.time_constant_s   temperature 300CH rising (a long capture, a load)
thermal.resistance_k_per_w the temperature it rises to
protocol.turnaround_ms    the time from each request to its reply
========================  ===================================================

The model is compared by its values before they are rounded to a register's
resolution (so the fit sees a smooth function); the recorded value carries the
rounding, which is within the noise. A parameter whose fitted uncertainty (from
the Jacobian at the solution) is large against its value, or which nothing in
the capture moves, is "not identifiable from this capture" and is kept from
the base profile; the report says why. Status words and fault codes are
compared too (a state the model does not reach is reported, not fitted).

The new profile is the base profile's file with each fitted value replaced and
commented with its source (``fitted from LOG, +-x``); it is loaded with
c20sim's own loader before it is written. A load change the user made by hand
(``c20sim exercise --load-change``) is in the log as a ``mark``; its torque is
fitted too and reported, not written (it belongs to the bench, not the drive).
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import math
import re
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.clock import VirtualClock
from ..core.simulator import Simulator
from ..drive import face
from ..drive.physics import STEP
from ..drive.profile import DEFAULT_PROFILE, Profile, load_profile
from ..wire.errors import C20SimError
from ..wire.protocol import (
    ExceptionResponse,
    ReadRequest,
    ReadResponse,
    WriteMultipleRequest,
    WriteSingleRequest,
    crc_ok,
    decode_request,
    decode_response,
    frame_time,
)
from ..wire.registers import BAUD_RATES, FIXED_REGISTERS, Reg
from .capture import LogRecord, _read_text, parse_log
from .exercise import LOAD_OFF, LOAD_ON
from .replay import exchanges, replay

__all__ = ["Capture", "FitResult", "Fitted", "add_fit_command", "fit", "load_capture", "write_profile"]

#: Registers whose reads are physical quantities or the drive's state: what a fit compares.
PHYSICAL = frozenset(range(0x3000, 0x3012)) | {Reg.STATUS1, Reg.STATUS2, Reg.FAULT_CODE}

#: The quantities the least squares compare: register -> (name, unit, resolution of one raw unit).
COMPARED: dict[int, tuple[str, str, float]] = {
    Reg.OUTPUT_CURRENT: ("current", "A", 0.01),
    Reg.MOTOR_SPEED: ("speed", "rpm", 1.0),
    Reg.OUTPUT_VOLTAGE: ("output voltage", "V", 0.1),
    Reg.BUS_VOLTAGE: ("bus voltage", "V", 0.1),
    Reg.TEMPERATURE: ("temperature", "degC", 0.1),
    Reg.RAMP_FREQUENCY: ("ramp frequency", "Hz", 0.01),  # no parameter moves it: it shows the ramps' behaviour
}

#: The state reads compared as states (not fitted): status word 1 and the fault code.
STATES = (Reg.STATUS1, Reg.FAULT_CODE)

#: Reads the least squares look at, at most, per quantity: a long capture is thinned (an hour at 10 reads a
#: second keeps its transients, the seconds after each change; what is dropped are reads of a steady drive).
MAX_FIT_READS = 2500

#: Seconds after a write or a load change whose reads are always kept when a long capture is thinned.
TRANSIENT = 5.0

#: A fitted value is kept when its standard uncertainty is below this fraction of it.
IDENTIFIABLE = 0.25

#: The temperature must move this much (K) over the capture for the thermal parameters to be fitted.
THERMAL_RISE = 1.5


@dataclass(frozen=True)
class Parameter:
    """One profile value the fit may move: where it lives, and how to set it on a profile."""

    section: str
    key: str
    unit: str
    needs: str  #: what the capture must hold, in words, for it to be identifiable

    @property
    def name(self) -> str:
        return f"{self.section}.{self.key}"

    def get(self, profile: Profile) -> float:
        return float(getattr(getattr(profile, self.section), self.key))

    def bounds(self, profile: Profile) -> tuple[float, float]:
        section = getattr(profile, self.section)
        meta = next(f.metadata for f in dataclasses.fields(section) if f.name == self.key)
        return float(meta["min"]), float(meta["max"])


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("motor", "kt_nm_per_a", "N m/A", "reads of the output voltage (3003H) while running"),
    Parameter("motor", "inertia_kg_m2", "kg m^2", "reads of the current (3004H) during speed ramps"),
    Parameter("motor", "friction_nm", "N m", "reads of the current (3004H) at a constant speed"),
    Parameter("motor", "viscous_nm_per_krpm", "N m/krpm", "reads of the current (3004H) at two or more speeds"),
    Parameter("supply", "voltage_v", "V", "reads of the bus voltage (3008H) at rest"),
    Parameter("supply", "source_resistance_ohm", "ohm", "reads of the bus voltage (3008H) under load (--load-change)"),
    Parameter("thermal", "time_constant_s", "s", "a temperature (300CH) rise of a few K: a long capture, a load"),
    Parameter("thermal", "resistance_k_per_w", "K/W", "a temperature (300CH) rise of a few K"),
)


@dataclass(frozen=True)
class Event:
    """What the model is given, in log time: a write, a load mark, or a read to compare."""

    t: float
    kind: str  #: "write", "load", "read"
    address: int = 0
    value: int = 0
    line: int = 0


@dataclass
class Capture:
    """A frame log, read for a fit."""

    path: str
    address: int
    events: list[Event]  #: writes, marks and physical reads, in time order
    reads: dict[int, list[Event]]  #: register -> its reads
    turnaround: list[float]  #: request end to reply, per answered request (s)
    reply_lengths: list[int]
    loads: int  #: load marks (load-on)
    settings: dict[int, int] = field(default_factory=dict)  #: 20xxH settings read (pole pairs, ramps)
    duration: float = 0.0


@dataclass(frozen=True)
class Fitted:
    parameter: Parameter
    base: float
    value: float
    sigma: float  #: standard uncertainty; inf when the capture says nothing of it
    identified: bool
    why: str = ""  #: why not identified


@dataclass
class FitResult:
    capture: Capture
    base: Profile
    fitted: list[Fitted]
    turnaround: Fitted | None
    load_nm: tuple[float, float] | None  #: the load the user applied, and its uncertainty
    before: dict[int, tuple[list[float], list[float], list[float]]]  #: register -> (t, recorded, model)
    after: dict[int, tuple[list[float], list[float], list[float]]]
    states_differ: int  #: status word and fault code reads the fitted model disagrees with
    states_compared: int
    evaluations: int
    seconds: float
    notes: list[str] = field(default_factory=list)
    profile: Profile | None = None


# --- Reading the capture.


def _load_records(path: str) -> list[LogRecord]:
    text = _read_text(path)
    lines = text.splitlines()
    try:
        return parse_log(lines, path)
    except C20SimError as exc:
        last = len(lines)
        if f"line {last}:" in str(exc) and not text.endswith("\n"):
            raise C20SimError(
                f"{path}: truncated: its last line ({last}) is cut short; remove that line, or record again"
            ) from None
        raise


def load_capture(path: str, profile: Profile, address: int | None = None) -> Capture:
    """The events of a frame log for a fit; C20SimError in one line for a log that cannot be fitted."""
    records = _load_records(path)
    if not any(r.direction == "rx" for r in records):
        raise C20SimError(f"{path}: no frame from the master (dir rx): not a capture of a master and a drive")
    found, _ = exchanges(records)
    registers = profile.registers
    t0 = found[0].record.t
    answered: dict[int, int] = {}
    foreign: list[str] = []
    requests = 0
    for exchange in found:
        if not exchange.record.data:
            continue
        requests += 1
        try:
            request = decode_request(exchange.record.data)
        except ValueError:
            foreign.append(f"line {exchange.record.line}: not a C20 request")
            continue
        if isinstance(request, ReadRequest | WriteSingleRequest | WriteMultipleRequest):
            start = request.start if isinstance(request, ReadRequest | WriteMultipleRequest) else request.register
            if start not in registers:
                foreign.append(f"line {exchange.record.line}: register {start:04X}H")
        else:
            foreign.append(f"line {exchange.record.line}: function 0x{request.function:02X}")
        if exchange.reply:
            answered[request.slave] = answered.get(request.slave, 0) + 1
    if requests and len(foreign) * 2 > requests:
        raise C20SimError(
            f"{path}: not a C20's traffic: {len(foreign)} of {requests} requests are nothing a C20 answers "
            f"(first: {foreign[0]}); is it another device's log?"
        )
    if address is None:
        address = max(answered, key=lambda a: answered[a]) if answered else 1
    events: list[Event] = []
    reads: dict[int, list[Event]] = {}
    turnaround: list[float] = []
    lengths: list[int] = []
    settings: dict[int, int] = {}
    loads = 0
    replies = {  # each request's first reply frame: when it ended
        id(r): n.t for r, n in itertools.pairwise(records) if r.direction == "rx" and n.direction == "tx" and n.data
    }
    for exchange in found:
        record = exchange.record
        t = record.t - t0
        if not record.data:
            if record.kind == "mark" and record.note in (LOAD_ON, LOAD_OFF):
                events.append(Event(t, "load", value=int(record.note == LOAD_ON), line=record.line))
                loads += record.note == LOAD_ON
            continue
        try:
            request = decode_request(record.data)
        except ValueError:
            continue
        if request.slave != address or not exchange.reply or not crc_ok(exchange.reply):
            continue
        try:
            response = decode_response(exchange.reply)
        except ValueError:
            continue
        if isinstance(response, ExceptionResponse):
            continue
        reply_t = replies.get(id(record))
        if reply_t is not None:
            turnaround.append(reply_t - record.t)
            lengths.append(len(exchange.reply))
        if isinstance(request, WriteSingleRequest):
            if request.register == Reg.BAUD:
                baud = BAUD_RATES[request.value] if request.value < len(BAUD_RATES) else request.value
                raise C20SimError(
                    f"{path}: line {record.line}: the master changes the baud (2009H = {baud} baud) mid-capture; "
                    "a fit needs one baud all through: record again without the change"
                )
            events.append(Event(t, "write", request.register, request.value, record.line))
        elif isinstance(request, WriteMultipleRequest):
            if request.start <= Reg.BAUD < request.start + len(request.values):
                raise C20SimError(
                    f"{path}: line {record.line}: the master changes the baud (2009H) mid-capture; "
                    "a fit needs one baud all through: record again without the change"
                )
            for offset, value in enumerate(request.values):
                events.append(Event(t, "write", request.start + offset, value, record.line))
        elif isinstance(request, ReadRequest) and isinstance(response, ReadResponse):
            for offset, value in enumerate(response.values):
                where = request.start + offset
                if where == Reg.DRIVE_ID and value != face.DRIVE_ID:
                    raise C20SimError(
                        f"{path}: line {record.line}: the drive ID (2103H) reads 0x{value:04X}, a C20 reads "
                        f"0x{face.DRIVE_ID:04X}: another device's log"
                    )
                if where in PHYSICAL:
                    event = Event(t, "read", where, value, record.line)
                    events.append(event)
                    reads.setdefault(where, []).append(event)
                elif where in (Reg.POLE_PAIRS, Reg.ACCEL_TIME, Reg.DECEL_TIME):
                    settings.setdefault(where, value)
    if not reads:
        raise C20SimError(
            f"{path}: no answered reads of physical quantities (3000H-3011H, 2100H-2102H) from drive {address}: "
            "nothing to fit; make a capture with: c20sim exercise PORT --out FILE"
        )
    duration = events[-1].t if events else 0.0
    return Capture(path, address, events, reads, turnaround, lengths, loads, settings, duration)


# --- The model, played along the capture.


Reader = Callable[[Any], float]


def _speed(d: Any) -> float:
    motion = d.motion
    return float(d.hall.rpm(d.t, d.t0 + motion.k * STEP, motion.speed, motion.cfg.pole_pairs))


#: The model's value of a compared register, before rounding, in the register's units.
READ_MODEL: dict[int, Reader] = {
    Reg.OUTPUT_CURRENT: face.output_amps,
    Reg.MOTOR_SPEED: _speed,
    Reg.OUTPUT_VOLTAGE: face.output_volts,
    Reg.BUS_VOLTAGE: lambda d: float(d.motion.bus),
    Reg.TEMPERATURE: lambda d: float(d.motion.temp),
    Reg.RAMP_FREQUENCY: lambda d: abs(d.motion.ramp) * d.motion.cfg.pole_pairs / 60.0,
}


def with_values(profile: Profile, values: dict[str, float]) -> Profile:
    """``profile`` with ``section.key`` values replaced."""
    sections: dict[str, dict[str, float]] = {}
    for name, value in values.items():
        section, key = name.split(".")
        sections.setdefault(section, {})[key] = value
    changes = {s: dataclasses.replace(getattr(profile, s), **kv) for s, kv in sections.items()}
    return dataclasses.replace(profile, **changes)


def given_settings(sim: Simulator, capture: Capture) -> Simulator:
    """``sim`` with the drive's own ramps and pole pairs, as the capture read them at its start."""
    slave = sim.slaves[capture.address]
    for address, value in capture.settings.items():
        reply = slave.handle(WriteSingleRequest(capture.address, address, value), sim.now(), communicated=False)
        if isinstance(reply, ExceptionResponse):
            raise C20SimError(
                f"{capture.path}: the drive's {FIXED_REGISTERS[address].name} ({address:04X}H = {value}) is outside "
                "what the base profile allows: give a --profile closer to this drive"
            )
    return sim


def simulate(
    profile: Profile, capture: Capture, events: Sequence[Event], load_nm: float
) -> tuple[dict[int, list[float]], list[tuple[Event, int]]]:
    """Play ``events`` into a fresh model: the compared values at each read, and each state read's model value."""
    sim = given_settings(Simulator(profile, [capture.address], clock=VirtualClock()), capture)
    drive = sim.drive(capture.address)
    slave = sim.slaves[capture.address]
    values: dict[int, list[float]] = {address: [] for address in COMPARED}
    states: list[tuple[Event, int]] = []
    for event in events:
        sim.run_until(event.t)
        if event.kind == "write":  # through the slave, as the drive took it: its access rules, its mirrors
            slave.handle(WriteSingleRequest(capture.address, event.address, event.value), event.t)
        elif event.kind == "load":
            drive.set_load_torque(load_nm if event.value else 0.0)
        else:
            drive.communicated(event.t)
            reader = READ_MODEL.get(event.address)
            if reader is not None:
                values[event.address].append(reader(drive))
            elif event.address in STATES:
                states.append((event, drive.read(event.address)))
    return values, states


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
    moving = _evenly(moving, limit)
    kept = {id(e) for e in moving} | {id(e) for e in _evenly(steady, limit - len(moving))}
    return [e for e in reads if id(e) in kept]


def _evenly(reads: list[Event], count: int) -> list[Event]:
    if len(reads) <= count:
        return reads
    stride = len(reads) / count
    return [reads[int(i * stride)] for i in range(count)]


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


def _turnaround(capture: Capture, baud: int, wire: str) -> Fitted | None:
    """protocol.turnaround_ms from the request-to-reply times: their median, less the reply's wire time where the
    log's times include it (auto: they cannot when a reply came sooner than its bytes take at ``baud``)."""
    samples = capture.turnaround
    if len(samples) < 5:
        return None
    wire_times = [frame_time(n, baud) for n in capture.reply_lengths]
    included = wire == "included" or (wire == "auto" and all(s >= w for s, w in zip(samples, wire_times, strict=True)))
    net = sorted(s - w if included else s for s, w in zip(samples, wire_times, strict=True))
    median = statistics.median(net)
    spread = statistics.median(abs(x - median) for x in net) * 1.4826
    param = Parameter("protocol", "turnaround_ms", "ms", "answered requests with their times")
    value = max(0.0, median * 1000.0)
    return Fitted(param, 0.0, value, spread * 1000.0 / math.sqrt(len(net)) + 1e-3, True, "")


def fit(
    capture: Capture,
    base: Profile,
    *,
    baud: int | None = None,
    wire: str = "auto",
    progress: Callable[[str], None] | None = None,
) -> FitResult:
    """Fit the parameters the capture reveals; the rest stay as in ``base``."""
    try:
        import numpy as np
        from scipy.optimize import least_squares
    except ImportError:
        raise C20SimError(
            "c20sim fit needs scipy, which the simulator itself does not: pip install 'c20sim[fit]'"
        ) from None

    started = time.perf_counter()
    say = progress or (lambda text: None)
    notes: list[str] = []
    changes = [e.t for e in capture.events if e.kind != "read"]
    compared = {a: _thin(capture.reads[a], MAX_FIT_READS, changes) for a in COMPARED if a in capture.reads}
    chosen = {id(e) for reads in compared.values() for e in reads}
    events = [e for e in capture.events if e.kind != "read" or id(e) in chosen or e.address in STATES]
    sigmas = {a: _sigma(a, capture) for a in compared}

    running = any(e.value in (1, 2) for e in capture.reads.get(Reg.STATUS1, ())) or any(
        e.value for e in capture.reads.get(Reg.MOTOR_SPEED, ())
    )
    temps = [_units(e) for e in capture.reads.get(Reg.TEMPERATURE, [])]
    rise = (max(temps) - min(temps)) if temps else 0.0
    speeds = _held_speeds(capture)
    reasons: dict[str, str] = {}
    if Reg.OUTPUT_VOLTAGE not in compared or not running:
        reasons["motor.kt_nm_per_a"] = "no reads of the output voltage (3003H) while running"
    if Reg.OUTPUT_CURRENT not in compared or not running:
        for key in ("inertia_kg_m2", "friction_nm", "viscous_nm_per_krpm"):
            reasons[f"motor.{key}"] = "no reads of the current (3004H) while running"
    elif len(speeds) < 2:
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
    free = [p for p in PARAMETERS if p.name not in reasons]
    start_values = {p.name: p.get(base) for p in PARAMETERS}
    if temps:
        base = with_values(base, {"thermal.ambient_c": temps[0]})  # the drive's temperature when the capture began
    fit_load = capture.loads > 0

    names = [p.name for p in free]
    # Each parameter moves as a multiple of its base value (1 = the base), within the profile format's range and
    # a factor of 50 either way; a base value of 0 (no viscous friction, say) starts at 0 on a scale of its range.
    x0: list[float] = []
    scales: list[float] = []
    lower: list[float] = []
    upper: list[float] = []
    for p in free:
        low, high = p.bounds(base)
        start = start_values[p.name]
        if start > 0:
            scale, low, high = start, max(low, start / 50.0), min(high, start * 50.0)
        else:
            scale = (high - low) / 1000.0 or 1.0
        x0.append(start / scale)
        scales.append(scale)
        lower.append(low / scale)
        upper.append(high / scale)
    load_scale = 0.25 * base.motor.kt_nm_per_a * base.motor.rated_current_a
    if fit_load:
        x0.append(1.0)
        lower.append(0.0)
        upper.append(20.0)
    recorded = {a: np.array([_units(e) for e in reads]) for a, reads in compared.items()}
    weights = {a: 1.0 / (sigmas[a] * math.sqrt(len(reads))) for a, reads in compared.items()}
    evaluations = [0]

    def model(x: Sequence[float]) -> tuple[Profile, float, dict[int, list[float]], list[tuple[Event, int]]]:
        values = {n: float(v) * s for n, v, s in zip(names, x, scales, strict=False)}
        profile = with_values(base, values)
        load = float(x[-1]) * load_scale if fit_load else 0.0
        evaluations[0] += 1
        got, states = simulate(profile, capture, events, load)
        return profile, load, got, states

    def residuals(x: Sequence[float]) -> Any:
        _, _, got, _ = model(x)
        parts = [(np.array(got[a]) - recorded[a]) * weights[a] for a in compared]
        return np.concatenate(parts)

    say(
        f"fitting {len(names)} parameter(s){' and the load' if fit_load else ''} to {sum(map(len, compared.values()))} reads"
    )
    _, _, before_values, _ = model(x0)
    if x0:
        result = least_squares(
            residuals, x0, bounds=(lower, upper), method="trf", x_scale="jac", diff_step=1e-3, max_nfev=60
        )
        if result.status == 0:
            notes.append("the least squares stopped at their limit of model runs before they converged")
        x, fun, jac = result.x, result.fun, result.jac
    else:  # nothing to fit: the comparison and the turnaround only
        x, fun, jac = np.array([]), residuals(x0), np.zeros((0, 0))
    profile_x, load, after_values, states = model(x)
    # Standard uncertainties from the Jacobian at the solution. Each quantity's residuals are weighted by
    # 1 / (sigma sqrt(n)): its reads count as one read's worth of information, not n. Averaging many reads does
    # not take away the rounding of a steady value (a bus that sits at 47.43 V reads 47.4 every time), so the
    # honest uncertainty is what one read at the register's resolution allows, times the misfit where it is worse.
    spread = max(1.0, float(np.sum(fun**2)) / max(1, len(compared)))
    try:
        covariance = np.linalg.pinv(jac.T @ jac) * spread if len(x) else np.zeros((0, 0))
        sigma_x = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    except np.linalg.LinAlgError:
        sigma_x = np.full(len(x), np.inf)
    fitted: list[Fitted] = []
    for parameter in PARAMETERS:
        base_value = start_values[parameter.name]
        if parameter.name in reasons:
            fitted.append(Fitted(parameter, base_value, base_value, math.inf, False, reasons[parameter.name]))
            continue
        i = names.index(parameter.name)
        value, sigma = float(x[i]) * scales[i], float(sigma_x[i]) * scales[i]
        column = float(np.abs(jac[:, i]).max()) if jac.size else 0.0
        if column == 0.0:
            fitted.append(Fitted(parameter, base_value, base_value, math.inf, False, "nothing in the capture moves it"))
        elif not sigma < IDENTIFIABLE * abs(value):
            why = f"fitted {value:.4g} +-{sigma:.2g}: too uncertain; it needs {parameter.needs}"
            fitted.append(Fitted(parameter, base_value, base_value, sigma, False, why))
        else:
            fitted.append(Fitted(parameter, base_value, value, sigma, True))
    load_fit = (load, float(sigma_x[-1]) * load_scale) if fit_load else None
    # the fitted profile holds only the identified values; it is what "after" shows
    final = with_values(base, {f.parameter.name: f.value for f in fitted if f.identified})
    turnaround = _turnaround(capture, baud or _baud(base), wire)
    if turnaround is not None:
        turnaround = dataclasses.replace(turnaround, base=base.protocol.turnaround_ms)
        final = with_values(final, {"protocol.turnaround_ms": turnaround.value})
    if final != profile_x:
        after_values, states = simulate(final, capture, events, load)
        evaluations[0] += 1
    differ = sum(1 for event, value in states if value != event.value)

    def series(values: dict[int, list[float]]) -> dict[int, tuple[list[float], list[float], list[float]]]:
        return {
            a: ([e.t for e in compared[a]], [float(v) for v in recorded[a]], [float(v) for v in values[a]])
            for a in compared
        }

    if capture.settings:
        words = ", ".join(
            f"{FIXED_REGISTERS[a].name} {FIXED_REGISTERS[a].describe(v)}" for a, v in sorted(capture.settings.items())
        )
        notes.append(f"the drive's settings, read at the start and given to the model: {words}")
    notes += _consistency(capture)
    return FitResult(
        capture,
        base,
        fitted,
        turnaround,
        load_fit,
        series(before_values),
        series(after_values),
        differ,
        len(states),
        evaluations[0],
        time.perf_counter() - started,
        notes,
        final,
    )


def _units(read: Event) -> float:
    """A read's value in its register's units (the temperature is signed)."""
    return FIXED_REGISTERS[read.address].engineering(read.value)


def _held_speeds(capture: Capture) -> set[int]:
    """The speeds the drive was held at: the set speeds written (2001H), or else the speeds read often
    (at least 10 reads within 50 rpm of each other)."""
    written = {e.value for e in capture.events if e.kind == "write" and e.address == Reg.SPEED_SETPOINT and e.value}
    if written:
        return written
    counts: dict[int, int] = {}
    for read in capture.reads.get(Reg.MOTOR_SPEED, ()):
        if read.value > 50:
            counts[round(read.value / 50.0)] = counts.get(round(read.value / 50.0), 0) + 1
    return {key * 50 for key, count in counts.items() if count >= 10}


def _consistency(capture: Capture) -> list[str]:
    """Pole pairs (2002H against 3001H / 3006H) and the Hall codes (3009H), in words."""
    notes: list[str] = []
    frequency = capture.reads.get(Reg.OUTPUT_FREQUENCY, [])
    speed = capture.reads.get(Reg.MOTOR_SPEED, [])
    ratios: list[float] = []
    j = 0
    for read in frequency:  # each output frequency with the speed read next to it
        while j + 1 < len(speed) and speed[j + 1].t <= read.t:
            j += 1
        if speed and read.value and speed[j].value > 200 and abs(speed[j].t - read.t) < 0.5:
            ratios.append(read.value / 100.0 * 60.0 / speed[j].value)
    if len(ratios) >= 3:
        found = statistics.median(ratios)
        read_pp = capture.settings.get(Reg.POLE_PAIRS)
        if read_pp is None:
            notes.append(f"pole pairs: output frequency against speed gives {found:.2f}; 2002H was not read")
        elif abs(found - read_pp) < 0.25:
            notes.append(f"pole pairs: output frequency against speed gives {found:.2f}, as 2002H reads ({read_pp})")
        else:
            notes.append(
                f"pole pairs: output frequency against speed gives {found:.2f}, but 2002H reads {read_pp}: "
                "the motor's pole pairs are set wrong on the drive, or its speed is measured another way"
            )
    halls = capture.reads.get(Reg.HALL, [])
    if halls:
        bad = sorted({e.value for e in halls if e.value in (0, 7)})
        seen = sorted({e.value for e in halls})
        if bad:
            notes.append(f"Hall codes (3009H): {seen}; {bad} is no healthy sensor's code: check the Hall wiring")
        else:
            notes.append(f"Hall codes (3009H): {seen}, each a healthy sensor's")
    return notes


def _baud(profile: Profile) -> int:
    raw = profile.default(Reg.BAUD)
    return BAUD_RATES[raw] if raw < len(BAUD_RATES) else 19200


# --- The new profile.


def _format(value: float) -> str:
    return f"{value:.6g}" if "e" not in f"{value:.6g}" else f"{value:.4e}"


def write_profile(result: FitResult, out: Path, log_name: str) -> Profile:
    """The base profile's file with each fitted value replaced and its source said; loaded before it is kept."""
    base = result.base
    text = Path(base.path).read_text(encoding="utf-8")
    changes: dict[tuple[str, str], str] = {}
    for f in result.fitted:
        if f.identified:
            value = _format(f.value)
            changes[(f.parameter.section, f.parameter.key)] = (
                f"{value}  # fitted from {log_name}, +-{f.sigma:.2g} (was {_format(f.base)})"
            )
    if result.turnaround is not None:
        t = result.turnaround
        changes[("protocol", "turnaround_ms")] = (
            f"{t.value:.3g}  # fitted from {log_name}, +-{t.sigma:.2g} (was {_format(t.base)})"
        )
    temps = result.capture.reads.get(Reg.TEMPERATURE)
    if temps:
        changes[("thermal", "ambient_c")] = (
            f"{_units(temps[0]):.4g}  # the drive's temperature when {log_name} began (was {_format(base.thermal.ambient_c)})"
        )
    lines = text.splitlines()
    section = ""
    done: set[tuple[str, str]] = set()
    out_lines: list[str] = []
    header = re.compile(r"^\s*\[([A-Za-z_]+)\]\s*(#.*)?$")
    for line in lines:
        match = header.match(line)
        if match or line.lstrip().startswith("[["):
            _add_missing(out_lines, section, changes, done)
            section = match.group(1) if match else "[[]]"  # an array of tables: nothing of ours in it
            out_lines.append(line)
            continue
        key = line.split("=", 1)[0].strip() if "=" in line and not line.lstrip().startswith("#") else ""
        if (section, key) in changes:
            out_lines.append(f"{key} = {changes[(section, key)]}")
            done.add((section, key))
        elif section == "" and key == "name":
            out_lines.append(f'name = "{out.stem}"')
        elif section == "" and key == "description":
            out_lines.append(f'description = "{base.name} fitted to {log_name} by c20sim fit"')
        else:
            out_lines.append(line)
    _add_missing(out_lines, section, changes, done)
    new_text = "\n".join(out_lines) + "\n"
    if missing := [f"{s}.{k}" for s, k in changes if (s, k) not in done]:
        raise C20SimError(f"{base.path}: no [{missing[0].split('.')[0]}] table to put {missing[0]} in")
    from ..drive.profile import parse_profile

    profile = parse_profile(new_text, str(out))  # c20sim's own loader: what is written loads
    try:
        out.write_text(new_text, encoding="utf-8")
    except OSError as exc:
        raise C20SimError(f"--out {out}: cannot write: {exc.strerror}") from None
    return profile


def _add_missing(
    lines: list[str], section: str, changes: dict[tuple[str, str], str], done: set[tuple[str, str]]
) -> None:
    for (s, key), value in changes.items():
        if s == section and (s, key) not in done:
            while lines and not lines[-1].strip():
                lines.pop()
            lines.append(f"{key} = {value}")
            lines.append("")
            done.add((s, key))


# --- In words.


def summary(result: FitResult) -> list[str]:
    """The fit in words: each parameter, its value and uncertainty or why it was not identified."""
    capture = result.capture
    reads = sum(len(r) for r in capture.reads.values())
    lines = [
        f"fit {capture.path} to {result.base.name}: drive {capture.address}, {capture.duration:.1f} s, "
        f"{reads} reads of physical quantities; {result.evaluations} model runs in {result.seconds:.1f} s",
    ]
    for f in result.fitted:
        p = f.parameter
        if f.identified:
            lines.append(f"  {p.name:<34} {_format(f.value):>10} {p.unit:<8} +-{f.sigma:.2g}  (base {_format(f.base)})")
        else:
            lines.append(f"  {p.name:<34} not identifiable from this capture: {f.why}; kept {_format(f.base)}")
    if result.turnaround is not None:
        t = result.turnaround
        lines.append(
            f"  {'protocol.turnaround_ms':<34} {t.value:>10.3g} ms       +-{t.sigma:.2g}  (base {_format(t.base)})"
        )
    else:
        lines.append(
            f"  {'protocol.turnaround_ms':<34} not identifiable from this capture: fewer than 5 answered requests"
        )
    if result.load_nm is not None:
        lines.append(f"  the load applied by hand: {result.load_nm[0]:.3g} N m +-{result.load_nm[1]:.2g} (not written)")
    for address, (_, recorded, before) in result.before.items():
        after = result.after[address][2]
        name, unit, _ = COMPARED[address]
        lines.append(
            f"  {name:<16} rms difference {_rms(recorded, before):.3g} {unit} with the base profile, "
            f"{_rms(recorded, after):.3g} {unit} fitted"
        )
    if result.states_compared:
        lines.append(
            f"  status words and fault codes: {result.states_compared - result.states_differ} of "
            f"{result.states_compared} reads agree with the fitted model"
        )
    lines += [f"  note: {n}" for n in result.notes]
    return lines


def _rms(a: Sequence[float], b: Sequence[float]) -> float:
    return math.sqrt(sum((x - y) ** 2 for x, y in zip(a, b, strict=True)) / max(1, len(a)))


def write_report(result: FitResult, directory: Path, profile_path: Path | None) -> list[Path]:
    """``report.md`` in words and, with matplotlib, a residual plot per quantity (PNG and SVG)."""
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise C20SimError(f"--report {directory}: cannot create: {exc.strerror}") from None
    written: list[Path] = []
    pictures: list[str] = []
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        pass  # the words still go out; the report says how to get the pictures
    else:
        for address, (t, recorded, before) in result.before.items():
            after = result.after[address][2]
            name, unit, _ = COMPARED[address]
            fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True, height_ratios=(2, 1))
            top.plot(t, recorded, ".", markersize=2, color="black", label="recorded")
            top.plot(t, before, "-", linewidth=0.8, color="tab:red", label=f"model, {result.base.name}")
            top.plot(t, after, "-", linewidth=0.8, color="tab:blue", label="model, fitted")
            top.set_ylabel(f"{name} ({unit})")
            top.legend(loc="best", fontsize=8)
            top.set_title(f"{name} ({address:04X}H): {Path(result.capture.path).name}")
            bottom.plot(t, [b - r for b, r in zip(before, recorded, strict=True)], ".", markersize=2, color="tab:red")
            bottom.plot(t, [a - r for a, r in zip(after, recorded, strict=True)], ".", markersize=2, color="tab:blue")
            bottom.axhline(0.0, color="grey", linewidth=0.5)
            bottom.set_ylabel(f"model - recorded ({unit})")
            bottom.set_xlabel("time in the capture (s)")
            fig.tight_layout()
            stem = name.replace(" ", "-")
            for suffix in (".png", ".svg"):
                path = directory / f"{stem}{suffix}"
                fig.savefig(path, dpi=100)
                written.append(path)
            plt.close(fig)
            pictures.append(f"![{name}]({stem}.png)")
    lines = ["# c20sim fit report", "", "```", *summary(result), "```", ""]
    if profile_path is not None:
        lines += [
            f"The fitted profile: `{profile_path}`. Compare it with the capture: "
            f"`c20sim replay {result.capture.path} --profile {profile_path}`.",
            "",
        ]
    lines += [
        "Each plot: the recorded reads (black), the model with the base profile (red) and fitted (blue); below, "
        "the model minus the recording. What remains after the fit is read noise, the registers' resolution, "
        "the timing of the reads, and what the model does not describe.",
        "",
    ]
    lines += pictures if pictures else ["(no plots: they need matplotlib: pip install 'c20sim[plots]')"]
    report = directory / "report.md"
    report.write_text("\n".join(lines) + "\n", encoding="utf-8")
    written.insert(0, report)
    return written


def cmd_fit(args: argparse.Namespace) -> int:
    base = load_profile(args.profile)
    out = Path(args.out)
    if out.suffix != ".toml":
        raise C20SimError(f"--out {out}: a profile is a .toml file, such as mydrive.toml")
    capture = load_capture(args.log, base, args.address)
    result = fit(capture, base, baud=args.baud, wire=args.wire_time, progress=lambda s: print(s, file=sys.stderr))
    log_name = Path(args.log).name
    profile = write_profile(result, out, log_name)
    for line in summary(result):
        print(line)
    print(f"wrote {out} ({profile.name}); compare: c20sim replay {args.log} --profile {out}")
    if args.report:
        written = write_report(result, Path(args.report), out)
        print(f"report: {written[0]} ({len(written) - 1} plot file(s))")
    # the replay against the fitted profile: the byte-for-byte view of what remains
    sim = given_settings(Simulator(profile, [capture.address], clock=VirtualClock()), capture)
    records = _load_records(args.log)
    replayed = replay(records, sim)
    print(
        f"replay against {out}: {replayed.exchanges - len(replayed.differences)} of {replayed.exchanges} replies "
        "match byte for byte; the rms differences above say by how much the rest differ"
    )
    return 0


def add_fit_command(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "fit",
        help="fit a profile to a capture of a real drive (c20sim exercise --out, record, serve --log-frames)",
        description="Play the master's side of a frame log into the model in virtual time, compare every read of a "
        "physical quantity, and fit what the capture reveals (Kt, inertia, friction, supply, thermal, turnaround) "
        "with bounded least squares; write a profile with each fitted value and its source.",
    )
    parser.add_argument("log", help="the JSONL frame log")
    parser.add_argument("--profile", default=DEFAULT_PROFILE, help=f"the base profile (default {DEFAULT_PROFILE})")
    parser.add_argument("--out", required=True, metavar="FILE.toml", help="the fitted profile to write")
    parser.add_argument("--report", metavar="DIR", help="write report.md and residual plots (PNG, SVG) here")
    parser.add_argument("--address", type=int, help="the drive to fit (default: the one answering most)")
    parser.add_argument("--baud", type=int, choices=BAUD_RATES, help="the line's baud (default: the profile's)")
    parser.add_argument(
        "--wire-time",
        default="auto",
        choices=["auto", "included", "excluded"],
        help="whether the log's reply times include the reply's bytes on the wire (record: yes; a pty: no)",
    )
    parser.set_defaults(func=cmd_fit)

"""What a fit moves and compares, and the model played along a capture in virtual time."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from ..core.clock import VirtualClock
from ..core.simulator import Simulator
from ..drive import face
from ..drive.physics import STEP
from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.protocol import (
    ExceptionResponse,
    WriteSingleRequest,
)
from ..wire.registers import FIXED_REGISTERS, Reg
from .fitcapture import Capture, Event
from .fitdialect import QuirkResult

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
    dialect: list[QuirkResult] = field(default_factory=list)  #: the quirks the dialect probe's frames show


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

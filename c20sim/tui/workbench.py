"""The bench around the drives: the keypad, the physical conditions, the fault switches.

Everything the dashboard does to a drive goes through here, so it is tested
without a screen. Device faults are injected as their *causes*: an
undervoltage trip is a supply switched low, an overheat is a hot ambient, an
external fault is the EF terminal. Conditions are set through
:func:`c20sim.control.set_conditions`, so they are checked as the control API
and the scenarios check them and a dashboard session can be replayed there;
they are read back from the drive, never copied, so what the control API
changes on the same loop shows here. Only faults the model has no physical
cause for (a power stage, the EEPROM, ...) are latched with ``force_fault``.
Link faults are the :class:`~c20sim.linkfaults.LinkFaults` switches of one
drive or of the whole bus. No textual import here.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from .. import control
from ..drive.model import Drive, HallFault, Telemetry
from ..drive.terminals import Input
from ..errors import C20SimError
from ..linkfaults import LinkFaults
from ..profile import FaultCause, Profile
from ..protocol import ExceptionCode
from ..registers import Reg
from ..simulator import Simulator, set_address

__all__ = [
    "CHANNEL_NAMES",
    "DEVICE_SWITCHES",
    "KEYPAD",
    "LINK_SWITCHES",
    "Conditions",
    "DriveView",
    "History",
    "Switch",
    "Workbench",
    "condition_range",
]

#: F00.01 values in words.
CHANNEL_NAMES = {0: "keypad", 1: "terminals", 2: "communication"}
#: F00.02 values in words.
SOURCE_NAMES = {0: "keypad", 1: "AI1 knob", 2: "AI2", 3: "Modbus", 4: "multi-speed"}

#: Keypad keys: name -> 2000H command value. JOG toggles between forward jog and jog stop.
KEYPAD = {
    short: control.KEYPAD[name]  # the 2000H command values, named once in the control API
    for short, name in (
        ("fwd", "forward"),
        ("rev", "reverse"),
        ("jog", "jog_forward"),
        ("jogrev", "jog_reverse"),
        ("stop", "stop"),
        ("reset", "reset"),
    )
}

#: Causes the bench injects physically; every other fault of the profile is latched with force_fault.
PHYSICAL_CAUSES = frozenset(
    {
        FaultCause.UNDERVOLTAGE,
        FaultCause.OVERVOLTAGE_ACCEL,
        FaultCause.OVERVOLTAGE_DECEL,
        FaultCause.OVERVOLTAGE_CONSTANT,
        FaultCause.OVERCURRENT_ACCEL,
        FaultCause.OVERCURRENT_DECEL,
        FaultCause.OVERCURRENT_CONSTANT,
        FaultCause.MOTOR_OVERLOAD,
        FaultCause.OVERHEAT,
        FaultCause.EXTERNAL,
        FaultCause.HALL,
        FaultCause.STALL,
    }
)

HALL_CYCLE: tuple[HallFault | None, ...] = (None, HallFault.STUCK0, HallFault.STUCK7, HallFault.SEQUENCE)


@dataclass(frozen=True)
class Switch:
    """One fault switch: its key, its label, and what it does physically."""

    key: str
    label: str
    how: str


#: Device fault switches with a physical cause (forced ones are added per profile: keys 1-9).
DEVICE_SWITCHES: tuple[Switch, ...] = (
    Switch("u", "undervoltage", "supply switched low (UV while running, off while stopped)"),
    Switch("v", "overvoltage", "supply switched high (OV1-3 by phase)"),
    Switch("c", "overcurrent", "load torque past the overcurrent level (OC1-3 by phase, while running)"),
    Switch("l", "overload", "load torque near the current limit (OL1 after about 30 s running)"),
    Switch("k", "locked rotor", "load torque past the current limit (stall while running)"),
    Switch("o", "overheat", "ambient at the control API's maximum (the trip time is the profile's)"),
    Switch("h", "Hall sensor", "cycles: stuck at 0, stuck at 7, out of sequence, mended"),
    Switch("e", "external fault", "the EF input terminal"),
)

LINK_SWITCHES: tuple[Switch, ...] = (
    Switch("o", "offline", "hears nothing, says nothing"),
    Switch("d", "drop next", "drop the next reply (press again for more)"),
    Switch("a", "drop 50 %", "drop half the replies at random"),
    Switch("y", "delay", "reply 500 ms late"),
    Switch("i", "jitter", "up to 200 ms random extra delay"),
    Switch("c", "bad CRC", "corrupt the reply's CRC"),
    Switch("u", "truncate", "send half the reply"),
    Switch("g", "garbage before", "two noise bytes before the reply"),
    Switch("n", "garbage after", "two noise bytes after the reply"),
    Switch("w", "wrong address", "answer from another address"),
    Switch("e", "exception", "cycles: force exception 0x01 .. 0x08, off"),
)

GARBAGE = b"\x00\xff"


@dataclass(frozen=True, slots=True)
class Conditions:
    """The physical conditions a drive is in now, as read from the drive."""

    supply_v: float
    load_torque_nm: float
    load_inertia_kg_m2: float
    ambient_c: float
    ai1_v: float
    ai2_v: float
    inputs: int  #: the physical input terminals (not the virtual ones of 2005H)
    hall: HallFault | None
    held_fault: int | None  #: a fault latched with force_fault(persistent=True), not yet released

    @classmethod
    def of(cls, drive: Drive) -> Conditions:
        tel = drive.telemetry()
        return cls(
            supply_v=tel.supply_v,
            load_torque_nm=tel.load_torque_nm,
            load_inertia_kg_m2=tel.load_inertia_kg_m2,
            ambient_c=tel.ambient_c,
            ai1_v=drive.ai(1),
            ai2_v=drive.ai(2),
            inputs=drive.physical_inputs,
            hall=drive.hall_fault,
            held_fault=drive.held_fault,
        )


@functools.cache
def condition_range(name: str) -> tuple[float, float]:
    """The range :data:`c20sim.control.CONDITION_RANGES` gives the numeric condition ``name``."""
    low, high = control.CONDITION_RANGES[name]
    return float(low), float(high)


@dataclass(frozen=True, slots=True)
class DriveView:
    """What the dashboard shows of one drive: its telemetry and the registers a master would read."""

    address: int
    telemetry: Telemetry
    status2: int  #: 2101H
    output_hz: float  #: 3001H
    set_hz: float  #: 3000H


@dataclass
class History:
    """The last minute of speed, current and bus voltage, one sample every ``every`` seconds of model time."""

    every: float = 0.5
    span: float = 60.0
    speed: deque[float] = field(default_factory=deque)
    current: deque[float] = field(default_factory=deque)
    bus: deque[float] = field(default_factory=deque)
    next_t: float | None = None
    samples: int = 0  #: samples taken so far (a view redraws the plot only when this moves)

    def add(self, tel: Telemetry) -> bool:
        """Sample ``tel`` if a sample is due; True if one was taken."""
        if self.next_t is not None and tel.t + 1e-9 < self.next_t:
            return False
        size = max(1, round(self.span / self.every))
        for series, value in ((self.speed, tel.speed_rpm), (self.current, tel.current_a), (self.bus, tel.bus_v)):
            series.append(value)
            while len(series) > size:
                series.popleft()
        self.samples += 1
        base = tel.t if self.next_t is None else self.next_t
        self.next_t = base + self.every * max(1, math.floor((tel.t - base) / self.every) + 1)
        return True


class Workbench:
    """A simulator's drives on the bench: what the dashboard (and its tests) do to them."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.profile: Profile = sim.profile
        self.drives: dict[int, Drive] = {}
        for address, drive in sim.drives.items():
            if not isinstance(drive, Drive):
                raise C20SimError("the dashboard needs the behavioural drive model (c20sim.drive.model.Drive)")
            self.drives[address] = drive
        self.history = {a: History() for a in self.drives}
        #: forced faults: key -> (code, name), the profile's faults with no physical cause, keys 1-9
        self.forced: dict[str, tuple[int, str]] = {}
        for spec in self.profile.faults.values():
            if spec.cause not in PHYSICAL_CAUSES and len(self.forced) < 9:
                self.forced[str(len(self.forced) + 1)] = (spec.code, spec.name)
        #: the device fault switches, the overheat's trip time worked out for this profile
        self.device_switches = tuple(
            replace(s, how=self._overheat_how()) if s.key == "o" else s for s in DEVICE_SWITCHES
        )

    # --- reading

    def drive(self, address: int) -> Drive:
        try:
            return self.drives[address]
        except KeyError:
            raise C20SimError(f"no drive at address {address}") from None

    def telemetry(self, address: int) -> Telemetry:
        return self.drive(address).telemetry()

    def conditions(self, address: int) -> Conditions:
        """The conditions drive ``address`` is in now, whoever set them."""
        return Conditions.of(self.drive(address))

    def sample(self) -> dict[int, DriveView]:
        """Bring the drives to the clock's time; what each shows, its telemetry added to the plot history."""
        self.sim.sync()
        out = {}
        for address, drive in self.drives.items():
            tel = drive.telemetry()
            self.history[address].add(tel)
            out[address] = DriveView(
                address,
                tel,
                drive.read(Reg.STATUS2),
                drive.read(Reg.OUTPUT_FREQUENCY) / 100.0,
                drive.read(Reg.SET_FREQUENCY) / 100.0,
            )
        return out

    def advance(self, seconds: float) -> None:
        """Virtual clock only: move time on, sampling the plot history on the way."""
        every = min(h.every for h in self.history.values())
        left = seconds
        while left > 1e-12:
            step = min(every, left)
            self.sim.advance(step)
            left -= step
            for address, drive in self.drives.items():
                self.history[address].add(drive.telemetry())

    # --- the keypad

    def keypad(self, address: int, key: str) -> str | None:
        """Press a keypad key; None if taken, else why it was refused."""
        self.sim.sync()
        drive = self.drive(address)
        command = KEYPAD[key]
        state = drive.state.value
        if key in ("jog", "jogrev") and state.startswith("jog"):
            command = control.KEYPAD["jog_stop"]  # a jog key pressed while jogging is released
        if drive.keypad(command):
            return None
        if key == "reset":
            if state != "fault":
                return "RESET: no fault to reset"
            return "RESET refused: the fault's cause is still present"
        channel = drive.telemetry().run_channel
        return (
            f"{key.upper()} refused: run commands come from the "
            f"{CHANNEL_NAMES.get(channel, str(channel))} (F00.01 = {channel}); press m to change the channel"
        )

    def cycle_channel(self, address: int) -> int:
        """The keypad's own parameter edit: F00.01 keypad -> terminals -> communication -> keypad."""
        self.sim.sync()
        drive = self.drive(address)
        cell = self.profile.registers.canonical(Reg.RUN_CHANNEL)
        value = (drive.read(cell) + 1) % 3
        drive.write(cell, value)
        return value

    def power_cycle(self, address: int) -> None:
        self.sim.sync()
        self.drive(address).power_cycle()

    def restore_defaults(self, address: int) -> str | None:
        """200FH = 1, as the keypad does it: only while stopped. Keeps the bus address given on the command line."""
        self.sim.sync()
        drive = self.drive(address)
        if drive.running:
            return "restore defaults refused: stop the motor first (200FH is W/R*)"
        drive.write(Reg.RESTORE_DEFAULTS, 1)
        set_address(drive, self.profile, address)
        return None

    # --- physical conditions, checked by the control API's one validation (ControlError if refused)

    def set_conditions(self, address: int, values: Mapping[str, object]) -> None:
        """Set conditions by their :data:`c20sim.control.CONDITIONS` names; none is set if one is refused."""
        control.set_conditions(self.sim, address, values)

    def set_supply(self, address: int, volts: float) -> None:
        self.set_conditions(address, {"supply_v": volts})

    def set_load(self, address: int, nm: float) -> None:
        self.set_conditions(address, {"load_torque_nm": nm})

    def set_ambient(self, address: int, celsius: float) -> None:
        self.set_conditions(address, {"ambient_c": celsius})

    def set_ai(self, address: int, channel: int, volts: float) -> None:
        self.set_conditions(address, {f"ai{channel}_v": volts})

    def set_inputs(self, address: int, bits: int) -> None:
        """The physical input terminals."""
        self.set_conditions(address, {"terminal_inputs": bits})

    def set_hall(self, address: int, fault: HallFault | None) -> None:
        self.set_conditions(address, {"hall_fault": None if fault is None else fault.value})

    # --- device faults, as causes

    def levels(self) -> dict[str, float]:
        """The condition each physical fault switch sets."""
        s, p, m = self.profile.supply, self.profile.protection, self.profile.motor
        return {
            "u": round(s.undervoltage_v * 0.5, 1),
            "v": round(s.overvoltage_v * 1.1, 1),
            "c": round(p.overcurrent_a * m.kt_nm_per_a * 1.25, 2),
            "l": round(p.current_limit_a * m.kt_nm_per_a * 0.9, 2),
            "k": round(p.current_limit_a * m.kt_nm_per_a * 1.5, 2),
        }

    def overheat_ambient(self) -> float:
        """The ambient the overheat switch sets: the highest the control API accepts."""
        return condition_range("ambient_c")[1]

    def overheat_seconds(self, from_c: float | None = None) -> float:
        """Seconds to the overheat trip at :meth:`overheat_ambient`, from ``from_c`` (the profile's ambient).

        Self-heating left out: T(t) = A - (A - T0) exp(-t / tau) reaching the trip level.
        """
        th = self.profile.thermal
        start = th.ambient_c if from_c is None else from_c
        ambient = self.overheat_ambient()
        if start > th.overheat_c:
            return 0.0
        if ambient <= th.overheat_c:
            return math.inf
        return th.time_constant_s * math.log((ambient - start) / (ambient - th.overheat_c))

    def _overheat_how(self) -> str:
        seconds = self.overheat_seconds()
        when = "never trips" if math.isinf(seconds) else f"trips in about {seconds:.0f} s"
        return f"ambient {self.overheat_ambient():g} °C, the control API's maximum: {when}; T/t advances virtual time"

    def device_fault_active(self, address: int, key: str) -> bool:
        """Whether the cause of a device fault is there now, whoever put it there.

        Supply and ambient are lit past their trip levels; the load switches when the load is their own level.
        """
        cond, levels = self.conditions(address), self.levels()
        s = self.profile.supply
        if key == "u":
            return cond.supply_v < s.undervoltage_v
        if key == "v":
            return cond.supply_v > s.overvoltage_v
        if key in ("c", "l", "k"):
            return math.isclose(cond.load_torque_nm, levels[key])
        if key == "o":
            return cond.ambient_c > self.profile.thermal.overheat_c
        if key == "h":
            return cond.hall is not None
        if key == "e":
            return bool(cond.inputs & Input.EF)
        if key in self.forced:
            return cond.held_fault == self.forced[key][0]
        return False

    def toggle_device_fault(self, address: int, key: str) -> str:
        """Switch a device fault's cause on or off; returns what was done, in words."""
        cond, levels = self.conditions(address), self.levels()
        active = self.device_fault_active(address, key)
        s, th = self.profile.supply, self.profile.thermal
        if key in ("u", "v"):
            volts = s.voltage_v if active else levels[key]
            self.set_supply(address, volts)
            return f"drive {address}: supply {volts:g} V"
        if key in ("c", "l", "k"):
            nm = 0.0 if active else levels[key]
            self.set_load(address, nm)
            return f"drive {address}: load torque {nm:g} N m"
        if key == "o":
            if active:
                self.set_ambient(address, th.ambient_c)
                return f"drive {address}: ambient {th.ambient_c:g} °C"
            celsius = self.overheat_ambient()
            self.set_ambient(address, celsius)
            seconds = self.overheat_seconds(self.telemetry(address).temperature_c)
            when = "never trips" if math.isinf(seconds) else f"trips in about {seconds:.0f} s"
            return f"drive {address}: ambient {celsius:g} °C ({when})"
        if key == "h":
            fault = HALL_CYCLE[(HALL_CYCLE.index(cond.hall) + 1) % len(HALL_CYCLE)]
            self.set_hall(address, fault)
            return f"drive {address}: Hall sensor {fault.value if fault else 'mended'}"
        if key == "e":
            self.set_inputs(address, cond.inputs ^ Input.EF)
            return f"drive {address}: EF terminal {'off' if active else 'on'}"
        if key in self.forced:
            code, name = self.forced[key]
            self.sim.sync()
            drive = self.drive(address)
            if active:
                drive.release_fault()
                return f"drive {address}: {name} cause gone (reset to clear)"
            drive.force_fault(code, persistent=True)
            return f"drive {address}: {name} (0x{code:02X}) latched"
        if key == "z":
            self.clear_device_faults(address)
            return f"drive {address}: every fault cause cleared"
        raise KeyError(key)

    def clear_device_faults(self, address: int) -> None:
        s, th = self.profile.supply, self.profile.thermal
        self.set_conditions(
            address,
            {
                "supply_v": s.voltage_v,
                "load_torque_nm": 0.0,
                "ambient_c": th.ambient_c,
                "hall_fault": None,
                "terminal_inputs": self.drive(address).physical_inputs & ~Input.EF,
            },
        )
        self.drive(address).release_fault()

    # --- link faults

    def link(self, scope: int | None) -> LinkFaults:
        """The link faults of one drive, or of the whole bus (None)."""
        return self.sim.link_faults(scope)

    def link_fault_active(self, scope: int | None, key: str) -> bool:
        link = self.link(scope)
        return {
            "o": link.offline,
            "d": link.drop_next > 0,
            "a": link.drop_percent > 0,
            "y": link.delay > 0,
            "i": link.delay_jitter > 0,
            "c": link.corrupt_crc,
            "u": link.truncate,
            "g": bool(link.garbage_before),
            "n": bool(link.garbage_after),
            "w": link.wrong_address is not None,
            "e": link.forced_exception is not None,
        }.get(key, False)

    def toggle_link_fault(self, scope: int | None, key: str) -> str:
        link = self.link(scope)
        where = "bus" if scope is None else f"drive {scope} link"
        if key == "o":
            link.offline = not link.offline
            return f"{where}: {'offline' if link.offline else 'online'}"
        if key == "d":
            link.drop_next += 1
            return f"{where}: dropping the next {link.drop_next} repl{'y' if link.drop_next == 1 else 'ies'}"
        if key == "a":
            link.drop_percent = 0.0 if link.drop_percent else 50.0
            return f"{where}: random drops {link.drop_percent:g} %"
        if key == "y":
            link.delay = 0.0 if link.delay else 0.5
            return f"{where}: reply delay {link.delay * 1000:.0f} ms"
        if key == "i":
            link.delay_jitter = 0.0 if link.delay_jitter else 0.2
            return f"{where}: jitter {link.delay_jitter * 1000:.0f} ms"
        if key == "c":
            link.corrupt_crc = not link.corrupt_crc
            return f"{where}: bad CRC {'on' if link.corrupt_crc else 'off'}"
        if key == "u":
            link.truncate = not link.truncate
            return f"{where}: truncated replies {'on' if link.truncate else 'off'}"
        if key == "g":
            link.garbage_before = b"" if link.garbage_before else GARBAGE
            return f"{where}: garbage before replies {'on' if link.garbage_before else 'off'}"
        if key == "n":
            link.garbage_after = b"" if link.garbage_after else GARBAGE
            return f"{where}: garbage after replies {'on' if link.garbage_after else 'off'}"
        if key == "w":
            wrong = 0x63 if scope is None else scope % 247 + 1
            link.wrong_address = None if link.wrong_address is not None else wrong
            return f"{where}: wrong address {'off' if link.wrong_address is None else link.wrong_address}"
        if key == "e":
            codes = [None, *ExceptionCode]
            current = codes.index(link.forced_exception)
            link.forced_exception = codes[(current + 1) % len(codes)]
            fe = link.forced_exception
            return f"{where}: forced exception {'off' if fe is None else f'0x{int(fe):02X} {fe.meaning}'}"
        if key == "z":
            link.clear()
            return f"{where}: every link fault cleared"
        raise KeyError(key)

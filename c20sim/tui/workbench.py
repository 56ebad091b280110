"""The bench around the drives: the keypad, the physical conditions, the fault switches.

Everything the dashboard does to a drive goes through here, so it is tested
without a screen. Device faults are injected as their *causes*, through the
drive's own API: an undervoltage trip is a supply switched low, an overheat is
a hot ambient, an external fault is the EF terminal. Only faults the model has
no physical cause for (a power stage, the EEPROM, ...) are latched with
``force_fault``. Link faults are the :class:`~c20sim.linkfaults.LinkFaults`
switches of one drive or of the whole bus. No textual import here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

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
]

#: F00.01 values in words.
CHANNEL_NAMES = {0: "keypad", 1: "terminals", 2: "communication"}
#: F00.02 values in words.
SOURCE_NAMES = {0: "keypad", 1: "AI1 knob", 2: "AI2", 3: "Modbus", 4: "multi-speed"}

#: Keypad keys: name -> 2000H command value. JOG toggles between forward jog and jog stop.
KEYPAD = {"fwd": 1, "rev": 2, "jog": 3, "jogrev": 4, "stop": 5, "reset": 7}

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

#: Seconds an overheat takes to trip once switched on (the ambient is set to make it so).
OVERHEAT_SECONDS = 30.0
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
    Switch("o", "overheat", f"ambient raised to trip in about {OVERHEAT_SECONDS:g} s"),
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
    Switch("x", "exception", "cycles: force exception 0x01 .. 0x08, off"),
)

GARBAGE = b"\x00\xff"


@dataclass
class Conditions:
    """The physical conditions the bench holds a drive in (the dashboard's own record)."""

    supply_v: float
    load_torque_nm: float
    ambient_c: float
    ai1_v: float = 0.0
    ai2_v: float = 0.0
    inputs: int = 0
    hall: HallFault | None = None
    forced: int | None = None  #: a fault code latched with force_fault (persistent until switched off)


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
        s, th = self.profile.supply, self.profile.thermal
        self.conditions = {a: Conditions(s.voltage_v, 0.0, th.ambient_c) for a in self.drives}
        self.history = {a: History() for a in self.drives}
        #: forced faults: key -> (code, name), the profile's faults with no physical cause, keys 1-9
        self.forced: dict[str, tuple[int, str]] = {}
        for spec in self.profile.faults.values():
            if spec.cause not in PHYSICAL_CAUSES and len(self.forced) < 9:
                self.forced[str(len(self.forced) + 1)] = (spec.code, spec.name)

    # --- reading

    def drive(self, address: int) -> Drive:
        try:
            return self.drives[address]
        except KeyError:
            raise C20SimError(f"no drive at address {address}") from None

    def telemetry(self, address: int) -> Telemetry:
        return self.drive(address).telemetry()

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

    def channel(self, address: int) -> int:
        return self.drive(address).telemetry().run_channel

    # --- the keypad

    def keypad(self, address: int, key: str) -> str | None:
        """Press a keypad key; None if taken, else why it was refused."""
        self.sim.sync()
        drive = self.drive(address)
        command = KEYPAD[key]
        state = drive.state.value
        if key == "jog" and state.startswith("jog"):
            command = 8  # jog stop: the key is released
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
        self.conditions[address].forced = None

    def restore_defaults(self, address: int) -> str | None:
        """200FH = 1, as the keypad does it: only while stopped. Keeps the bus address given on the command line."""
        self.sim.sync()
        drive = self.drive(address)
        if drive.running:
            return "restore defaults refused: stop the motor first (200FH is W/R*)"
        drive.write(Reg.RESTORE_DEFAULTS, 1)
        set_address(drive, self.profile, address)
        return None

    # --- physical conditions

    def set_supply(self, address: int, volts: float) -> None:
        self.sim.sync()
        self.conditions[address].supply_v = max(0.0, volts)
        self.drive(address).set_supply_voltage(volts)

    def set_load(self, address: int, nm: float) -> None:
        self.sim.sync()
        self.conditions[address].load_torque_nm = max(0.0, nm)
        self.drive(address).set_load_torque(nm)

    def set_ambient(self, address: int, celsius: float) -> None:
        self.sim.sync()
        self.conditions[address].ambient_c = celsius
        self.drive(address).set_ambient(celsius)

    def set_ai(self, address: int, channel: int, volts: float) -> None:
        self.sim.sync()
        volts = min(max(volts, 0.0), 10.0)
        if channel == 1:
            self.conditions[address].ai1_v = volts
        else:
            self.conditions[address].ai2_v = volts
        self.drive(address).set_ai(channel, volts)

    def set_inputs(self, address: int, bits: int) -> None:
        self.sim.sync()
        self.conditions[address].inputs = bits & 0x1FF
        self.drive(address).set_terminal_inputs(bits & 0x1FF)

    def set_hall(self, address: int, fault: HallFault | None) -> None:
        self.sim.sync()
        self.conditions[address].hall = fault
        self.drive(address).set_hall_fault(fault)

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

    def device_fault_active(self, address: int, key: str) -> bool:
        cond, levels = self.conditions[address], self.levels()
        if key == "u":
            return cond.supply_v == levels["u"]
        if key == "v":
            return cond.supply_v == levels["v"]
        if key in ("c", "l", "k"):
            return cond.load_torque_nm == levels[key]
        if key == "o":
            return cond.ambient_c > self.profile.thermal.overheat_c
        if key == "h":
            return cond.hall is not None
        if key == "e":
            return bool(cond.inputs & Input.EF)
        if key in self.forced:
            return cond.forced == self.forced[key][0]
        return False

    def toggle_device_fault(self, address: int, key: str) -> str:
        """Switch a device fault's cause on or off; returns what was done, in words."""
        cond, levels = self.conditions[address], self.levels()
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
                celsius = th.ambient_c
            else:
                temp = self.telemetry(address).temperature_c
                rise = (th.overheat_c + 1.0 - temp) / (1.0 - math.exp(-OVERHEAT_SECONDS / th.time_constant_s))
                celsius = float(round(temp + max(rise, 1.0)))
            self.set_ambient(address, celsius)
            return f"drive {address}: ambient {celsius:g} °C"
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
                cond.forced = None
                return f"drive {address}: {name} cause gone (reset to clear)"
            drive.force_fault(code, persistent=True)
            cond.forced = code
            return f"drive {address}: {name} (0x{code:02X}) latched"
        if key == "z":
            self.clear_device_faults(address)
            return f"drive {address}: every fault cause cleared"
        raise KeyError(key)

    def clear_device_faults(self, address: int) -> None:
        s, th = self.profile.supply, self.profile.thermal
        cond = self.conditions[address]
        self.set_supply(address, s.voltage_v)
        self.set_load(address, 0.0)
        self.set_ambient(address, th.ambient_c)
        self.set_hall(address, None)
        self.set_inputs(address, cond.inputs & ~Input.EF)
        if cond.forced is not None:
            self.drive(address).release_fault()
            cond.forced = None

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
            "x": link.forced_exception is not None,
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
        if key == "x":
            codes = [None, *ExceptionCode]
            current = codes.index(link.forced_exception)
            link.forced_exception = codes[(current + 1) % len(codes)]
            fe = link.forced_exception
            return f"{where}: forced exception {'off' if fe is None else f'0x{int(fe):02X} {fe.meaning}'}"
        if key == "z":
            link.clear()
            return f"{where}: every link fault cleared"
        raise KeyError(key)

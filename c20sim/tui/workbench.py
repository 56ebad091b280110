"""The bench around the drives: the keypad, the physical conditions, the fault switches.

Everything the dashboard does to a drive goes through here, and everything
here is an operation of :mod:`c20sim.control` (the same checks as the control
API, the scenarios and pytest), so it is tested without a screen and a
dashboard session means what a script would mean. The operations come from a
:class:`BenchOps`: :class:`~c20sim.control.client.RemoteOps` (the control API
of a served simulator: the dashboard) or :class:`LocalOps` (a simulator in
this process: tests and scripts). Device faults are switched
as their causes (:mod:`c20sim.control.causes`); conditions and link faults are
read back through the operations, never copied, so what another front end
changes shows here. The switches come from the operations' own tables: a new
cause or link fault has its key here without a line of this file changing.
No textual import here.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, overload

from ..control import causes, ops, routes
from ..core.linkfaults import KNOBS
from ..core.simulator import Simulator
from ..drive.faultrecord import CURRENT_CONTEXT, FAULT_TYPES, has_record
from ..drive.model import HallFault, Telemetry
from ..drive.profile import Profile
from ..drive.trips import Cycle
from ..wire.errors import C20SimError
from ..wire.protocol import ExceptionCode
from ..wire.registers import RUN_CHANNELS, Command, Reg, RunChannel, fcode_address

__all__ = [
    "DEVICE_SWITCHES",
    "KEYPAD",
    "LINK_SWITCHES",
    "BenchOps",
    "Conditions",
    "DriveView",
    "History",
    "LocalOps",
    "Switch",
    "Workbench",
    "condition_range",
]

#: Keypad keys: the panel's key name -> 2000H command. JOG toggles between a jog and jog stop.
KEYPAD: Mapping[str, Command] = {
    "fwd": Command.FORWARD,
    "rev": Command.REVERSE,
    "jog": Command.JOG_FORWARD,
    "jogrev": Command.JOG_REVERSE,
    "stop": Command.STOP,
    "reset": Command.RESET,
}


@dataclass(frozen=True)
class Switch:
    """One fault switch: its key, its label, and what it does physically."""

    key: str
    label: str
    how: str


class _DeviceSwitches(Sequence[Switch]):
    """The device fault switches as the cause rows are now (:data:`c20sim.control.causes.CAUSES`, read when asked)."""

    @staticmethod
    def now() -> tuple[Switch, ...]:
        return tuple(Switch(c.key, c.label, c.how) for c in causes.CAUSES.values())

    @overload
    def __getitem__(self, index: int) -> Switch: ...
    @overload
    def __getitem__(self, index: slice) -> tuple[Switch, ...]: ...
    def __getitem__(self, index: int | slice) -> Switch | tuple[Switch, ...]:
        return self.now()[index]

    def __len__(self) -> int:
        return len(causes.CAUSES)

    def __repr__(self) -> str:
        return f"DEVICE_SWITCHES{self.now()!r}"


#: Device fault switches, one per physical cause (latched faults are added per profile: keys 1-9), read from the
#: rows when asked: a cause registered after this module was imported has its switch here.
DEVICE_SWITCHES: Sequence[Switch] = _DeviceSwitches()


def cause_of_key() -> dict[str, str]:
    """The cause behind each device switch key, as the rows are now."""
    return {c.key: c.name for c in causes.CAUSES.values()}


#: Link fault switches, one per link fault, from the link faults' own knobs.
LINK_SWITCHES: tuple[Switch, ...] = tuple(Switch(k.key, k.label, k.how) for k in KNOBS.values())
#: The link fault behind each link switch key.
LINK_OF_KEY: Mapping[str, str] = {knob.key: name for name, knob in KNOBS.items()}


@dataclass(frozen=True, slots=True)
class Conditions:
    """The physical conditions a drive is in now, as read through the operations: every condition of
    :data:`c20sim.control.ops.CONDITIONS` by its name, in ``values`` or as an attribute (``.supply_v``; a
    continuous one as a float), with the terminals as ``inputs`` and the Hall sensor's fault as ``hall``."""

    values: Mapping[str, object]
    held_fault: int | None  #: a fault latched persistently, not yet released

    @classmethod
    def of(cls, values: Mapping[str, object], held_fault: int | None) -> Conditions:
        return cls(dict(values), held_fault)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name in ("values", "held_fault"):
            raise AttributeError(name)
        try:
            value = self.values[name]
        except KeyError:
            raise AttributeError(f"no condition {name!r}; conditions: {', '.join(self.values)}") from None
        condition = ops.CONDITIONS.get(name)
        if condition is not None and condition.continuous and isinstance(value, int | float):
            return float(value)
        return value

    @property
    def inputs(self) -> int:
        """The physical input terminals (not the virtual ones of 200AH)."""
        value = self.values["terminal_inputs"]
        assert isinstance(value, int)
        return value

    @property
    def hall(self) -> HallFault | None:
        value = self.values["hall_fault"]
        return None if value is None else HallFault(value)


@functools.cache
def condition_range(name: str) -> tuple[float, float]:
    """The range the operations accept for the numeric condition ``name``."""
    condition = ops.CONDITIONS[name]
    assert condition.low is not None and condition.high is not None
    return float(condition.low), float(condition.high)


@dataclass(frozen=True, slots=True)
class DriveView:
    """What the dashboard shows of one drive: its telemetry and the registers a master would read."""

    address: int
    telemetry: Telemetry
    status2: int  #: 2101H
    output_hz: float  #: 3001H
    set_hz: float  #: 3000H
    #: while faulted, from the fault record (F07.28, F07.33, F07.36, F07.37): the fault before, and the running
    #: frequency (0.01 Hz), output current (0.01 A) and bus (0.1 V) at the trip; empty otherwise
    record: tuple[int, ...] = ()


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


class BenchOps(Protocol):
    """The operations the bench uses, on the drives of one simulator, wherever it runs: what it reads, and
    :meth:`call`, every operation of the route table (:mod:`c20sim.control.routes`) by its name."""

    profile: Profile
    addresses: tuple[int, ...]
    virtual: bool

    def now(self) -> float: ...
    def telemetry(self, address: int) -> Telemetry: ...
    def conditions(self, address: int) -> dict[str, object]: ...
    def held_fault(self, address: int) -> int | None: ...
    def register(self, address: int, register: int) -> int: ...
    def causes(self, address: int) -> dict[str, bool]: ...
    def link(self, scope: int | None) -> dict[str, Any]: ...
    def call(self, name: str, /, **arguments: Any) -> Any: ...


class LocalOps:
    """:class:`BenchOps` on a simulator in this process, straight through the route table's operations."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.profile = sim.profile
        self.addresses = tuple(sim.drives)
        self.virtual = sim.virtual

    def now(self) -> float:
        return self.sim.now()

    def telemetry(self, address: int) -> Telemetry:
        return ops.telemetry(self.sim, address)

    def conditions(self, address: int) -> dict[str, object]:
        return ops.conditions(self.sim, address)

    def held_fault(self, address: int) -> int | None:
        return ops.held_fault(self.sim, address)

    def register(self, address: int, register: int) -> int:
        raw: int = ops.read_register(self.sim, address, register)["raw"]
        return raw

    def causes(self, address: int) -> dict[str, bool]:
        return causes.active(self.sim, address)

    def link(self, scope: int | None) -> dict[str, Any]:
        return ops.link_state(ops.links(self.sim, scope))

    def call(self, name: str, /, **arguments: Any) -> Any:
        row = routes.table().named(name)
        parameters = {p: arguments.pop(p) for p in row.parameters}
        data = arguments[row.whole] if row.whole is not None else arguments
        return routes.invoke(self.sim, row, parameters, data)


class Workbench:
    """Drives on the bench: what the dashboard (and its tests) do to them, through the operations.

    ``source`` is a :class:`BenchOps` (the dashboard's: the control API) or a Simulator in this process.
    """

    def __init__(self, source: Simulator | BenchOps) -> None:
        self.ops: BenchOps = LocalOps(source) if isinstance(source, Simulator) else source
        #: the simulator, for a bench in the same process (tests); None over the control API
        self.sim: Simulator | None = source if isinstance(source, Simulator) else None
        self.profile: Profile = self.ops.profile
        self._has_record = has_record(self.profile.defaults)
        self.addresses: tuple[int, ...] = tuple(self.ops.addresses)
        self.virtual: bool = self.ops.virtual
        self.history = {a: History() for a in self.addresses}
        #: latched faults: key -> (code, name), the profile's faults with no physical cause, keys 1-9
        self.forced: dict[str, tuple[int, str]] = {}
        self._latched_cause: dict[str, str] = {}
        latched = causes.latched(self.profile)
        for spec in self.profile.faults.values():
            if spec.cause is not None and spec.cause.value in latched and len(self.forced) < 9:
                key = str(len(self.forced) + 1)
                self.forced[key] = (spec.code, spec.name)
                self._latched_cause[key] = spec.cause.value
        #: the device fault switches, a cause's trip time (its ``eta``) worked out for this profile
        self.device_switches = tuple(self._switch(s) for s in DEVICE_SWITCHES)

    # --- reading

    def _check(self, address: int) -> int:
        if address not in self.addresses:
            raise C20SimError(f"no drive at address {address}")
        return address

    def telemetry(self, address: int) -> Telemetry:
        return self.ops.telemetry(self._check(address))

    def conditions(self, address: int) -> Conditions:
        """The conditions drive ``address`` is in now, whoever set them."""
        return Conditions.of(self.ops.conditions(address), self.ops.held_fault(address))

    def register(self, address: int, register: int) -> int:
        return self.ops.register(address, register)

    def sample(self) -> dict[int, DriveView]:
        """Bring the drives to the clock's time; what each shows, its telemetry added to the plot history."""
        out = {}
        for address in self.addresses:
            tel = self.ops.telemetry(address)
            self.history[address].add(tel)
            out[address] = DriveView(
                address,
                tel,
                self.register(address, Reg.STATUS2),
                self.register(address, Reg.OUTPUT_FREQUENCY) / 100.0,
                self.register(address, Reg.SET_FREQUENCY) / 100.0,
                self._record(address) if tel.fault_code and self._has_record else (),
            )
        return out

    def _record(self, address: int) -> tuple[int, ...]:
        """What the status shows of the fault record beside the fault (four reads, only while faulted)."""
        cells = (FAULT_TYPES[1], CURRENT_CONTEXT[0], CURRENT_CONTEXT[3], CURRENT_CONTEXT[4])
        return tuple(self.register(address, cell) for cell in cells)

    def advance(self, seconds: float) -> None:
        """Virtual clock only: move time on, sampling the plot history on the way."""
        every = min(h.every for h in self.history.values())
        now = self.ops.now()
        end = now + seconds
        while now < end - 1e-12:
            now = float(self.ops.call("advance", seconds=min(every, end - now))["t"])
            for address in self.addresses:
                self.history[address].add(self.ops.telemetry(address))

    # --- the keypad

    def keypad(self, address: int, key: str) -> str | None:
        """Press a keypad key; None if taken, else why it was refused."""
        command = KEYPAD[key]
        tel = self.telemetry(address)
        state = tel.state
        if key in ("jog", "jogrev") and state.startswith("jog"):
            command = Command.JOG_STOP  # a jog key pressed while jogging is released
        if self.ops.call("press_key", address=address, key=command)["accepted"]:
            return None
        if key == "reset":
            if state != "fault":
                return "RESET: no fault to reset"
            return f"RESET refused: {self.holding(address)}"
        channel = tel.run_channel
        return (
            f"{key.upper()} refused: run commands come from the "
            f"{RUN_CHANNELS.get(channel, str(channel))} (F00.01 = {channel}); press m to change the channel"
        )

    def cycle_channel(self, address: int) -> int:
        """The keypad's own parameter edit: F00.01 keypad -> terminals -> communication -> keypad."""
        now = self.telemetry(address).run_channel
        channel = (now + 1) % (RunChannel.COMMUNICATION + 1)
        return int(self.ops.call("set_run_channel", address=address, channel=channel)["channel"])

    def cycle_speed_source(self, address: int) -> str:
        """The keypad's edit of F00.02: the next speed source this model takes; returns it in words."""
        spec = self.profile.registers[Reg.SPEED_SOURCE]
        now = self.register(address, Reg.SPEED_SOURCE)
        span = spec.maximum - spec.minimum + 1
        for step in range(1, span):
            value = spec.minimum + (now - spec.minimum + step) % span
            try:
                return str(self._panel(address, Reg.SPEED_SOURCE, value)["text"])
            except ops.ControlError:
                continue  # a source this model lacks (simple PLC): the panel skips it
        raise ops.ControlError("no other speed source is allowed here", status=409)

    def step_keypad_speed(self, address: int, steps: int) -> str:
        """The panel's up/down on the keypad speed reference (F00.10), one step of 1.00 Hz; returns it in words."""
        cell = fcode_address(0, 10)
        spec = self.profile.registers[cell]
        value = min(max(self.register(address, cell) + steps * 100, spec.minimum), spec.maximum)
        return str(self._panel(address, cell, value)["text"])

    def registers(self, address: int) -> list[dict[str, object]]:
        """Every register and function code, grouped as the sheet groups them, with its value now."""
        return list(self.ops.call("registers", address=address)["registers"])

    def write_register(self, address: int, register: str, value: int) -> str | None:
        """Write as a master would (the same checks); None if taken, else the refusal with its exception code."""
        try:
            self.ops.call("write_register", address=address, register=register, value=value)
        except ops.ControlError as exc:
            return str(exc)
        return None

    def audit(self) -> dict[str, Any] | None:
        """The live audit's report (``GET /audit``: findings, line demand); None when the server audits nothing."""
        try:
            return dict(self.ops.call("audit"))
        except ops.ControlError as exc:
            if exc.status == 409:  # serve --no-audit
                return None
            raise

    def drill(self) -> dict[str, Any] | None:
        """The drill's state and report (``GET /drill``); None where the server has no drill (409)."""
        try:
            return dict(self.ops.call("drill"))
        except ops.ControlError as exc:
            if exc.status == 409:
                return None
            raise

    def start_drill(self, plan: list[str] | None) -> dict[str, Any]:
        """Start a drill of ``plan`` (incidents by name; None: the standard plan) on the master polling the serve."""
        return dict(self.ops.call("start_drill", plan=plan))

    def stop_drill(self) -> dict[str, Any]:
        return dict(self.ops.call("stop_drill"))

    def counters(self, address: int) -> dict[str, object]:
        """The drive's traffic: requests, replies, exceptions by code, CRC errors, silences, injected."""
        return dict(self.ops.call("counters", address=address))

    def power_cycle(self, address: int) -> None:
        self.ops.call("power_cycle", address=address)

    def restore_defaults(self, address: int) -> str | None:
        """200FH = 1, as the keypad does it: only while stopped. Keeps the bus address given on the command line."""
        try:
            self.ops.call("restore_defaults", address=address)
        except ops.ControlError as exc:
            return str(exc)
        return None

    def _panel(self, address: int, register: int, value: int) -> dict[str, Any]:
        answer: dict[str, Any] = self.ops.call("keypad_edit", address=address, register=register, value=value)
        return answer

    # --- physical conditions, checked by the operations (ControlError if refused)

    def set_conditions(self, address: int, values: Mapping[str, object]) -> None:
        """Set conditions by their :data:`c20sim.control.ops.CONDITIONS` names; none is set if one is refused."""
        self.ops.call("set_conditions", address=address, values=dict(values))

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

    # --- device faults, as causes

    def overheat_seconds(self, from_c: float | None = None) -> float:
        """Seconds to the overheat trip with the overheat cause on, from ``from_c`` (the profile's ambient)."""
        return causes.overheat_seconds(self.profile, from_c)

    def _switch(self, switch: Switch) -> Switch:
        """A device switch as this profile shows it: with its cause's trip time where the cause has one."""
        cause = causes.CAUSES[cause_of_key()[switch.key]]
        if cause.eta is None or not cause.dashboard:
            return switch
        seconds = cause.eta(self.profile, None)
        when = "never trips" if math.isinf(seconds) else f"trips in about {seconds:.0f} s"
        return replace(switch, how=cause.dashboard.format(when=when))

    def _cause(self, key: str) -> str:
        by_key = cause_of_key()
        if key in by_key:
            return by_key[key]
        if key in self._latched_cause:
            return self._latched_cause[key]
        raise KeyError(key)

    def holding(self, address: int) -> str:
        """What keeps the drive's fault from a reset, in words, with the F4 key that ends it."""
        active = self.ops.causes(address)
        for key, (code, name) in self.forced.items():
            if active.get(self._latched_cause[key]):
                return f"{name} (0x{code:02X}) is held on by F4 key {key}; press {key} to release it, then reset"
        for switch in self.device_switches:
            cause = cause_of_key().get(switch.key, "")
            if active.get(cause):
                return f"its cause, {cause}, is still present; press {switch.key} (F4) to end it"
        return "the fault's cause is still present"

    def device_fault_active(self, address: int, key: str) -> bool:
        """Whether the cause behind switch ``key`` is there now, whoever brought it about."""
        try:
            return self.ops.causes(address)[self._cause(key)]
        except KeyError:
            return False

    def toggle_device_fault(self, address: int, key: str) -> str:
        """Switch a device fault's cause on or off; returns what was done, in words."""
        if key == "z":
            self.ops.call("clear_causes", address=address)
            return f"drive {address}: every fault cause cleared"
        cause = self._cause(key)
        row = causes.CAUSES.get(cause)
        if row is not None and row.cycle is not None:  # a switch that steps a condition (the Hall sensor's faults)
            return self._step(address, row.label, row.cycle)
        if self.device_fault_active(address, key):
            return str(self.ops.call("clear_fault", address=address, cause=cause, reset=False)["note"])
        note = str(self.ops.call("fault", address=address, request={"cause": cause})["note"])
        if row is not None and row.eta is not None:
            seconds = row.eta(self.profile, self.telemetry(address).temperature_c)
            note += " (never trips)" if math.isinf(seconds) else f" (trips in about {seconds:.0f} s)"
        return note

    def _step(self, address: int, label: str, cycle: Cycle) -> str:
        """The next of the cycle's values for its condition; returns it in words."""
        now = self.ops.conditions(address)[cycle.condition]
        values = cycle.values
        value = values[(values.index(now) + 1) % len(values)] if now in values else values[0]
        self.set_conditions(address, {cycle.condition: value})
        return f"drive {address}: {label} {cycle.off if value is None else value}"

    # --- link faults

    def link(self, scope: int | None) -> dict[str, object]:
        """The link faults of one drive, or of the whole bus (None), as the operations show them."""
        return self.ops.link(scope)

    def link_active(self, scope: int | None) -> list[str]:
        """The names of the link faults switched on."""
        return list(self.ops.link(scope)["active"])

    def link_fault_active(self, scope: int | None, key: str) -> bool:
        name = LINK_OF_KEY.get(key)
        return name is not None and name in self.link_active(scope)

    def toggle_link_fault(self, scope: int | None, key: str) -> str:
        """Press a link fault's switch: on, off, or (a count, an exception) the next step; returns it in words."""
        where = "bus" if scope is None else f"drive {scope} link"
        if key == "z":
            self._link_op("clear", scope)
            return f"{where}: every link fault cleared"
        name = LINK_OF_KEY[key]
        knob = KNOBS[name]
        state = self.link(scope)
        now = state[name]
        value: object
        if knob.kind == "count":
            value = int(now) + int(knob.on) if isinstance(now, int) and isinstance(knob.on, int) else knob.on
        elif knob.kind == "exception":
            codes: list[int | None] = [None, *(int(c) for c in ExceptionCode)]
            value = codes[(codes.index(now if isinstance(now, int) else None) + 1) % len(codes)]
        elif name in self.link_active(scope):
            value = None if knob.kind == "address" else {"flag": False, "bytes": ""}.get(knob.kind, 0.0)
        elif knob.kind == "address":
            value = knob.on if scope is None else scope % 247 + 1
        elif knob.kind == "bytes":
            assert isinstance(knob.on, bytes)
            value = knob.on.hex(" ")
        else:
            value = knob.on
        self._link_op("set", scope, values={name: value})
        return f"{where}: {knob.label} {self._words(name, self.link(scope)[name])}"

    def _link_op(self, verb: str, scope: int | None, **arguments: Any) -> None:
        """Set or clear link faults of one drive, or of the bus (None): the route table's link rows."""
        if scope is None:
            self.ops.call(f"{verb}_link", **arguments)
        else:
            self.ops.call(f"{verb}_drive_link", address=scope, **arguments)

    @staticmethod
    def _words(name: str, value: object) -> str:
        if value in (None, False, 0, 0.0, ""):
            return "off"
        if value is True:
            return "on"
        if name == "forced_exception" and isinstance(value, int):
            return f"0x{value:02X} {ExceptionCode(value).meaning}"
        if name in ("delay", "delay_jitter") and isinstance(value, float):
            return f"{value * 1000:.0f} ms"
        if name == "drop_percent" and isinstance(value, float):
            return f"{value:g} %"
        return f"{value}"

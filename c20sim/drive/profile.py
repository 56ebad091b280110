"""Drive profiles: one TOML file per C20 variant, checked once at load.

A profile holds what differs between C20 models and what the sheet leaves
open: the motor and drive parameters of the behavioural model, the fault-code
table, the function-code table, and the protocol quirks. Loading turns it into
frozen dataclasses; a bad profile raises :class:`ProfileError` naming the
file, the key and the allowed range, with a "did you mean" for a misspelt key.
Anything not confirmed by the sheet is marked ``source = "assumed"`` in the
file, so a user with a real drive can correct it.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..wire.errors import ProfileError
from ..wire.registers import (
    FIXED_REGISTERS,
    Access,
    Reg,
    RegisterMap,
    RegisterSpec,
    format_fcode,
    is_fcode,
    parse_fcode,
)
from .files import MAX_DEPTH, FileReadError, read_text, toml_depth, too_deep

__all__ = [
    "DEFAULT_PROFILE",
    "ControlParams",
    "FaultCause",
    "FaultSpec",
    "MotorParams",
    "Profile",
    "ProtectionParams",
    "ProtocolParams",
    "SupplyParams",
    "ThermalParams",
    "available_profiles",
    "load_profile",
    "parse_profile",
    "profile_path",
]

DEFAULT_PROFILE = "c20-400hr"

#: 20xxH registers that must mirror a function code of the profile: they are
#: drive parameters, so their value lives in the (EEPROM) function-code store.
REQUIRED_MIRRORS = (
    Reg.POLE_PAIRS,
    Reg.ACCEL_TIME,
    Reg.DECEL_TIME,
    Reg.CONTROL_MODE,
    Reg.RUN_CHANNEL,
    Reg.SPEED_SOURCE,
    Reg.ADDRESS,
    Reg.BAUD,
)


def _num(minimum: float, maximum: float, unit: str = "", doc: str = "") -> dict[str, Any]:
    return {"min": minimum, "max": maximum, "unit": unit, "doc": doc}


@dataclass(frozen=True)
class ProtocolParams:
    """How this model speaks Modbus where the sheet leaves room."""

    reply_to_bad_crc: bool = field(
        default=True, metadata={"doc": "answer a bad CRC with exception 0x06 (sheet) or stay silent"}
    )
    max_read_registers: int = field(
        default=1, metadata=_num(1, 125, "registers", "most registers one 0x03 may read (sheet: 1)")
    )
    turnaround_ms: float = field(
        default=2.0, metadata=_num(0, 1000, "ms", "delay between a request's end and the reply")
    )
    run_while_faulted_exception: int = field(
        default=1,
        metadata=_num(
            0, 8, "", "exception answering a run or jog command (2000H = 1-4) while faulted; 0 = echo, ignore"
        ),
    )
    byte_count_exception: int = field(
        default=6,
        metadata={
            **_num(3, 6, "", "exception answering a 0x10 whose byte count is not 2 x N: 6 (sheet) or 3 (Modbus)"),
            "choices": (3, 6),
        },
    )
    lacking_feature_exception: int = field(
        default=3,
        metadata=_num(1, 8, "", "exception refusing a setting for a feature this model lacks (simple_plc = false)"),
    )
    simple_plc: bool = field(
        default=False, metadata={"doc": "the model runs a simple PLC program (2007H = 6); false: refused"}
    )
    ram_only_alias: bool = field(
        default=False,
        metadata={
            "doc": "a write at a function code's address | 8000H changes it in RAM only (not saved, lost at "
            "power-off; write-only: reads there get 0x02), as the INVT family does"
        },
    )
    password: int = field(default=0, metadata=_num(0, 65535, "", "user password; 0 = none"))
    password_register: str = field(default="F07.00", metadata={"doc": "function code where the password is written"})
    eeprom_endurance_writes: int = field(
        default=100_000,
        metadata=_num(1000, 10**9, "writes", "writes one function code's EEPROM cell stands (the audit's wear figure)"),
    )
    broadcast_delay_ms: float = field(
        default=100.0,
        metadata=_num(0, 10000, "ms", "time the drive needs after a broadcast before the next request (the audit)"),
    )


@dataclass(frozen=True)
class MotorParams:
    """The brushless motor and its mechanical load."""

    rated_speed_rpm: float = field(metadata=_num(100, 3000, "rpm"))
    rated_current_a: float = field(metadata=_num(0.1, 300, "A"))
    kt_nm_per_a: float = field(
        metadata=_num(0.001, 20, "N m/A", "torque constant; back-EMF constant in V s/rad is equal")
    )
    resistance_ohm: float = field(metadata=_num(0.001, 100, "ohm", "winding resistance, line to line"))
    inertia_kg_m2: float = field(metadata=_num(1e-7, 10, "kg m^2", "rotor plus coupled load"))
    friction_nm: float = field(metadata=_num(0, 100, "N m", "Coulomb friction"))
    viscous_nm_per_krpm: float = field(metadata=_num(0, 100, "N m/krpm"))
    jog_speed_rpm: float = field(metadata=_num(0, 3000, "rpm"))
    active_load_free_rpm: float = field(
        default=3300.0,
        metadata=_num(
            100,
            30000,
            "rpm",
            "an active load's torque falls from full at rated_speed_rpm to zero here (its own drag): "
            "a free rotor it drives settles below it",
        ),
    )


@dataclass(frozen=True)
class SupplyParams:
    """The DC bus and what feeds it."""

    voltage_v: float = field(metadata=_num(5, 800, "V", "nominal DC bus from the supply"))
    source_resistance_ohm: float = field(metadata=_num(0, 100, "ohm"))
    bus_capacitance_uf: float = field(metadata=_num(1, 100000, "uF"))
    undervoltage_v: float = field(metadata=_num(1, 800, "V", "trip level while running; below it stopped = off"))
    overvoltage_v: float = field(metadata=_num(5, 1000, "V"))
    brake_chopper_v: float = field(
        default=0.0,
        metadata=_num(0, 1000, "V", "bus voltage above which the brake resistor is switched in; 0 = no chopper"),
    )
    brake_resistor_ohm: float = field(default=10.0, metadata=_num(0.1, 100000, "ohm", "brake resistor"))
    bleed_time_constant_s: float = field(
        default=2.0, metadata=_num(0.01, 3600, "s", "bus discharge time constant with the supply off")
    )
    undervoltage_recover_v: float = field(
        default=0.0,
        metadata=_num(0, 800, "V", "the bus counts as back only above this (hysteresis); 0 = undervoltage_v"),
    )


@dataclass(frozen=True)
class ProtectionParams:
    """Limits and trips of the drive."""

    current_limit_a: float = field(metadata=_num(0.1, 300, "A"))
    overcurrent_a: float = field(metadata=_num(0.1, 600, "A", "instantaneous trip"))
    drive_rated_current_a: float = field(metadata=_num(0.1, 300, "A"))
    motor_overload_curve: tuple[tuple[float, float], ...] = field(
        metadata={"doc": "[[multiple of rated current, seconds to trip], ...]: the motor's inverse-time curve"}
    )
    drive_overload_curve: tuple[tuple[float, float], ...] = field(
        metadata={"doc": "[[multiple of drive rated current, seconds to trip], ...]: the drive's inverse-time curve"}
    )
    overload_warning: float = field(
        metadata=_num(0.1, 1, "", "fraction of the I^2 t budget that sets status word 2 bit 4")
    )
    stall_time_s: float = field(metadata=_num(0.1, 60, "s"))
    stall_speed_rpm: float = field(metadata=_num(0, 3000, "rpm"))
    overload_cooling_s: float = field(
        default=600.0,
        metadata=_num(1, 36000, "s", "time a full overload budget takes to cool away at zero current"),
    )
    brake_hold_s: float = field(
        default=0.5, metadata=_num(0, 60, "s", "electronic brake (status 6) hold after a ramp stop reaches zero")
    )


@dataclass(frozen=True)
class ThermalParams:
    """The inverter's temperature (300CH)."""

    ambient_c: float = field(metadata=_num(-20, 60, "degC"))
    resistance_k_per_w: float = field(metadata=_num(0.001, 100, "K/W", "heatsink to ambient"))
    time_constant_s: float = field(metadata=_num(1, 100000, "s"))
    conduction_resistance_ohm: float = field(
        metadata=_num(0, 100, "ohm", "inverter conduction loss: this times the current squared")
    )
    switching_loss_w_per_a: float = field(metadata=_num(0, 1000, "W/A", "inverter switching loss per amp of current"))
    overheat_c: float = field(metadata=_num(40, 150, "degC"))
    overheat_reset_k: float = field(
        default=5.0, metadata=_num(0, 50, "K", "an overheat fault resets only this far below overheat_c")
    )


@dataclass(frozen=True)
class ControlParams:
    """The drive's speed loop and speed measurement."""

    speed_loop_hz: float = field(
        default=20.0, metadata=_num(0.1, 1000, "Hz", "speed loop bandwidth, tuned on the coupled inertia")
    )
    min_speed_rpm: float = field(default=0.0, metadata=_num(0, 3000, "rpm", "a set speed below it runs at it"))
    speed_noise_rpm: float = field(
        default=0.0, metadata=_num(0, 1000, "rpm", "read noise on 3006H while turning (uniform +-); 0 = none")
    )
    noise_seed: int = field(default=0, metadata=_num(0, 2**31 - 1, "", "seed of the read noise"))


class FaultCause(enum.Enum):
    """What the model can trip on; the profile maps each to a wire code."""

    POWER_STAGE_U = "power_stage_u"
    POWER_STAGE_V = "power_stage_v"
    POWER_STAGE_W = "power_stage_w"
    OVERCURRENT_ACCEL = "overcurrent_accel"
    OVERCURRENT_DECEL = "overcurrent_decel"
    OVERCURRENT_CONSTANT = "overcurrent_constant"
    OVERVOLTAGE_ACCEL = "overvoltage_accel"
    OVERVOLTAGE_DECEL = "overvoltage_decel"
    OVERVOLTAGE_CONSTANT = "overvoltage_constant"
    UNDERVOLTAGE = "undervoltage"
    MOTOR_OVERLOAD = "motor_overload"
    DRIVE_OVERLOAD = "drive_overload"
    OUTPUT_PHASE_LOSS = "output_phase_loss"
    OVERHEAT = "overheat"
    EXTERNAL = "external"
    COMMUNICATION = "communication"
    CURRENT_DETECTION = "current_detection"
    EEPROM = "eeprom"
    HALL = "hall"
    STALL = "stall"


@dataclass(frozen=True)
class FaultSpec:
    code: int
    name: str
    meaning: str
    cause: FaultCause | None
    source: str


@dataclass(frozen=True)
class Profile:
    """One C20 variant, validated."""

    name: str
    description: str
    path: str
    software_version: int  #: 300AH raw value, 0.01 units (100 = 1.00)
    protocol: ProtocolParams
    motor: MotorParams
    supply: SupplyParams
    protection: ProtectionParams
    thermal: ThermalParams
    control: ControlParams
    faults: Mapping[int, FaultSpec]
    parameters: tuple[RegisterSpec, ...]
    mirrors: Mapping[int, int]  #: 20xxH register -> function code address
    defaults: Mapping[int, int]  #: function code address -> default raw value
    registers: RegisterMap = field(repr=False, compare=False)
    #: named behaviours (entry-point group c20sim.behaviours) hooking this model's registers or step
    behaviours: tuple[str, ...] = ()

    def fault_code(self, cause: FaultCause) -> int:
        """The wire code of a fault cause (raises KeyError if the profile has none)."""
        for spec in self.faults.values():
            if spec.cause is cause:
                return spec.code
        raise KeyError(cause)

    def fault_name(self, code: int) -> str:
        spec = self.faults.get(code)
        return f"{spec.name}: {spec.meaning}" if spec else f"fault 0x{code:02X} (not in the profile's table)"

    @property
    def password_address(self) -> int:
        return parse_fcode(self.protocol.password_register)

    def default(self, address: int) -> int:
        """Default raw value of a function code or of the 20xxH register mirroring one."""
        return self.defaults[self.registers.canonical(address)]


# --- Locating profiles.


def _profile_dirs() -> list[Path]:
    package = Path(__file__).resolve().parent.parent
    # Inside the wheel the profiles are package data; in a checkout they sit beside the package.
    return [d for d in (package / "profiles", package.parent / "profiles") if d.is_dir()]


def available_profiles() -> dict[str, Path]:
    """Shipped profiles by name."""
    found: dict[str, Path] = {}
    for directory in _profile_dirs():
        for path in sorted(directory.glob("*.toml")):
            found.setdefault(path.stem, path)
    return found


def profile_path(name_or_path: str) -> Path:
    """The file of a shipped profile name, or the path given."""
    shipped = available_profiles()
    if name_or_path in shipped:
        return shipped[name_or_path]
    path = Path(name_or_path)
    if path.suffix == ".toml" or path.exists() or "/" in name_or_path:
        return path
    hint = _did_you_mean(name_or_path, shipped)
    raise ProfileError(name_or_path, "", f"no such profile; shipped profiles: {', '.join(shipped)}{hint}")


def load_profile(name_or_path: str = DEFAULT_PROFILE) -> Profile:
    """Load and check a profile by shipped name or by path."""
    path = profile_path(name_or_path)
    try:
        text = read_text(path, "profile", named="TOML profile")
    except FileReadError as exc:
        raise ProfileError(str(path), "", "file not found" if exc.missing else exc.reason) from None
    return parse_profile(text, str(path))


# --- Checking.


def _did_you_mean(word: str, choices: Any) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


class _Checker:
    def __init__(self, path: str) -> None:
        self.path = path

    def fail(self, key: str, message: str) -> ProfileError:
        return ProfileError(self.path, key, message)

    def table(self, data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
        value = data.get(key)
        if not isinstance(value, dict):
            raise self.fail(key, "missing table" if value is None else f"must be a table, not {type(value).__name__}")
        return value

    def unknown_keys(self, data: Mapping[str, Any], allowed: Any, prefix: str) -> None:
        for key in data:
            if key not in allowed:
                raise self.fail(
                    f"{prefix}{key}", f"unknown key{_did_you_mean(key, allowed)}; allowed: {', '.join(allowed)}"
                )

    def number(
        self, value: Any, key: str, kind: type, minimum: float | None, maximum: float | None, unit: str = ""
    ) -> Any:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"must be a number, not {value!r}")
        if kind is int and not isinstance(value, int):
            raise self.fail(key, f"must be a whole number, not {value!r}")
        if not math.isfinite(value):
            bounds = f"; allowed {minimum:g} to {maximum:g}" if minimum is not None and maximum is not None else ""
            raise self.fail(key, f"must be a finite number, not {value}{bounds}{' ' + unit if unit and bounds else ''}")
        if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
            raise self.fail(
                key, f"{value} is out of range; allowed {minimum:g} to {maximum:g}{' ' + unit if unit else ''}"
            )
        return kind(value)

    def curve(self, value: Any, key: str) -> tuple[tuple[float, float], ...]:
        """An inverse-time curve: [[multiple, seconds], ...], multiples above 1 rising, times falling."""
        shape = "[[multiple of rated current, seconds], ...]"
        if not isinstance(value, list) or not value:
            raise self.fail(key, f"must be a non-empty array {shape}")
        points: list[tuple[float, float]] = []
        for i, pair in enumerate(value):
            if not isinstance(pair, list) or len(pair) != 2:
                raise self.fail(f"{key}[{i}]", f"must be a pair [multiple, seconds], not {pair!r}")
            multiple = self.number(pair[0], f"{key}[{i}][0]", float, 1.01, 20.0, "x rated")
            seconds = self.number(pair[1], f"{key}[{i}][1]", float, 0.01, 36000.0, "s")
            if multiple != multiple or seconds != seconds:  # NaN passes every comparison
                raise self.fail(f"{key}[{i}]", "must be finite numbers, not nan")
            if points and (multiple <= points[-1][0] or seconds >= points[-1][1]):
                raise self.fail(f"{key}[{i}]", "multiples must rise and times fall from one point to the next")
            points.append((multiple, seconds))
        return tuple(points)

    def section(self, data: Mapping[str, Any], name: str, cls: type) -> Any:
        table = self.table(data, name) if name in data or _required(cls) else {}
        fields = {f.name: f for f in dataclasses.fields(cls)}
        self.unknown_keys(table, fields, f"{name}.")
        values: dict[str, Any] = {}
        for fname, f in fields.items():
            key = f"{name}.{fname}"
            if fname not in table:
                if f.default is dataclasses.MISSING:
                    raise self.fail(key, f"missing; {_describe_field(f)}")
                continue
            value = table[fname]
            if f.type == "tuple[tuple[float, float], ...]":
                values[fname] = self.curve(value, key)
                continue
            kind = (
                bool
                if f.type in ("bool", bool)
                else int
                if f.type in ("int", int)
                else float
                if f.type in ("float", float)
                else str
            )
            if kind is bool:
                if not isinstance(value, bool):
                    raise self.fail(key, f"must be true or false, not {value!r}")
            elif kind is str:
                if not isinstance(value, str):
                    raise self.fail(key, f"must be a string, not {value!r}")
            else:
                meta = f.metadata
                value = self.number(value, key, kind, meta.get("min"), meta.get("max"), meta.get("unit", ""))
                if "choices" in meta and value not in meta["choices"]:
                    raise self.fail(key, f"{value} is not allowed; allowed: {', '.join(map(str, meta['choices']))}")
            values[fname] = value
        return cls(**values)


def _required(cls: type) -> bool:
    return any(f.default is dataclasses.MISSING for f in dataclasses.fields(cls))


def _describe_field(f: dataclasses.Field[Any]) -> str:
    meta = f.metadata
    parts = []
    if "min" in meta:
        parts.append(f"allowed {meta['min']:g} to {meta['max']:g}{' ' + meta['unit'] if meta.get('unit') else ''}")
    if meta.get("doc"):
        parts.append(meta["doc"])
    return "; ".join(parts) or "required"


_TOP_KEYS = (
    "name",
    "description",
    "software_version",
    "protocol",
    "motor",
    "supply",
    "protection",
    "thermal",
    "control",
    "fault",
    "parameter",
    "behaviours",
)
_FAULT_KEYS = ("code", "name", "meaning", "cause", "source")
_PARAM_KEYS = (
    "code",
    "name",
    "default",
    "min",
    "max",
    "unit",
    "scale",
    "access",
    "mirror",
    "signed",
    "values",
    "source",
)
_SOURCES = ("sheet", "notes", "field", "assumed")


def parse_profile(text: str, path: str = "<profile>") -> Profile:
    """Check a profile's TOML text; ``path`` names it in errors."""
    check = _Checker(path)
    if toml_depth(text) > MAX_DEPTH:
        raise check.fail("", too_deep(path, "profile").reason)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise check.fail("", f"not valid TOML: {exc}") from None
    check.unknown_keys(data, _TOP_KEYS, "")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise check.fail("name", "missing or empty; the profile's name, such as 'c20-400hr'")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise check.fail("description", "must be a string")
    version = check.number(data.get("software_version", 1.0), "software_version", float, 1.0, 99.0)

    protocol = check.section(data, "protocol", ProtocolParams)
    try:
        password_address = parse_fcode(protocol.password_register)
    except ValueError as exc:
        raise check.fail("protocol.password_register", str(exc)) from None
    motor = check.section(data, "motor", MotorParams)
    supply = check.section(data, "supply", SupplyParams)
    protection = check.section(data, "protection", ProtectionParams)
    thermal = check.section(data, "thermal", ThermalParams)
    control = check.section(data, "control", ControlParams)
    if supply.undervoltage_v >= supply.voltage_v:
        raise check.fail(
            "supply.undervoltage_v",
            f"{supply.undervoltage_v:g} V must be below supply.voltage_v = {supply.voltage_v:g} V",
        )
    if supply.undervoltage_recover_v and not supply.undervoltage_v < supply.undervoltage_recover_v < supply.voltage_v:
        raise check.fail(
            "supply.undervoltage_recover_v",
            f"{supply.undervoltage_recover_v:g} V must be between supply.undervoltage_v = {supply.undervoltage_v:g} V "
            f"and supply.voltage_v = {supply.voltage_v:g} V",
        )
    if motor.active_load_free_rpm <= motor.rated_speed_rpm:
        raise check.fail(
            "motor.active_load_free_rpm",
            f"{motor.active_load_free_rpm:g} rpm must be above motor.rated_speed_rpm = {motor.rated_speed_rpm:g} rpm",
        )
    if supply.overvoltage_v <= supply.voltage_v:
        raise check.fail(
            "supply.overvoltage_v",
            f"{supply.overvoltage_v:g} V must be above supply.voltage_v = {supply.voltage_v:g} V",
        )

    faults = _parse_faults(check, data.get("fault"))
    parameters, defaults, mirrors = _parse_parameters(check, data.get("parameter"))
    if protocol.password and password_address in {p.address for p in parameters}:
        raise check.fail(
            "protocol.password_register", f"{protocol.password_register} is also a parameter; it must be a free address"
        )
    for register in REQUIRED_MIRRORS:
        if register not in mirrors:
            raise check.fail(
                "parameter",
                f'no function code mirrors {register:04X}H ({register.name.lower()}); add one with mirror = "{register:04X}H"',
            )
    registers = RegisterMap(parameters, mirrors)
    behaviours = data.get("behaviours", [])
    if not isinstance(behaviours, list) or not all(isinstance(b, str) and b for b in behaviours):
        raise check.fail("behaviours", 'must be a list of behaviour names, such as ["slow-eeprom"]')
    if len(set(behaviours)) != len(behaviours):
        raise check.fail("behaviours", "a behaviour is listed twice")
    return Profile(
        name=name,
        description=description,
        path=path,
        software_version=round(version * 100),
        protocol=protocol,
        motor=motor,
        supply=supply,
        protection=protection,
        thermal=thermal,
        control=control,
        faults=faults,
        parameters=tuple(parameters),
        mirrors=mirrors,
        defaults=defaults,
        registers=registers,
        behaviours=tuple(behaviours),
    )


def _parse_faults(check: _Checker, raw: Any) -> dict[int, FaultSpec]:
    if not isinstance(raw, list) or not raw:
        raise check.fail("fault", "missing; an array of [[fault]] tables with code, name, meaning")
    faults: dict[int, FaultSpec] = {}
    causes: dict[FaultCause, int] = {}
    cause_names = [c.value for c in FaultCause]
    for i, entry in enumerate(raw):
        where = f"fault[{i}]"
        if not isinstance(entry, dict):
            raise check.fail(where, "must be a table")
        check.unknown_keys(entry, _FAULT_KEYS, f"{where}.")
        code = check.number(entry.get("code"), f"{where}.code", int, 1, 255)
        if code in faults:
            raise check.fail(f"{where}.code", f"code {code} is listed twice")
        fname = entry.get("name")
        if not isinstance(fname, str) or not fname:
            raise check.fail(f"{where}.name", "missing; a short name such as 'UV'")
        cause: FaultCause | None = None
        if "cause" in entry:
            text = entry["cause"]
            if text not in cause_names:
                raise check.fail(
                    f"{where}.cause",
                    f"unknown cause {text!r}{_did_you_mean(str(text), cause_names)}; allowed: {', '.join(cause_names)}",
                )
            cause = FaultCause(text)
            if cause in causes:
                raise check.fail(f"{where}.cause", f"cause {text!r} already has code {causes[cause]}")
            causes[cause] = code
        source = entry.get("source", "assumed")
        if source not in _SOURCES:
            raise check.fail(
                f"{where}.source", f"must be one of {', '.join(_SOURCES)}{_did_you_mean(str(source), _SOURCES)}"
            )
        faults[code] = FaultSpec(code, fname, str(entry.get("meaning", "")), cause, source)
    return faults


def _parse_parameters(check: _Checker, raw: Any) -> tuple[list[RegisterSpec], dict[int, int], dict[int, int]]:
    if not isinstance(raw, list) or not raw:
        raise check.fail("parameter", "missing; an array of [[parameter]] tables (the function-code table)")
    specs: list[RegisterSpec] = []
    defaults: dict[int, int] = {}
    mirrors: dict[int, int] = {}
    accesses = [a.value for a in Access]
    for i, entry in enumerate(raw):
        if not isinstance(entry, dict):
            raise check.fail(f"parameter[{i}]", "must be a table")
        code_text = entry.get("code")
        where = f"parameter[{i}]" if not isinstance(code_text, str) else f"parameter {code_text}"
        check.unknown_keys(entry, _PARAM_KEYS, f"{where}: ")
        try:
            address = parse_fcode(str(code_text))
        except ValueError as exc:
            raise check.fail(f"{where}.code", str(exc)) from None
        if address in defaults:
            raise check.fail(f"{where}.code", f"{format_fcode(address)} is listed twice")
        pname = entry.get("name")
        if not isinstance(pname, str) or not pname:
            raise check.fail(f"{where}.name", "missing; what the parameter is")
        signed = entry.get("signed", False)
        if not isinstance(signed, bool):
            raise check.fail(f"{where}.signed", "must be true or false")
        low, high = (-32768, 32767) if signed else (0, 65535)
        minimum = check.number(entry.get("min", low), f"{where}.min", int, low, high)
        maximum = check.number(entry.get("max", high), f"{where}.max", int, minimum, high)
        if "default" not in entry:
            raise check.fail(f"{where}.default", f"missing; allowed {minimum} to {maximum}")
        default = check.number(entry["default"], f"{where}.default", int, minimum, maximum)
        scale = check.number(entry.get("scale", 1), f"{where}.scale", float, 1e-6, 1e6)
        unit = entry.get("unit", "")
        if not isinstance(unit, str):
            raise check.fail(f"{where}.unit", "must be a string")
        access_text = entry.get("access", "W/R")
        if access_text not in accesses:
            raise check.fail(f"{where}.access", f"must be one of {', '.join(accesses)}, not {access_text!r}")
        values_raw = entry.get("values", {})
        if not isinstance(values_raw, dict) or not all(
            k.isdigit() and isinstance(v, str) for k, v in values_raw.items()
        ):
            raise check.fail(f"{where}.values", 'must be a table of "number" = "meaning"')
        source = entry.get("source", "assumed")
        if source not in _SOURCES:
            raise check.fail(
                f"{where}.source", f"must be one of {', '.join(_SOURCES)}{_did_you_mean(str(source), _SOURCES)}"
            )
        if "mirror" in entry:
            mirror_text = entry["mirror"]
            register = _parse_register(mirror_text)
            if register is None or register not in REQUIRED_MIRRORS:
                allowed = ", ".join(f"{r:04X}H" for r in REQUIRED_MIRRORS)
                raise check.fail(
                    f"{where}.mirror", f"{mirror_text!r} cannot mirror a function code; allowed: {allowed}"
                )
            if register in mirrors:
                raise check.fail(
                    f"{where}.mirror", f"{register:04X}H already mirrors {format_fcode(mirrors[register])}"
                )
            fixed = FIXED_REGISTERS[register]
            if fixed.access is Access.RW_STOPPED and access_text != Access.RW_STOPPED.value:
                raise check.fail(f"{where}.access", f"must be W/R* like the register it mirrors, {register:04X}H")
            if minimum < fixed.minimum or maximum > fixed.maximum:
                raise check.fail(
                    f"{where}.max" if maximum > fixed.maximum else f"{where}.min",
                    f"{minimum}-{maximum} goes beyond {register:04X}H's range in the sheet, "
                    f"{fixed.minimum}-{fixed.maximum}",
                )
            mirrors[register] = address
        specs.append(
            RegisterSpec(
                address,
                pname,
                Access(access_text),
                minimum,
                maximum,
                unit,
                scale,
                signed,
                {int(k): v for k, v in values_raw.items()},
                source=source,
            )
        )
        defaults[address] = default & 0xFFFF
    assert all(is_fcode(s.address) for s in specs)
    return specs, defaults, mirrors


def _parse_register(text: Any) -> int | None:
    if not isinstance(text, str):
        return None
    body = text.strip().upper().removesuffix("H").removeprefix("0X")
    try:
        return int(body, 16)
    except ValueError:
        return None

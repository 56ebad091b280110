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

import tomllib
from pathlib import Path

from ..wire.errors import ProfileError
from ..wire.registers import Reg, RegisterMap, parse_fcode
from .files import MAX_DEPTH, FileReadError, read_text, toml_depth, too_deep
from .profilecheck import _FAULT_KEYS as _FAULT_KEYS  # the scenario's schema builds from these
from .profilecheck import _PARAM_KEYS as _PARAM_KEYS
from .profilecheck import _SOURCES as _SOURCES
from .profilecheck import _TOP_KEYS as _TOP_KEYS
from .profilecheck import _Checker, _did_you_mean, _parse_faults, _parse_parameters, own_sections, parse_levels
from .profiletypes import (
    DEFAULT_PROFILE,
    REQUIRED_MIRRORS,
    ControlParams,
    FaultCause,
    FaultSpec,
    MotorParams,
    Profile,
    ProtectionParams,
    ProtocolParams,
    SupplyParams,
    ThermalParams,
)

__all__ = [
    "DEFAULT_PROFILE",
    "REQUIRED_MIRRORS",
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


def parse_profile(text: str, path: str = "<profile>") -> Profile:
    """Check a profile's TOML text; ``path`` names it in errors."""
    check = _Checker(path)
    if toml_depth(text) > MAX_DEPTH:
        raise check.fail("", too_deep(path, "profile").reason)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise check.fail("", f"not valid TOML: {exc}") from None
    check.unknown_keys(data, [*_TOP_KEYS, *own_sections()], "")
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
    _check_levels(check, motor, supply)
    levels = parse_levels(check, data)  # the cause rows' own keys
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
    fault_words = {
        0: "no fault",
        **{code: f"{f.name}: {f.meaning}" if f.meaning else f.name for code, f in faults.items()},  # as fault_name
    }
    registers = RegisterMap(parameters, mirrors, {Reg.FAULT_CODE: fault_words, Reg.CURRENT_FAULT: fault_words})
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
        levels=levels,
    )


def _check_levels(check: _Checker, motor: MotorParams, supply: SupplyParams) -> None:
    """The levels that must keep their order across keys: the bus's trip levels about the supply, the active
    load's free speed above the rated one."""
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

"""What a drive profile holds, as frozen dataclasses: its sections, its fault table, the profile itself.

:mod:`c20sim.drive.profile` loads and checks them (with :mod:`c20sim.drive.profilecheck`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ..wire.registers import Reg, RegisterMap, RegisterSpec, parse_fcode
from .trips import FaultCause  # what the model can trip on: one per row of the causes' table

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
    #: the cause rows' own keys (:class:`c20sim.drive.trips.Level`), by ``section.name``: the profile's value or the
    #: row's default
    levels: Mapping[str, bool | int | float] = field(default_factory=dict)

    def level(self, key: str) -> bool | int | float:
        """A cause row's profile key (``"protection.condensation_rh_pct"``): the profile's value or its default;
        KeyError if no row declares it (or it was declared after this profile was parsed)."""
        return self.levels[key]

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

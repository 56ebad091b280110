"""c20sim: a virtual ZBLD.C20 brushless DC drive behind a Modbus RTU slave."""

from .errors import C20SimError, ModbusError, ProfileError
from .profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile
from .protocol import ExceptionCode, FunctionCode, RtuFramer, crc16
from .registers import Access, Reg, RegisterMap

__all__ = [
    "DEFAULT_PROFILE",
    "Access",
    "C20SimError",
    "ExceptionCode",
    "FunctionCode",
    "ModbusError",
    "Profile",
    "ProfileError",
    "Reg",
    "RegisterMap",
    "RtuFramer",
    "available_profiles",
    "crc16",
    "load_profile",
]

__version__ = "0.1.0"

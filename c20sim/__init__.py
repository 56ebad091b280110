"""c20sim: a virtual ZBLD.C20 brushless DC drive behind a Modbus RTU slave."""

from .bus import Bus, FrameRecord
from .clock import RealtimeClock, VirtualClock
from .drive.model import Drive, HallFault, Telemetry
from .drive.params import StateFileError
from .errors import C20SimError, ModbusError, ProfileError
from .linkfaults import LinkFaults
from .profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile
from .protocol import ExceptionCode, FunctionCode, RtuFramer, crc16
from .registers import Access, Reg, RegisterMap
from .simulator import Simulator
from .slave import Slave

__all__ = [
    "DEFAULT_PROFILE",
    "Access",
    "Bus",
    "C20SimError",
    "Drive",
    "ExceptionCode",
    "FrameRecord",
    "FunctionCode",
    "HallFault",
    "LinkFaults",
    "ModbusError",
    "Profile",
    "ProfileError",
    "RealtimeClock",
    "Reg",
    "RegisterMap",
    "RtuFramer",
    "Simulator",
    "Slave",
    "StateFileError",
    "Telemetry",
    "VirtualClock",
    "available_profiles",
    "crc16",
    "load_profile",
]

__version__ = "0.1.0"

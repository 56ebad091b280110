"""c20sim: a virtual ZBLD.C20 brushless DC drive behind a Modbus RTU slave."""

from . import _compiled  # noqa: F401 (first: it says so if a compiled module is older than its source)
from .core.bus import Bus, FrameRecord
from .core.clock import RealtimeClock, VirtualClock
from .core.linkfaults import LinkFaults
from .core.simulator import Simulator
from .core.slave import Slave
from .drive.model import Drive, HallFault, Telemetry
from .drive.params import StateFileError
from .drive.profile import DEFAULT_PROFILE, Profile, available_profiles, load_profile
from .wire.errors import C20SimError, ModbusError, ProfileError
from .wire.framing import RtuFramer
from .wire.protocol import ExceptionCode, FunctionCode, crc16
from .wire.registers import Access, Reg, RegisterMap

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

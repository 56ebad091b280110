"""Exceptions of c20sim.

Every error the package raises on purpose derives from :class:`C20SimError`.
:class:`ModbusError` carries the wire exception code the drive answers with:
raised anywhere under the slave, it becomes that exception reply. Any other
exception there is a bug, logged with its traceback, never swallowed.
"""

from __future__ import annotations

from .protocol import ExceptionCode

__all__ = ["C20SimError", "ModbusError", "ProfileError"]


class C20SimError(Exception):
    """Base class of every error c20sim raises deliberately."""


class ModbusError(C20SimError):
    """A request the drive refuses with an exception reply."""

    def __init__(self, code: ExceptionCode, reason: str = "") -> None:
        self.code = ExceptionCode(code)
        self.reason = reason
        super().__init__(f"{self.code.name} (0x{int(self.code):02X}){': ' + reason if reason else ''}")


class ProfileError(C20SimError):
    """A profile that cannot be loaded: names the file, the key and what is allowed."""

    def __init__(self, path: str, key: str, message: str) -> None:
        self.path = path
        self.key = key
        self.message = message
        where = f"{path}: {key}" if key else path
        super().__init__(f"{where}: {message}")

"""Function-code storage: the drive's EEPROM, as values keyed by address.

Holds every function code of the profile at its default, and answers for the
20xxH registers that mirror one. Restoring defaults (200FH) is done here.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..profile import Profile

__all__ = ["ParameterStore"]


class ParameterStore:
    """The function-code values of one drive."""

    def __init__(self, profile: Profile) -> None:
        self.profile = profile
        self._values: dict[int, int] = dict(profile.defaults)

    def __contains__(self, address: object) -> bool:
        return address in self._values

    def get(self, address: int) -> int:
        """Value of a function code, or of the 20xxH register mirroring one."""
        return self._values[self.profile.registers.canonical(address)]

    def set(self, address: int, value: int) -> None:
        self._values[self.profile.registers.canonical(address)] = value & 0xFFFF

    def restore_defaults(self) -> None:
        self._values = dict(self.profile.defaults)

    def snapshot(self) -> dict[int, int]:
        """A copy of every value, by function-code address."""
        return dict(self._values)

    def load(self, values: Mapping[int, int]) -> None:
        """Take stored values for the function codes this profile knows."""
        for address, value in values.items():
            if address in self._values:
                self._values[address] = value & 0xFFFF

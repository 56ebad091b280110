"""Function-code storage: the drive's EEPROM, as values keyed by address.

Holds every function code of the profile at its default, and answers for the
20xxH registers that mirror one. Restoring defaults (200FH) is done here.

Two layers, as in the drive: the EEPROM (what :meth:`ParameterStore.set`
writes, what the state file holds) and RAM (what the drive works from). A
write to a function code's RAM-only address changes RAM only
(:meth:`ParameterStore.set_ram`): it acts at once, is never saved, and is
gone at the next power-up (:meth:`ParameterStore.power_up`).

With a state file the store is an EEPROM: every change is on disk before
:meth:`ParameterStore.set` returns, written atomically (a temporary file in
the same directory, fsync, ``os.replace``, fsync of the directory), so a kill
at any moment leaves the old file or the new one, never a broken one. A file
that cannot be read or makes no sense raises :class:`StateFileError` naming
it; nothing is silently reset.

Save first, apply after: a change is written to the file before it takes
effect, so a write the disk refuses (read-only directory, full disk) leaves
the old value both in RAM and on disk, and the master is answered 0x04
(operation failed) instead of an acknowledgement that a restart would undo.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from collections.abc import Iterable, Mapping
from glob import escape as glob_escape
from pathlib import Path
from typing import Any

from ..wire.errors import C20SimError, ModbusError
from ..wire.protocol import ExceptionCode
from ..wire.registers import format_fcode, parse_fcode
from .files import MAX_DEPTH, FileReadError, json_depth, read_bytes
from .profile import Profile

__all__ = ["STATE_FORMAT", "ParameterStore", "StateFileError"]

#: Marks a c20sim state file; bumped if the layout changes.
STATE_FORMAT = "c20sim-eeprom/1"

log = logging.getLogger(__name__)


class StateFileError(C20SimError):
    """A state file that cannot be read, written or understood: names the file."""

    def __init__(self, path: str | Path, message: str) -> None:
        self.path = str(path)
        self.message = message
        super().__init__(f"{self.path}: {message}")


class ParameterStore:
    """The function-code values of one drive, optionally persisted to ``path``."""

    def __init__(self, profile: Profile, path: str | Path | None = None) -> None:
        self.profile = profile
        self.path = Path(path) if path is not None else None
        #: the EEPROM: what is saved
        self._stored: dict[int, int] = dict(profile.defaults)
        if self.path is not None:
            self._remove_stale_temporaries()
            if self.path.exists():
                self._stored.update(self._read(self.path))
            else:
                self.save()
        #: RAM: what the drive works from (the EEPROM's values, and RAM-only writes since power-up)
        self._values: dict[int, int] = dict(self._stored)

    def __contains__(self, address: object) -> bool:
        return address in self._values

    def get(self, address: int) -> int:
        """Value of a function code, or of the 20xxH register mirroring one."""
        value = self._values.get(address)  # a function code's own address: the common, cheap case
        return value if value is not None else self._values[self.profile.registers.canonical(address)]

    def set(self, address: int, value: int) -> None:
        """Store a value in EEPROM and RAM (persisted before returning when there is a state file)."""
        cell = self.profile.registers.canonical(address)
        value &= 0xFFFF
        if self._stored.get(cell) != value:
            self._commit({**self._stored, cell: value})
        self._values[cell] = value

    def set_ram(self, address: int, value: int) -> None:
        """Change a value in RAM only: it acts at once, is never saved, and goes at the next power-up."""
        self._values[self.profile.registers.canonical(address)] = value & 0xFFFF

    def power_up(self) -> None:
        """RAM takes the EEPROM's values again: RAM-only writes are lost."""
        self._values = dict(self._stored)

    def restore_defaults(self, keep: Iterable[int] = ()) -> None:
        """Every function code back to its default but those in ``keep`` (a record the drive keeps)."""
        values = dict(self.profile.defaults)
        values.update({a: self._stored[a] for a in keep if a in self._stored})
        self._commit(values)
        self._values = dict(self._stored)

    def record(self, values: Mapping[int, int]) -> bool:
        """The drive's own write of several cells (its fault record) in one EEPROM save, and in RAM.

        A save the disk refuses keeps the values in RAM (the drive goes on; a power cycle loses them) and
        is logged; False then.
        """
        self._values.update(values)
        try:
            self._commit({**self._stored, **values})
        except ModbusError:
            return False
        return True

    def snapshot(self) -> dict[int, int]:
        """A copy of every value in effect (RAM), by function-code address."""
        return dict(self._values)

    def stored(self) -> dict[int, int]:
        """A copy of every value in EEPROM (what the state file holds), by function-code address."""
        return dict(self._stored)

    def load(self, values: Mapping[int, int]) -> None:
        """Take stored values for the function codes this profile knows."""
        new = dict(self._stored)
        for address, value in values.items():
            if address in new:
                new[address] = value & 0xFFFF
        self._write(new)
        self._stored = new
        self._values = dict(new)

    # --- The state file.

    def _remove_stale_temporaries(self) -> None:
        """Delete the temporary files a kill mid-write left beside the state file (one process per file)."""
        assert self.path is not None
        for stale in self.path.parent.glob(f".{glob_escape(self.path.name)}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()

    def _commit(self, values: dict[int, int]) -> None:
        """Save ``values``, then make them the drive's; a failed save keeps the old ones and refuses with 0x04."""
        try:
            self._write(values)
        except StateFileError as exc:
            log.error("parameter write refused (0x04): the EEPROM save failed: %s; the old values are kept", exc)
            raise ModbusError(ExceptionCode.OPERATION_FAILED, f"EEPROM save failed: {exc.message}") from None
        self._stored = values

    def save(self) -> None:
        """Write the state file atomically (no-op without one)."""
        self._write(self._stored)

    def _write(self, values: dict[int, int]) -> None:
        if self.path is None:
            return
        document = {
            "format": STATE_FORMAT,
            "profile": self.profile.name,
            "parameters": {format_fcode(a): v for a, v in sorted(values.items())},
        }
        data = (json.dumps(document, indent=1) + "\n").encode()
        directory = self.path.parent
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=directory)
        except OSError as exc:
            raise StateFileError(self.path, f"cannot write: {exc.strerror}") from None
        try:
            with os.fdopen(fd, "wb") as handle:
                handle.write(data)
                handle.flush()
                os.fsync(handle.fileno())
            os.replace(tmp, self.path)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise StateFileError(self.path, f"cannot write: {exc.strerror}") from None
        _fsync_directory(directory)

    def _read(self, path: Path) -> dict[int, int]:
        try:
            text = read_bytes(path, "state file").decode("utf-8")
        except FileReadError as exc:
            raise StateFileError(path, exc.reason) from None
        except UnicodeDecodeError:
            raise StateFileError(path, "not a c20sim state file (not UTF-8 text)") from None
        if json_depth(text) > MAX_DEPTH:
            raise StateFileError(path, "not a c20sim state file (JSON nested too deeply)")
        try:
            document: Any = json.loads(text)
        except json.JSONDecodeError as exc:
            raise StateFileError(path, f"corrupt state file (not valid JSON: {exc.msg}, line {exc.lineno})") from None
        except RecursionError:
            raise StateFileError(path, "not a c20sim state file (JSON nested too deeply)") from None
        if not isinstance(document, dict) or document.get("format") != STATE_FORMAT:
            raise StateFileError(path, f"not a c20sim state file (expected format {STATE_FORMAT!r})")
        if document.get("profile") != self.profile.name:
            raise StateFileError(
                path,
                f"written for profile {document.get('profile')!r}, not {self.profile.name!r}; "
                "use another state file or delete this one",
            )
        raw = document.get("parameters")
        if not isinstance(raw, dict):
            raise StateFileError(path, "corrupt state file: 'parameters' must be a table")
        values: dict[int, int] = {}
        for code, value in raw.items():
            try:
                address = parse_fcode(code)
            except ValueError as exc:
                raise StateFileError(path, f"corrupt state file: {exc}") from None
            spec = self.profile.registers.get(address)
            if spec is None:
                continue  # a function code this profile does not have: ignore, as a newer EEPROM layout would
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
                raise StateFileError(path, f"corrupt state file: {code} = {value!r} is not a 16-bit value")
            if not spec.accepts(value):
                raise StateFileError(
                    path, f"{code} = {value} is out of range; allowed {spec.minimum} to {spec.maximum}"
                )
            values[address] = value
        return values


def _fsync_directory(directory: Path) -> None:
    """Make the rename itself durable (not possible on every platform: best effort)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)

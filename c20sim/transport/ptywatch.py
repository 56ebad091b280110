"""Who has the pty open: counted with inotify, so that what a closed master left behind can be dropped.

The simulator keeps the pty's slave side open itself (a master may then
close and reopen the device freely), so it never sees a master go. A real
port loses what arrives while nobody has it open; a pty keeps it, and the
next program that opens it (libmodbus and mbpoll do not flush on open) reads
the previous program's replies as its own. Linux reports every open and
close of the device node through inotify: :class:`PtyOpeners` counts them,
and calls back when the last opener has closed (with the number open by
then: another master may have opened the device already). Where inotify is missing the
count is unknown (None) and nothing is dropped.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import logging
import os
import struct
from collections.abc import Callable

__all__ = ["PtyOpeners"]

log = logging.getLogger(__name__)

IN_CLOSE_WRITE = 0x00000008
IN_CLOSE_NOWRITE = 0x00000010
IN_OPEN = 0x00000020
IN_Q_OVERFLOW = 0x00004000
_EVENT = struct.Struct("iIII")


def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    except OSError:
        return None


class PtyOpeners:
    """Counts the programs that have the device at ``path`` open; ``on_last_close(open_now)`` when none was left."""

    def __init__(self, path: str, on_last_close: Callable[[int], None]) -> None:
        self.path = path
        self._on_last_close = on_last_close
        self._fd = -1
        self._count = 0

    def start(self) -> bool:
        """Watch the device; False (and no watch) where inotify is not available."""
        libc = _libc()
        if libc is None or not hasattr(libc, "inotify_init1"):
            return False
        fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        if fd < 0:
            return False
        if libc.inotify_add_watch(fd, os.fsencode(self.path), IN_OPEN | IN_CLOSE_WRITE | IN_CLOSE_NOWRITE) < 0:
            os.close(fd)
            return False
        self._fd = fd
        asyncio.get_running_loop().add_reader(fd, self._readable)
        return True

    @property
    def count(self) -> int | None:
        """Programs with the device open now (the simulator's own slave fd not counted); None if unknown."""
        if self._fd < 0:
            return None
        self._drain()
        return self._count

    def still_open(self) -> bool:
        """Before a reply: has the master that asked still the device open? Handles a close not yet seen first,
        so a reply due to a master that has gone is never handed to the next one (True where unknown)."""
        if self._fd < 0:
            return True
        if self._drain():
            self._on_last_close(self._count)
            return False
        return self._count > 0

    def _drain(self) -> bool:
        """Read the pending events; True if the last opener closed meanwhile."""
        went = False
        while True:
            try:
                data = os.read(self._fd, 4096)
            except BlockingIOError:
                return went
            except OSError as exc:
                log.info("pty %s: cannot read inotify events (%s); not watching who has it open", self.path, exc)
                self.close()
                return False
            for offset in range(0, len(data), _EVENT.size):  # no names: a watch on a file, not a directory
                _wd, mask, _cookie, _length = _EVENT.unpack_from(data, offset)
                if mask & IN_OPEN:
                    self._count += 1
                elif mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE) and self._count > 0:
                    self._count -= 1
                    went = went or self._count == 0
                elif mask & IN_Q_OVERFLOW:
                    self._count = 0  # lost track: assume nobody, as after a close
                    went = True

    def _readable(self) -> None:
        if self._drain():
            self._on_last_close(self._count)

    def close(self) -> None:
        if self._fd >= 0:
            with contextlib.suppress(RuntimeError, ValueError):
                asyncio.get_running_loop().remove_reader(self._fd)
            os.close(self._fd)
            self._fd = -1

"""Opening byte pipes: a pty with a stable link, a serial port in the line's format.

Every port that serves a line (:mod:`.pty`, :mod:`.serial`) and every
pass-through side of the sniffer (:mod:`.passthrough`) opens its device here,
so a pty is raw and linked, and a serial port exclusive and in its format,
the same way everywhere, with the same one-line errors.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Any

from ..wire.errors import C20SimError

__all__ = ["PARITIES", "check_link", "open_pty", "open_serial", "remove_link"]

#: The line's parity letter -> pyserial's constant name (pyserial is imported only when a port is opened).
PARITIES = {"N": "PARITY_NONE", "E": "PARITY_EVEN", "O": "PARITY_ODD"}


def open_serial(device: str, baud: int, parity: str, stopbits: int) -> Any:
    """``device`` opened exclusively, 8 data bits, ``parity`` N/E/O, ``stopbits`` 1 or 2, non-blocking reads;
    raises pyserial's SerialException (or OSError, ValueError) as it does."""
    import serial

    return serial.Serial(
        device,
        baud,
        bytesize=serial.EIGHTBITS,
        parity=getattr(serial, PARITIES[parity]),
        stopbits=serial.STOPBITS_TWO if stopbits == 2 else serial.STOPBITS_ONE,
        timeout=0,
        exclusive=True,
    )


def check_link(link: Path | None, option: str) -> None:
    """C20SimError naming ``option`` if ``link`` is taken by a file that is not a symlink (ours to replace)."""
    if link is not None and link.exists() and not link.is_symlink():
        raise C20SimError(
            f"{option} {link}: a file that is not a symlink is in the way; remove it or choose another path"
        )


def open_pty(link: Path | None, option: str) -> tuple[int, int, str]:
    """A raw pty: (master fd, slave fd, the device's path), with ``link`` a symlink to it when given;
    C20SimError naming ``option`` when the link cannot be made (nothing is left open then)."""
    import tty  # POSIX only, so imported here: importing c20sim works where there are no ptys (Windows)

    if link is not None and link.exists() and not link.is_symlink():
        raise C20SimError(
            f"{option} {link}: a file that is not a symlink is in the way; remove it or choose another path"
        )
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    if link is not None:
        try:
            if link.is_symlink():
                link.unlink()
            link.symlink_to(path)
        except OSError as exc:
            os.close(master)
            os.close(slave)
            raise C20SimError(
                f"{option} {link}: cannot create the symlink: {exc.strerror}; choose a writable path"
            ) from None
    return master, slave, path


def remove_link(link: Path | None, path: str) -> None:
    """Remove ``link`` if it still points at ``path`` (another program may have taken the name since)."""
    if link is None or not link.is_symlink():
        return
    with contextlib.suppress(OSError):
        if os.readlink(link) == path:
            link.unlink()

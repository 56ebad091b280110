"""A virtual serial port: a pseudo-terminal whose other end a master opens like a device.

The simulator holds the pty's master side and keeps the slave side open too,
so that a master may open, close and reopen the device without the simulator
seeing an error. ``--link PATH`` adds a stable symlink such as /tmp/ttyC20.
With ``line_timing`` the pty is a :class:`~c20sim.transport.timed.TimedEndpoint`:
frames are strict and held to the sheet's 1.5/3.5-character rules for an 8N1
line, and replies are paced at the line's baud, byte by byte, on a thread of
their own.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import tty
from pathlib import Path

from ..errors import C20SimError
from .endpoint import RtuEndpoint, stream_framer
from .line import Line
from .timed import TimedEndpoint

__all__ = ["PtyPort"]


class PtyPort:
    """A pty in front of a simulator's bus."""

    def __init__(self, line: Line, *, link: str | None = None, line_timing: bool = False) -> None:
        self.line = line
        self.link = Path(link) if link else None
        self.line_timing = line_timing
        self.path = ""
        self._master = -1
        self._slave = -1
        self._endpoint: RtuEndpoint | TimedEndpoint | None = None
        self._unsent = bytearray()  # what the pty's buffer would not take yet

    async def start(self) -> None:
        if self.link is not None and self.link.exists() and not self.link.is_symlink():
            raise C20SimError(
                f"--link {self.link}: a file that is not a symlink is in the way; remove it or choose another path"
            )
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        if self.link is not None:
            try:
                if self.link.is_symlink():
                    self.link.unlink()
                self.link.symlink_to(self.path)
            except OSError as exc:
                self.close()
                raise C20SimError(
                    f"--link {self.link}: cannot create the symlink: {exc.strerror}; choose a writable path"
                ) from None
        framer = stream_framer(self.line.sim.bus.line_baud, line_timing=self.line_timing)
        if self.line_timing:  # a pty has no line format: it is the sheet's 8N1
            self._endpoint = TimedEndpoint(self.line, self._master, framer, pace=True, name=f"pty {self.path}")
            return
        self._endpoint = RtuEndpoint(self.line, framer, self._send, name=f"pty {self.path}")
        asyncio.get_running_loop().add_reader(self._master, self._readable)

    @property
    def baud(self) -> int:
        """The baud the pty's framing follows now (the line's)."""
        return self._endpoint.framer.baud if self._endpoint is not None else self.line.sim.bus.line_baud

    @property
    def name(self) -> str:
        return str(self.link) if self.link else self.path

    def _readable(self) -> None:
        assert isinstance(self._endpoint, RtuEndpoint)
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no one has the device open: nothing to read
                return
            raise
        if data and self._endpoint is not None:
            self._endpoint.feed(data)

    def _send(self, data: bytes, baud: int) -> None:
        if self._unsent:
            self._unsent += data
            return
        written = self._write_some(data)
        if written < len(data):
            self._unsent += data[written:]
            asyncio.get_running_loop().add_writer(self._master, self._flush_unsent)

    def _write_some(self, data: bytes | bytearray) -> int:
        try:
            return os.write(self._master, data)
        except BlockingIOError:
            return 0

    def _flush_unsent(self) -> None:
        del self._unsent[: self._write_some(self._unsent)]
        if not self._unsent:
            asyncio.get_running_loop().remove_writer(self._master)

    def close(self) -> None:
        if self._endpoint is not None:
            self._endpoint.close()
        if self._master >= 0:
            with contextlib.suppress(RuntimeError):
                loop = asyncio.get_running_loop()
                loop.remove_reader(self._master)
                loop.remove_writer(self._master)
            os.close(self._master)
            self._master = -1
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1
        if self.link is not None and self.link.is_symlink() and os.readlink(self.link) == self.path:
            self.link.unlink()

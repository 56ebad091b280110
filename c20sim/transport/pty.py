"""A virtual serial port: a pseudo-terminal whose other end a master opens like a device.

The simulator holds the pty's master side and keeps the slave side open too,
so that a master may open, close and reopen the device without the simulator
seeing an error. ``--link PATH`` adds a stable symlink such as /tmp/ttyC20.
With ``line_timing`` replies are paced at the configured baud, byte by byte,
and incoming frames are held to the sheet's 1.5/3.5-character rules.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import tty
from pathlib import Path

from ..errors import C20SimError
from ..protocol import RtuFramer, char_time
from ..simulator import Simulator
from .endpoint import RtuEndpoint

__all__ = ["PtyPort"]


class PtyPort:
    """A pty in front of a simulator's bus."""

    def __init__(
        self, sim: Simulator, line: asyncio.Lock, *, link: str | None = None, line_timing: bool = False
    ) -> None:
        self.sim = sim
        self.line = line
        self.link = Path(link) if link else None
        self.line_timing = line_timing
        self.path = ""
        self._master = -1
        self._slave = -1
        self._endpoint: RtuEndpoint | None = None

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
        baud = self.sim.bus.line_baud
        framer = RtuFramer(baud, complete_on_length=not self.line_timing, check_gaps=self.line_timing)
        self._endpoint = RtuEndpoint(self.sim, framer, self._send, self.line, name=f"pty {self.path}")
        asyncio.get_running_loop().add_reader(self._master, self._readable)

    @property
    def name(self) -> str:
        return str(self.link) if self.link else self.path

    def _readable(self) -> None:
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

    async def _send(self, data: bytes) -> None:
        if not self.line_timing:
            await self._write_all(data)
            return
        loop = asyncio.get_running_loop()
        per_char = char_time(self.sim.bus.line_baud)
        start = loop.time()
        sent = 0
        while sent < len(data):
            due = int((loop.time() - start) / per_char) + 1
            chunk = data[sent : max(sent + 1, min(len(data), due))]
            await self._write_all(chunk)
            sent += len(chunk)
            if sent < len(data):
                await asyncio.sleep(max(0.0, start + sent * per_char - loop.time()))

    async def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                written = os.write(self._master, view)
            except BlockingIOError:
                await asyncio.sleep(0.001)
                continue
            view = view[written:]

    def close(self) -> None:
        if self._endpoint is not None:
            self._endpoint.close()
        if self._master >= 0:
            with contextlib.suppress(RuntimeError):
                asyncio.get_running_loop().remove_reader(self._master)
            os.close(self._master)
            self._master = -1
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1
        if self.link is not None and self.link.is_symlink() and os.readlink(self.link) == self.path:
            self.link.unlink()

"""A virtual serial port: a pseudo-terminal whose other end a master opens like a device.

The simulator holds the pty's master side and keeps the slave side open too,
so that a master may open, close and reopen the device without the simulator
seeing an error. ``--link PATH`` adds a stable symlink such as /tmp/ttyC20.
With ``line_timing`` the pty is a :class:`~c20sim.transport.timed.TimedEndpoint`:
frames are strict and held to the sheet's 1.5/3.5-character rules for an 8N1
line, and replies are paced at the line's baud, byte by byte, on a thread of
their own.

A real port loses what arrives while nobody has it open: when the last
program that opened the device closes it (:class:`~.ptywatch.PtyOpeners`),
the replies it did not read and the requests it left are flushed (those
still on the device's side, and those that had crossed to ours unread), and
replies due while nobody has it open are dropped.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import os
from pathlib import Path

from ..wire.errors import C20SimError
from .device import check_link, open_pty, remove_link
from .endpoint import RtuEndpoint, stream_framer
from .line import Line
from .ptywatch import PtyOpeners
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
        self._lock = -1  #: the open lock file beside --link, held while this port owns the link
        self._openers: PtyOpeners | None = None

    async def start(self) -> None:
        check_link(self.link, "--link")  # before the lock: a refused link leaves no lock file beside it
        if self.link is not None:
            self._take_link_lock(self.link)
        try:
            self._master, self._slave, self.path = open_pty(self.link, "--link")
        except C20SimError:
            self.close()
            raise
        os.set_blocking(self._master, False)
        self._openers = PtyOpeners(self.path, self._master_gone)
        if not self._openers.start():
            self._openers = None
        framer = stream_framer(self.line.sim.bus.line_baud, line_timing=self.line_timing)
        if self.line_timing:  # a pty has no line format: it is the sheet's 8N1
            self._endpoint = TimedEndpoint(
                self.line, self._master, framer, pace=True, name=f"pty {self.path}", may_reply=self._still_open
            )
            return
        self._endpoint = RtuEndpoint(
            self.line, framer, self._send, name=f"pty {self.path}", pause=self._pause, resume=self._resume
        )
        asyncio.get_running_loop().add_reader(self._master, self._readable)

    def _still_open(self) -> bool:
        """Has the master that asked still the device open (True where that is not known)?"""
        return self._openers is None or self._openers.still_open()

    def _take_link_lock(self, link: Path) -> None:
        """Hold ``LINK.lock`` for as long as this port owns the link: a second c20sim is refused, naming the first.

        The kernel drops the lock when its holder dies, however it dies, so a stale link is taken over.
        """
        lock_path = link.with_name(link.name + ".lock")
        try:
            fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise C20SimError(
                f"--link {link}: cannot create {lock_path}: {exc.strerror}; choose a writable path"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise C20SimError(
                f"--link {link} is held by another c20sim (PID {holder}); stop it or choose another --link"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock = fd

    @property
    def baud(self) -> int:
        """The baud the pty's framing follows now (the line's)."""
        return self._endpoint.framer.baud if self._endpoint is not None else self.line.sim.bus.line_baud

    @property
    def name(self) -> str:
        return str(self.link) if self.link else self.path

    def _pause(self) -> None:
        """Backpressure: leave the master's bytes in the pty while its request is on the line."""
        if self._master >= 0:
            asyncio.get_running_loop().remove_reader(self._master)

    def _resume(self) -> None:
        if self._master >= 0:
            asyncio.get_running_loop().add_reader(self._master, self._readable)

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

    def _master_gone(self, _open_now: int) -> None:
        """The last master closed the device: what it left is lost, as on a real port."""
        if self._slave < 0:
            return
        # Its unread replies and its unread requests. A master that opened meanwhile may lose its first
        # request with them (it times out and asks again): better than reading the old master's answers.
        import termios  # POSIX only, as tty above

        if isinstance(self._endpoint, TimedEndpoint):
            self._endpoint.reset()  # first: no byte of its replies is written after the flush
        termios.tcflush(self._slave, termios.TCIOFLUSH)
        # The requests it wrote that have crossed to our side already: the kernel's flush of the device's output
        # leaves those in the master side's own input buffer (up to 4 KiB), which we would read and answer, to
        # the next master. Dropped too.
        with contextlib.suppress(OSError):
            termios.tcflush(self._master, termios.TCIFLUSH)
        if self._unsent:
            self._unsent.clear()
            asyncio.get_running_loop().remove_writer(self._master)
        if isinstance(self._endpoint, RtuEndpoint):
            self._endpoint.write_blocked(False)
            self._endpoint.reset()

    def _send(self, data: bytes, baud: int) -> None:
        if not self._still_open():
            return  # the master that asked has gone: the reply is lost, as on a real port
        if self._unsent:
            self._unsent += data
            return
        written = self._write_some(data)
        if written < len(data):
            self._unsent += data[written:]
            asyncio.get_running_loop().add_writer(self._master, self._flush_unsent)
            if isinstance(self._endpoint, RtuEndpoint):
                self._endpoint.write_blocked(True)  # a master that does not read: read no more from it

    def _write_some(self, data: bytes | bytearray) -> int:
        try:
            return os.write(self._master, data)
        except BlockingIOError:
            return 0

    def _flush_unsent(self) -> None:
        del self._unsent[: self._write_some(self._unsent)]
        if not self._unsent:
            asyncio.get_running_loop().remove_writer(self._master)
            if isinstance(self._endpoint, RtuEndpoint):
                self._endpoint.write_blocked(False)

    def close(self) -> None:
        if self._openers is not None:
            self._openers.close()
            self._openers = None
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
        remove_link(self.link, self.path)
        if self._lock >= 0:
            # The lock file stays (unlinking it would let a third c20sim lock a fresh file while a
            # second holds the old one); emptied, it names no holder.
            with contextlib.suppress(OSError):
                os.ftruncate(self._lock, 0)
            os.close(self._lock)  # releases the lock
            self._lock = -1

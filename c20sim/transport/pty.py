"""A virtual serial port: a pseudo-terminal whose other end a master opens like a device.

The simulator holds the pty's master side; a master opens, closes and
reopens the device freely. ``--link PATH`` adds a stable symlink such as
/tmp/ttyC20. With ``line_timing`` the pty is a
:class:`~c20sim.transport.timed.TimedEndpoint`: frames are strict and held to
the sheet's 1.5/3.5-character rules for an 8N1 line, and replies are paced at
the line's baud, byte by byte, on a thread of its own.

A real port loses what arrives while nobody has it open. Whether anybody has
it open is the device's own answer (:mod:`.ptywatch`: the simulator keeps no
slave descriptor, so the master side reports a hang-up exactly while no
program has the device open): two programs may have it open, and one that
closes leaves the other answered. When the last one closes, the requests it
left (read up to the hang-up, so none of a next master's) and the replies it
did not read are dropped, and replies due while nobody has it open are never
written. A master that opens right after another's close loses nothing of
its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import fcntl
import os
import select
from pathlib import Path

from ..wire.errors import C20SimError
from .device import check_link, open_pty, remove_link
from .endpoint import RtuEndpoint, stream_framer
from .line import Line
from .ptywatch import HangupWatch, PtyOpened, someone_has_it_open
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
        self._opened: PtyOpened | None = None
        self._hangups: HangupWatch | None = None
        self._epoch = 0  #: the hang-ups counted when the master's bytes were last read: a reply is for them
        self._present = False  #: a program had the device open when last seen (a hang-up ends it)
        self._reading = False  #: the master side is on the loop's readers
        self._paused = False  #: backpressure: the master's request is on the line

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
        # The device's settings (raw) stay while our master side is open; without our own slave descriptor the
        # master side tells whether any program has the device open.
        os.close(self._slave)
        self._slave = -1
        framer = stream_framer(self.line.sim.bus.line_baud, line_timing=self.line_timing)
        if self.line_timing:  # a pty has no line format: it is the sheet's 8N1
            self._endpoint = TimedEndpoint(
                self.line,
                self._master,
                framer,
                pace=True,
                name=f"pty {self.path}",
                may_reply=self._still_open,
                on_hangup=self._flush_device,
            )
            return
        self._endpoint = RtuEndpoint(
            self.line, framer, self._send, name=f"pty {self.path}", pause=self._pause, resume=self._resume
        )
        if hasattr(select, "epoll"):  # Linux; elsewhere the hang-up is seen by the loop (a read's EIO, a reply)
            self._hangups = HangupWatch(self._master, self._flush_left, self._after_hangup, name=self.path)
        self._opened = PtyOpened(self.path, self._maybe_opened)
        self._opened.start()
        self._maybe_opened()

    def _flush_left(self) -> None:
        """On the hang-up watch's thread, the moment the last program closed the device: the requests it wrote
        and we have not read, and the replies it did not read, are dropped before a next one can open it."""
        import termios  # POSIX only, as tty above

        with contextlib.suppress(OSError):
            termios.tcflush(self._master, termios.TCIFLUSH)
        self._flush_device()

    def _after_hangup(self) -> None:
        """On the loop, after the watch's flush: the old master's requests leave the framer and the line, unless
        the loop has read a next master's bytes already (and dropped the old master's then)."""
        if self._hangups is None or self._master < 0 or self._epoch == self._hangups.hangups:
            return
        self._epoch = self._hangups.hangups
        self._drop_left()
        if not someone_has_it_open(self._master):
            self._present = False
            self._stop_reading()

    def _stale(self) -> bool:
        """Has the device hung up since the master's bytes were last read (a reply would be for a gone master)?"""
        return self._hangups is not None and self._hangups.hangups != self._epoch

    def _still_open(self) -> bool:
        """Has a program the device open now (the device's answer)? If not, what the last one left is dropped."""
        if self._master < 0:
            return False
        if someone_has_it_open(self._master):
            return True
        if not self.line_timing:
            self._hung_up(read_all=False)
        return False

    def _maybe_opened(self) -> None:
        """A program may have opened or closed the device (inotify, or the clock): read it if the device says
        somebody has it open; if nobody has and somebody had, what that program left is dropped now."""
        if self._master < 0:
            return
        if someone_has_it_open(self._master):
            self._present = True
            if self._hangups is not None:
                self._hangups.opened()
            self._read_if_wanted()
        elif self._present:
            self._hung_up(read_all=False)

    def _read_if_wanted(self) -> None:
        if not self._reading and not self._paused and self._master >= 0:
            asyncio.get_running_loop().add_reader(self._master, self._readable)
            self._reading = True

    def _stop_reading(self) -> None:
        if self._reading:
            asyncio.get_running_loop().remove_reader(self._master)
            self._reading = False

    def _hung_up(self, *, read_all: bool) -> None:
        """Nobody has the device open (a read failed with EIO, having read all the device held: ``read_all``; or
        the device says so before a reply): stop reading until a program opens it; if one had it open, what it
        left is dropped."""
        if not read_all and self._present:
            # What waits unread on our side (reading was paused) was written by the master that left, the device
            # having just said nobody has it open: dropped at once, before a next master can write.
            import termios  # POSIX only, as tty above

            with contextlib.suppress(OSError):
                termios.tcflush(self._master, termios.TCIFLUSH)
        self._stop_reading()
        if self._present:
            self._present = False
            self._master_gone()

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
        self._paused = True
        self._stop_reading()

    def _resume(self) -> None:
        self._paused = False
        self._read_if_wanted()  # a hang-up meanwhile shows as EIO at once

    def _readable(self) -> None:
        assert isinstance(self._endpoint, RtuEndpoint)
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no one has the device open: all it wrote has been read already
                self._hung_up(read_all=True)
                return
            raise
        if data and self._endpoint is not None:
            self._present = True
            if self._hangups is not None:
                self._hangups.opened()
                if self._epoch != self._hangups.hangups:
                    self._epoch = self._hangups.hangups
                    self._drop_left()  # a hang-up the loop has not handled yet: nothing before it is answered
            self._endpoint.feed(data)

    def _master_gone(self) -> None:
        """The last master closed the device: what it left is lost, as on a real port."""
        self._drop_left()
        self._flush_device()

    def _drop_left(self) -> None:
        """The requests the last master left (read up to the hang-up: the kernel hands what it wrote over before
        it reports one, so none of a next master's is among them) leave the framer and the line, and the replies
        not yet written are dropped."""
        if self._unsent:
            self._unsent.clear()
            asyncio.get_running_loop().remove_writer(self._master)
        if isinstance(self._endpoint, RtuEndpoint):
            self._endpoint.write_blocked(False)
            self._endpoint.reset()

    def _flush_device(self) -> None:
        """Drop the replies the last master did not read: they wait in the device's input, which only a
        descriptor of the device can flush (a moment's open; a master opening meanwhile has no reply yet)."""
        import termios  # POSIX only, as tty above

        with contextlib.suppress(OSError):
            fd = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            try:
                termios.tcflush(fd, termios.TCIFLUSH)
            finally:
                os.close(fd)

    def _send(self, data: bytes, baud: int) -> None:
        if self._stale() or not self._still_open():
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
        if self._stale():
            self._unsent.clear()  # its master hung up: the watch's loop callback follows
        del self._unsent[: self._write_some(self._unsent)]
        if not self._unsent:
            asyncio.get_running_loop().remove_writer(self._master)
            if isinstance(self._endpoint, RtuEndpoint):
                self._endpoint.write_blocked(False)

    def close(self) -> None:
        if self._opened is not None:
            self._opened.close()
            self._opened = None
        if self._hangups is not None:
            self._hangups.close()
            self._hangups = None
        if self._endpoint is not None:
            self._endpoint.close()
        if self._master >= 0:
            with contextlib.suppress(RuntimeError):
                loop = asyncio.get_running_loop()
                loop.remove_reader(self._master)
                loop.remove_writer(self._master)
            self._reading = False
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

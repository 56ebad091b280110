"""Whether any program has the pty open, asked of the device itself; and a wake-up when one opens it.

The simulator holds only the pty's master side: it closes its own slave
descriptor once the device is set up (raw, 8N1), so the kernel's own count of
the slave's openers decides. While no program has the device open the master
side reports a hang-up (``POLLHUP``; a read fails with EIO), and as soon as
one opens it the hang-up is gone, however many programs open and close it
meanwhile: two programs that open the device at once and one that closes
leave it open for the other. The settings the simulator made stay with the
device while its master side is open.

A reader cannot wait for an open on a hung-up master side (it reports the
hang-up at once, again and again), so while nobody has the device open the
port stops reading and waits for an open; and a port that is not reading
(its master's request is on the line) would not see the hang-up. Linux
reports every open and close of the device node through inotify
(:class:`PtyOpened`). An inotify event only wakes the port up; what it then
believes is the device's hang-up state, so events folded together or lost
cost nothing. Where inotify is missing the
port looks every :data:`POLL_WITHOUT_INOTIFY` seconds.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import ctypes.util
import logging
import os
import select
import threading
from collections.abc import Callable

__all__ = ["POLL_WITHOUT_INOTIFY", "HangupWatch", "PtyOpened", "someone_has_it_open"]

log = logging.getLogger(__name__)

IN_CLOSE_WRITE = 0x00000008
IN_CLOSE_NOWRITE = 0x00000010
IN_OPEN = 0x00000020

#: How often a port without inotify looks whether a program opened the device (seconds).
POLL_WITHOUT_INOTIFY = 0.05


def someone_has_it_open(master: int) -> bool:
    """True while any program has the pty's slave side open: the master side reports no hang-up."""
    poller = select.poll()
    poller.register(master, select.POLLIN)
    return not any(mask & select.POLLHUP for _fd, mask in poller.poll(0))


def _libc() -> ctypes.CDLL | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    except OSError:
        return None


class PtyOpened:
    """Calls ``on_open()`` on the loop when a program may have opened or closed the device at ``path`` (a
    wake-up only: the caller asks the device what holds now)."""

    def __init__(self, path: str, on_open: Callable[[], None]) -> None:
        self.path = path
        self._on_open = on_open
        self._fd = -1
        self._timer: asyncio.TimerHandle | None = None

    def start(self) -> None:
        """Watch the device with inotify; where that is not available, look every POLL_WITHOUT_INOTIFY."""
        libc = _libc()
        fd = -1
        if libc is not None and hasattr(libc, "inotify_init1"):
            fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
            if (
                fd >= 0
                and libc.inotify_add_watch(fd, os.fsencode(self.path), IN_OPEN | IN_CLOSE_WRITE | IN_CLOSE_NOWRITE) < 0
            ):
                os.close(fd)
                fd = -1
        if fd < 0:
            self._tick()
            return
        self._fd = fd
        asyncio.get_running_loop().add_reader(fd, self._readable)

    def _tick(self) -> None:
        self._timer = asyncio.get_running_loop().call_later(POLL_WITHOUT_INOTIFY, self._tick)
        self._on_open()

    def _readable(self) -> None:
        try:
            while os.read(self._fd, 4096):  # the events say only "opened": what counts is the device's state
                pass
        except BlockingIOError:
            pass
        except OSError as exc:
            log.info("pty %s: cannot read inotify events (%s); looking for openers by the clock", self.path, exc)
            self.close()
            self._tick()
        self._on_open()

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._fd >= 0:
            with contextlib.suppress(RuntimeError, ValueError):
                asyncio.get_running_loop().remove_reader(self._fd)
            os.close(self._fd)
            self._fd = -1


class HangupWatch:
    """A thread that sees the pty's hang-up (the last program closed the device) the moment it happens.

    The event loop may be late by milliseconds on a busy machine, and a master that opens the device meanwhile
    would find what the last one left. This thread waits on the master side for ``EPOLLHUP`` alone (it never
    reads), and when the device says nobody has it open it counts the hang-up (:attr:`hangups`, read by the
    loop to drop a reply to a request read before it) and calls ``on_hangup()`` on the thread at once (the
    flush), then ``later()`` on the loop. A program that opens the device afterwards finds nothing of the last.
    """

    def __init__(self, master: int, on_hangup: Callable[[], None], later: Callable[[], None], name: str = "") -> None:
        self.master = master
        self.hangups = 0  #: hang-ups seen so far (an int the loop reads; the GIL makes its update whole)
        self._on_hangup = on_hangup
        self._later = later
        self._loop = asyncio.get_running_loop()
        self._epoll = select.epoll()
        self._epoll.register(master, select.EPOLLHUP | select.EPOLLET)
        self._wake_r, self._wake_w = os.pipe()
        self._epoll.register(self._wake_r, select.EPOLLIN)
        self._thread = threading.Thread(target=self._run, name=f"c20sim hang-up watch {name}", daemon=True)
        self._open = someone_has_it_open(master)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                events = self._epoll.poll()
            except InterruptedError:
                continue
            except (OSError, ValueError):
                return
            if any(fd == self._wake_r for fd, _mask in events):
                return
            if someone_has_it_open(self.master):
                self._open = True
                continue
            if not self._open:
                continue  # still nobody (our own moment's open and close, say)
            self._open = False
            self.hangups += 1
            try:
                self._on_hangup()
            except Exception:
                log.exception("bug while dropping what the last program left on the pty; it keeps serving")
            with contextlib.suppress(RuntimeError):  # the loop has closed: the server is shutting down
                self._loop.call_soon_threadsafe(self._later)

    def opened(self) -> None:
        """The loop saw a program open the device: the next hang-up counts."""
        self._open = True

    def close(self) -> None:
        if self._wake_w < 0:
            return
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._thread.join(timeout=2.0)
        self._epoll.close()
        os.close(self._wake_r)
        os.close(self._wake_w)
        self._wake_w = -1

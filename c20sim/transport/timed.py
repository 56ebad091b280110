"""A line-timed byte stream (``--line-timing``): framed and paced on threads of its own, on the monotonic clock.

The event loop's timers are about 1 ms coarse, coarser than a character at
19200 baud (0.52 ms) and than t1.5 (0.78 ms); and whatever else the loop does
(the dashboard, the control API, other ports) would delay a byte further. So a
line-timed stream does its timing off the loop:

- a reader thread waits on the port with ``select`` (microsecond timeouts),
  stamps every chunk with ``time.perf_counter`` as it arrives (on a pty,
  which hands the master's bytes over at once, with the time they would
  have ended on the line: each takes a character after the last one's end
  or its own arrival, whichever is later), feeds the strict framer and
  ticks it at its t3.5 deadline; the framing events go to
  the loop, which serves them on the shared :class:`~c20sim.transport.line.Line`.
  Without real-time scheduling (below), inside a frame at 19200 baud and
  above (t1.5 under 1 ms) it polls without sleeping until the frame ends,
  since an ordinary thread's wake-up can be late by more than t1.5 on a busy
  machine: a frame then costs that thread's CPU for its own length plus t3.5
  (about 6.5 ms for an 8-byte request at 19200 baud);
- a writer thread puts each reply on the port starting t3.5 + the reply's
  turnaround after the request's last byte, and, where the port does not pace
  bytes itself (a pty), one byte every character time, each when its
  character would end on the line (as a UART hands over a byte it received): it sleeps to just
  before each byte's time and spins the rest, so a byte leaves within a few
  microseconds of its time on an idle machine (bench/bench_line_timing.py).

While a line-timed port is open the interpreter's switch interval is lowered
to 0.2 ms (from 5 ms), so that a timing thread waking up gets the GIL from a
busy loop thread within a fraction of a character.

Each timing thread asks the kernel for real-time scheduling (SCHED_FIFO, at a
low real-time priority) where it is allowed: root, CAP_SYS_NICE, or an
RLIMIT_RTPRIO (``ulimit -r``). A real-time thread that wakes takes its CPU
from any ordinary thread at once, so the reader waits for each byte asleep
instead of polling through a frame, and the writer spins only the last 0.1 ms
before a byte. Without it they ask for nice -10 (root or
CAP_SYS_NICE), where a woken thread can still wait up to a scheduler tick
behind another on its CPU (kernel threads included: seen with ftrace), and
so the reader polls through a fast frame as above; elsewhere they run at the
process's own priority, and on a loaded machine arrival times are as late as
the scheduler makes them.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import logging
import os
import queue
import select
import sys
import threading
import time
from collections.abc import Callable

from ..core.bus import Reply
from ..wire.framing import RtuFramer
from ..wire.protocol import MAX_ADU, FrameEvent, char_time
from .line import Line, SelfTimed

__all__ = ["TimedEndpoint"]

log = logging.getLogger(__name__)

#: The last stretch before a byte's time is spun, not slept: an ordinary thread's sleep overshoots by 50-100 us.
SPIN = 0.0003
#: The same for a real-time thread, whose timers have no slack. Shorter is better here, not only cheaper: a
#: real-time spinner keeps the pty's kernel worker off its CPU, and with 0.3 ms (longer than a character at 57600
#: baud) bytes left in clumps: 71 % of intervals within +-0.1 character at 57600, against 83 % with 0.1 ms.
SPIN_REALTIME = 0.0001
#: Inside a frame whose t1.5 is shorter than this, the reader polls the port without sleeping (seconds).
SPIN_READ_BELOW = 0.001
#: While nobody has a pty open, how often its reader looks for an opener (seconds): a hung-up pty reports
#: itself readable at once, so the reader sleeps this long between looks; a request written meanwhile waits
#: in the device and is read whole.
HUNG_UP_POLL = 0.002
#: Replies waiting for the writer at most; more means the master does not wait for answers: they are dropped.
MAX_PENDING_REPLIES = 8
#: The SCHED_FIFO priority the timing threads ask for (1-99): above every ordinary thread, below the
#: kernel's interrupt threads (50), so that the port's own interrupts are never held up by it.
REALTIME_PRIORITY = 10
#: The nice value they ask for where real-time scheduling is not allowed (root or CAP_SYS_NICE only).
THREAD_NICE = -10
#: The interpreter's switch interval while a line-timed port is open (seconds).
SWITCH_INTERVAL = 0.0002

_switch_lock = threading.Lock()
_switch_users = 0
_switch_saved = 0.005


def _raise_thread_priority() -> bool:
    """Real-time scheduling for the calling thread where allowed (True); else nice -10 where allowed; else nothing."""
    tid = threading.get_native_id()
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except (OSError, AttributeError):  # not allowed here, or not Linux
        with contextlib.suppress(OSError, AttributeError):
            os.setpriority(os.PRIO_PROCESS, tid, THREAD_NICE)
        return False
    return True


def _lower_switch_interval() -> None:
    global _switch_users, _switch_saved
    with _switch_lock:
        if _switch_users == 0:
            _switch_saved = sys.getswitchinterval()
            sys.setswitchinterval(min(_switch_saved, SWITCH_INTERVAL))
        _switch_users += 1


def _restore_switch_interval() -> None:
    global _switch_users
    with _switch_lock:
        _switch_users -= 1
        if _switch_users == 0:
            sys.setswitchinterval(_switch_saved)


class TimedEndpoint:
    """Frames what arrives on ``fd`` and puts replies on it, timed on the monotonic clock.

    ``pace``: write a reply byte by byte at the character time (a pty, which
    passes bytes on at once); without it the reply is written whole at its
    start time (a UART paces it itself). ``write`` writes bytes to the port
    and returns how many it took (default: ``os.write`` on ``fd``).
    ``on_baud`` runs on the writer thread once every reply before a baud
    change has been handed to the port. ``may_reply`` is asked on the loop
    before a reply is queued: False drops it (the master that asked has gone).
    """

    def __init__(
        self,
        line: Line,
        fd: int,
        framer: RtuFramer,
        *,
        pace: bool,
        name: str = "",
        write: Callable[[bytes], int] | None = None,
        on_baud: Callable[[int], None] | None = None,
        may_reply: Callable[[], bool] | None = None,
        on_hangup: Callable[[], None] | None = None,
    ) -> None:
        if not framer.strict:
            raise ValueError("a line-timed endpoint needs a strict framer")
        self.line = line
        self.fd = fd
        self.framer = framer
        self.pace = pace
        self.name = name
        self._write = write if write is not None else functools.partial(os.write, fd)
        self._on_baud = on_baud
        self._may_reply = may_reply
        self._on_hangup = on_hangup
        #: who asks the line: one token per generation, so a reset cancels the old master's requests only
        self._source = object()
        self._loop = asyncio.get_running_loop()
        self._lock = threading.Lock()  # the framer: fed by the reader, its baud set from the loop
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._jobs: queue.SimpleQueue[tuple[bytes, int, float, int] | int | None] = queue.SimpleQueue()
        #: Bumped by :meth:`reset`: a reply of an earlier generation is not sent, or not sent further.
        self._generation = 0
        self._write_lock = threading.Lock()  # a byte's write against reset's bump: no byte of a dropped reply after
        self._pending = 0  # replies queued for the writer, bounded by MAX_PENDING_REPLIES
        self._spin = SPIN  # the writer's, once it knows its scheduling
        self._detach = line.on_baud(self._baud_changed)
        _lower_switch_interval()
        self._reader = threading.Thread(target=self._read_loop, name=f"c20sim reader {name}", daemon=True)
        self._writer = threading.Thread(target=self._write_loop, name=f"c20sim writer {name}", daemon=True)
        self._reader.start()
        self._writer.start()

    def close(self) -> None:
        """Stop both threads (within a character time); a half-received frame and unsent replies are dropped."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._detach()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        self._jobs.put(None)
        for thread in (self._reader, self._writer):
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)
        os.close(self._wake_r)
        os.close(self._wake_w)
        _restore_switch_interval()

    def reset(self) -> None:
        """The master went away (on the loop): its half-received frame, its requests waiting on the line and the
        replies not yet sent are dropped. A reply's bytes written before are the caller's to flush, after this."""
        self.line.cancel(self._new_generation())

    def _new_generation(self) -> object:
        """Drop the half-received frame, start a new generation; returns the old one's line source (any thread)."""
        with self._lock:  # the reader's frames framed before this are of the old generation, even those in flight
            self.framer.flush()
            self.framer.events()
            with self._write_lock:
                self._generation += 1
                old, self._source = self._source, object()
        return old

    def _hung_up(self, old_source: object) -> None:
        """On the loop: the master side reported a hang-up (nobody has the device open): the old master's
        requests leave the line, and the caller drops what it left in the device."""
        self.line.cancel(old_source)
        if self._on_hangup is not None:
            self._on_hangup()

    # --- the reader thread

    def _read_loop(self) -> None:
        realtime = _raise_thread_priority()
        fd, wake = self.fd, self._wake_r
        hung_up = True  #: no program had the device open when last seen (a pty's EIO); a read ends it
        wire_end = 0.0  #: a pty: when the bytes read so far would have ended on the line
        while not self._stop.is_set():
            with self._lock:
                deadline = self.framer.deadline()
            timeout = None if deadline is None else max(0.0, deadline - time.perf_counter())
            if timeout is not None and not realtime and self.framer.t15 < SPIN_READ_BELOW:
                timeout = 0.0  # inside a fast frame: poll without sleeping, so that no wake-up delays a stamp
            try:
                ready, _, _ = select.select([fd, wake], [], [], timeout)
            except (OSError, ValueError) as exc:
                log.error("line-timed port %s: cannot wait for bytes (%s); it no longer reads", self.name, exc)
                return
            now = time.perf_counter()
            if wake in ready:
                return
            data = b""
            if fd in ready:
                try:
                    data = os.read(fd, 4096)
                except BlockingIOError:
                    pass
                except OSError as exc:
                    if exc.errno != errno.EIO:  # EIO: no one has the device open; all it wrote was read already
                        log.error("line-timed port %s: read failed (%s); it no longer reads", self.name, exc)
                        return
                    if self._on_hangup is None:  # a serial port: as before, look again a little later
                        self._stop.wait(0.05)
                        continue
                    wire_end = 0.0  # nobody has the device open: the line is quiet
                    if not hung_up:
                        hung_up = True
                        # here, before another byte is read: what the next master writes is of the new generation
                        old = self._new_generation()
                        with contextlib.suppress(RuntimeError):
                            self._loop.call_soon_threadsafe(self._hung_up, old)
                    self._stop.wait(HUNG_UP_POLL)  # a hung-up pty is always readable: look again for an opener
                    continue
            stamp = now
            if data:
                hung_up = False
                if self.pace:
                    # A pty hands the master's bytes over at once; on the line they take a character each, and
                    # the request's last byte ends that much later: its time on the wire counts before the reply
                    # (t3.5 after it) may start, as on the drive's line.
                    # A master that writes faster than the line (a flood) is held to one frame's backlog at
                    # most (MAX_ADU characters), so its bytes never stamp a next master's far in the future.
                    char = char_time(self.framer.baud, self.framer.bits)
                    wire_end = stamp = min(max(now, wire_end) + len(data) * char, now + MAX_ADU * char)
            with self._lock:
                if data:
                    self.framer.feed(data, stamp)
                self.framer.tick(now)
                events = self.framer.events()
                generation = self._generation
            if events:
                try:
                    self._loop.call_soon_threadsafe(self._submit, events, generation)
                except RuntimeError:  # the loop has closed: the server is shutting down
                    return

    # --- on the loop

    def _submit(self, events: list[FrameEvent], generation: int) -> None:
        if self._stop.is_set() or generation != self._generation:
            return
        for event in events:
            respond = functools.partial(self._respond, event.t, self.framer.t35, generation)
            self.line.submit(event, SelfTimed(respond), self._source)

    def _respond(self, request_end: float, t35: float, generation: int, reply: Reply | None) -> None:
        if reply is None or self._stop.is_set() or generation != self._generation:
            return
        if self._may_reply is not None and not self._may_reply():
            return  # the master that asked has gone: the reply is lost, as on a real port
        if self._pending >= MAX_PENDING_REPLIES:
            log.info("reply on %s dropped: %d replies wait for the line already", self.name, self._pending)
            return
        self._pending += 1
        # Handed over at once (SelfTimed): the reply starts t3.5 after the request's last byte (the end of
        # the frame), plus its delay (the profile's turnaround, and any injected delay), on this clock.
        self._jobs.put((reply.data, reply.baud, request_end + t35 + reply.delay, generation))

    def _baud_changed(self, baud: int) -> None:
        with self._lock:
            self.framer.set_baud(baud)
        if self._on_baud is not None:
            self._jobs.put(baud)  # after the replies queued before it, at the old baud

    # --- the writer thread

    def _write_loop(self) -> None:
        self._spin = SPIN_REALTIME if _raise_thread_priority() else SPIN
        while True:
            job = self._jobs.get()
            if job is None or self._stop.is_set():
                return
            if isinstance(job, int):
                assert self._on_baud is not None
                try:
                    self._on_baud(job)
                except Exception:
                    log.exception("bug while changing %s to %d baud; it keeps serving", self.name, job)
                continue
            data, baud, start, generation = job
            try:
                self._transmit(data, char_time(baud, self.framer.bits), start, generation)
            except OSError as exc:
                log.info("reply on %s not sent: %s", self.name, exc)
            finally:
                with contextlib.suppress(RuntimeError):  # the loop has closed: the server is shutting down
                    self._loop.call_soon_threadsafe(self._sent)

    def _sent(self) -> None:
        self._pending -= 1

    def _transmit(self, data: bytes, per_char: float, start: float, generation: int) -> None:
        t0 = max(start, time.perf_counter())
        if not self.pace:
            self._sleep_until(t0)
            sent = 0
            while sent < len(data) and not self._stop.is_set():
                written = self._write_or_wait(data[sent:], per_char, generation)
                if written < 0:
                    return
                sent += written
            return
        for i in range(len(data)):
            # a byte is handed over when its character ends on the line, as a UART hands over a byte it received
            if not self._sleep_until(t0 + (i + 1) * per_char):
                return
            written = self._write_or_wait(data[i : i + 1], per_char, generation)
            if written == 0:
                log.info("reply on %s cut short: the port takes no more bytes (no one reads them)", self.name)
            if written <= 0:
                return

    def _write_or_wait(self, data: bytes, per_char: float, generation: int) -> int:
        """Bytes written; 0 if the port took none (after waiting a character); -1 if the reply was dropped."""
        with self._write_lock:
            if generation != self._generation:
                return -1
            try:
                return self._write(data)
            except BlockingIOError:
                pass
        self._stop.wait(per_char)
        return 0

    def _sleep_until(self, target: float) -> bool:
        """Wait until ``target`` on the monotonic clock; False if the endpoint closed meanwhile."""
        remaining = target - time.perf_counter()
        if remaining > self._spin and self._stop.wait(remaining - self._spin):
            return False
        while time.perf_counter() < target:
            pass
        return not self._stop.is_set()

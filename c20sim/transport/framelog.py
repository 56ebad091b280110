"""The frame log, off the wire's path: a bounded buffer, drained by a writer thread of its own.

``--log-frames PATH`` writes every frame as a JSON line. The bus hands each
record to :meth:`FrameLog.put` on the event loop, which only appends it to a
bounded buffer; a thread turns records into lines and writes them. The buffer
is a :class:`~c20sim.core.framering.FrameRing`: what waits for the writer is
bytes and numbers in storage made once, never an object per frame that a
garbage collection would walk while the wire waits. When the
sink is slow (a pipe nobody reads), full (ENOSPC) or gone (the reader exited,
the file was deleted), records are dropped and counted, never the wire
delayed. What is written is whole lines only: a write the disk cut short is
taken back (the file is truncated to its last whole line), and a pipe gets
whole lines in writes no longer than PIPE_BUF, which a pipe never splits.

When writing works again, a ``{"kind": "log-dropped", ...}`` line says how
many records were lost, and the server's log says so in one line. A deleted
or replaced file is noticed and a new one started. A regular file is rotated
by size (``--log-frames-max-mb``): PATH becomes PATH.1, PATH.1 becomes PATH.2,
up to :data:`KEEP` old files. There is no reopen on SIGHUP: SIGHUP means the
terminal closed.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import select
import stat
import threading
import time
from pathlib import Path

from ..core.bus import FrameRecord
from ..core.framering import FrameRing
from ..wire.errors import C20SimError
from .wallclock import WALL_OFFSET

__all__ = ["KEEP", "FrameLog"]

log = logging.getLogger(__name__)

#: Records the buffer holds before it drops: a few seconds of a busy line (2 records a request).
BUFFER_RECORDS = 4096

#: Old files kept by rotation: PATH.1 (newest) to PATH.KEEP.
KEEP = 3

#: Seconds between attempts to write again after the sink failed (full disk, a file that cannot be opened).
RETRY = 0.5

#: Seconds between checks that PATH is still the file written to (it may have been deleted or replaced).
CHECK_PATH = 1.0

#: Free space a full disk must have again before writing resumes, so that the log does not flap.
HEADROOM = 256 * 1024

#: The most bytes given to one write on a pipe or terminal: whole lines up to this are never split.
PIPE_CHUNK = select.PIPE_BUF


class FrameLog:
    """Writes frame records to ``path`` as JSON lines, from a thread; ``put`` never blocks."""

    def __init__(self, path: str, *, max_bytes: int | None = None, buffer_records: int = BUFFER_RECORDS) -> None:
        self.path = path
        self.max_bytes = max_bytes
        self._buffer: FrameRing[FrameRecord] = FrameRing(buffer_records, FrameRecord)
        self._limit = buffer_records
        #: the buffer between the loop (append) and the writer thread (popleft, clear)
        self._buffer_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._fd = -1
        self._regular = False
        self._size = 0
        self._identity: tuple[int, int] | None = None
        self._checked = 0.0
        # Each counter has one writer, so no count is lost between the threads: records the full buffer refused
        # (the loop's), records the sink refused (the writer thread's), and what the last notice reported.
        self._refused = 0
        self._lost = 0
        self._reported = 0
        self._failing = ""  #: why writing stopped, while it is stopped
        self._gone = False  #: a pipe whose reader has exited: nothing will be written again
        self._thread: threading.Thread | None = None

    # -- the event loop's side

    def start(self) -> None:
        """Open the sink (an error here is the user's: one line) and start the writer thread."""
        try:
            self._open()
        except OSError as exc:
            raise C20SimError(f"--log-frames {self.path}: cannot open: {exc.strerror or exc}") from None
        self._thread = threading.Thread(target=self._run, name=f"c20sim frame log {self.path}", daemon=True)
        self._thread.start()

    def put(self, record: FrameRecord) -> None:
        """Queue a record; when the buffer is full it is dropped and counted (the wire never waits)."""
        if self._gone or len(self._buffer) >= self._limit:
            if self._refused == 0 and not self._gone:
                log.warning(
                    "frame log %s: its buffer is full, the sink is slower than the line; records are "
                    "dropped and counted (log_dropped in GET /frames)",
                    self.path,
                )
            self._refused += 1
            return
        with self._buffer_lock:
            self._buffer.append(record)
        if not self._wake.is_set():
            self._wake.set()

    @property
    def dropped(self) -> int:
        """Records lost in all: refused by the full buffer, or by the sink."""
        return self._refused + self._lost

    @property
    def _unreported(self) -> int:
        return self.dropped - self._reported

    def close(self, timeout: float = 1.0) -> None:
        """Write what is buffered if the sink takes it within ``timeout``, then stop; never hangs."""
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                return  # stuck in a write to a sink that does not drain: a daemon thread, gone at exit
            self._thread = None
        self._close_fd()

    # -- the writer thread

    def _run(self) -> None:
        try:
            while True:
                self._wake.wait(RETRY if self._failing else None)
                self._wake.clear()
                if self._buffer or self._unreported:
                    self._drain()
                if self._stop and (not self._buffer or self._failing):
                    return
        except Exception:
            log.exception("frame log %s: bug in the writer; frames are no longer logged", self.path)
            self._stop = True

    def _drain(self) -> None:
        if self._failing and not self._reopen_if_due():
            return
        self._check_path()
        if self._fd < 0:
            return
        if self._unreported:
            count = self._unreported
            note = self._failing or "the log could not keep up"
            notice = json.dumps({"kind": "log-dropped", "dropped": count, "note": note}) + "\n"
            if not self._write_lines([notice.encode()], records=0):
                return
            self._reported += count
            if self._failing:
                log.warning("frame log %s: writing again; %d frames were dropped (%s)", self.path, count, note)
                self._failing = ""
        elif self._failing:
            log.warning("frame log %s: writing again", self.path)
            self._failing = ""
        while self._buffer:
            batch: list[bytes] = []
            size = 0
            cap = 65536 if self.max_bytes is None else max(1, min(65536, self.max_bytes // 4))
            while self._buffer and size < cap:
                with self._buffer_lock:
                    record = self._buffer.popleft()
                line = (json.dumps(record.as_dict(WALL_OFFSET)) + "\n").encode()
                batch.append(line)
                size += len(line)
            if not self._write_lines(batch):
                return
            if self._stop and self._failing:
                return

    def _write_lines(self, lines: list[bytes], records: int | None = None) -> bool:
        """Write whole lines; on failure count the ``records`` among them dropped, remember why, return False."""
        if self._regular and self.max_bytes is not None and self._size + sum(map(len, lines)) > self.max_bytes:
            self._rotate()
        try:
            if self._regular:
                self._write_file(b"".join(lines))
            else:
                self._write_stream(lines)
        except OSError as exc:
            self._fail(len(lines) if records is None else records, exc)
            return False
        return True

    def _write_file(self, data: bytes) -> None:
        start = self._size
        written = 0
        try:
            while written < len(data):
                written += os.write(self._fd, data[written:])
        except OSError:
            if written:
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fd, start)  # take back the lines the disk cut short: whole lines only
            raise
        self._size = start + written

    def _write_stream(self, lines: list[bytes]) -> None:
        chunk: list[bytes] = []
        size = 0
        for line in lines:
            if chunk and size + len(line) > PIPE_CHUNK:
                self._send_all(b"".join(chunk))
                chunk, size = [], 0
            chunk.append(line)
            size += len(line)
        if chunk:
            self._send_all(b"".join(chunk))

    def _send_all(self, data: bytes) -> None:
        """A pipe or terminal in non-blocking mode: wait for room, but give up when told to stop."""
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self._fd, view) :]
            except BlockingIOError:
                if self._stop:
                    raise OSError(errno.EAGAIN, "the reader is not reading, and the server is stopping") from None
                select.select([], [self._fd], [], 0.1)

    def _fail(self, lines: int, exc: OSError) -> None:
        self._lost += lines
        why = exc.strerror or str(exc)
        if exc.errno == errno.EPIPE:
            why = "the reader has gone"
        if not self._failing:
            log.warning(
                "frame log %s: cannot write (%s); frames are dropped and counted until it can be written again",
                self.path,
                why,
            )
        self._failing = why
        if exc.errno == errno.EPIPE:
            self._close_fd()  # a pipe without a reader never comes back
            self._gone = True

    # -- the sink

    def _open(self) -> None:
        flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC | os.O_NONBLOCK
        fd = os.open(self.path, flags, 0o644)
        info = os.fstat(fd)
        self._regular = stat.S_ISREG(info.st_mode)
        if self._regular:
            os.set_blocking(fd, True)
            self._size = info.st_size
            self._identity = (info.st_dev, info.st_ino)
        self._fd = fd

    def _close_fd(self) -> None:
        if self._fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = -1

    def _reopen_if_due(self) -> bool:
        """While failing: True when it is time to try again (a file is reopened if it was closed)."""
        if self._gone:
            with self._buffer_lock:
                self._lost += len(self._buffer)  # nobody will read them
                self._buffer.clear()
            return False
        if self._fd < 0:
            try:
                self._open()
            except OSError:
                return False
        if self._regular:
            try:
                room = os.fstatvfs(self._fd)
            except OSError:
                return True
            if room.f_bavail * room.f_frsize < HEADROOM:
                return False
        return True

    def _check_path(self) -> None:
        """A deleted or replaced file: start a new one at PATH, and say so once."""
        if not self._regular or self._fd < 0:
            return
        now = time.monotonic()
        if now - self._checked < CHECK_PATH:
            return
        self._checked = now
        try:
            info = os.stat(self.path)
            same = (info.st_dev, info.st_ino) == self._identity
        except OSError:
            same = False
        if same:
            return
        log.warning("frame log %s: the file was deleted or replaced; writing a new one", self.path)
        self._close_fd()
        with contextlib.suppress(OSError):
            self._open()

    def _rotate(self) -> None:
        """PATH -> PATH.1 -> ... -> PATH.KEEP (the oldest is removed), then a new PATH."""
        base = Path(self.path)
        self._close_fd()
        with contextlib.suppress(OSError):
            Path(f"{base}.{KEEP}").unlink(missing_ok=True)
        for index in range(KEEP - 1, 0, -1):
            older = Path(f"{base}.{index}")
            if older.exists():
                with contextlib.suppress(OSError):
                    older.rename(f"{base}.{index + 1}")
        with contextlib.suppress(OSError):
            base.rename(f"{base}.1")
        try:
            self._open()
        except OSError as exc:
            self._failing = exc.strerror or str(exc)

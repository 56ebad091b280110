"""Reading a file c20sim is given: bounded, never a FIFO or a device, nesting checked before a parser recurses.

Every file the program opens to read (a profile, a state file, a scenario, a
ready file, a capture) goes through :func:`read_bytes` or :func:`read_text`:

- the path is looked at first (``stat``), then opened with ``O_NONBLOCK`` and
  looked at again (``fstat``) before a byte is read, so a FIFO never blocks
  and a link swapped meanwhile is caught; anything but a regular file (a FIFO,
  a character or block device such as ``/dev/zero``, a socket, a directory)
  is refused with one line;
- each format has its own bound (:data:`LIMITS`): a file bigger than that is
  refused by its size before it is read (a sparse file of gigabytes costs
  nothing), and a file growing while it is read stops at the bound;
- :func:`toml_depth` and :func:`json_depth` measure nesting without recursing,
  so a document nested deeper than :data:`MAX_DEPTH` is refused with one line
  before ``tomllib`` or ``json`` could end in a ``RecursionError``.

Errors are :class:`FileReadError`, whose ``reason`` reads after the file's
name; each format's loader wraps it in its own error (``ProfileError``,
``StateFileError``, ``ScenarioError``), so the line names the file as before.
"""

from __future__ import annotations

import io
import os
import stat
from collections.abc import Mapping
from pathlib import Path

from ..wire.errors import C20SimError

__all__ = [
    "LIMITS",
    "MAX_DEPTH",
    "FileReadError",
    "json_depth",
    "open_stream",
    "read_bytes",
    "read_text",
    "toml_depth",
]

KIB = 1024
MIB = 1024 * KIB

#: The most bytes of each kind of file: a state file is under a kilobyte, a profile a few dozen, a scenario
#: suite file larger; a capture (``replay``, ``decode``) is the largest. Each is far above any real one.
LIMITS: Mapping[str, int] = {
    "state file": 256 * KIB,
    "ready file": 64 * KIB,
    "token file": 4 * KIB,
    "profile": 1 * MIB,
    "scenario": 4 * MIB,
    "capture": 64 * MIB,
}

#: Nesting of arrays and tables (objects) a profile, a scenario or a frame-log line may have; the shipped ones
#: nest three levels at most.
MAX_DEPTH = 64

#: Bytes read at a time.
_CHUNK = 1 * MIB


class FileReadError(C20SimError):
    """A file that cannot be read as given: ``path``, and ``reason`` to say after it."""

    def __init__(self, path: str, reason: str, *, missing: bool = False) -> None:
        self.path = path
        self.reason = reason
        self.missing = missing  #: no such file (the reason is ``cannot read: No such file or directory``)
        super().__init__(f"{path}: {reason}")


def _size(limit: int) -> str:
    return f"{limit // MIB} MiB" if limit >= MIB and limit % MIB == 0 else f"{limit // KIB} KiB"


def _kind(mode: int) -> str | None:
    """What a file that is not a regular file is, in words; None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _not_regular(path: str, kind: str, what: str) -> FileReadError:
    return FileReadError(path, f"is {kind}, not a regular file; give the {what} as a file")


def _cannot(name: str, exc: OSError) -> FileReadError:
    return FileReadError(name, f"cannot read: {exc.strerror or exc}", missing=isinstance(exc, FileNotFoundError))


def _open_regular(name: str, what: str) -> int:
    """``name`` opened for reading (non-blocking), if it is a regular file: looked at before the open (a device
    is not even opened: opening some has effects, a tape, a modem; a FIFO's open would wait for a writer) and
    again after it (a link swapped between the look and the open). Raises :class:`FileReadError`."""
    try:
        before = os.stat(name)
    except OSError as exc:
        raise _cannot(name, exc) from None
    if (kind := _kind(before.st_mode)) is not None:
        raise _not_regular(name, kind, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(name, flags)
    except OSError as exc:
        raise _cannot(name, exc) from None
    if (kind := _kind(os.fstat(fd).st_mode)) is not None:
        os.close(fd)
        raise _not_regular(name, kind, what)
    return fd


def read_bytes(path: str | os.PathLike[str], what: str, limit: int | None = None) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` (default: ``LIMITS[what]``).

    ``what`` names the kind of file in the refusal (``"profile"``, ``"state file"``, ...). Raises
    :class:`FileReadError`: no such file, not readable, not a regular file, or bigger than the bound.
    """
    name = os.fspath(path)
    bound = LIMITS[what] if limit is None else limit
    fd = _open_regular(name, what)
    try:
        info = os.fstat(fd)
        too_big = FileReadError(name, f"bigger than {_size(bound)}, too big for a {what}; is it the right file?")
        if info.st_size > bound:
            raise too_big
        chunks: list[bytes] = []
        total = 0
        while True:
            try:
                chunk = os.read(fd, min(_CHUNK, bound + 1 - total))
            except BlockingIOError:  # not for a regular file; kept so that nothing here can block
                break
            except OSError as exc:
                raise FileReadError(name, f"cannot read: {exc.strerror or exc}") from None
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > bound:  # it grew while being read
                raise too_big
        return b"".join(chunks)
    finally:
        os.close(fd)


def open_stream(path: str | os.PathLike[str], what: str) -> io.BufferedReader:
    """The regular file ``path`` open for reading a little at a time (a frame log of any length), by the same
    rules as :func:`read_bytes`: never a FIFO (whose open would wait for a writer) or a device, looked at again
    once open. Raises :class:`FileReadError`."""
    fd = _open_regular(os.fspath(path), what)
    os.set_blocking(fd, True)
    return io.BufferedReader(io.FileIO(fd, "rb", closefd=True))


def read_text(path: str | os.PathLike[str], what: str, limit: int | None = None, *, named: str = "") -> str:
    """:func:`read_bytes` as UTF-8 text; text that is not UTF-8 is refused naming the first bad byte (``named``:
    what the file is not, then, such as ``"TOML profile"``; ``what`` by default)."""
    data = read_bytes(path, what, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FileReadError(os.fspath(path), f"not a {named or what}: not UTF-8 text (byte {exc.start})") from None


def json_depth(text: str) -> int:
    """The deepest nesting of ``[`` and ``{`` in a JSON text, strings skipped; no recursion. A text with no more
    than :data:`MAX_DEPTH` brackets is not scanned: their count is given, a bound that is within the limit
    (a frame log has a line or millions, each with one bracket)."""
    brackets = text.count("[") + text.count("{")
    if brackets <= MAX_DEPTH:
        return brackets
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def toml_depth(text: str) -> int:
    """The deepest nesting of arrays and inline tables in a TOML text (strings and comments skipped), or
    of a table header's or a key's dotted parts, whichever is deeper; no recursion. A text with no more than
    :data:`MAX_DEPTH` brackets and dots is not scanned: their count is given, a bound within the limit."""
    brackets = text.count("[") + text.count("{")
    if brackets <= MAX_DEPTH and text.count(".") <= MAX_DEPTH:
        return max(brackets, text.count("."))
    deepest = depth = dots = 0
    i, n = 0, len(text)
    while i < n:
        char = text[i]
        if char in "\"'":
            triple = text.startswith(char * 3, i)
            quote = char * 3 if triple else char
            i += len(quote)
            while i < n and not text.startswith(quote, i):
                if char == '"' and text[i] == "\\":
                    i += 1
                elif not triple and text[i] == "\n":
                    break
                i += 1
            i += len(quote)
            continue
        if char == "#":
            end = text.find("\n", i)
            i = n if end < 0 else end
            continue
        if char in "[{":
            depth += 1
        elif char in "]}":
            depth = max(0, depth - 1)
        elif char == ".":
            dots += 1  # a dotted key or header nests one level a dot (a number's dot is counted too: harmless)
        elif char in "\n=,":
            dots = 0
        deepest = max(deepest, depth, dots)
        i += 1
    return deepest


def too_deep(path: str | Path, what: str) -> FileReadError:
    """The refusal of a document nested deeper than :data:`MAX_DEPTH`."""
    return FileReadError(str(path), f"not a {what}: nested deeper than {MAX_DEPTH} levels")

"""``c20sim dashboard``: start ``c20sim serve`` in a process of its own and attach to it, or attach to one running.

The process that owns the wire owns the simulator and does nothing else: the
dashboard is a client of its control API, so a redraw never holds a reply.
``c20sim dashboard [serve's options]`` starts ``python -m c20sim serve`` with
those options, ``--control 127.0.0.1:0`` and a ready file in a temporary
directory, waits for the ready file, attaches, and stops the server (SIGTERM,
then waits for it) when the dashboard closes. The dashboard then lowers its own
scheduling priority (``nice`` 10): on a busy machine the server gets the CPU
first. ``--attach ready.json`` or ``--attach http://HOST:PORT`` attaches to a server already running, which is
left running when the dashboard closes. A server that cannot start is its own
one line of error and exit code 2.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..control.client import TOKEN_ENV, ControlClient, RemoteOps, attach_target
from ..transport.rows import rows
from ..wire.errors import C20SimError

__all__ = ["SERVE_OPTIONS", "run_dashboard", "serve_argv", "serve_options", "served"]

#: Seconds a started server may take to write its ready file, and to stop.
START_TIMEOUT = 30.0
STOP_TIMEOUT = 10.0

#: serve's own options that the dashboard passes on, beside the transports' (:func:`serve_options`): argparse
#: dest -> the option.
SERVE_OPTIONS = {
    "baud": "--baud",
    "parity": "--parity",
    "stopbits": "--stopbits",
    "line_timing": "--line-timing",
    "bus_timing": "--bus-timing",
    "max_connections": "--max-connections",
    "gateway_timeout": "--gateway-timeout",
    "control": "--control",
    "profile": "--profile",
    "drives": "--drives",
    "clock": "--clock",
    "speed": "--speed",
    "state": "--state",
    "seed": "--seed",
    "log_frames": "--log-frames",
    "log_frames_max_mb": "--log-frames-max-mb",
    "metrics": "--metrics",
    "audit": "--no-audit",
    "ready_file": "--ready-file",
}
#: Options that say which server to attach to (the rest are the server's own business).
ATTACH_OPTIONS = frozenset({"control_token"})


def serve_options() -> dict[str, str]:
    """Every option the dashboard passes on to the serve it starts: each transport's (one row each,
    c20sim.transport.rows), then serve's own (:data:`SERVE_OPTIONS`); argparse dest -> the option."""
    transports = {option.dest: option.flag for row in rows() for option in row.options}
    return {**transports, **SERVE_OPTIONS}


def serve_argv(args: argparse.Namespace, ready_file: str) -> list[str]:
    """The ``c20sim serve`` command line for the dashboard's options (a control API on loopback if none given)."""
    argv = [sys.executable, "-m", "c20sim", "serve"]
    for dest, option in serve_options().items():
        value = getattr(args, dest, None)
        if dest == "control" and value is None:
            value = "127.0.0.1:0"
        if dest == "ready_file":
            value = ready_file
        if dest in ("bus_timing", "audit"):
            if value is False:  # on is serve's default: only off needs saying
                argv.append("--no-bus-timing" if dest == "bus_timing" else option)
            continue
        if value is None or value is False:
            continue
        argv += [option] if value is True else [option, str(value)]
    return argv


def _server_error(stderr: Path, code: int | None) -> str:
    lines = [line for line in stderr.read_text(errors="replace").splitlines() if line.strip()]
    if not lines:
        return f"the server (c20sim serve) ended with exit code {code} before it was ready"
    return lines[-1].removeprefix("c20sim: ")


@contextlib.contextmanager
def served(args: argparse.Namespace) -> Iterator[tuple[str, str | None]]:
    """Start ``c20sim serve`` for ``args``; yields (control URL, token) once ready; stops it on the way out."""
    with tempfile.TemporaryDirectory(prefix="c20sim-") as tmp:
        ready = Path(args.ready_file) if args.ready_file else Path(tmp) / "ready.json"
        ready.unlink(missing_ok=True)
        stderr_path = Path(tmp) / "serve.stderr"
        with stderr_path.open("w") as stderr:
            env = {k: v for k, v in os.environ.items() if k != TOKEN_ENV}
            if args.control_token is not None:
                env[TOKEN_ENV] = args.control_token  # not on the command line, where every local user sees it
            process = subprocess.Popen(
                serve_argv(args, str(ready)),
                env=env,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=stderr,
                start_new_session=True,  # the terminal's Ctrl+C goes to the dashboard, which stops the server itself
            )

        def cleanup() -> None:
            stop(process)
            if args.ready_file:
                ready.unlink(missing_ok=True)

        def hung_up() -> None:
            cleanup()
            shutil.rmtree(tmp, ignore_errors=True)  # the process ends at once: nothing else will

        hangup = _stop_on_hangup(hung_up)
        try:
            deadline = time.monotonic() + START_TIMEOUT
            while not ready.exists():
                if process.poll() is not None:
                    message = _server_error(stderr_path, process.returncode)
                    stderr_path.write_text("")  # said once, as the error
                    raise C20SimError(message)
                if time.monotonic() > deadline:
                    raise C20SimError(f"the server (c20sim serve) was not ready within {START_TIMEOUT:g} s")
                time.sleep(0.02)
            yield attach_target(str(ready), args.control_token)
        finally:
            hangup()
            cleanup()
            for line in stderr_path.read_text(errors="replace").splitlines():
                print(line, file=sys.stderr)  # what the server said (warnings, a bug's traceback), after the screen


#: What the screen switched on, switched off: mouse tracking, focus events, bracketed paste, the alternate screen,
#: and the cursor shown again (the sequences Textual's driver writes on a clean exit).
RESTORE_TERMINAL = b"\x1b[?1000l\x1b[?1003l\x1b[?1015l\x1b[?1006l\x1b[?1004l\x1b[?2004l\x1b[?1049l\x1b[?25h"


def _stop_on_hangup(cleanup: Callable[[], None]) -> Callable[[], None]:
    """Until the returned function is called: on SIGHUP (the terminal closed) ``cleanup`` (stop the server), give
    the terminal back if it is still there, then end at once (status 0: an expected way to close).

    A screen with no terminal cannot be closed cleanly (its writes fail, its shutdown can wait forever), and
    the server is in a session of its own, so the hangup would not reach it: it is stopped here. The terminal
    is restored by hand, best effort, for a SIGHUP whose terminal lives on (kill -HUP, a multiplexer).
    """
    if not hasattr(signal, "SIGHUP"):
        return lambda: None
    saved = _terminal_modes()

    def hung_up(signum: int, _frame: object) -> None:
        cleanup()
        _restore_terminal(saved)
        os._exit(0)

    previous = signal.signal(signal.SIGHUP, hung_up)

    def restore() -> None:
        signal.signal(signal.SIGHUP, previous)

    return restore


def _terminal_modes() -> list[Any] | None:
    """The terminal's modes before the screen takes it (raw mode is the screen's), or None without one."""
    try:
        import termios
    except ImportError:  # not POSIX: no modes to keep
        return None
    try:
        return termios.tcgetattr(sys.stdin.fileno())
    except (termios.error, OSError, ValueError):  # not a terminal (a pipe, a test, the web)
        return None


def _restore_terminal(saved: list[Any] | None) -> None:
    """Write :data:`RESTORE_TERMINAL` and put the modes back, without waiting on a terminal that is gone."""
    with contextlib.suppress(OSError, ValueError):
        fd = sys.__stdout__.fileno() if sys.__stdout__ is not None else 1
        os.set_blocking(fd, False)
        os.write(fd, RESTORE_TERMINAL)
    if saved is not None:
        import termios  # it gave the saved modes: it imports

        with contextlib.suppress(termios.error, OSError, ValueError):
            termios.tcsetattr(sys.stdin.fileno(), termios.TCSANOW, saved)


def stop(process: subprocess.Popen[bytes]) -> None:
    """Stop a started server cleanly (SIGTERM, as serve expects), killing it only if it does not end in time."""
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGTERM)
    try:
        process.wait(STOP_TIMEOUT)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
        print(f"c20sim: the server did not stop within {STOP_TIMEOUT:g} s of SIGTERM; killed it", file=sys.stderr)


def check_attach_options(args: argparse.Namespace, parser_defaults: dict[str, object]) -> None:
    """--attach takes the server as it is: a serve option beside it is a mistake, said as one."""
    for dest, option in serve_options().items():
        if dest in ATTACH_OPTIONS:
            continue
        if getattr(args, dest, None) != parser_defaults.get(dest):
            raise C20SimError(
                f"--attach: {option} is the server's option; give it to the serve you attach to, "
                "or leave out --attach to start one"
            )


def run_dashboard(args: argparse.Namespace, parser_defaults: dict[str, object]) -> int:
    """``c20sim dashboard``: attach to ``--attach``, or to a serve started for the options."""
    with contextlib.ExitStack() as stack:
        if args.attach:
            check_attach_options(args, parser_defaults)
            url, token = attach_target(args.attach, args.control_token or os.environ.get(TOKEN_ENV) or None)
        else:
            url, token = stack.enter_context(served(args))
        return attach(url, token)
    raise AssertionError("unreachable")


#: How much lower the dashboard's scheduling priority is than the server's (Unix ``nice``): on a small, busy machine
#: the server gets the CPU first, and a redraw waits for a reply, never the other way round.
NICENESS = 10


def attach(url: str, token: str | None) -> int:
    """Run the dashboard on the control API at ``url`` until it is closed."""
    from .app import Dashboard  # textual loads only for the dashboard

    if hasattr(os, "nice"):  # after the server started: it keeps its own priority
        with contextlib.suppress(OSError):
            os.nice(NICENESS)
    client = ControlClient(url, token)
    try:
        remote = RemoteOps(client)
    except C20SimError as exc:
        raise C20SimError(f"cannot attach to {url}: {exc}") from None
    app = Dashboard(remote)
    app.run()
    if app.error is not None:
        raise app.error
    return app.return_code or 0

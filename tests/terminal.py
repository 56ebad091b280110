"""A real terminal for the tests: a program in a tmux pane of a set size, keys in, the screen out.

Every tmux call of the suite goes through here, so that the pane is the same wherever the suite is typed:

- the tmux server is the test's own (``-L``) and reads no configuration (``-f /dev/null``): a developer's
  ``~/.tmux.conf`` (another ``default-terminal``, ``remain-on-exit``, a ``default-command``) changes nothing;
- the server's environment has no ``COLUMNS`` or ``LINES``. The server keeps the environment it was started
  with and hands it to the pane, and a program in the pane (Textual, through ``shutil.get_terminal_size``) takes
  those variables before the pane's real size. A pytest run typed at a terminal has them: pytest imports GNU
  readline, which exports the terminal's size into the C environment (not ``os.environ``, so the test cannot see
  them, but every child inherits them). A dashboard in a 100x30 pane then drew a 200x50 screen into it, inside a
  developer's tmux window of that size, and no test found ``STOPPED`` on it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

TMUX = shutil.which("tmux")
NEEDS_TMUX = "tmux is not installed (apt-get install tmux); .ci/run installs it"

#: the variables a pane's program must not inherit (see the module's docstring)
SIZE_VARIABLES = ("COLUMNS", "LINES")


def wait_for(what: str, check: Callable[[], bool], timeout: float = 20.0, show: Callable[[], str] = str) -> None:
    """Poll ``check`` until it holds; on time out, fail saying what was awaited and what ``show`` gives."""
    deadline = time.monotonic() + timeout
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}\n{show()}"
        time.sleep(0.05)


def pane_environment() -> dict[str, str]:
    """The environment for the tmux server, and so for the pane: the test run's, less the terminal's size."""
    return {name: value for name, value in os.environ.items() if name not in SIZE_VARIABLES}


class Terminal:
    """One tmux server with one session and one pane, all named ``session``."""

    def __init__(self, session: str) -> None:
        self.session = session
        self.address = ("", 0)  #: the served RTU-over-TCP endpoint, where a test keeps it
        self.ready = Path()
        self.status_file = Path()

    def tmux(self, *args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
        """``tmux ARGS`` on this terminal's own server; never the developer's terminal on stdin."""
        return subprocess.run(
            [TMUX or "tmux", "-L", self.session, "-f", os.devnull, *args],
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            check=check,
            env=pane_environment(),
        )

    def screen(self) -> str:
        return self.tmux("capture-pane", "-p", "-t", self.session, check=False).stdout

    def keys(self, *keys: str) -> None:
        self.tmux("send-keys", "-t", self.session, *keys)

    def wait_for_text(self, text: str) -> str:
        wait_for(repr(text), lambda: text in self.screen(), show=self.screen)
        return self.screen()

    def pane(self, fmt: str) -> str:
        """A tmux format of the session's pane, such as ``#{pane_dead}``."""
        return self.tmux("display-message", "-p", "-t", self.session, fmt).stdout.strip()

    def run(self, command: str, cwd: Path, status_file: Path) -> None:
        """Run ``command`` in the pane; its exit status goes to ``status_file`` (tmux's own pane_dead_status is
        sometimes never filled in once the pane is dead, so the shell writes it)."""
        self.status_file = status_file
        wrapped = f"{command}; echo $? > {status_file}"
        self.tmux("respawn-pane", "-k", "-t", self.session, "-c", str(cwd), wrapped)

    def exit_status(self) -> str:
        """Wait for the program in the pane to end; how it ended: ``status N`` or ``signal N``."""
        path = self.status_file
        wait_for(
            "the program's exit status", lambda: path.exists() and path.read_text().endswith("\n"), show=self.screen
        )
        code = int(path.read_text())
        return f"signal {code - 128}" if code > 128 else f"status {code}"

    def kill(self) -> None:
        """End the session (its programs get SIGHUP, as when a terminal window is closed)."""
        self.tmux("kill-session", "-t", self.session, check=False)


@contextlib.contextmanager
def terminal_running(
    status_file: Path, command: str, *, size: tuple[int, int] = (100, 30), cwd: Path | None = None
) -> Iterator[Terminal]:
    """``command`` in a tmux pane of ``size`` (columns, rows) that is kept when it ends, its exit status written to
    ``status_file``."""
    # a tmux server of its own: a session killed by one test takes a shared server down while the next test's
    # new-session may be connecting to it (seen once in CI: new-session exited 1)
    terminal = Terminal(f"c20sim-{uuid.uuid4().hex[:8]}")
    cwd = cwd or Path(__file__).parents[1]
    # A shell first, so the pane is kept when the program ends (remain-on-exit) before the program starts.
    width, height = size
    terminal.tmux("new-session", "-d", "-s", terminal.session, "-x", str(width), "-y", str(height), "-c", str(cwd))
    try:
        terminal.tmux("set-option", "-w", "-t", terminal.session, "remain-on-exit", "on")
        terminal.run(command, cwd, status_file)
        yield terminal
    finally:
        terminal.kill()

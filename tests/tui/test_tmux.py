"""The dashboard in a real terminal: tmux runs ``python -m c20sim dashboard``, keys go in, the screen and the wire are read."""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymodbus import FramerType
from pymodbus.client import ModbusTcpClient

from tests.terminal import NEEDS_TMUX, TMUX, Terminal, terminal_running, wait_for

pytestmark = pytest.mark.skipif(TMUX is None, reason=NEEDS_TMUX)


@pytest.fixture
def dashboard(tmp_path: Path) -> Iterator[tuple[Terminal, ModbusTcpClient]]:
    ready = tmp_path / "ready.json"
    command = f"{sys.executable} -m c20sim dashboard --tcp 127.0.0.1:0 --clock virtual --ready-file {ready}"
    with terminal_running(tmp_path / "status", command) as terminal:
        wait_for("the ready file", ready.exists)
        host, port = json.loads(ready.read_text())["tcp"].rsplit(":", 1)
        client = ModbusTcpClient(host, port=int(port), framer=FramerType.RTU, timeout=1, retries=0)
        assert client.connect()
        terminal.address = (host, int(port))
        terminal.ready = ready
        try:
            yield terminal, client
        finally:
            client.close()


def read(client: ModbusTcpClient, address: int) -> int:
    response = client.read_holding_registers(address, count=1, device_id=1)
    assert not response.isError(), response
    return int(response.registers[0])


def test_dashboard_in_tmux(dashboard: tuple[Terminal, ModbusTcpClient]) -> None:
    terminal, client = dashboard
    terminal.wait_for_text("f Fwd")
    screen = terminal.wait_for_text("STOPPED")
    assert "connect: RTU/TCP 127.0.0.1:" in screen
    # A master runs the drive; the dashboard shows it once time moves on (t: +1 s).
    assert not client.write_register(0x2001, 1500, device_id=1).isError()
    assert not client.write_register(0x2000, 1, device_id=1).isError()
    terminal.keys("t")
    screen = terminal.wait_for_text("FORWARD RUNNING")
    assert "1500 rpm of 1500" in screen
    # The bench breaks it: device faults, undervoltage, time.
    terminal.keys("F4")
    terminal.wait_for_text("u undervoltage")
    terminal.keys("u")
    terminal.wait_for_text("supply 10 V")  # half the 20 V trip level
    terminal.keys("t")
    screen = terminal.wait_for_text("0x0A UV: bus undervoltage")
    assert read(client, 0x2102) == 0x000A
    assert read(client, 0x2100) == 4
    terminal.keys("q")
    assert terminal.exit_status() == "status 0", terminal.screen()
    # The serve the dashboard started is stopped with it: its port is closed, its ready file gone.
    with socket.socket() as probe:
        assert probe.connect_ex(terminal.address) != 0, "the server the dashboard started still listens"
    assert not terminal.ready.exists()


@pytest.mark.parametrize("how", ["kill-session", "SIGTERM"])
def test_a_dashboard_ended_from_outside_stops_its_server(dashboard: tuple[Terminal, ModbusTcpClient], how: str) -> None:
    """The terminal closed (tmux kills the session: SIGHUP) or a kill (SIGTERM): the dashboard closes as q does
    and stops the serve it started; none is left running on its own."""
    terminal, _ = dashboard
    terminal.wait_for_text("STOPPED")
    if how == "SIGTERM":
        os.kill(int(terminal.pane("#{pane_pid}")), signal.SIGTERM)  # the shell: it passes nothing on
        os.kill(_dashboard_pid(terminal.ready), signal.SIGTERM)
    else:
        terminal.kill()

    def port_closed() -> bool:
        with socket.socket() as probe:
            return probe.connect_ex(terminal.address) != 0

    wait_for("the started server to stop", port_closed)
    wait_for("its ready file to go", lambda: not terminal.ready.exists())


def _dashboard_pid(ready: Path) -> int:
    """The dashboard's process: the one whose command line names the ready file and is not the serve."""
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                args = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if str(ready).encode() in args and b"serve" not in args and b"c20sim" in args:
                return int(entry.name)
    raise AssertionError("no dashboard process")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_gives_the_terminal_back(tmp_path: Path, sig: signal.Signals) -> None:
    """kill -TERM, or the terminal window closed (HUP): the alternate screen and mouse tracking are switched
    off, the link and the ready file are removed, exit status 0."""
    ready, link = tmp_path / "ready.json", tmp_path / "ttyC20"
    command = f"{sys.executable} -m c20sim --pty --link {link} --tcp 127.0.0.1:0 --clock virtual --ready-file {ready}"
    with terminal_running(tmp_path / "status", command) as terminal:
        wait_for("the ready file", ready.exists)
        terminal.wait_for_text("STOPPED")
        assert link.is_symlink()
        assert terminal.pane("#{alternate_on} #{mouse_any_flag}") == "1 1"
        os.kill(_dashboard_pid(ready), sig)
        assert terminal.exit_status() == "status 0", terminal.screen()
        assert terminal.pane("#{alternate_on} #{mouse_any_flag}") == "0 0"
        wait_for("the link to go", lambda: not link.is_symlink())
        wait_for("the ready file to go", lambda: not ready.exists())


def test_a_burst_of_keys_in_a_120_column_pane(tmp_path: Path) -> None:
    """A new user's pane: 120x40, a realtime clock paused from the keyboard, keys sent in one send-keys call.

    The title shows the addresses, the clock's state and the profile whole; the footer the realtime clock's keys;
    ``F3 Home C-k 36 Enter F8`` in one burst sets the supply to 36 V and ends on the Drill tab (it ended blank)."""
    ready = tmp_path / "ready.json"
    command = f"{sys.executable} -m c20sim dashboard --tcp 127.0.0.1:0 --modbus-tcp 127.0.0.1:0 --ready-file {ready}"
    with terminal_running(tmp_path / "status", command, size=(120, 40)) as terminal:
        wait_for("the ready file", ready.exists)
        where = json.loads(ready.read_text())
        terminal.wait_for_text("STOPPED")
        terminal.keys("p")
        screen = terminal.wait_for_text("realtime paused │ c20-400hr")
        title = screen.splitlines()[0]
        assert f"connect: RTU/TCP {where['tcp']} · Modbus TCP {where['modbus_tcp']} │ t " in title, title

        def footer() -> str:  # the screen's last line drawn (a capture may come mid-draw: wait for it)
            lines = [line for line in terminal.screen().splitlines() if line.strip()]
            return " ".join(lines[-1].split()) if lines else ""

        keys = "f Fwd r Rev s Stop j Jog x Reset p Pause < Slower > Faster ? Help q Quit"
        wait_for("the realtime clock's footer", lambda: footer().startswith(keys), show=footer)
        terminal.keys("F3", "Home", "C-k", "3", "6", "Enter", "F8")
        screen = terminal.wait_for_text("supply 36 V")
        terminal.keys("F1")  # the usual help key: tmux sends it as the terminal does
        terminal.wait_for_text("Keypad (works as on the drive)")
        terminal.keys("F1")
        wait_for("the help closed", lambda: "Keypad (works as on the drive)" not in terminal.screen())
        terminal.keys("q")
        assert terminal.exit_status() == "status 0"

"""The README's first minutes, verbatim: its shell lines that talk to the simulator, run against a served drive.

The lines are read from README.md itself (its ```sh blocks), so a line that changes is the line tested. Set-up
command 1's options are served (``c20sim serve`` with the options the dashboard would pass it), and the master
lines are run as written, with only the documented fixed addresses (the /tmp/ttyC20 link, ports 5020, 1502 and
8020, ready.json) moved to this test's own, so that parallel runs and a simulator already running do not meet.
mbpoll is the independent master.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.conftest import DEFAULT_PORT_TAKEN, wait_for_ready_file
from tests.terminal import TMUX, terminal_running, wait_for

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
MBPOLL = shutil.which("mbpoll")


def shell_blocks(text: str) -> list[list[str]]:
    """The lines of every ```sh block, comments and blank lines left out (a line's trailing comment kept)."""
    blocks = re.findall(r"^```sh\n(.*?)^```", text, flags=re.M | re.S)
    return [[line for line in block.splitlines() if line.strip() and not line.startswith("#")] for block in blocks]


def lines_starting(prefix: str) -> list[str]:
    return [line for block in shell_blocks(README) for line in block if line.startswith(prefix)]


def setup_options() -> list[str]:
    """Set-up command 1's options to c20sim (after ``.venv/bin/c20sim``)."""
    [command] = [line for line in lines_starting("python3 -m venv .venv") if ".venv/bin/c20sim" in line]
    return shlex.split(command.split(".venv/bin/c20sim", 1)[1])


class Place:
    """This test's own stand-ins for the README's fixed addresses."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.link = folder / "ttyC20"
        self.ports: dict[str, str] = {}

    def local(self, line: str) -> str:
        line = line.replace("/tmp/ttyC20", str(self.link)).replace("ready.json", str(self.folder / "ready.json"))
        for port in ("5020", "5021", "1502", "8020"):
            real = self.ports.get(port, "0")
            line = line.replace(f"127.0.0.1:{port}", f"127.0.0.1:{real}").replace(f"-p {port} ", f"-p {real} ")
        return line


@pytest.fixture
def place() -> Iterator[Place]:
    # a short folder: the link's path must fit the dashboard's title bar beside the two TCP addresses
    folder = Path(tempfile.mkdtemp(prefix="c20-", dir="/tmp"))
    yield Place(folder)
    shutil.rmtree(folder, ignore_errors=True)


def test_set_up_command_1_opens_what_the_master_lines_use() -> None:
    """Set-up command 1 opens a fixed pty link and both TCP ports; every master line uses one of them."""
    assert setup_options() == ["--link", "/tmp/ttyC20", "--tcp", "127.0.0.1:5020", "--modbus-tcp", "127.0.0.1:1502"]
    masters = lines_starting("mbpoll")
    assert len(masters) >= 4, masters
    for line in masters:
        words = shlex.split(line, comments=True)
        mode = words[words.index("-m") + 1]
        if mode == "rtu":
            assert "/tmp/ttyC20" in words, line
        else:
            assert (mode, words[words.index("-p") + 1], "127.0.0.1" in words) == ("tcp", "1502", True), line


def run_master_lines(place: Place, runs: Callable[[], None]) -> None:
    """Every mbpoll line of the README in order, as written (addresses moved to ``place``'s); each must succeed, and
    ``runs`` checks that the drive runs after the forward-run line."""
    seen: list[str] = []
    for line in lines_starting("mbpoll"):
        done = subprocess.run(["bash", "-c", place.local(line)], capture_output=True, text=True, timeout=30)
        assert done.returncode == 0, f"{line}\n{done.stdout}{done.stderr}"
        writes = re.search(r"Written \d+ references?", done.stdout)
        read = re.search(r"^\[(\d+)\]:\s+(-?\d+)", done.stdout, flags=re.M)
        assert writes or read, f"{line}\n{done.stdout}{done.stderr}"
        seen.append("written" if writes else f"read {read.group(1) if read else ''}")
        if " 0x2000 " in line and line.split("#")[0].split()[-1] == "1":
            runs()  # forward run: the drive runs at once
    reads = [what for what in seen if what.startswith("read")]
    assert reads == ["read 12294"] * len(reads) and len(reads) >= 2  # 3006H, the speed, over RTU and Modbus TCP


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll is not installed (apt-get install mbpoll); .ci/run installs it")
def test_the_readme_master_lines_drive_the_set_up_drive(place: Place, procs: list[subprocess.Popen[str]]) -> None:
    """Set-up command 1's simulator, then every mbpoll line of the README in order, as written."""
    ready = place.folder / "served.json"
    argv = [sys.executable, "-m", "c20sim", "serve", *shlex.split(place.local(shlex.join(setup_options())))]
    proc = subprocess.Popen(
        [*argv, "--control", "127.0.0.1:0", "--ready-file", str(ready)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    procs.append(proc)
    info = wait_for_ready_file(ready, proc)
    assert info["pty"] == str(place.link)
    place.ports = {"5020": info["tcp"].rsplit(":", 1)[1], "1502": info["modbus_tcp"].rsplit(":", 1)[1]}

    def state() -> dict[str, object]:
        with urllib.request.urlopen(info["control"] + "/drives/1", timeout=10) as response:
            data: dict[str, object] = json.load(response)
        return data

    def runs() -> None:
        assert state()["state"] == "forward", state()

    run_master_lines(place, runs)
    assert state()["set_speed_rpm"] == 1500
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert (proc.returncode, err) == (0, "")


@pytest.mark.parametrize("line", lines_starting("c20sim serve"))
def test_every_serve_line_of_the_readme_serves(line: str, place: Place, procs: list[subprocess.Popen[str]]) -> None:
    """Each ``c20sim serve`` line of the README opens what it names, and only that (the ready file), each endpoint
    answers a master for each drive, the clock is the one asked for (a virtual one moved by ``ctl advance`` as the
    README says), and it stops cleanly with nothing on stderr (a serial port that is not here: one line)."""
    words = shlex.split(place.local(line), comments=True)
    assert words[:2] == ["c20sim", "serve"]
    if "--serial" in words and not os.path.exists(words[words.index("--serial") + 1]):
        done = subprocess.run([sys.executable, "-m", "c20sim", *words[1:]], capture_output=True, text=True, timeout=60)
        assert (done.returncode, done.stdout) == (2, "")
        assert done.stderr.startswith("c20sim: --serial ") and done.stderr.count("\n") == 1, done.stderr
        return
    if "--ready-file" not in words:
        words += ["--ready-file", str(place.folder / "ready.json")]
    ready = Path(words[words.index("--ready-file") + 1])
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", *words[1:]], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    procs.append(proc)
    info = wait_for_ready_file(ready, proc)
    asked = {"pty": "--pty" in words, "tcp": "--tcp" in words, "modbus_tcp": "--modbus-tcp" in words}
    asked["control"] = "--control" in words
    assert {key for key in info if key != "token"} == {key for key, on in asked.items() if on}, (line, info)
    drives = [int(d) for d in words[words.index("--drives") + 1].split(",")] if "--drives" in words else [1]
    for drive in drives:  # every endpoint the line opens answers a master, for every drive it serves
        for key in ("pty", "tcp", "modbus_tcp"):
            if key in info:
                assert status_over(key, info[key], drive) == 3, (line, key, drive)  # stopped
    clock = words[words.index("--clock") + 1] if "--clock" in words else "realtime"
    if "control" in info:
        time_before = get_json(info["control"] + "/time")
        assert time_before["clock"] == clock
        if clock == "virtual":  # the README's way to move it
            done = subprocess.run(
                [sys.executable, "-m", "c20sim", "ctl", "--ready-file", str(ready), "advance", "1"],
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert done.returncode == 0, done.stderr
            assert get_json(info["control"] + "/time")["t"] == pytest.approx(time_before["t"] + 1.0)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=20)
    assert (proc.returncode, err) == (0, ""), line
    assert out.startswith(f"c20sim ready: c20-400hr, drives {','.join(map(str, drives))}, {clock} clock; "), out
    assert not ready.exists()


def get_json(url: str) -> dict[str, Any]:
    with urllib.request.urlopen(url, timeout=10) as response:
        data: dict[str, Any] = json.load(response)
    return data


def status_over(kind: str, where: str, drive: int) -> int:
    """2100H (status word 1) of ``drive``, read by pymodbus over the endpoint ``where`` of ``kind``."""
    from pymodbus import FramerType
    from pymodbus.client import ModbusSerialClient, ModbusTcpClient

    client: ModbusSerialClient | ModbusTcpClient
    if kind == "pty":
        client = ModbusSerialClient(where, framer=FramerType.RTU, baudrate=19200, timeout=2, retries=0)
    else:
        host, port = where.rsplit(":", 1)
        framer = FramerType.RTU if kind == "tcp" else FramerType.SOCKET
        client = ModbusTcpClient(host, port=int(port), framer=framer, timeout=2, retries=0)
    assert client.connect(), where
    try:
        response = client.read_holding_registers(0x2100, count=1, device_id=drive)
        assert not response.isError(), response
        return int(response.registers[0])
    finally:
        client.close()


@pytest.mark.parametrize("line", [*lines_starting("c20sim decode"), *lines_starting("c20sim profiles")])
def test_the_tours_decode_and_profiles_lines(line: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", *shlex.split(line, comments=True)[1:]],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (done.returncode, done.stderr) == (0, ""), line
    assert done.stdout, line


def test_the_decode_example_prints_what_the_readme_shows() -> None:
    [example] = re.findall(r"^```\n\$ (c20sim decode [^\n]*)\n(.*?)^```", README, flags=re.M | re.S)
    command, shown = example
    done = subprocess.run(
        [sys.executable, "-m", "c20sim", *shlex.split(command)[1:]], capture_output=True, text=True, timeout=60
    )
    assert done.stdout == shown
    assert done.returncode == 1  # a broken frame


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
    return port


class Pane:
    """A program in a tmux pane of 240x40 that is kept when the program ends, its exit status written to a file."""

    def __init__(self, command: str, folder: Path) -> None:
        self.status = folder / f"pane-{uuid.uuid4().hex[:8]}.status"
        self._stack = contextlib.ExitStack()
        self.terminal = self._stack.enter_context(terminal_running(self.status, command, size=(240, 40), cwd=ROOT))

    def screen(self) -> str:
        return self.terminal.screen()

    def wait_for(self, what: str, check: Callable[[str], bool]) -> None:
        wait_for(what, lambda: check(self.screen()), show=self.screen)

    def dashboard(self, title: str) -> None:
        """Wait for the dashboard, its title bar showing ``title``."""
        self.wait_for(f"the title bar: {title}", lambda screen: title in screen)

    def quit(self) -> str:
        """Press q; the program's exit status."""
        self.terminal.keys("q")
        wait_for("the program's exit", lambda: self.status.exists() and self.status.read_text().endswith("\n"))
        return self.status.read_text().strip()

    def close(self) -> None:
        self._stack.close()


def python_c20sim(line: str) -> str:
    """A README command line with ``c20sim`` (or ``.venv/bin/c20sim``) run by this interpreter."""
    head, _, rest = line.partition("c20sim")
    assert head in ("", ".venv/bin/"), line
    return f"{shlex.quote(sys.executable)} -m c20sim{rest}"


@pytest.mark.skipif(MBPOLL is None or TMUX is None, reason="needs mbpoll and tmux (.ci/run installs them)")
def test_set_up_command_1_in_a_terminal_then_the_master_lines(place: Place) -> None:
    """Set-up command 1's dashboard in a real terminal: its title bar shows where to connect, the README's master
    lines run the drive it shows, and ``q`` closes it with the simulator (the link removed)."""
    place.ports = {"5020": str(free_port()), "1502": str(free_port())}
    [command] = [line for line in lines_starting("python3 -m venv .venv") if ".venv/bin/c20sim" in line]
    pane = Pane(place.local(python_c20sim(command.split(" && ")[-1])), place.folder)
    try:
        pane.dashboard(
            f"connect: pty {place.link} · RTU/TCP 127.0.0.1:{place.ports['5020']} · "
            f"Modbus TCP 127.0.0.1:{place.ports['1502']} │"
        )
        pane.wait_for("the drive stopped", lambda screen: "STOPPED" in screen)

        def runs() -> None:
            pane.wait_for("the drive running on the dashboard", lambda screen: "FORWARD RUNNING" in screen)

        run_master_lines(place, runs)
        pane.wait_for("the drive stopping on the dashboard", lambda screen: "FORWARD RUNNING" not in screen)
        assert pane.quit() == "0"
        assert not os.path.lexists(place.link)
    finally:
        pane.close()


def port_free(port: int) -> bool:
    with socket.socket() as probe:
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


TOUR_DASHBOARDS = [
    line
    for line in lines_starting("c20sim")
    if (words := shlex.split(line, comments=True)) == ["c20sim"] or words[1].startswith("-")
]


@pytest.mark.serial  # bare ``c20sim`` takes the default ports: no other test may hold them meanwhile
@pytest.mark.skipif(TMUX is None, reason="needs tmux (.ci/run installs it)")
@pytest.mark.parametrize("line", TOUR_DASHBOARDS)
def test_the_tours_dashboard_lines(line: str, place: Place) -> None:
    """``c20sim`` and ``c20sim --link ...`` as the tour gives them: the dashboard shows where to connect; q closes it.
    Bare ``c20sim`` takes the fixed default ports, so it is run only where they are free."""
    words = shlex.split(line, comments=True)
    if words == ["c20sim"]:
        if not (port_free(5020) and port_free(1502)):
            pytest.skip(f"{DEFAULT_PORT_TAKEN}: 127.0.0.1:5020 or 127.0.0.1:1502 (another simulator?)")
        title = "· RTU/TCP 127.0.0.1:5020 · Modbus TCP 127.0.0.1:1502 │"
    else:
        place.ports = {"5020": str(free_port())}
        title = f"connect: pty {place.link} · RTU/TCP 127.0.0.1:{place.ports['5020']} │"
    pane = Pane(place.local(python_c20sim(line.split("#")[0].strip())), place.folder)
    try:
        pane.dashboard(title)
        if words == ["c20sim"]:
            assert "connect: pty /dev/pts/" in pane.screen()
        assert pane.quit() == "0"
    finally:
        pane.close()


@pytest.mark.skipif(TMUX is None, reason="needs tmux (.ci/run installs it)")
def test_the_tours_attach_lines(place: Place, procs: list[subprocess.Popen[str]]) -> None:
    """The tour's first serve line, then its ``dashboard --attach ready.json`` and ``web --attach ready.json`` on it:
    the dashboard shows the serve's endpoints and leaves the serve running; the page answers."""
    [serve_line] = [line for line in lines_starting("c20sim serve --pty --link")]
    words = shlex.split(place.local(serve_line), comments=True)
    proc = subprocess.Popen([sys.executable, "-m", *words], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    procs.append(proc)
    info = wait_for_ready_file(place.folder / "ready.json", proc)
    [attach] = lines_starting("c20sim dashboard --attach ready.json")
    pane = Pane(place.local(python_c20sim(attach.split("#")[0].strip())), place.folder)
    try:
        pane.dashboard(f"connect: pty {place.link} · RTU/TCP {info['tcp']} │")
        assert pane.quit() == "0"
    finally:
        pane.close()
    assert proc.poll() is None  # an attached dashboard leaves the serve running
    [web_line] = lines_starting("c20sim web --attach ready.json")
    # the page on a port of its own, as the other fixed addresses are moved: its default, 8000, may be taken
    page = f"127.0.0.1:{free_port()}"
    web = subprocess.Popen(
        [sys.executable, "-m", *shlex.split(place.local(web_line), comments=True), "--web", page],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    procs.append(web)
    assert web.stdout is not None
    said = web.stdout.readline()
    assert said.startswith(f"c20sim web ready: http://{page}"), said + (web.stderr.read() if web.poll() else "")
    with urllib.request.urlopen(said.split()[3], timeout=10) as page:
        assert page.status == 200 and b"<html" in page.read().lower()
    web.send_signal(signal.SIGTERM)
    assert web.wait(20) == 0
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=20)
    assert (proc.returncode, err) == (0, "")

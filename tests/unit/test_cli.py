"""``c20sim decode`` and ``c20sim profiles``: what a SCADA developer reads."""

from __future__ import annotations

import itertools
import json
import signal
import socket
import struct
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from c20sim import cli
from c20sim.cli import main
from c20sim.drive.profile import load_profile
from c20sim.wire.protocol import SHEET_CHAR_BITS, transaction_time
from tests.conftest import wait_for_ready_file
from tests.plugin.test_bus_timing_setting import mbap, receive


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("frame", "words"),
    [
        ("01 06 20 00 00 01 43 CA", "request or echo: slave 1: write 2000H = 0001: forward run; CRC ok"),
        ("01 03 21 00 00 01 8E 36", "request: slave 1: read 2100H (status word 1); CRC ok"),
        ("01 06 00 0A 09 C4 AE 0B", "request or echo: slave 1: write F00.10 = 09C4: 25.00 Hz; CRC ok"),
        ("01 83 02 C0 F1", "exception: slave 1: exception 0x02 to read: illegal data address; CRC ok"),
        ("01 86 03 02 61", "exception: slave 1: exception 0x03 to write: illegal data value; CRC ok"),
        ("01 03 02 00 41 78 74", "response: slave 1: read reply: 0041; CRC ok"),
        ("00 06 20 01 0B B8 D5 59", "request or echo: broadcast: write 2001H = 0BB8: 3000 rpm; CRC ok"),
    ],
)
def test_decode_good_frames(capsys: pytest.CaptureFixture[str], frame: str, words: str) -> None:
    code, out, _ = run(capsys, "decode", frame)
    assert code == 0
    assert out == f"{frame}\n  {words}\n"


def test_decode_bad_crc_gives_the_expected_crc(capsys: pytest.CaptureFixture[str]) -> None:
    # The sheet's erratum: "enable function code writable" with the CRC of writing 0.
    code, out, _ = run(capsys, "decode", "01:06:20:0e:00:01:e3:c9")
    assert code == 1
    assert out.splitlines()[1] == (
        "  broken: slave 1: write 200EH = 0001: function codes writable; bad CRC: got E3 C9, expected 22 09"
    )


def test_decode_wrong_length(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "decode", "010321000001", "8E")
    assert code == 1
    assert "wrong length: 7 bytes; a 0x03 request has 8" in out


def test_decode_not_hex(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "decode", "01", "zz")
    assert (code, out) == (2, "")
    assert err == "c20sim: not hex bytes: '01 zz'; give a frame such as '01 06 20 00 00 01 43 CA'\n"


def test_profiles_list_and_show(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "profiles")
    assert code == 0
    assert "c20-400hr      48 V, 400 W class brushless DC drive, Modbus control (default)" in out
    assert "c20-2200hv" in out
    code, out, _ = run(capsys, "profiles", "show", "c20-400hr")
    assert code == 0
    assert (
        "  F00.10 000AH  keypad speed setting       50.00 Hz           0.00 Hz - 400.00 Hz    W/R            [sheet]"
        in out
    )
    assert (
        "  F00.01 0001H  run command channel        communication      0-4                    W/R  <-> 2006H [field]"
        in out
    )
    assert "  0x0A UV     bus undervoltage [sheet]" in out


def test_profiles_show_unknown(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "profiles", "show", "nope")
    assert code == 2
    assert err.startswith("c20sim: nope: no such profile; shipped profiles:")


def test_python_dash_m_runs_the_cli() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", "decode", "01 06 20 00 00 05 42 09"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0
    assert "write 2000H = 0005: stop; CRC ok" in result.stdout


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (
            ["serve", "--lnik", "/tmp/ttyC20"],
            "c20sim serve: unrecognized arguments: --lnik /tmp/ttyC20; did you mean --link? (see: c20sim serve --help)",
        ),
        (
            ["--modbus-tpc", "127.0.0.1:1502"],
            "c20sim dashboard: unrecognized arguments: --modbus-tpc 127.0.0.1:1502; did you mean --modbus-tcp? "
            "(see: c20sim dashboard --help)",
        ),
        (
            ["ctl", "frames", "--lats", "2"],
            "c20sim ctl frames: unrecognized arguments: --lats 2; did you mean --last? (see: c20sim ctl frames --help)",
        ),
        (
            ["serve", "--clock", "virtaul"],
            "c20sim serve: argument --clock: invalid choice: 'virtaul' (choose from 'realtime', 'virtual'); "
            "did you mean virtual? (see: c20sim serve --help)",
        ),
        (
            ["serv", "--pty"],
            "c20sim: argument COMMAND: invalid choice: 'serv' (choose from 'decode', 'audit', 'drill', 'profiles', 'serve', "
            "'dashboard', 'web', 'mcp', 'ctl', 'run-scenario', 'schema', 'plant', 'plant-check', 'record', "
            "'replay', 'exercise', 'fit', 'site'); "
            "did you mean serve? (see: c20sim --help)",
        ),
        (
            ["serve", "--zzzz"],
            "c20sim serve: unrecognized arguments: --zzzz (see: c20sim serve --help)",
        ),
    ],
)
def test_a_mistyped_option_is_one_line_naming_the_command_and_what_was_meant(argv: list[str], said: str) -> None:
    """One ``c20sim`` prefix, a "did you mean" for options as for values, and the help of the command it went to."""
    result = subprocess.run(
        [sys.executable, "-m", "c20sim", *argv], capture_output=True, text=True, check=False, timeout=60
    )
    assert (result.returncode, result.stdout, result.stderr) == (2, "", said + "\n")


def _four_at_once_at_1200_baud(tmp_path: Path, *options: str) -> list[float]:
    """A served drive at 1200 baud, four reads sent in one segment by a Modbus TCP master: the frame log's times of
    the four requests (from the control API), as ``c20sim serve`` with ``options`` put them on the line."""
    tmp_path.mkdir()
    ready = tmp_path / "ready.json"
    argv = ["serve", "--modbus-tcp", "127.0.0.1:0", "--control", "127.0.0.1:0", "--ready-file", str(ready), *options]
    proc = subprocess.Popen(
        [sys.executable, "-m", "c20sim", *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        info = wait_for_ready_file(ready, proc)
        host, port = info["modbus_tcp"].rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=10) as sock:
            sock.sendall(mbap(1, struct.pack(">BHH", 0x06, 0x2009, 0)))  # 1200 baud, after this reply
            assert receive(sock, 12) == mbap(1, struct.pack(">BHH", 0x06, 0x2009, 0))
            read = struct.pack(">BHH", 0x03, 0x2100, 1)
            sock.sendall(b"".join(mbap(n, read) for n in range(2, 6)))
            assert len(receive(sock, 44)) == 44
        with urllib.request.urlopen(info["control"] + "/frames", timeout=10) as response:
            frames = json.load(response)["frames"]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=20)
    reads = [f for f in frames if f["dir"] == "rx" and f["kind"] == "request" and f["rtu"].startswith("01 03")]
    assert len(reads) == 4
    return [float(f["t"]) for f in reads]


def test_serve_holds_the_line_for_its_rs485_time_unless_told_not_to(tmp_path: Path) -> None:
    """Judged on the wire, on the serve's own loop (uvloop where installed): each of four requests in flight
    starts on the line no earlier than the last transaction's end (its request, the drive's turnaround, its
    reply, each frame with its t3.5), unless --no-bus-timing, when all four are served as they came."""
    turnaround = load_profile().protocol.turnaround_ms / 1000
    line_time = transaction_time(8, 7, 1200, SHEET_CHAR_BITS, turnaround)  # about 185 ms
    held = _four_at_once_at_1200_baud(tmp_path / "on")
    assert all(later - earlier >= line_time for earlier, later in itertools.pairwise(held)), held
    free = _four_at_once_at_1200_baud(tmp_path / "off", "--no-bus-timing")
    assert free[-1] - free[0] < line_time, free
    parser = cli.build_parser()  # and the option is what serve's options say
    assert cli.serve_options(parser.parse_args(["serve", "--tcp", "127.0.0.1:0"])).bus_timing is True

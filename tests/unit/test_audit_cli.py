"""``c20sim audit LOG``: the report, JSON, JUnit, --fail-on, --ignore, and one line for a log it cannot read."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from c20sim.audit import RULES, Auditor
from c20sim.cli import main
from c20sim.drive.profile import load_profile
from c20sim.traffic.auditlog import MAX_LINE, read_frames
from c20sim.wire.protocol import ReadRequest, ReadResponse, encode, transaction_time

REQUEST = encode(ReadRequest(1, 0x2100, 1)).hex(" ").upper()
REPLY = encode(ReadResponse(1, (5,))).hex(" ").upper()


def line(t: float, direction: str, text: str, **more: object) -> str:
    """A frame-log line as serve writes it (more keys than the audit reads)."""
    record = {"t": round(t, 6), "model_t": t, "dir": direction, "hex": text, "kind": "request", "slave": 1, **more}
    return json.dumps({**record, "text": "read 2100H", "note": ""}) + "\n"


def poll_log(path: Path, every: float, n: int) -> Path:
    with path.open("w") as f:
        for k in range(n):
            f.write(line(k * every, "rx", REQUEST))
            f.write(line(k * every + 0.002, "tx", REPLY))
    return path


@pytest.fixture
def fast(tmp_path: Path) -> Path:
    return poll_log(tmp_path / "fast.jsonl", 1 / 256, 600)


def test_a_fast_poller_fails_with_its_finding(fast: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["audit", str(fast)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("error line-demand line: line demand 341 % of 19200 8N1: 256 transactions in 1.010 s")
    assert out[-1] == "1200 frames, 600 requests; line demand peak 341 %, mean 343 % of 19200 8N1; 1 finding"


def test_json_report(fast: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["audit", str(fast), "--format", "json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == 1200
    read = transaction_time(8, 7, 19200, 10, 0.002)
    assert report["line_demand"]["peak_percent"] == pytest.approx(256 * read * 100 / (255 / 256 + read), abs=0.05)
    (finding,) = report["findings"]
    assert (finding["rule"], finding["severity"], finding["drive"]) == ("line-demand", "error", None)
    assert finding["frames"][-1]["seq"] == 513  # the first request a whole second in


def test_a_faster_line_and_fail_on(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fast = poll_log(tmp_path / "100.jsonl", 0.01, 300)  # 100 reads a second: 134 % of 19200 8N1
    assert main(["audit", str(fast)]) == 1
    assert capsys.readouterr().out.startswith("error line-demand line: line demand 134 %")
    # at 57600 baud a read takes 8.1 ms: 81 %, below 100 % but a warning above 80 %
    assert main(["audit", str(fast), "--baud", "57600"]) == 0
    assert capsys.readouterr().out.startswith("warning line-demand")
    assert main(["audit", str(fast), "--baud", "57600", "--fail-on", "warning"]) == 1


def test_ignore_and_junit(fast: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    report = tmp_path / "audit.xml"
    assert main(["audit", str(fast), "--junit", str(report)]) == 1
    suite = ET.parse(report).getroot().find("testsuite")
    assert suite is not None and suite.get("failures") == "1"
    failed = [case.get("name") for case in suite.iter("testcase") if case.find("failure") is not None]
    assert failed == ["line-demand"]
    assert [case.get("name") for case in suite.iter("testcase")] == list(RULES)  # a case per rule, in order
    assert main(["audit", str(fast), "--ignore", "line-demand", "--junit", str(report)]) == 0
    assert ET.parse(report).getroot().get("failures") == "0"


def test_a_sane_log_passes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = poll_log(tmp_path / "sane.jsonl", 0.1, 50)
    log.write_text(log.read_text() + json.dumps({"kind": "log-dropped", "dropped": 3}) + "\n")
    assert main(["audit", str(log)]) == 0
    assert capsys.readouterr().out.endswith("; 0 findings\n")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("not json\n", "line 2: not JSON; a frame log has one JSON object a line with t, dir and hex"),
        ('{"t": -1, "dir": "rx", "hex": "01"}\n', "line 2: key 't': expected the frame's time in seconds"),
        ('{"t": 1, "dir": "up", "hex": "01"}\n', "line 2: key 'dir': expected \"rx\" (master to drive)"),
        ('{"t": 1, "dir": "rx", "hex": "zz"}\n', "line 2: key 'hex': not hex bytes: 'zz'"),
        ("[1, 2]\n", "line 2: expected a JSON object with t, dir and hex"),
        ("x" * (MAX_LINE + 10) + "\n", f"line 2: longer than {MAX_LINE} characters; not a frame log"),
    ],
)
def test_a_bad_line_is_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str, message: str
) -> None:
    log = tmp_path / "bad.jsonl"
    log.write_text(line(0.0, "rx", REQUEST) + text)
    assert main(["audit", str(log)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"c20sim: {log}: {message}")


def test_files_it_cannot_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["audit", str(tmp_path / "none.jsonl")]) == 2
    assert capsys.readouterr().err == f"c20sim: {tmp_path / 'none.jsonl'}: cannot read: No such file or directory\n"
    assert main(["audit", str(tmp_path)]) == 2
    assert capsys.readouterr().err == (
        f"c20sim: {tmp_path}: is a directory, not a regular file; give the frame log or capture as a file\n"
    )
    (tmp_path / "empty.jsonl").write_text("")
    assert main(["audit", str(tmp_path / "empty.jsonl")]) == 2
    assert "no frames" in capsys.readouterr().err


def test_bad_options_are_one_line(fast: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["audit", str(fast), "--ignore", "nope"]) == 2
    assert capsys.readouterr().err.startswith("c20sim: --ignore: unknown rule 'nope'; the rules are line-demand")
    assert main(["audit", str(fast), "--baud", "1000"]) == 2
    assert "--baud 1000: not one the C20 supports" in capsys.readouterr().err


def test_the_log_is_streamed_not_read_whole() -> None:
    class Endless(io.StringIO):
        """A log that never ends: reading it whole would never return."""

        def __init__(self) -> None:
            super().__init__()
            self.lines = 0

        def readline(self, size: int | None = -1) -> str:  # type: ignore[override]
            self.lines += 1
            return line(self.lines * 0.1, "rx", REQUEST)

        def read(self, size: int | None = -1) -> str:  # pragma: no cover - the test fails if called
            raise AssertionError("read whole")

    stream = Endless()
    frames = read_frames(stream, "endless")
    auditor = Auditor(load_profile("c20-400hr"))
    for _ in range(1000):
        auditor.feed(*next(frames))
    assert stream.lines == 1000


def test_a_modbus_tcp_log_is_judged_by_its_rtu_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """serve's log of a Modbus TCP frame has the MBAP frame in hex and the line's frame in rtu (null: the gateway's
    own 0x0B, never on the line)."""

    def mbap(rtu: str) -> str:
        body = bytes.fromhex(rtu)[:-2]
        return (b"\x00\x07\x00\x00" + len(body).to_bytes(2, "big") + body).hex(" ").upper()

    with (tmp_path / "tcp.jsonl").open("w") as f:
        for k in range(300):
            t = k / 100
            f.write(line(t, "rx", mbap(REQUEST), modbus_tcp={"transaction": 7, "unit": 1}, rtu=REQUEST))
            f.write(line(t + 0.002, "tx", mbap(REPLY), modbus_tcp={"transaction": 7, "unit": 1}, rtu=REPLY))
        f.write(line(3.5, "tx", "00 07 00 00 00 03 01 83 0B", modbus_tcp={"transaction": 7, "unit": 1}, rtu=None))
    assert main(["audit", str(tmp_path / "tcp.jsonl"), "--format", "json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report["frames"] == 600
    assert [(f["rule"], round(f["value"])) for f in report["findings"]] == [("line-demand", 134)]


def test_a_deeply_nested_line_is_one_line_not_a_traceback(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A line the fast path does not take (keys in another order) is read by json: its depth is checked first."""
    log = tmp_path / "deep.jsonl"
    log.write_text('{"x": ' + "[" * 5000 + "]" * 5000 + ', "t": 1, "dir": "rx", "hex": "01"}\n')
    assert main(["audit", str(log)]) == 2
    assert capsys.readouterr().err == (
        f"c20sim: {log}: line 1: nested deeper than 64 levels; a frame log has one flat JSON object a line\n"
    )

"""The line-demand window charges each transaction the reply the drive sent, and a broadcast its own frame: the
tail of ``c20sim exercise --dialect`` (back-to-back reads, a read of 126 registers refused with a 5-byte exception,
a broadcast, then 0.5 s of the master's own wait) reads as the full line it was, a warning, not an error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from c20sim.audit import Auditor, Severity
from c20sim.cli import main
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    FunctionCode,
    ReadRequest,
    ReadResponse,
    WriteSingleRequest,
    encode,
    frame_time,
    transaction_time,
)
from c20sim.wire.registers import Reg

READ, ANSWER = encode(ReadRequest(1, Reg.STATUS1, 1)), encode(ReadResponse(1, (5,)))
WIDE = encode(ReadRequest(1, 0x3012, 126))  # the probe's read of one register more than the drive allows
REFUSED = encode(ExceptionResponse(1, FunctionCode.READ_REGISTERS, ExceptionCode.ILLEGAL_VALUE))
BROADCAST = encode(WriteSingleRequest(0, Reg.STATUS1, 0))
READ_TX = transaction_time(8, 7, 19200, 10, 0.002)  # a one-register read at 19200 8N1, 2 ms turnaround
PACE = 1 / 70  # 70 such reads a second: 94.2 % of the line


def probe_tail() -> list[tuple[float, str, bytes]]:
    """140 reads at 70 a second, each answered; the wide read, refused; the broadcast; a read 0.5 s later."""
    frames: list[tuple[float, str, bytes]] = []
    for k in range(140):
        frames += [(k * PACE, "rx", READ), (k * PACE + 0.0125, "tx", ANSWER)]
    frames += [(140 * PACE, "rx", WIDE), (140 * PACE + 0.0105, "tx", REFUSED), (141 * PACE, "rx", BROADCAST)]
    frames += [(141 * PACE + 0.5, "rx", READ), (141 * PACE + 0.5125, "tx", ANSWER)]
    return frames


@pytest.fixture
def profile() -> Profile:
    return load_profile()


def test_a_refused_wide_read_and_a_broadcast_are_charged_what_the_line_carried(profile: Profile) -> None:
    auditor = Auditor(profile)
    assert (auditor.baud, auditor.bits, auditor.turnaround) == (19200, 10, 0.002)
    auditor.feed_all(probe_tail())
    demand = auditor.line_demand()
    # the refused read holds the line for its request, the turnaround and the 5-byte exception (12.4 ms, not the
    # 143.7 ms of the 257 bytes it asked for); the broadcast for its own frame: the 0.5 s after it is the master's
    refused = transaction_time(8, 5, 19200, 10, 0.002)
    assert round(refused * 1000, 3) == 12.417
    assert demand.busy == pytest.approx(141 * READ_TX + refused + frame_time(8, 19200, 10), abs=1e-12)
    assert demand.peak == pytest.approx(70 * READ_TX * 100, abs=1e-9)  # the back-to-back reads' 94.2 %
    (finding,) = auditor.findings()
    assert (finding.rule, finding.severity) == ("line-demand", Severity.WARNING)
    assert finding.figure == "line demand 94 % of 19200 8N1: 70 transactions in 1.000 s need 0.942 s of line"


def test_a_request_never_answered_is_judged_at_the_next_frame_charged_the_reply_it_asked_for(
    profile: Profile,
) -> None:
    """A master polling a drive that never answers: each read judged, as before, by the reply it asked for."""
    auditor = Auditor(profile)
    for k in range(80):
        auditor.feed(k * PACE, "rx", READ)
    assert auditor.line_demand().peak == pytest.approx(70 * READ_TX * 100, abs=1e-9)
    assert auditor.line_demand().busy == pytest.approx(80 * READ_TX, abs=1e-12)


def test_the_dialect_probes_tail_through_the_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / "dialect.jsonl"
    log.write_text(
        "".join(
            json.dumps({"t": round(t, 6), "dir": direction, "hex": data.hex(" ").upper()}) + "\n"
            for t, direction, data in probe_tail()
        )
    )
    assert main(["audit", str(log), "--format", "json"]) == 0  # a warning: the default --fail-on is error
    report = json.loads(capsys.readouterr().out)
    assert [(f["rule"], f["severity"], round(f["value"], 1)) for f in report["findings"]] == [
        ("line-demand", "warning", 94.2)
    ]

"""``refused-repeat`` and the drill agree on exception 0x06: a data frame error to an intact request is a line
fault, asked again rightly (the drill's ``retries`` check requires it), so its repeats are no finding; a 0x06 to a
request malformed on the wire, and any other refusal, repeated, still is."""

from __future__ import annotations

import pytest

from c20sim.audit import Auditor, Severity
from c20sim.audit.rules.refused_repeat import RETRIED, intact
from c20sim.drill.checks import _Txn
from c20sim.drive.profile import Profile, load_profile
from c20sim.wire.protocol import (
    ExceptionCode,
    ExceptionResponse,
    FunctionCode,
    ReadRequest,
    WriteMultipleRequest,
    encode,
)
from c20sim.wire.registers import Reg

READ = encode(ReadRequest(1, Reg.STATUS1, 1))
#: a 0x10 of one register whose byte count says 4: its CRC checks, its length fits its byte count, but the drive
#: refuses it 0x06 every time ("the length of data frame is incorrect")
MALFORMED = encode(WriteMultipleRequest(1, Reg.SPEED_SETPOINT, (1500, 0), count=1, byte_count=4))


def refusal(function: int, code: ExceptionCode) -> bytes:
    return encode(ExceptionResponse(1, function, code))


@pytest.fixture
def profile() -> Profile:
    return load_profile()


def asked(profile: Profile, request: bytes, reply: bytes, times: int) -> Auditor:
    auditor = Auditor(profile)
    for k in range(times):
        auditor.feed(0.1 * k, "rx", request)
        auditor.feed(0.1 * k + 0.015, "tx", reply)
    return auditor


def test_asking_again_after_a_data_frame_error_is_no_finding(profile: Profile) -> None:
    auditor = asked(profile, READ, refusal(FunctionCode.READ_REGISTERS, ExceptionCode.FRAME_ERROR), 5)
    assert auditor.findings() == []


def test_a_malformed_request_refused_0x06_again_and_again_is_a_finding(profile: Profile) -> None:
    assert len(MALFORMED) == 13 and not intact(MALFORMED) and intact(READ)
    auditor = asked(profile, MALFORMED, refusal(FunctionCode.WRITE_MULTIPLE, ExceptionCode.FRAME_ERROR), 3)
    (finding,) = auditor.findings()
    assert (finding.rule, finding.severity, finding.drive, finding.subject) == (
        "refused-repeat",
        Severity.WARNING,
        1,
        "2001H",
    )
    assert finding.figure == "write of 2001H refused 0x06 (data frame error) 3 times"


def test_another_refusal_asked_again_is_still_a_finding(profile: Profile) -> None:
    auditor = asked(profile, READ, refusal(FunctionCode.READ_REGISTERS, ExceptionCode.READ_ONLY), 3)
    (finding,) = auditor.findings()
    assert (finding.rule, finding.figure) == (
        "refused-repeat",
        "read of 2100H refused 0x07 (parameter is read-only) 3 times",
    )


@pytest.mark.parametrize("code", list(ExceptionCode))
def test_the_codes_not_counted_are_those_the_drill_requires_retrying(code: ExceptionCode) -> None:
    """The drill takes a reply with ``code`` as a failed request (to be asked again) exactly when the audit does
    not count its repeats."""
    txn = _Txn(1, 0.0, READ, refusal(FunctionCode.READ_REGISTERS, code))
    txn.settle()
    assert (txn.status == "failed") == (code in RETRIED)
    assert txn.status in ("failed", "refused")

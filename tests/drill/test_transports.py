"""Every reference master (raw sockets, pymodbus, mbpoll in a shell loop, of two registers or one) earns exactly its verdicts on the pty,
RTU over TCP and Modbus TCP. (The raw masters over RTU over TCP, with their figures: test_raw_masters.py.)"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

from tests.drill.conftest import MBPOLL, PYMODBUS, RAW, SMALL_PLAN, drill

pytestmark = pytest.mark.serial  # the drill judges a master's real rhythm: .ci/run runs it alone

#: Over Modbus TCP a gateway forwards no broken reply: a reply from another address stands in for the CRC fault.
MBAP_PLAN = SMALL_PLAN.replace('incident = "crc"', 'incident = "wrong-address"')

ALL_PASS = {"1 crc": [], "2 no-reply": [], "3 trip": [], "4 power-cycle": [], "5 offline": []}
NAIVE = {
    "1 crc": ["retries"],
    "2 no-reply": ["retries"],
    "3 trip": ["notices", "no-run-into-fault"],
    "4 power-cycle": ["restores-ram"],
    "5 offline": [],
}
#: mbpoll in a loop: one attempt a request (no retry), reads the status, never runs the drive again
MBPOLL_LOOP = {"1 crc": ["retries"], "2 no-reply": ["retries"], "3 trip": [], "4 power-cycle": [], "5 offline": []}

WHERE = {"tcp": "--tcp {tcp}", "pty": "--pty {pty}", "modbus-tcp": "--modbus-tcp {modbus_tcp}"}


def _expect(expected: dict[str, list[str]], transport: str) -> dict[str, list[str]]:
    if transport != "modbus-tcp":
        return expected
    return {key.replace("1 crc", "1 wrong-address"): value for key, value in expected.items()}


def _run(tmp_path: Path, script: Path, style: str, transport: str) -> dict[str, list[str]]:
    plan = MBAP_PLAN if transport == "modbus-tcp" else SMALL_PLAN
    master = f"{sys.executable} {script} {style} {WHERE[transport]}"
    return drill(tmp_path, master, "--transport", transport, plan=plan).failed()


@pytest.mark.parametrize("transport", ["pty", "modbus-tcp"])
@pytest.mark.parametrize("style", ["careful", "naive"])
def test_the_raw_masters(tmp_path: Path, style: str, transport: str) -> None:
    expected = ALL_PASS if style == "careful" else NAIVE
    assert _run(tmp_path, RAW, style, transport) == _expect(expected, transport)


def test_the_raw_stormy_master_over_modbus_tcp(tmp_path: Path) -> None:
    failed = _run(tmp_path, RAW, "stormy", "modbus-tcp")
    assert failed["3 trip"] == []
    assert "no-storm" in failed["2 no-reply"]
    assert {"backs-off", "bounded"} & set(failed["5 offline"])


@pytest.mark.parametrize("transport", ["tcp", "pty", "modbus-tcp"])
def test_the_careful_pymodbus_master_passes_every_drill(tmp_path: Path, transport: str) -> None:
    assert _run(tmp_path, PYMODBUS, "careful", transport) == _expect(ALL_PASS, transport)


def test_the_naive_pymodbus_master(tmp_path: Path) -> None:
    assert _run(tmp_path, PYMODBUS, "naive", "tcp") == NAIVE


def test_the_stormy_pymodbus_master_storms_on_a_dead_link(tmp_path: Path) -> None:
    # its 30 ms timeout is longer than the line needs when the machine is idle, not under load: the reply faults'
    # verdicts follow the load; a silent drive shows its storm either way
    failed = _run(tmp_path, PYMODBUS, "stormy", "tcp")
    assert failed["3 trip"] == []
    assert "backs-off" in failed["4 power-cycle"] and "backs-off" in failed["5 offline"]


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed")
@pytest.mark.parametrize("transport", ["pty", "modbus-tcp"])
def test_mbpoll_in_a_shell_loop(tmp_path: Path, transport: str) -> None:
    plan = MBAP_PLAN if transport == "modbus-tcp" else SMALL_PLAN
    where = "tcp 127.0.0.1 {modbus_tcp_port}" if transport == "modbus-tcp" else "rtu {pty}"
    failed = drill(tmp_path, f"{MBPOLL} {where}", "--transport", transport, plan=plan).failed()
    assert failed == _expect(MBPOLL_LOOP, transport)


ONE_REGISTER_PLAN = """\
warmup = 2.0
[[drill]]
incident = "offline"
[[drill]]
incident = "echo"
"""


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is not installed")
def test_mbpoll_polling_one_register_in_a_shell_loop_on_the_pty(tmp_path: Path) -> None:
    """One request polled, one try a process: through the outage it polls at its own rhythm (no retry, so
    `bounded` passes, saying why); behind the echo libmodbus does not skip its own request and each poll waits out
    the frame it cannot complete, so it keeps under half its rate."""
    drilled = drill(tmp_path, f"{MBPOLL} one rtu {{pty}}", "--transport", "pty", plan=ONE_REGISTER_PLAN)
    assert drilled.failed() == {"1 offline": [], "2 echo": ["keeps-polling"]}
    bounded = drilled.figure("1 offline", "bounded")
    assert bounded.startswith("at most 0 retries of one request in a row (limit 3); ")
    assert "are polls at its own period" in bounded


WIRE_PLAN = """\
warmup = 2.0
[[drill]]
incident = "wrong-transaction"
[[drill]]
incident = "split"
[[drill]]
incident = "late"
"""


@pytest.mark.parametrize(("style", "expected"), [("careful", []), ("naive", ["waits-own-id"])])
def test_a_wrong_transaction_id_and_a_split_reply_over_modbus_tcp(
    tmp_path: Path, style: str, expected: list[str]
) -> None:
    master = f"{sys.executable} {RAW} {style} --modbus-tcp {{modbus_tcp}}"
    drilled = drill(tmp_path, master, "--transport", "modbus-tcp", plan=WIRE_PLAN)
    assert drilled.failed() == {"1 wrong-transaction": expected, "2 split": [], "3 late": []}
    if style == "naive":
        assert "took the reply under another id" in drilled.figure("1 wrong-transaction", "waits-own-id")

"""An audit rule and a drill incident are each one row: a throwaway one, registered here and nothing else edited,
reaches every front end that shows rules, findings or incidents, and is gone once taken out.

The audit rule (a file's worth of class, as one under c20sim/audit/rules/ would be) finds a write of 2001H = 1234.
It reaches: ``c20sim audit`` (text, JSON, JUnit, ``--ignore``), serve's live audit through the control API
(``GET /audit``), ``c20sim ctl audit`` and the MCP tool ``audit``, the dashboard's audit tab (F7), the
scenarios' schema (``expect_findings``), the test handle's ``ignore`` and docs/audit.md's check. The OpenAPI
document lists no rule (``GET /audit`` answers findings whose ``rule`` is a string): it has nothing to show.

The drill incident (a row as one in c20sim/drill/incidents.py) slows the replies for a while, and is judged by a
throwaway check (a row as one in c20sim/drill/checks.py) besides three of the table's. It reaches: a plan
(by name, with its parameters checked), the standard plan, the judge (a verdict of its checks), the reports
(text, JSON, JUnit, Markdown), ``c20sim drill --list``, ``POST /drill``, the scenarios' schema, the dashboard's
drill tab (F8) and docs/drill.md's check.
"""

from __future__ import annotations

import contextlib
import io
import json
import time
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
from mcp.shared.memory import create_connected_server_and_client_session
from mcp.types import TextContent
from textual.widgets import DataTable

from c20sim.audit import RULES, Auditor, FrameRef, Rule, Severity
from c20sim.audit.window import Window
from c20sim.cli import main
from c20sim.control.client import ControlClient
from c20sim.core.clock import RealtimeClock
from c20sim.drill import CHECKS, INCIDENTS, Check, CheckResult, Incident, Learned, Step, judge, read_plan, standard_plan
from c20sim.drill.incidents import Param
from c20sim.drill.report import json_report, junit_xml, markdown, text_report
from c20sim.drive.profile import load_profile
from c20sim.mcpserver import Bench as McpBench
from c20sim.mcpserver import build_server
from c20sim.scenario.schema import scenario_schema
from c20sim.testing import C20Sim
from c20sim.tui.audit import AuditPanel
from c20sim.tui.drill import DrillPanel
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import WriteSingleRequest, WriteSingleResponse, encode
from tests.tui.conftest import attached, running, serving, until
from tests.unit import test_audit, test_drill

RULE_ID = "throwaway-probe"
INCIDENT = "throwaway-slow"
CHECK = "throwaway-count"


class ProbeRule(Rule):
    """A rule of the test's: 2001H = 1234 written to a drive is a warning."""

    id = RULE_ID
    title = "a throwaway rule of tests/unit/test_rows_audit.py"
    source = "assumed (a test's)"

    def judges(self, register: int, value: int) -> bool:
        return register == 0x2001 and value == 1234

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        self.report(
            audit,
            Severity.WARNING,
            slave,
            "2001H",
            (FrameRef(seq, t),),
            "2001H = 1234 written",
            float(value),
            "write another speed",
            bump=True,
        )


def _slow(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    seconds = values["seconds"]
    assert isinstance(seconds, float)
    return (Step(0.0, "link", {"delay": 0.01}), Step(seconds, "clear-link")), seconds


def _count(drill: Any) -> CheckResult:
    """The throwaway check: the requests while the incident lasted (at least one)."""
    during = drill.during
    return CheckResult(
        CHECK, len(during) > 0, f"{len(during)} requests during the incident", len(during), (), "assumed"
    )


THROWAWAY_CHECK = Check(CHECK, "the master asked something while the incident lasted", "assumed", _count)

THROWAWAY = Incident(
    INCIDENT,
    "line",
    "a throwaway incident of tests/unit/test_rows_audit.py: every reply 10 ms late",
    "the incident's seconds, then its timeout plus 5 poll periods",
    "waits for the later reply and keeps polling",
    ("keeps-polling", "no-storm", "recovers", CHECK),
    "assumed",
    _slow,
    {"seconds": Param(1.0, 0.1, 10.0, "seconds")},
)


@pytest.fixture
def probe_rule() -> Iterator[None]:
    """The throwaway rule registered, and taken out after (whatever the test did)."""
    RULES[RULE_ID] = ProbeRule
    try:
        yield
    finally:
        del RULES[RULE_ID]
    assert RULE_ID not in RULES


@pytest.fixture
def throwaway_incident() -> Iterator[None]:
    """The throwaway incident and its own check registered, and taken out after."""
    CHECKS[CHECK] = THROWAWAY_CHECK
    INCIDENTS[INCIDENT] = THROWAWAY
    try:
        yield
    finally:
        del INCIDENTS[INCIDENT]
        del CHECKS[CHECK]
    assert INCIDENT not in INCIDENTS and CHECK not in CHECKS


WRITE = encode(WriteSingleRequest(1, 0x2001, 1234))
WRITTEN = encode(WriteSingleResponse(1, 0x2001, 1234))


def _frame_log(path: Path) -> Path:
    lines = []
    for k in range(2):
        t = 1.0 + k
        lines.append({"t": t, "dir": "rx", "hex": WRITE.hex(" ")})
        lines.append({"t": t + 0.02, "dir": "tx", "hex": WRITTEN.hex(" ")})
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    return path


# -- the audit rule


def test_a_throwaway_rule_reaches_the_offline_reports(
    probe_rule: None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = str(_frame_log(tmp_path / "frames.jsonl"))
    assert main(["audit", log, "--fail-on", "warning", "--junit", str(tmp_path / "audit.xml")]) == 1
    text = capsys.readouterr().out
    assert text.splitlines()[0] == (
        f"warning {RULE_ID} drive 1 2001H: 2001H = 1234 written. Write another speed. [assumed (a test's)]"
    )
    junit = (tmp_path / "audit.xml").read_text()
    assert f'<testcase name="{RULE_ID}" classname="audit">' in junit
    assert 'message="2001H = 1234 written" type="warning"' in junit
    assert main(["audit", log, "--format", "json"]) == 0
    (finding,) = json.loads(capsys.readouterr().out)["findings"]
    assert (finding["rule"], finding["drive"], finding["count"], finding["source"]) == (
        RULE_ID,
        1,
        2,
        "assumed (a test's)",
    )
    assert main(["audit", log, "--ignore", RULE_ID, "--fail-on", "warning", "--format", "json"]) == 0
    assert json.loads(capsys.readouterr().out)["findings"] == []


def test_a_throwaway_rule_reaches_the_schema_the_handle_and_the_docs_check(probe_rule: None) -> None:
    properties = scenario_schema()["properties"]["step"]["items"]["properties"]
    assert RULE_ID in properties["expect_findings"]["items"]["enum"]
    assert RULE_ID in properties["forbid_findings"]["items"]["enum"]
    assert [type(rule) for rule in Auditor(load_profile()).rules][-1] is ProbeRule
    with C20Sim.start() as sim:
        assert sim.audit(ignore=[RULE_ID]) == []  # a known rule: no "unknown rule" error
    with pytest.raises(AssertionError, match=RULE_ID):
        test_audit.test_every_rule_has_a_section_in_the_docs()


async def test_a_throwaway_rule_reaches_the_live_audit_the_api_ctl_mcp_and_the_dashboard(probe_rule: None) -> None:
    async with running() as bench:
        await bench.write(0x2001, 1234)
        report = bench.served.remote().call("audit")
        (finding,) = [f for f in report["findings"] if f["rule"] == RULE_ID]
        assert (finding["drive"], finding["subject"], finding["figure"]) == (1, "2001H", "2001H = 1234 written")
        out = io.StringIO()  # the dashboard holds sys.stdout while it runs: ctl's answer is taken here
        with contextlib.redirect_stdout(out):
            assert main(["ctl", "--url", bench.served.url, "--format", "json", "audit"]) == 0
        shown = json.loads(out.getvalue())
        assert [f["rule"] for f in shown["findings"]] == [RULE_ID]
        mcp = build_server(McpBench(ControlClient(bench.served.url)))
        async with create_connected_server_and_client_session(mcp) as session:
            result = await session.call_tool("audit", {})
            assert not result.isError
            (content,) = result.content
            assert isinstance(content, TextContent)
            assert [f["rule"] for f in json.loads(content.text)["findings"]] == [RULE_ID]
        await bench.press("f7")
        panel = bench.app.get_screen_main().query_one(AuditPanel)
        table = panel.query_one(DataTable)

        def rows() -> list[list[str]]:
            return [[str(cell) for cell in table.get_row_at(i)] for i in range(table.row_count)]

        await until(lambda: [row[1] for row in rows()] == [RULE_ID], "the throwaway rule's finding in the F7 tab")
        assert rows()[0] == ["warning", RULE_ID, "drive 1 2001H", "2001H = 1234 written"]


def test_a_rule_taken_out_is_gone() -> None:
    assert RULE_ID not in RULES
    assert ProbeRule not in [type(rule) for rule in Auditor(load_profile()).rules]
    assert (
        RULE_ID
        not in scenario_schema()["properties"]["step"]["items"]["properties"]["expect_findings"]["items"]["enum"]
    )
    with pytest.raises(ValueError, match=f"unknown rule '{RULE_ID}'"):
        Auditor(load_profile(), ignore=[RULE_ID])
    with C20Sim.start() as sim, pytest.raises(C20SimError, match=f"ignore: unknown rule '{RULE_ID}'"):
        sim.audit(ignore=[RULE_ID])


# -- the drill incident


def _played() -> tuple[test_drill.Stream, object]:
    """A master polling on through the throwaway incident (1 s), each reply 10 ms later, and back after."""
    s = test_drill.Stream()
    s.warm()
    s.mark("start", 1, INCIDENT)
    for _ in range(10):
        start = s.t
        s.ask(test_drill.STATUS, test_drill.STATUS_OK, 0.025)
        s.ask(test_drill.SPEED, test_drill.SPEED_OK, 0.025)
        s.t = start + 0.1
    s.mark("end", 1, INCIDENT)
    s.cycle(10)
    plan = read_plan({"drill": [{"incident": INCIDENT, "seconds": 1.0}]}, "p.toml")
    return s, plan


def test_a_throwaway_incident_reaches_the_plan_the_judge_and_the_reports(throwaway_incident: None) -> None:
    assert [d.name for d in standard_plan().drills][-1] == INCIDENT
    assert [d.name for d in standard_plan(transport="modbus-tcp").drills][-1] == INCIDENT
    with pytest.raises(C20SimError, match=r"p.toml: drill 1: seconds: 0.01 is outside 0.1-10"):
        read_plan({"drill": [{"incident": INCIDENT, "seconds": 0.01}]}, "p.toml")
    s, plan = _played()
    judgement = judge(s.frames, plan, s.marks)  # type: ignore[arg-type]
    (verdict,) = judgement.verdicts
    assert (verdict.incident, verdict.passed) == (INCIDENT, True), verdict.line()
    assert [c.check for c in verdict.checks] == ["keeps-polling", "no-storm", "recovers", CHECK]
    # 20 in the incident's second, and the one sent the instant it ended (the judge counts its end in)
    assert verdict.checks[-1].figure == "21 requests during the incident"
    assert verdict.source == "assumed"
    assert f"pass 1 {INCIDENT}: keeps-polling: " in text_report(judgement)
    assert json.loads(json_report(judgement))["verdicts"][0]["incident"] == INCIDENT
    assert f'<testcase name="1 {INCIDENT}" classname="drill.{INCIDENT}">' in junit_xml(judgement).decode()
    assert f"## 1 {INCIDENT}: pass" in markdown(judgement, plan)  # type: ignore[arg-type]
    assert f"- {CHECK}: pass: 21 requests during the incident [assumed]" in markdown(judgement, plan)  # type: ignore[arg-type]


def test_a_throwaway_incident_reaches_the_list_the_schema_and_the_docs_check(
    throwaway_incident: None, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["drill", "--list"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"{INCIDENT:<17} line   {THROWAWAY.does}"
    drill = scenario_schema()["properties"]["step"]["items"]["properties"]["drill"]["oneOf"]
    assert INCIDENT in drill[0]["enum"]
    with pytest.raises(AssertionError, match=f"no row for {INCIDENT}, {CHECK}\n"):
        test_drill.test_every_incident_and_check_has_a_row_in_the_docs()


async def test_a_throwaway_incident_reaches_the_dashboard_tab(throwaway_incident: None) -> None:
    with serving() as served:
        async with attached(served) as (app, pilot):
            await pilot.press("f8")
            panel = app.get_screen_main().query_one(DrillPanel)
            table = panel.query_one(DataTable)
            await until(lambda: table.row_count == len(INCIDENTS), "the incidents listed")
            last = [str(cell) for cell in table.get_row_at(table.row_count - 1)]
            assert last == [INCIDENT, "line", "-", THROWAWAY.does]


def test_a_throwaway_incident_reaches_the_drill_api(throwaway_incident: None) -> None:
    """POST /drill reads the row (its parameter's range here, so that no master is needed: the plan is refused)."""
    with serving(clock=RealtimeClock()) as served:
        remote = served.remote()
        remote.call("start_drill", plan=[{"incident": INCIDENT, "seconds": 99}])
        deadline = time.monotonic() + 10.0
        while (status := remote.call("drill"))["state"] == "running":
            assert time.monotonic() < deadline, f"the drill still runs: {status}"
            time.sleep(0.02)
        assert (status["state"], status["error"]) == ("failed", "POST /drill: drill 1: seconds: 99 is outside 0.1-10")


def test_an_incident_taken_out_is_gone() -> None:
    assert INCIDENT not in INCIDENTS and CHECK not in CHECKS
    assert INCIDENT not in [d.name for d in standard_plan().drills]
    with pytest.raises(C20SimError, match=f"incident '{INCIDENT}' is unknown"):
        read_plan({"drill": [{"incident": INCIDENT}]}, "p.toml")

"""Scenarios that expect or forbid the audit's findings: the scenario's own writes are a master on the line."""

from __future__ import annotations

import pytest

from c20sim.control import liveaudit
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile
from c20sim.scenario.timeline import ScenarioError, parse_scenario, run


def cyclic_writer(last: dict[str, object]) -> dict[str, object]:
    """A master storing F00.10 every 100 ms (200EH on first), then a last step with ``last``'s keys."""
    steps: list[dict[str, object]] = [{"at": 0.0, "write": {"200EH": 1}}]
    steps += [{"at": 0.1 * (k + 1), "write": {"F00.10": 2000 + k}} for k in range(8)]
    steps.append({"at": 1.0, "write": {"200EH": 0}, **last})
    return {"name": "cyclic F00.10", "step": steps}


def played(data: dict[str, object]) -> list[tuple[bool, str]]:
    sim = Simulator(load_profile(), (1,))
    try:
        report = run(parse_scenario(data, "audit.toml"), sim)
    finally:
        audit = liveaudit.of(sim)
        if audit is not None:
            audit.close()
    return [(o.ok, o.text) for o in report.outcomes if o.text.startswith("audit:")]


def test_an_expected_finding_passes_and_names_its_figure() -> None:
    outcomes = played(cyclic_writer({"expect_findings": ["eeprom-wear"], "forbid_findings": ["line-demand"]}))
    assert outcomes == [
        (
            True,
            "audit: eeprom-wear found: drive 1: F00.10 stored 36,000 times an hour (8 writes): "
            "rated 100,000 writes reached in 2.8 h",
        ),
        (True, "audit: no line-demand finding"),
    ]


def test_a_forbidden_finding_fails() -> None:
    (outcome,) = played(cyclic_writer({"forbid_findings": ["any"]}))
    assert outcome == (
        False,
        "audit: eeprom-wear drive 1: F00.10 stored 36,000 times an hour (8 writes): rated 100,000 writes "
        "reached in 2.8 h, forbidden",
    )


def test_a_missing_finding_fails() -> None:
    (outcome,) = played(
        {"name": "quiet", "step": [{"at": 0.0, "write": {"2001H": 100}, "expect_findings": ["reset-loop"]}]}
    )
    assert outcome == (False, "audit: no reset-loop finding, expected one (findings: none)")


@pytest.mark.parametrize(
    ("step", "message"),
    [
        ({"expect_findings": "eeprom-wear"}, "key 'expect_findings': expected a list of the audit's rules"),
        ({"expect_findings": ["eeprom-waer"]}, "key 'expect_findings': unknown rule 'eeprom-waer'"),
        ({"expect_findings": ["any"]}, "key 'expect_findings': unknown rule 'any'"),
        (
            {"expect_findings": ["reset-loop"], "forbid_findings": ["reset-loop"]},
            "key 'forbid_findings': reset-loop is expected and forbidden at once",
        ),
    ],
)
def test_bad_audit_keys_name_the_step_and_key(step: dict[str, object], message: str) -> None:
    with pytest.raises(ScenarioError) as caught:
        parse_scenario({"name": "bad", "step": [{"at": 0.0, **step}]}, "bad.toml")
    assert message in str(caught.value)
    assert str(caught.value).startswith("bad.toml: step 1")

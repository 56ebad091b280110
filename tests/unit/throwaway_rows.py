"""The throwaway rows of tests/unit/test_rows_causes.py, and its docs checks.

Imports nothing but the drive's tables (the conditions' front ends build theirs when imported, so a child
interpreter registers these rows before it imports any; the causes' front ends read the rows when asked).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from c20sim.drive import conditions, trips

ROOT = Path(__file__).resolve().parents[2]
PROFILE = ROOT / "profiles" / "c20-400hr.toml"
#: The shipped profile with one more fault: code 99 for the throwaway cause.
WET_FAULT = (
    '\n[[fault]]\ncode = 99\nname = "CDN"\nmeaning = "condensation"\ncause = "condensation"\nsource = "assumed"\n'
)


def causes_block() -> str:
    """docs/faults.md's table of the causes, between its markers."""
    text = (ROOT / "docs" / "faults.md").read_text(encoding="utf-8")
    match = re.search(r"<!-- causes:[^\n]*-->\n(.*?)<!-- /causes -->", text, re.S)
    assert match is not None, "docs/faults.md has lost its causes markers"
    return match.group(1)


def undocumented_conditions() -> list[str]:
    """The conditions docs/scenario-format.md does not name (as tests/automation/test_schema.py checks it)."""
    text = (ROOT / "docs" / "scenario-format.md").read_text(encoding="utf-8")
    from c20sim.scenario.schema import build  # a front end: imported once the rows are in

    step = build("scenario")["properties"]["step"]["items"]["properties"]
    return sorted(k for k in step["set"]["properties"] if f"`{k}`" not in text)


def unnamed_profile_keys() -> list[str]:
    """The profile's keys docs/profile-format.md does not name (as tests/automation/test_schema.py checks it)."""
    text = (ROOT / "docs" / "profile-format.md").read_text(encoding="utf-8")
    from c20sim.scenario.schema import build  # a front end: imported once the rows are in

    schema = build("profile")
    keys = set(schema["properties"])
    for prop in schema["properties"].values():
        keys |= set(prop.get("properties", {})) | set(prop.get("items", {}).get("properties", {}))
    return sorted(k for k in keys if f"`{k}`" not in text and f"[{k}]" not in text)


def humid(m: Any) -> bool:
    """The throwaway cause's condition: the cabinet's humidity (the throwaway condition) above 95 %."""
    value = m.motion.bench.extra.get("humidity_pct", 0.0)
    return float(value) > 95.0


HUMIDITY = conditions.Condition(
    "humidity_pct",
    "%",
    0,
    100,
    help="relative humidity in the cabinet (a test's throwaway condition)",
    initial=40.0,
    panel=conditions.Panel("humidity", "humidity", 5.0),
)
CONDENSATION = trips.Trip(
    "condensation",
    "the cabinet's humidity is above 95 % (a test's throwaway cause)",
    check=8.5,  # after the external fault, before the communication timeout
    detect=lambda p: lambda m, mo: humid(m),
    present=humid,
    persists=humid,
    bench=trips.Bench(
        "condensation",
        "w",
        "condensation",
        "the cabinet's humidity at 99 %",
        lambda p, c: {"humidity_pct": 99.0},
        lambda p, c: {"humidity_pct": 40.0},
        rank=9,
    ),
)

"""The F7 view's line-demand gauge turns red where the audit's line-demand is an error, not at a full line."""

from __future__ import annotations

import pytest

from c20sim.tui.audit import gauge_text


def demand(now: float) -> dict[str, object]:
    return {"now_percent": now, "peak_percent": now, "baud": 19200, "format": "8N1"}


@pytest.mark.parametrize(
    ("now", "style"),
    [
        (79.9, "green"),
        (80.0, "yellow"),
        (100.0, "yellow"),  # a line kept exactly full: the audit's warning
        (100.1, "yellow"),  # within the frames' times' jitter
        (100.2, "bold red"),  # beyond it: the audit's error
        (341.3, "bold red"),
    ],
)
def test_the_gauge_is_red_where_the_audit_says_error(now: float, style: str) -> None:
    text = gauge_text(demand(now))
    bar = next(span for span in text.spans if "█" in text.plain[span.start : span.end])
    assert str(bar.style) == style

"""``early-retry``: a retry sooner than the reply could have come."""

from __future__ import annotations

from ._early import EarlyRule

__all__ = ["EarlyRetryRule"]


class EarlyRetryRule(EarlyRule):
    """The same request again, sent while its reply could still be on the line."""

    id = "early-retry"
    title = "a retry sooner than the reply could have come"
    source = "Modbus over Serial Line"
    retry = True

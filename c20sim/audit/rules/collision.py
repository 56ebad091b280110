"""``collision``: a request before the previous reply could have finished."""

from __future__ import annotations

from ._early import EarlyRule

__all__ = ["CollisionRule"]


class CollisionRule(EarlyRule):
    """Another request (other bytes) sent while the last one's reply could still be on the line."""

    id = "collision"
    title = "a request before the previous reply could have finished"
    source = "Modbus over Serial Line"
    retry = False

"""``refused-repeat``: the same request refused again and again (any refusal no other rule claims)."""

from __future__ import annotations

from ..state import _Request
from ..window import Window
from ._refusal import RefusalRule

__all__ = ["RefusedRepeatRule"]


class RefusedRepeatRule(RefusalRule):
    """Any refusal no other rule claims, repeated."""

    id = "refused-repeat"
    title = "the same request refused again and again"
    source = "sheet 1.4"
    fallback = True

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        return True

    def advice(self, request: _Request) -> str:
        return "read the refusal: repeating the request gets the same answer"

"""The Textual dashboard: ``c20sim dashboard``, and ``c20sim`` with no arguments."""

from __future__ import annotations

from .app import Dashboard
from .workbench import Workbench

__all__ = ["Dashboard", "Workbench"]

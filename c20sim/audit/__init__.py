"""The bench examines the master: rules over the frame stream that report what would fail in the field.

Pure like the wire and the drive (frames and times in, findings out, no I/O):
:class:`~c20sim.audit.engine.Auditor` is fed frames live by the bus or offline
from a frame log, and reports :class:`~c20sim.audit.findings.Finding` values.
Each rule is an object in its own file under :mod:`c20sim.audit.rules`; :data:`RULES`
is their table. docs/audit.md lists the rules.
"""

from .engine import Auditor, Limits, LineDemand
from .findings import Finding, FrameRef, Severity
from .rules import RULES, Rule

__all__ = ["RULES", "Auditor", "Finding", "FrameRef", "Limits", "LineDemand", "Rule", "Severity"]

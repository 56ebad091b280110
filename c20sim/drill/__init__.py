"""The drill: incidents c20sim plays on a running master, and a verdict on how the master came through each,
judged from the frames on the wire alone. Pure like the audit (frames and marks in, verdicts out, no I/O):
:mod:`~c20sim.drill.incidents` (the table of incidents), :mod:`~c20sim.drill.plan` (a plan, checked),
:mod:`~c20sim.drill.checks` (the table of checks), :mod:`~c20sim.drill.judge` (the judge). docs/drill.md lists the incidents.
"""

from .checks import CHECKS, Check
from .incidents import INCIDENTS, Incident, Learned, Step
from .judge import CheckResult, Judgement, Mark, Verdict, judge, learn, watch_seconds
from .plan import Drill, Plan, read_plan, standard_plan

__all__ = [
    "CHECKS",
    "INCIDENTS",
    "Check",
    "CheckResult",
    "Drill",
    "Incident",
    "Judgement",
    "Learned",
    "Mark",
    "Plan",
    "Step",
    "Verdict",
    "judge",
    "learn",
    "read_plan",
    "standard_plan",
    "watch_seconds",
]

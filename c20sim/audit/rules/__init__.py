"""The audit's rules, one file each, and :data:`RULES`, the table everything iterates.

The report (text, JSON, JUnit), ``--ignore``, the scenarios' ``expect_findings``, the live audit and its
views, and docs/audit.md's check all read :data:`RULES`. To add a rule: a file here with a
:class:`~c20sim.audit.rules.base.Rule` subclass, its row below, and its section in docs/audit.md.
"""

from __future__ import annotations

from .absent_register import AbsentRegisterRule
from .answer_delay_timeout import AnswerDelayTimeoutRule
from .auto_reset_race import AutoResetRaceRule
from .base import HOOKS, Rule, hooked
from .broadcast_turnaround import BroadcastTurnaroundRule
from .collision import CollisionRule
from .comm_watchdog import CommWatchdogRule
from .early_retry import EarlyRetryRule
from .eeprom_wear import EepromWearRule
from .fault_record_unread import FaultRecordUnreadRule
from .fcode_locked import FcodeLockedRule
from .line_demand import LineDemandRule
from .refused_repeat import RefusedRepeatRule
from .refused_while_running import RefusedWhileRunningRule
from .reset_loop import ResetLoopRule
from .run_channel import RunChannelRule
from .speed_above_max import SpeedAboveMaxRule
from .write_enable_left_on import WriteEnableLeftOnRule

__all__ = ["HOOKS", "RULES", "Rule", "hooked"]

#: Every rule, by id, in the report's order (a JUnit test case each, in this order). A dict, so that a test
#: can add a throwaway row and take it out again.
RULES: dict[str, type[Rule]] = {
    rule.id: rule
    for rule in (
        LineDemandRule,
        EepromWearRule,
        CommWatchdogRule,
        CollisionRule,
        EarlyRetryRule,
        BroadcastTurnaroundRule,
        RefusedWhileRunningRule,
        FcodeLockedRule,
        WriteEnableLeftOnRule,
        AbsentRegisterRule,
        RunChannelRule,
        RefusedRepeatRule,
        ResetLoopRule,
        SpeedAboveMaxRule,
        AutoResetRaceRule,
        FaultRecordUnreadRule,
        AnswerDelayTimeoutRule,
    )
}

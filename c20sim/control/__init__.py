"""Control of a running simulator: one set of operations under every front end.

- :mod:`.ops`: the checked operations (conditions, faults by code, keypad,
  link faults, time, registers, frames), the only vocabulary;
- :mod:`.causes`: device faults as physical causes, levels from the profile;
- :mod:`.routes`: the control surface, one row per operation (:mod:`.routing`
  the row type; the rows by family in ``routes_*.py``);
- :mod:`.http`: the operations as a JSON API, a row served by its kind
  (``httpbody``, ``httpserved``, ``httpstream``; with ``httpguard`` the API's
  aiohttp servers: import them only to serve the API);
- :mod:`.client`: the one HTTP client of the API (the dashboard's
  operations, ``c20sim ctl``, the MCP tools);
- :mod:`.ctl`: ``c20sim ctl``, the API from a shell.

The operations are re-exported here: ``from c20sim import control`` then
``control.set_conditions(sim, 1, {"supply_v": 24})``.
"""

from __future__ import annotations

from . import causes, ops
from .ops import (
    CONDITIONS,
    KEYS,
    Condition,
    ControlError,
    advance,
    check_conditions,
    check_fault,
    check_link_faults,
    clear_fault,
    clear_link_faults,
    conditions,
    drive,
    drive_state,
    frames,
    inject_fault,
    key_command,
    link_state,
    parse_register,
    power_cycle,
    press_key,
    read_register,
    register_address,
    restore_defaults,
    set_conditions,
    set_link_faults,
    set_run_channel,
    unknown,
)

__all__ = [
    "CONDITIONS",
    "KEYS",
    "Condition",
    "ControlError",
    "advance",
    "causes",
    "check_conditions",
    "check_fault",
    "check_link_faults",
    "clear_fault",
    "clear_link_faults",
    "conditions",
    "drive",
    "drive_state",
    "frames",
    "inject_fault",
    "key_command",
    "link_state",
    "ops",
    "parse_register",
    "power_cycle",
    "press_key",
    "read_register",
    "register_address",
    "restore_defaults",
    "set_conditions",
    "set_link_faults",
    "set_run_channel",
    "unknown",
]

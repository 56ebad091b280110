"""What an audit rule is: an object with an id, a title, a source and the hooks it needs.

The :class:`~c20sim.audit.engine.Auditor` makes one of each rule of :data:`c20sim.audit.rules.RULES` for
each stream and calls, for every frame, the hooks its rules define (a hook a rule leaves as the base's is
never called), in this order:

- ``gap``: a request sent too soon after the last (still :attr:`Window.pending`): after a broadcast, or
  before the last one's reply came out (with none, before one could have finished on the line;
  :attr:`Window.need`: the seconds it needed).
- ``demand``: the line-demand window reached a new peak (percent); noise frames hold the line too.
- ``request``: a request (CRC good) now the window's pending one, after the line-demand window took it.
- ``written``: each (register, value) a request to one drive writes that the rule :meth:`Rule.judges`.
- ``refused``: a drive answered the pending request with an exception code the rule :meth:`Rule.claims`
  (the first claiming rule takes it; a ``fallback`` rule only what no other rule claims).
- ``stored``: the drive took a write of a function code (EEPROM) or a register mirroring one.
- ``read``: a drive answered the pending read (0x03) of registers the rule :meth:`Rule.watches` with values (not
  an exception): what the master saw.
- ``idle``: now and then: on each request while a drive has 200EH = 1, and at the stream's end.

A rule keeps its own memory on itself (it is made per stream) or in the window's counters
(:meth:`Window.count`), and says what it found with :meth:`Rule.report`.
"""

from __future__ import annotations

from typing import ClassVar

from ...drive.profile import Profile
from ..findings import FrameRef, Severity
from ..state import _Request
from ..window import Window

__all__ = ["HOOKS", "Rule", "hooked"]

#: The hooks, in the order the auditor calls them within a frame.
HOOKS = ("gap", "demand", "request", "written", "refused", "stored", "read", "idle")


class Rule:
    """A rule of the audit: what it looks for and where its facts come from (docs/audit.md has a section for
    each, under ``### `id```)."""

    id: ClassVar[str] = ""
    title: ClassVar[str] = ""
    source: ClassVar[str] = ""
    #: takes a refusal only when no other rule claims it
    fallback: ClassVar[bool] = False

    def source_for(self, profile: Profile) -> str:
        """Where the figure's facts come from, with the profile's assumed values it judged by."""
        return self.source

    def report(
        self,
        audit: Window,
        severity: Severity,
        drive: int | None,
        subject: str,
        frames: tuple[FrameRef, ...],
        figure: str,
        value: float,
        advice: str,
        *,
        bump: bool = False,
    ) -> None:
        """Say a finding of this rule (see :meth:`Window.report`)."""
        if self.id in audit.ignore:
            return
        source = self.source_for(audit.profile)
        audit.report(self.id, source, severity, drive, subject, frames, figure, value, advice, bump=bump)

    # -- the hooks (see the module's text); the base's do nothing and are not called

    def gap(self, audit: Window, seq: int, t: float, data: bytes) -> None:
        """A request (``data``, at ``seq``, ``t``) too soon after the pending one (see the module's text)."""

    def demand(self, audit: Window, seq: int, t: float, percent: float) -> None:
        """The line-demand window's new peak, ``percent`` of the line, on the frame at ``seq``, ``t``."""

    def request(self, audit: Window, request: _Request, seq: int, t: float) -> None:
        """A request (CRC good), now :attr:`Window.pending`."""

    def judges(self, register: int, value: int) -> bool:
        """Whether :meth:`written` is called for this write (asked once per distinct request frame)."""
        return False

    def written(self, audit: Window, slave: int, register: int, value: int, seq: int, t: float) -> None:
        """A write to one drive that :meth:`judges` said yes to, as the master sent it."""

    def claims(self, audit: Window, request: _Request, code: int) -> bool:
        """Whether the refusal ``code`` of ``request`` is this rule's to judge: from the request and the code
        alone (asked once per distinct request frame and code; the answer is remembered)."""
        return False

    def refused(self, audit: Window, request: _Request, code: int, ref: FrameRef) -> None:
        """The drive refused the pending request with ``code`` (the reply at ``ref``), and this rule claimed it."""

    def stored(self, audit: Window, slave: int, register: int, value: int) -> None:
        """The drive took a write of a function code (EEPROM), or a register mirroring one."""

    def watches(self, register: int, count: int) -> bool:
        """Whether :meth:`read` is called for a read of ``count`` registers from ``register`` (asked once per
        distinct request frame)."""
        return False

    def read(self, audit: Window, slave: int, register: int, values: tuple[int, ...], seq: int, t: float) -> None:
        """A drive answered a read of ``values`` from ``register`` on (the reply at ``seq``, ``t``): what the master
        saw."""

    def idle(self, audit: Window, t: float) -> None:
        """Time has passed to ``t``."""


def hooked(rules: list[Rule], hook: str) -> list[Rule]:
    """The rules that define ``hook`` (the base's does nothing), in their order; a fallback claimant last."""
    chosen = [rule for rule in rules if getattr(type(rule), hook) is not getattr(Rule, hook)]
    if hook == "refused":
        chosen.sort(key=lambda rule: rule.fallback)  # stable: the table's order, the fallback last
    return chosen

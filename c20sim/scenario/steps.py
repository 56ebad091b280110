"""A scenario's steps: what a step is, and the table of step kinds a ``[[step]]`` table is read by.

A step kind is one row (:class:`StepKind`): its key, the parser that checks the key's value once at load, its
JSON Schema fragment, its line on the docs page, and what it does when the step is played (before the step's
writes, after them, or, on a served simulator only, awaited). The loader, the player, the JSON Schema
(``c20sim schema scenario``) and the docs check all iterate the rows (:class:`Kinds`); the rows themselves are
in :mod:`c20sim.scenario.stepkinds` and :mod:`c20sim.scenario.stepchecks`. The format's reference is
docs/scenario-format.md; :mod:`c20sim.scenario.timeline` loads and plays a scenario.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Awaitable, Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from ..control import causes, ops
from ..wire.errors import C20SimError
from ..wire.vocabulary import UnknownRegister, resolve_register

if TYPE_CHECKING:
    from ..core.simulator import Simulator

T = TypeVar("T")

__all__ = [
    "Act",
    "Against",
    "Expect",
    "Kinds",
    "Outcome",
    "Parser",
    "Reading",
    "ScenarioError",
    "Served",
    "Step",
    "StepKind",
    "missing_register",
]


class ScenarioError(C20SimError):
    """A scenario that cannot be loaded or played: names the file, the step and the key."""

    def __init__(self, path: str, where: str, message: str) -> None:
        self.path = path
        self.where = where
        self.message = message
        super().__init__(f"{path}: {where}: {message}" if where else f"{path}: {message}")


@dataclass(frozen=True)
class Expect:
    """A register must read ``value`` (raw) within ``tolerance``."""

    register: str  #: as written in the file
    address: int
    value: int
    tolerance: int = 0


@dataclass(frozen=True)
class Step:
    """What happens at time ``at`` (seconds from the start), to ``drive`` (None: the first drive).

    The fields are what the shipped step kinds read; a kind with no field of its own keeps its value in
    :attr:`more` (:meth:`value` reads either). :attr:`given` holds the keys the file gave.
    """

    index: int  #: 1-based, in file order
    at: float
    drive: int | None = None
    note: str = ""
    set: Mapping[str, object] = field(default_factory=dict)
    link: Mapping[str, object] = field(default_factory=dict)
    clear_link: bool = False
    fault: causes.FaultRequest | None = None  #: a fault by its cause, or latched by code
    clear_fault: bool = False
    release: str | None = None  #: a fault's cause to end, before clear_fault's reset
    power_cycle: bool = False
    write: tuple[tuple[str, int, int], ...] = ()  #: (register as written, address, value)
    keypad: str | int | None = None
    expect: tuple[Expect, ...] = ()
    expect_exception: int | None = None  #: every write of the step must be refused with this code
    expect_silence: bool = False  #: no write (or a read of 2100H, with none) may be answered
    within: float | None = None  #: poll ``expect`` in model time for up to this long
    expect_findings: tuple[str, ...] = ()  #: the audit's rules that must have found something by now
    forbid_findings: tuple[str, ...] = ()  #: rules that must have found nothing ("any": no finding at all)
    #: a drill (docs/drill.md) on the master polling the served drive: its incidents, as a plan's [[drill]] tables
    drill: tuple[Mapping[str, object], ...] = ()
    given: frozenset[str] = frozenset()  #: the keys the file gave this step
    more: Mapping[str, object] = field(default_factory=dict)  #: values of the kinds with no field here

    @property
    def audited(self) -> bool:
        """The step reads the audit (docs/audit.md)."""
        return bool(self.expect_findings or self.forbid_findings)

    @property
    def cause(self) -> str | None:
        """The fault's cause this step brings about, if it asks for one by cause."""
        return self.fault.cause if self.fault is not None else None

    @property
    def label(self) -> str:
        return f"step {self.index} (at {self.at:g} s)"

    def value(self, key: str) -> object:
        """What the step holds for ``key``: a field, or a kind's value in :attr:`more` (None if not given)."""
        return self.more[key] if key in self.more else getattr(self, key, None)


#: The names of Step's own fields: a kind's parsed value for any other name goes to ``Step.more``.
STEP_FIELDS = frozenset(f.name for f in dataclasses.fields(Step))


@dataclass(frozen=True)
class Outcome:
    """One expectation or action of one step, and whether it held."""

    step: Step
    t: float
    ok: bool
    text: str
    key: str = ""  #: the step kind whose act made it ("expect": an expectation a ``within`` step reads again)


class Reading:
    """One ``[[step]]`` table being read: its keys as given, the fields read so far, and errors that name the
    file, the step and the key."""

    def __init__(self, raw: Mapping[str, Any], index: int, path: str) -> None:
        self.raw = raw
        self.index = index
        self.path = path
        self.read: dict[str, Any] = {}  #: Step fields (and new kinds' values) read so far, in table order

    @property
    def label(self) -> str:
        at = self.read.get("at")
        return f"step {self.index} (at {at:g} s)" if at is not None else f"step {self.index}"

    def fail(self, key: str, message: str) -> ScenarioError:
        return ScenarioError(self.path, f"{self.label}, key {key!r}", message)

    def table(self, key: str, value: object) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(key, "expected a table, such as { supply_v = 24 }")
        return value

    def flag(self, key: str, value: object) -> bool:
        if not isinstance(value, bool):
            raise self.fail(key, "expected true or false")
        return value

    def unquoted(self, key: str, register: str, value: object) -> None:
        """TOML reads ``F00.10 = 5000`` unquoted as the table F00 = { 10 = 5000 }: say to quote it."""
        if isinstance(value, dict) and register.upper().startswith("F") and all(k.isdigit() for k in value):
            first = sorted(value)[0]
            raise self.fail(
                key, f'{register}: unknown key {first!r}; quote a function code, as "{register}.{first}" = N'
            )

    def checked(self, key: str, fn: Callable[[], T]) -> T:
        """Check with control's own checker: one vocabulary, and its message, for the API and the scenarios."""
        try:
            return fn()
        except ops.ControlError as exc:
            raise self.fail(key, str(exc)) from None


#: A kind's parser: the key's value as given, and the table being read -> the Step fields it sets.
Parser = Callable[[Any, Reading], Mapping[str, object]]
#: What a kind does when its step is played: (step, simulator, drive address, the step's time) -> outcomes.
Act = Callable[[Step, "Simulator", int, float], list[Outcome]]
#: What a kind does on a served simulator, awaited after the step's writes and checks.
Served = Callable[[Step, "Simulator"], Awaitable[Outcome]]
#: A kind's check against the simulator it is to play on, before it plays: the problem in words, or None.
Against = Callable[[Step, "Simulator"], str | None]


def missing_register(items: Iterable[tuple[str, int]], sim: Simulator) -> str | None:
    """The first (register as written, address) the simulator's profile lacks, in the register vocabulary's own
    words with its did-you-mean (2100 is decimal: 2100H?); None if it has them all."""
    registers = sim.profile.registers
    for register, address in items:
        if address not in registers:
            try:
                resolve_register(register, registers, f"the profile {sim.profile.name}")
            except UnknownRegister as exc:
                return str(exc)
    return None


@dataclass(frozen=True)
class StepKind:
    """One key of a ``[[step]]`` table: how it is read, shown and played.

    ``act`` runs when a step that gives the key is played: before the step's writes, or after them with
    ``after_writes`` (a check, whose outcomes are the step's); kinds that share one act run it once. ``served``
    is awaited only on a served simulator (``serve --scenario``); ``served_only`` is run-scenario's refusal of
    a step that gives the key. ``against`` checks the key against the simulator (its drives, registers and
    causes) before anything plays.
    """

    key: str
    parse: Parser
    schema: Callable[[], dict[str, Any]]  #: the key's JSON Schema fragment
    value: str  #: the docs table's "type" column
    doc: str  #: the docs table's "meaning" column
    act: Act | None = None
    after_writes: bool = False
    served: Served | None = None
    served_only: str = ""
    required: bool = False
    against: Against | None = None

    def line(self) -> str:
        """The kind's row in docs/scenario-format.md's step keys table."""
        return f"| `{self.key}` | {self.value} | {self.doc} |"


class Kinds:
    """The step kinds, in the order they are read and played; a test may add one and remove it again."""

    def __init__(self, rows: Iterable[StepKind]) -> None:
        self._rows: dict[str, StepKind] = {}
        for row in rows:
            self.add(row)

    def add(self, row: StepKind) -> None:
        if row.key in self._rows:
            raise ValueError(f"step kind {row.key!r}: declared twice")
        self._rows[row.key] = row

    def remove(self, key: str) -> None:
        del self._rows[key]

    def __iter__(self) -> Iterator[StepKind]:
        return iter(list(self._rows.values()))

    def __contains__(self, key: object) -> bool:
        return key in self._rows

    def keys(self) -> tuple[str, ...]:
        return tuple(self._rows)

    def parse(self, raw: object, index: int, path: str) -> Step:
        """A ``[[step]]`` table, read by the rows: the required ones first (``at``, which names the step in every
        error after it), then any key no row knows, then each given key in the table's order."""
        if not isinstance(raw, dict):
            raise ScenarioError(path, f"step {index}", "expected a table ([[step]])")
        reading = Reading(raw, index, path)
        for row in self:
            if row.required:
                reading.read.update(row.parse(raw.get(row.key), reading))
        for key in raw:
            if key not in self._rows:
                raise reading.fail(key, str(ops.unknown("key", key, self.keys())))
        for row in self:
            if not row.required and row.key in raw:
                reading.read.update(row.parse(raw[row.key], reading))
        fields = {k: v for k, v in reading.read.items() if k in STEP_FIELDS}
        more = {k: v for k, v in reading.read.items() if k not in STEP_FIELDS}
        return Step(index=index, **fields, given=frozenset(raw), more=more)

    def schema(self) -> dict[str, Any]:
        """The JSON Schema of a ``[[step]]`` table: each row's fragment."""
        return {
            "type": "object",
            "properties": {row.key: row.schema() for row in self},
            "required": [row.key for row in self if row.required],
            "additionalProperties": False,
        }

    def docs_table(self) -> str:
        """The step keys table of docs/scenario-format.md, one line a row."""
        lines = ["| key | type | meaning |", "| --- | --- | --- |", *(row.line() for row in self)]
        return "\n".join(lines) + "\n"

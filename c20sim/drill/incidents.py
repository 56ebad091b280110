"""The drill's incidents, one row each: what c20sim does, how long it watches, what a robust master does, how
that is judged from the wire, and where the rule comes from.

Pure: a row turns its parameters (and the master's learned poll period and timeout) into :class:`Step` values,
the operations the runner plays at offsets from the incident's start (link faults, a cause, a power cycle, a
function code), and names the checks (:mod:`c20sim.drill.checks`) its verdict is made of. To add an incident:
a row in :data:`INCIDENTS`, and its row in docs/drill.md's tables; nothing else.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

__all__ = [
    "INCIDENTS",
    "SOURCES",
    "Incident",
    "Learned",
    "Param",
    "Step",
]

#: Where a rule comes from, by a short name used in the rows.
SOURCES: Mapping[str, str] = {
    "guide": "Modbus over Serial Line V1.02 (2.4.1 response timeout; 2.5.1 frame checks)",
    "tcp": "Modbus Messaging on TCP/IP Implementation Guide V1.0b (4.4.1 transaction identifier)",
    "sheet": "the C20 protocol sheet (2000H commands, 2100H/2102H status and fault, 0x06 frame error)",
    "invt": "INVT Goodrive/GD20 manuals (P14.04/P14.05 comm timeout and action; fault reset)",
    "invt-auto": "INVT GD20 P08.28/P08.29 (automatic fault reset; the family's, assumed for the C20's F08.28/F08.29)",
    "invt-record": "INVT GD20 P07.27-P07.40 (the fault record; the family's, its C20 addresses F07.27-F07.40 assumed)",
    "assumed": "assumed",
}


@dataclass(frozen=True, slots=True)
class Learned:
    """The master's rhythm: its poll period (seconds between two asks of the same request) and its response
    timeout (seconds from an unanswered request to its next request), learned from the warm-up or given."""

    period: float
    timeout: float
    rate: float = 0.0  #: requests a second in the warm-up
    given: bool = False

    def as_dict(self) -> dict[str, object]:
        return {
            "poll_period_s": round(self.period, 4),
            "timeout_s": round(self.timeout, 4),
            "rate_per_s": round(self.rate, 2),
            "given": self.given,
        }


@dataclass(frozen=True, slots=True)
class Step:
    """One operation the runner plays, ``at`` seconds after the incident's start.

    ``op`` is one of ``link`` (set link faults of the bus: ``args`` by their names), ``clear-link``, ``trip``
    and ``release`` (a cause, ``args["cause"]``), ``set`` (conditions), ``fcode`` (a function code by the
    keypad, ``args["code"]``, ``args["value"]``), ``power-off`` (the drive's supply off: the link silent) and
    ``power-on`` (the drive powers up: RAM lost, EEPROM kept), ``clear-fault`` (the plant made healthy again)."""

    at: float
    op: str
    args: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Param:
    """A parameter of an incident: its default, its range and what it means."""

    default: float
    low: float
    high: float
    what: str
    integer: bool = False


#: Makes an incident's steps: (its parameters, the learned rhythm) -> the steps, and the incident's length (s);
#: a length of None: the incident ends when its faulted replies are spent (the runner watches the count).
Plan = Callable[[Mapping[str, object], Learned], tuple[tuple[Step, ...], float | None]]


@dataclass(frozen=True, slots=True)
class Incident:
    """One incident: a row of the table."""

    name: str
    group: str  #: ``reply`` (a fault of the replies), ``line`` (the line and the adapter), ``drive``
    does: str  #: what c20sim does, in words
    watch: str  #: how long it watches, in words
    robust: str  #: what a robust master does, as seen on the wire
    checks: tuple[str, ...]  #: the checks (:data:`c20sim.drill.checks.CHECKS`) its verdict is made of
    source: str  #: a key of :data:`SOURCES`
    plan: Plan
    params: Mapping[str, Param] = field(default_factory=dict)
    #: the transports it can be played on (a fault a Modbus TCP gateway would turn into exception 0x0B is not
    #: played there: the gateway forwards no broken reply)
    transports: tuple[str, ...] = ("pty", "tcp", "modbus-tcp")
    #: the drive has a fault (a trip) during the incident; the checks of faults are judged from ``trip_at`` s
    trips: bool = False
    #: the drive is silent during the incident (link offline, power off)
    silent: bool = False

    def steps(self, values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
        return self.plan(values, learned)


RTU_ONLY = ("pty", "tcp")
_REPLIES = Param(3, 1, 100, "faulted replies", integer=True)
_SECONDS = Param(3.0, 0.1, 60.0, "seconds")


def _n(values: Mapping[str, object], name: str) -> int:
    value = values[name]
    assert isinstance(value, (int, float))
    return int(value)


def _f(values: Mapping[str, object], name: str) -> float:
    value = values[name]
    assert isinstance(value, (int, float))
    return float(value)


def _reply_fault(**faults: object) -> Plan:
    def plan(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
        return (Step(0.0, "link", {**faults, "replies": _n(values, "replies")}),), None

    return plan


def _late(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    delay = round(_f(values, "fraction") * learned.timeout, 4)
    return (Step(0.0, "link", {"delay": delay, "replies": _n(values, "replies")}),), None


def _split(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    return (Step(0.0, "link", {"split": _f(values, "gap"), "replies": _n(values, "replies")}),), None


def _wrong_id(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    hold = round(_f(values, "fraction") * learned.timeout, 4)
    return (Step(0.0, "link", {"wrong_transaction": hold, "replies": _n(values, "replies")}),), None


def _for(seconds: str, **faults: object) -> Plan:
    def plan(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
        length = _f(values, seconds)
        chosen = {k: (values[v] if isinstance(v, str) and v in values else v) for k, v in faults.items()}
        return (Step(0.0, "link", chosen), Step(length, "clear-link")), length

    return plan


def _trip(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    hold = _f(values, "hold")
    cause = values.get("cause", "external")
    return (Step(0.0, "trip", {"cause": cause}), Step(hold, "release", {"cause": cause})), hold


def _dip(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    length = _f(values, "seconds")
    return (Step(0.0, "trip", {"cause": "undervoltage"}), Step(length, "release", {"cause": "undervoltage"})), length


#: F08.29 as the shipped profiles have it (1.0 s), put back after the auto-reset incident.
AUTO_RESET_INTERVAL_DEFAULT = 10


def _auto_reset(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    interval, hold = _f(values, "interval"), _f(values, "hold")
    length = round(interval + _f(values, "after"), 4)
    return (
        Step(0.0, "fcode", {"code": "F08.28", "value": 1}),
        Step(0.0, "fcode", {"code": "F08.29", "value": round(interval * 10)}),
        Step(0.0, "trip", {"cause": "external"}),
        Step(min(hold, interval), "release", {"cause": "external"}),
        Step(length, "fcode", {"code": "F08.28", "value": 0}),
        Step(length, "fcode", {"code": "F08.29", "value": AUTO_RESET_INTERVAL_DEFAULT}),
    ), length


def _watchdog(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    timeout = _f(values, "timeout")
    silence = timeout + _f(values, "beyond")
    return (
        Step(0.0, "fcode", {"code": "F08.02", "value": round(timeout * 10)}),
        Step(0.0, "link", {"offline": True}),
        Step(silence, "clear-link"),
        Step(silence, "fcode", {"code": "F08.02", "value": 0}),
    ), silence


def _power(values: Mapping[str, object], learned: Learned) -> tuple[tuple[Step, ...], float | None]:
    off = _f(values, "off")
    return (Step(0.0, "power-off"), Step(off, "power-on")), off


#: Every incident, by name: the table the plan (its names, the standard plan), the judge (each incident's checks),
#: the reports, ``c20sim drill --list``, the scenarios' schema, the dashboard's F8 tab and docs/drill.md's check
#: iterate. docs/drill.md has a row for each. A dict, so that a test can add a throwaway row and take it out.
INCIDENTS: dict[str, Incident] = {
    i.name: i
    for i in (
        Incident(
            "crc",
            "reply",
            "corrupts the CRC of the next N replies",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "discards each broken reply and asks again, a bounded number of times, not at once",
            ("retries", "no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(corrupt_crc=True),
            {"replies": _REPLIES},
            RTU_ONLY,
        ),
        Incident(
            "no-reply",
            "reply",
            "keeps the next N replies off the wire",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "asks again after its timeout, a bounded number of times",
            ("retries", "no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(drop_percent=100.0),
            {"replies": _REPLIES},
        ),
        Incident(
            "truncated",
            "reply",
            "sends the first half of the next N replies",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "discards the short reply (after its timeout) and asks again",
            ("retries", "no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(truncate=True),
            {"replies": _REPLIES},
            RTU_ONLY,
        ),
        Incident(
            "extra-bytes",
            "reply",
            "adds two bytes (00 FF) after the next N replies",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "takes the good frame in front (or discards it all and asks again) and drops the trailing bytes "
            "before its next request",
            ("no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(garbage_after="00 FF"),
            {"replies": _REPLIES},
            RTU_ONLY,
        ),
        Incident(
            "wrong-address",
            "reply",
            "answers the next N requests from address 99 (CRC good)",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "discards a reply from a drive it did not ask, waits for its own, asks again",
            ("retries", "no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(wrong_address=99),
            {"replies": _REPLIES},
        ),
        Incident(
            "wrong-function",
            "reply",
            "answers the next N requests with another function code (the code XOR 7, CRC good)",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "discards a reply to a function it did not ask, and asks again",
            ("retries", "no-storm", "bounded", "recovers"),
            "guide",
            _reply_fault(wrong_function=True),
            {"replies": _REPLIES},
        ),
        Incident(
            "split",
            "reply",
            "sends the next N replies in two pieces a gap apart (two TCP segments; on the pty a gap in the frame)",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "assembles the pieces into its reply: asks nothing again",
            ("takes-replies", "no-storm", "bounded", "recovers"),
            "tcp",
            _split,
            {"replies": _REPLIES, "gap": Param(0.02, 0.001, 1.0, "seconds between the pieces")},
        ),
        Incident(
            "wrong-transaction",
            "reply",
            "Modbus TCP: sends each of the next N replies under another transaction id first, the right one a "
            "fraction of the master's timeout later",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "discards the reply under another id and waits for its own: sends nothing new before it",
            ("waits-own-id", "no-storm", "recovers"),
            "tcp",
            _wrong_id,
            {"replies": _REPLIES, "fraction": Param(0.5, 0.05, 0.95, "fraction of the master's timeout")},
            ("modbus-tcp",),
        ),
        Incident(
            "exception-06",
            "reply",
            "answers the next N requests with exception 0x06 (the sheet's frame error), without acting on them",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "takes 0x06 as a garbled request and sends it again, a bounded number of times",
            ("retries", "no-storm", "bounded", "recovers"),
            "sheet",
            _reply_fault(forced_exception=6),
            {"replies": _REPLIES},
        ),
        Incident(
            "late",
            "reply",
            "sends the next N replies late by a fraction of the master's own timeout",
            "until the N replies are spent, then its timeout plus 5 poll periods",
            "waits for a reply within its timeout: asks nothing again, is back at its rhythm after",
            ("takes-replies", "no-storm", "bounded", "recovers"),
            "guide",
            _late,
            {"replies": _REPLIES, "fraction": Param(0.5, 0.05, 0.95, "fraction of the master's timeout")},
        ),
        Incident(
            "echo",
            "line",
            "echoes each request before its reply (a two-wire RS485 adapter without echo suppression)",
            "the incident's seconds, then its timeout plus 5 poll periods",
            "skips its own echo and takes the reply behind it: polls on at its rhythm, no retries",
            ("takes-replies", "keeps-polling", "no-storm", "recovers"),
            "assumed",
            _for("seconds", echo=True),
            {"seconds": _SECONDS},
            RTU_ONLY,
        ),
        Incident(
            "bursts",
            "line",
            "hands replies over only at 16 ms boundaries (a USB adapter's latency timer)",
            "the incident's seconds, then its timeout plus 5 poll periods",
            "a timeout with room for 16 ms more: polls on, no retries",
            ("takes-replies", "keeps-polling", "no-storm", "recovers"),
            "assumed",
            _for("seconds", burst="burst"),
            {"seconds": _SECONDS, "burst": Param(0.016, 0.001, 0.1, "seconds between bursts")},
        ),
        Incident(
            "slow",
            "line",
            "answers every request later by a fixed delay (a slower drive or gateway)",
            "the incident's seconds, then its timeout plus 5 poll periods",
            "waits for the slower reply within its timeout and keeps polling",
            ("takes-replies", "keeps-polling", "no-storm", "recovers"),
            "assumed",
            _for("seconds", delay="delay"),
            {"seconds": _SECONDS, "delay": Param(0.05, 0.001, 5.0, "seconds of extra delay")},
        ),
        Incident(
            "noise",
            "line",
            "flips one bit in a share of the frames, both ways (a request hit gets 0x06 or silence)",
            "the incident's seconds, then its timeout plus 5 poll periods",
            "discards the broken replies, retries a bounded number of times, keeps polling",
            ("no-storm", "bounded", "recovers"),
            "guide",
            _for("seconds", noise_percent="percent"),
            {"seconds": Param(5.0, 0.1, 60.0, "seconds"), "percent": Param(20.0, 0.1, 100.0, "percent of frames")},
            RTU_ONLY,
        ),
        Incident(
            "offline",
            "line",
            "takes the drive's link offline: it hears nothing and says nothing",
            "the incident's seconds, then its timeout plus 5 poll periods",
            "backs off while the link is dead and polls again within a few poll periods once it returns",
            ("backs-off", "bounded", "recovers"),
            "assumed",
            _for("seconds", offline=True),
            {"seconds": _SECONDS},
            silent=True,
        ),
        Incident(
            "trip",
            "drive",
            "brings a fault's cause about while the drive runs (by cause: it stays present for the hold)",
            "the hold, then its timeout plus 5 poll periods, and 3 s for a reset",
            "notices the trip (reads 2100H or 2102H), sends no run command into the fault, resets at most once "
            "while the cause is present",
            ("notices", "no-run-into-fault", "resets-once", "recovers"),
            "invt",
            _trip,
            {"hold": Param(2.0, 0.1, 60.0, "seconds the cause stays")},
            trips=True,
        ),
        Incident(
            "comm-watchdog",
            "drive",
            "sets F08.02 to a timeout and takes the link offline for longer: the drive trips CE (F08.03 = 0)",
            "the silence, then its timeout plus 5 poll periods, and 3 s for a reset",
            "notices the CE trip once the link is back, sends no run command into it, resets it",
            ("notices", "no-run-into-fault", "recovers"),
            "invt",
            _watchdog,
            {
                "timeout": Param(1.0, 0.1, 10.0, "F08.02 in seconds"),
                "beyond": Param(0.5, 0.1, 10.0, "seconds of silence past it"),
            },
            trips=True,
            silent=True,
        ),
        Incident(
            "power-cycle",
            "drive",
            "switches the drive off (the link silent) and on again: RAM values and the run command lost, EEPROM kept",
            "the time off, then its timeout plus 5 poll periods, and 3 s to run again",
            "backs off while the drive is off, and writes 2001H again before it runs the drive",
            ("backs-off", "bounded", "restores-ram", "recovers"),
            "sheet",
            _power,
            {"off": Param(1.0, 0.1, 60.0, "seconds off")},
            silent=True,
        ),
        Incident(
            "undervoltage-dip",
            "drive",
            "sags the supply below the undervoltage level for a moment: a running drive trips UV",
            "the dip, then its timeout plus 5 poll periods, and 3 s for a reset",
            "notices the trip, sends no run command into it, resets at most once while the supply is low",
            ("notices", "no-run-into-fault", "resets-once", "recovers"),
            "invt",
            _dip,
            {"seconds": Param(0.3, 0.05, 10.0, "seconds of the dip")},
            trips=True,
        ),
        Incident(
            "auto-reset",
            "drive",
            "sets one automatic fault reset (F08.28 = 1) after the interval (F08.29), trips the running drive on an "
            "external cause gone after the hold: the drive resets itself once the interval is up; F08.28 and F08.29 "
            "back to 0 and 1.0 s after",
            "the interval and 1 s more, then its timeout plus 5 poll periods, and 3 s to run again",
            "notices the trip, keeps polling, sends no reset of its own (and no run command) while the drive's "
            "counts down, and runs the drive again once it has reset itself",
            ("notices", "keeps-polling", "waits-auto-reset", "no-run-into-fault", "resumes"),
            "invt-auto",
            _auto_reset,
            {
                "interval": Param(1.0, 0.2, 30.0, "F08.29 in seconds"),
                "hold": Param(0.3, 0.05, 30.0, "seconds the cause stays (at most the interval)"),
                "after": Param(1.0, 0.5, 30.0, "seconds watched past the interval before F08.28 goes back to 0"),
            },
            trips=True,
        ),
        Incident(
            "fault-record",
            "drive",
            "trips the running drive on an external cause held for a moment: the fault record (F07.27-F07.48) "
            "takes the state at the trip",
            "the hold, then its timeout plus 5 poll periods, and 3 s for a reset",
            "notices the trip and reads the fault record (F07.27, or the state at it F07.33-F07.40) before it "
            "resets the fault, once",
            ("notices", "reads-record", "resets-once", "recovers"),
            "invt-record",
            _trip,
            {"hold": Param(0.5, 0.1, 60.0, "seconds the cause stays")},
            trips=True,
        ),
    )
}

#: The causes a trip may be given (the drive's physical causes, as c20sim.control.causes names them).
TRIP_CAUSES = ("external", "undervoltage", "overvoltage", "overcurrent", "overload", "stall", "overheat", "hall")

"""How a capture's transactions were carried, and what each link adds to a transaction's time.

A capture times each request and its reply where the master (or a sniffer)
saw them. Between the two lie, depending on the link, the request's own
characters on the line, one or two silences of t3.5, the drive's turnaround,
and the reply's characters: :class:`LinkModel` says which, and
:func:`choose_link` tells the link from the capture where its header leaves a
choice (a pty or TCP may or may not keep the line's time): on a link that keeps
it, a longer reply takes longer, by one character a byte; on one that does not,
it does not. What remains, once the link's part is taken away, is the
drive's turnaround (docs/fit.md, "What each link adds").
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from ..wire.errors import C20SimError
from ..wire.protocol import char_time, silence_times

__all__ = ["LINKS", "PORT_LINKS", "LinkModel", "Timing", "choose_link", "format_bits", "turnaround_of"]


@dataclass(frozen=True)
class LinkModel:
    """The parts of a transaction's time, from the request's record to its reply's, that are not the turnaround."""

    name: str
    words: str
    request_chars: bool  #: the request's characters go by on the line after its record's time
    silences: int  #: t3.5 silences: the drive's end of the request, and a device server's end of the reply
    reply_chars: int  #: 0: none; 1: the reply's n characters; -1: n - 1 (each byte written at its start)

    def why_words(self, why: str) -> str:
        return why or "told"

    def fixed(self, request: int, reply: int, baud: int, bits: int) -> float:
        """Seconds of a transaction's recorded time that the link adds around the turnaround."""
        return self.before_sample(request, baud, bits) + self.after_sample(reply, baud, bits)

    def before_sample(self, request: int, baud: int, bits: int) -> float:
        """From the request's record to the drive having the request (its last byte, then t3.5)."""
        char = char_time(baud, bits)
        return (request * char if self.request_chars else 0.0) + (
            silence_times(baud, bits)[1] if self.silences else 0.0
        )

    def after_sample(self, reply: int, baud: int, bits: int) -> float:
        """From the reply's first byte on the line (after the turnaround) to the reply's record."""
        char = char_time(baud, bits)
        chars = {0: 0, 1: reply, -1: max(0, reply - 1)}[self.reply_chars]
        return chars * char + (silence_times(baud, bits)[1] if self.silences == 2 else 0.0)


LINKS: dict[str, LinkModel] = {
    link.name: link
    for link in (
        LinkModel(
            "bare",
            "no line time: a pty without --line-timing, TCP to a server that does not keep the line's time, c20sim "
            "in virtual time",
            False,
            0,
            0,
        ),
        LinkModel(
            "pty",
            "c20sim's line-timed pty (--line-timing), timed as the serial line it stands for: the request's "
            "characters, t3.5, the turnaround, the reply's characters (each handed over as it ends)",
            True,
            1,
            1,
        ),
        LinkModel(
            "serial",
            "a serial port (the UART sends the request, then the reply comes): request, t3.5, reply",
            True,
            1,
            1,
        ),
        LinkModel("sniffer", "a sniffer on the line (c20sim record): each frame at its last byte", False, 1, 1),
        LinkModel(
            "device-server",
            "RTU over TCP through a serial device server that keeps the line's time (serve's default): request, "
            "t3.5, turnaround, t3.5, reply",
            True,
            2,
            1,
        ),
        LinkModel(
            "gateway",
            "Modbus TCP through a gateway to the line (serve --modbus-tcp's default): request, t3.5, turnaround, "
            "t3.5, reply",
            True,
            2,
            1,
        ),
    )
}

#: The links a capture's header (``{"kind": "link", "note": "link PORT BAUD FORMAT"}``) leaves open, by its port.
PORT_LINKS: dict[str, tuple[str, ...]] = {
    "serial": ("serial",),
    "pty": ("pty", "bare"),
    "tcp": ("device-server", "bare"),
    "modbus-tcp": ("gateway", "bare"),
    "simulated": ("bare",),
}

#: A reply may come this much sooner than a link's arithmetic says and the link still be the one (a server's
#: timer hands a reply over up to half a millisecond early: docs/line-timing.md).
EARLY = 0.0006

#: Two links are told apart only where their arithmetic differs by this much (s) between replies of two lengths.
SEPARATION = 0.0006

#: Where a transaction's time is the link's arithmetic and lateness (a queue, a timer, the machine's load; never
#: much early), this low quantile of the times is the arithmetic: robust to one early reply, blind to late ones.
LOW = 0.1


def low_quantile(values: Sequence[float]) -> float:
    ordered = sorted(values)
    return ordered[int(LOW * (len(ordered) - 1))]


def format_bits(text: str) -> int:
    """Bits of one character for a format such as ``8N1`` (10) or ``8E1`` (11)."""
    if len(text) != 3 or text[0] not in "78" or text[1] not in "NEO" or text[2] not in "12":
        raise ValueError(text)
    return 1 + int(text[0]) + (text[1] != "N") + int(text[2])


@dataclass(frozen=True)
class Timing:
    """One answered transaction's times: the request's record, the reply's, and both frames' lengths."""

    request_t: float
    reply_t: float
    request_len: int
    reply_len: int

    @property
    def elapsed(self) -> float:
        return self.reply_t - self.request_t


def _groups(timings: Sequence[Timing]) -> dict[tuple[int, int], list[float]]:
    groups: dict[tuple[int, int], list[float]] = {}
    for t in timings:
        groups.setdefault((t.request_len, t.reply_len), []).append(t.elapsed)
    return {key: values for key, values in groups.items() if len(values) >= 6}


def choose_link(
    timings: Sequence[Timing], candidates: Sequence[str], baud: int, bits: int, where: str
) -> tuple[LinkModel, str]:
    """The link among ``candidates`` that the capture's times fit, and in words why; C20SimError (asking for
    ``--link``) when the times cannot tell."""
    links = [LINKS[name] for name in candidates]
    if len(links) == 1 or not timings:
        return links[0], "as the capture's header says" if len(links) == 1 else "no answered request to tell by"
    # a link whose arithmetic leaves a negative turnaround for a good share of the replies is not the one
    possible = []
    for link in links:
        net = sorted(t.elapsed - link.fixed(t.request_len, t.reply_len, baud, bits) for t in timings)
        if net[len(net) // 10] >= -EARLY:
            possible.append(link)
    if len(possible) == 1:
        return possible[0], "the others leave the replies sooner than their bytes take"
    if not possible:
        raise C20SimError(
            f"{where}: the replies come sooner than any link ({', '.join(candidates)}) allows: is the baud right? "
            "give --baud, or --link"
        )
    groups = {key: low_quantile(values) for key, values in _groups(timings).items()}
    spread: dict[str, float] = {}
    for link in possible:
        net = [m - link.fixed(q, r, baud, bits) for (q, r), m in groups.items()]
        spread[link.name] = max(net) - min(net) if net else 0.0
    ranked = sorted(possible, key=lambda link: spread[link.name])
    best, second = ranked[0], ranked[1]
    apart = _separation(best, second, list(groups), baud, bits)
    if apart >= SEPARATION and spread[best.name] <= 0.4 * apart and spread[second.name] >= 0.6 * apart:
        return best, (
            f"replies of {len({r for _, r in groups})} lengths: their times fit {best.name} within "
            f"{spread[best.name] * 1000:.2f} ms, {second.name} within {spread[second.name] * 1000:.2f} ms only"
        )
    raise C20SimError(
        f"{where}: cannot tell how the capture was carried ({' or '.join(link.name for link in possible)}): "
        f"its replies are of one length, or too close in length at {baud} baud, or their times fit each; give --link "
        f"{possible[0].name} or another (docs/fit.md, 'What each link adds')"
    )


def _separation(a: LinkModel, b: LinkModel, keys: Sequence[tuple[int, int]], baud: int, bits: int) -> float:
    """How far apart two links' arithmetic puts the transactions of the lengths ``keys`` (s)."""
    gaps = [a.fixed(q, r, baud, bits) - b.fixed(q, r, baud, bits) for q, r in keys]
    return max(gaps) - min(gaps) if gaps else 0.0


def turnaround_of(timings: Sequence[Timing], link: LinkModel, baud: int, bits: int) -> tuple[float, float, int]:
    """The drive's turnaround (s): a low quantile (:data:`LOW`) of what the link leaves of each transaction's time,
    since what is not the link's arithmetic nor the drive is lateness (a queue behind other masters, a server's
    timer, the machine's load); its standard uncertainty; and how many transactions were over 1 ms later."""
    net = sorted(t.elapsed - link.fixed(t.request_len, t.reply_len, baud, bits) for t in timings)
    value = low_quantile(net)
    late = sum(1 for x in net if x > value + 0.001)
    median = statistics.median(net)
    mad = statistics.median(abs(x - median) for x in net) * 1.4826
    # the quantile's own spread, and a floor for what no link's arithmetic holds: 0.1 ms on a line or a pty
    # (the benches' timing, bench/RESULTS.md); 0.5 ms through a device server or gateway, whose own hand-over
    # of a reply is in the figure too (assumed; c20sim serve's timer hands replies over 0.2-1.5 ms late)
    floor = 0.0005 if link.silences == 2 else 0.0001
    sigma = ((mad / len(net) ** 0.5) ** 2 + floor**2) ** 0.5
    return value, sigma, late

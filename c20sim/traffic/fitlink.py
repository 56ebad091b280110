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

import itertools
import statistics
from collections.abc import Sequence
from dataclasses import dataclass

from ..wire.errors import C20SimError
from ..wire.protocol import char_time, silence_times

__all__ = [
    "LINKS",
    "PORT_LINKS",
    "Group",
    "LinkModel",
    "Timing",
    "choose_link",
    "format_bits",
    "slope",
    "turnaround_of",
]


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
    """The :data:`LOW` quantile of ``values``, and never the least of two or more: one early reply (0.9 ms before
    the nine others of its length, through serve's Modbus TCP on a loaded machine) is not the floor."""
    ordered = sorted(values)
    index = int(LOW * (len(ordered) - 1))
    return ordered[max(index, 1) if len(ordered) > 1 else 0]


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


#: A group of transactions (one request length, one reply length) counts towards telling the link from this many.
GROUP = 6

#: What a capture's times may grow by, as a share of what one link's arithmetic adds over another's between its
#: replies of different lengths, and still be that link (1 is the link, 0 the other): the 40 % / 60 % of
#: docs/fit.md ("What each link adds").
SLOPE = 0.4


@dataclass(frozen=True)
class Group:
    """The transactions of one request length and one reply length: how many, and the low envelope of their times
    (:func:`low_quantile`: the link's arithmetic and the turnaround are a floor; lateness only adds)."""

    request_len: int
    reply_len: int
    count: int
    floor: float


def _groups(timings: Sequence[Timing]) -> list[Group]:
    groups: dict[tuple[int, int], list[float]] = {}
    for t in timings:
        groups.setdefault((t.request_len, t.reply_len), []).append(t.elapsed)
    return [Group(q, r, len(v), low_quantile(v)) for (q, r), v in sorted(groups.items()) if len(v) >= GROUP]


@dataclass(frozen=True)
class Fit:
    """How the groups' floors fit a link: its turnaround (the count-weighted mean of what it leaves of each
    floor) and the count-weighted rms of what is left over (s)."""

    link: LinkModel
    turnaround: float
    rms: float


def _fit(link: LinkModel, groups: Sequence[Group], baud: int, bits: int) -> Fit:
    net = [(g.floor - link.fixed(g.request_len, g.reply_len, baud, bits), g.count) for g in groups]
    total = sum(n for _, n in net)
    mean = sum(x * n for x, n in net) / total
    return Fit(link, mean, (sum((x - mean) ** 2 * n for x, n in net) / total) ** 0.5)


def slope(a: LinkModel, b: LinkModel, groups: Sequence[Group], baud: int, bits: int) -> tuple[float, float]:
    """How much of what ``a``'s arithmetic adds over ``b``'s the groups' floors grow by (1: ``a``, 0: ``b``): the
    weighted median of the slopes between each two groups, each pair weighted by its smaller group's count and
    how far apart the links put the two (a small group late as a whole moves it not at all, unless the pairs
    it is in hold half the weight); and how far apart the two links put the groups (s, the largest gap less the
    smallest)."""
    x = [
        a.fixed(g.request_len, g.reply_len, baud, bits) - b.fixed(g.request_len, g.reply_len, baud, bits)
        for g in groups
    ]
    y = [g.floor - b.fixed(g.request_len, g.reply_len, baud, bits) for g in groups]
    pairs = []
    for i, j in itertools.combinations(range(len(groups)), 2):
        dx = x[j] - x[i]
        if abs(dx) > 1e-9:
            pairs.append(((y[j] - y[i]) / dx, min(groups[i].count, groups[j].count) * abs(dx)))
    apart = max(x) - min(x) if x else 0.0
    if not pairs:
        return 0.0, apart
    pairs.sort()
    half, total = sum(w for _, w in pairs) / 2, 0.0
    for k, w in pairs:
        total += w
        if total >= half:
            return k, apart
    return pairs[-1][0], apart


def choose_link(
    timings: Sequence[Timing], candidates: Sequence[str], baud: int, bits: int, where: str
) -> tuple[LinkModel, str]:
    """The link among ``candidates`` that the capture's times fit, and in words why; C20SimError (asking for
    ``--link``, saying which reason and its figures) when the times cannot tell."""
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
    groups = _groups(timings)
    ask = f"give --link {possible[0].name} or another (docs/fit.md, 'What each link adds')"
    names = " or ".join(link.name for link in possible)
    head = f"{where}: cannot tell how the capture was carried ({names})"
    lengths = sorted({g.reply_len for g in groups})
    if len({(g.request_len, g.reply_len) for g in groups}) < 2:
        counted = f"{lengths[0]} bytes" if lengths else "none"
        raise C20SimError(
            f"{head}: its replies are of one length ({counted}, in groups of {GROUP} or more of one request and "
            f"reply length; {len(timings)} answered): {ask}"
        )
    fits = sorted((_fit(link, groups, baud, bits) for link in possible), key=lambda f: f.rms)
    best, second = fits[0], fits[1]
    # the slope is of the link whose arithmetic grows more with the frames' lengths over the other's: 1 is it, 0 the
    # other, whichever fits better
    more, less = sorted((best.link, second.link), key=lambda link: -_growth(link, baud, bits))
    k, apart = slope(more, less, groups, baud, bits)
    span = f"replies of {len(lengths)} lengths ({', '.join(map(str, lengths))} bytes)"
    if apart < 1e-9:
        alike = [f.link.name for f in fits if slope(best.link, f.link, groups, baud, bits)[1] < 1e-9]
        raise C20SimError(
            f"{head}: {', '.join(alike[:-1])} and {alike[-1]} add the same time to each of its {span} (less a "
            f"constant, which the turnaround takes): the times cannot tell them apart: give --link {alike[0]} or "
            "another (docs/fit.md, 'What each link adds')"
        )
    if apart < SEPARATION:
        raise C20SimError(
            f"{head}: its {span} are too close in length at {baud} baud: {more.name} and "
            f"{less.name} put them {apart * 1000:.2f} ms apart, under {SEPARATION * 1000:.1f} ms: {ask}"
        )
    figures = (
        f"their times fit {best.link.name} within {best.rms * 1000:.2f} ms rms, {second.link.name} within "
        f"{second.rms * 1000:.2f} ms; they grow by {k:.2f} of what {more.name}'s arithmetic adds over "
        f"{less.name}'s ({apart * 1000:.2f} ms across them)"
    )
    if abs(k - 1) <= SLOPE:
        return more, f"{span}: {figures}"
    if abs(k) <= SLOPE:
        return less, f"{span}: {figures}"
    raise C20SimError(
        f"{head}: its {span}: {figures}, not within {SLOPE:.1f} of 1 ({more.name}) or of 0 ({less.name}): {ask}"
    )


def _growth(link: LinkModel, baud: int, bits: int) -> float:
    """How much more of a transaction's time the link's arithmetic holds for long frames than for short (s)."""
    return link.fixed(256, 256, baud, bits) - link.fixed(8, 5, baud, bits)


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

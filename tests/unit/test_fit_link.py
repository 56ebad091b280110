"""fit tells the link of a capture from its times: robust to late transactions (a queue, a timer, the machine's
load), and a refusal says which reason and its figures (c20sim/traffic/fitlink.py; docs/fit.md, "What each link
adds")."""

from __future__ import annotations

import json
import random
import re
from pathlib import Path

import pytest

from c20sim.cli import main
from c20sim.traffic.fitlink import LINKS, PORT_LINKS, LinkModel, Timing, choose_link
from c20sim.wire.errors import C20SimError
from c20sim.wire.protocol import ExceptionCode, ExceptionResponse, ReadRequest, ReadResponse, encode

#: the groups of the capture in the report (exercise --dialect, 45 s, RTU over TCP): reads of one register (7
#: bytes back), the exceptions exercise asks for at the start (5 bytes), writes of one register (an 8-byte echo)
SHAPE = {(8, 7): 592, (8, 5): 20, (8, 8): 6}


def capture(
    link: str,
    turnaround: float,
    seed: int,
    *,
    late_share: float = 0.15,
    jitter: float = 0.0008,
    shape: dict[tuple[int, int], int] = SHAPE,
    baud: int = 19200,
    late_group: tuple[int, int] | None = (8, 8),
    early: bool = True,
) -> list[Timing]:
    """Transactions carried by ``link``: its arithmetic, the turnaround, a jitter of up to ``jitter`` s (serve's
    millisecond timer), a share late by 1-20 ms, and one small group late as a whole by 0.7 ms (as the writes of
    the capture in the report were: 0.6 ms), and one of the 5-byte replies 0.9 ms early."""
    rng = random.Random(seed)
    model = LINKS[link]
    out = []
    t = 0.0
    early_done = not early
    keys = [key for key, n in shape.items() for _ in range(n)]
    rng.shuffle(keys)
    for q, r in keys:
        elapsed = model.fixed(q, r, baud, 10) + turnaround + rng.uniform(0.0, jitter)
        if rng.random() < late_share:
            elapsed += rng.uniform(0.001, 0.020)
        if (q, r) == late_group:
            elapsed += 0.0007
        if (q, r) == (8, 5) and not early_done:
            elapsed -= 0.0009  # one early reply, as through serve's Modbus TCP under load
            early_done = True
        out.append(Timing(t, t + elapsed, q, r))
        t += 0.05
    return out


CASES = [(port, truth) for port in ("pty", "tcp", "modbus-tcp") for truth in PORT_LINKS[port]]


@pytest.mark.parametrize(("port", "truth"), CASES)
@pytest.mark.parametrize("seed", range(20))
def test_the_link_is_told_with_a_share_of_late_transactions(port: str, truth: str, seed: int) -> None:
    # a bare link with a long turnaround: the others' arithmetic does not leave it a negative one, so the times'
    # growth with the reply's length, not their floor, tells it
    turnaround = 0.002 if truth != "bare" else 0.015
    timings = capture(truth, turnaround, seed)
    assert sum(t.elapsed > LINKS[truth].fixed(t.request_len, t.reply_len, 19200, 10) + 0.004 for t in timings) > 30
    link, why = choose_link(timings, PORT_LINKS[port], 19200, 10, "capture.jsonl")
    assert link.name == truth, why
    other = next(name for name in PORT_LINKS[port] if name != truth)
    assert why.startswith(f"replies of 3 lengths (5, 7, 8 bytes): their times fit {truth} within "), why
    assert f"ms rms, {other} within " in why
    # the slope is of what the link keeping the line's time adds over the bare one: near 1 or near 0
    keeps = truth if truth != "bare" else other
    found = re.search(rf"they grow by (-?[0-9.]+) of what {keeps}'s arithmetic adds over bare's ", why)
    assert found is not None, why
    assert abs(float(found.group(1)) - (truth != "bare")) <= 0.4, why


@pytest.mark.parametrize("late_share", [0.0, 0.3, 0.5])
def test_device_server_is_told_whatever_the_share_late(late_share: float) -> None:
    for seed in range(10):
        timings = capture("device-server", 0.002, seed, late_share=late_share)
        link, why = choose_link(timings, ("device-server", "bare"), 19200, 10, "c.jsonl")
        assert link.name == "device-server", why


def test_the_figures_of_a_clean_capture() -> None:
    # no jitter, none late, the writes not late: the floors are the arithmetic exactly
    timings = capture("device-server", 0.002, 0, late_share=0.0, jitter=0.0, late_group=None, early=False)
    link, why = choose_link(timings, ("device-server", "bare"), 19200, 10, "c.jsonl")
    assert link.name == "device-server"
    assert why.startswith(
        "replies of 3 lengths (5, 7, 8 bytes): their times fit device-server within 0.00 ms rms, bare within "
    )
    # 5 to 8 bytes back: 3 characters of 0.521 ms
    assert why.endswith("they grow by 1.00 of what device-server's arithmetic adds over bare's (1.56 ms across them)")


def test_replies_of_one_length_are_refused_saying_so() -> None:
    timings = capture("device-server", 0.002, 1, shape={(8, 7): 50, (8, 5): 2})
    with pytest.raises(C20SimError) as caught:
        choose_link(timings, ("device-server", "bare"), 19200, 10, "c.jsonl")
    assert str(caught.value) == (
        "c.jsonl: cannot tell how the capture was carried (device-server or bare): its replies are of one length "
        "(7 bytes, in groups of 6 or more of one request and reply length; 52 answered): give --link "
        "device-server or another (docs/fit.md, 'What each link adds')"
    )


def test_replies_too_close_at_a_high_baud_are_refused_with_the_figures() -> None:
    timings = capture("device-server", 0.002, 1, shape={(8, 7): 50, (8, 5): 10}, baud=115200, late_group=None)
    with pytest.raises(C20SimError) as caught:
        choose_link(timings, ("device-server", "bare"), 115200, 10, "c.jsonl")
    message = str(caught.value)
    assert message.startswith(
        "c.jsonl: cannot tell how the capture was carried (device-server or bare): its replies of 2 lengths "
        "(5, 7 bytes) are too close in length at 115200 baud: "
    ), message
    # two characters of 10/115200 s
    assert message.endswith(
        " put them 0.17 ms apart, under 0.6 ms: give --link device-server or another "
        "(docs/fit.md, 'What each link adds')"
    ), message


def test_times_that_fit_neither_are_refused_with_the_figures() -> None:
    # times halfway between a bare link's and a device server's: they grow by half what the device server adds
    bare, server = LINKS["bare"], LINKS["device-server"]
    timings = [
        Timing(i, i + 0.015 + 0.55 * (server.fixed(q, r, 19200, 10) - bare.fixed(q, r, 19200, 10)), q, r)
        for i, (q, r) in enumerate([(8, 7)] * 30 + [(8, 5)] * 30)
    ]
    with pytest.raises(C20SimError) as caught:
        choose_link(timings, ("device-server", "bare"), 19200, 10, "c.jsonl")
    assert str(caught.value) == (
        "c.jsonl: cannot tell how the capture was carried (device-server or bare): its replies of 2 lengths (5, 7 "
        "bytes): their times fit device-server within 0.23 ms rms, bare within 0.29 ms; they grow by 0.55 of what "
        "device-server's arithmetic adds over bare's (1.04 ms across them), not within 0.4 of 1 (device-server) "
        "or of 0 (bare): give --link device-server or another (docs/fit.md, 'What each link adds')"
    )


def test_the_capture_of_the_report_is_told_device_server() -> None:
    # the floors (tenth percentile) of each length's times in the capture of the report (exercise --dialect, 45 s,
    # RTU over TCP, load average ~9 on 2 cores): the writes' 6 echoes 0.6 ms later than the reads. The largest
    # floor less the smallest, the rule before, left device-server 0.63 ms, over 40 % of the 1.56 ms the links
    # put them apart, and refused; the pair of the 20 exceptions and the 592 reads holds the weight, and grows as
    # device-server's arithmetic does
    floors = {(8, 5): (20, 0.01252), (8, 7): (592, 0.01359), (8, 8): (6, 0.01471)}
    timings = [Timing(0.0, floor, q, r) for (q, r), (n, floor) in floors.items() for _ in range(n)]
    link, why = choose_link(timings, ("device-server", "bare"), 19200, 10, "capture.jsonl")
    assert link.name == "device-server"
    assert why == (
        "replies of 3 lengths (5, 7, 8 bytes): their times fit device-server within 0.06 ms rms, bare within "
        "0.22 ms; they grow by 1.03 of what device-server's arithmetic adds over bare's (1.56 ms across them)"
    )


def test_a_link_grows_by_one_row(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # a throwaway link (a hub that stamps each frame at its last byte and adds its own t3.5 after the reply) and
    # the port a capture's header names for it: one row each, no other edit. fit's --link offers it, and a capture
    # whose header names its port is told from the times as that link, not the bare one
    hub = LinkModel("hub", "a throwaway hub: t3.5, turnaround, reply, t3.5", False, 2, 1)
    monkeypatch.setitem(LINKS, "hub", hub)
    monkeypatch.setitem(PORT_LINKS, "hub-port", ("hub", "bare"))
    read, value = encode(ReadRequest(1, 0x3008, 1)), encode(ReadResponse(1, (480,)))
    refused = encode(ReadRequest(1, 0x3FF0, 1)), encode(ExceptionResponse(1, 0x03, ExceptionCode.ILLEGAL_ADDRESS))
    lines = [json.dumps({"t": 0.0, "dir": "rx", "hex": "", "kind": "link", "note": "link hub-port 19200 8N1"})]
    for i, (request, reply) in enumerate([(read, value)] * 20 + [refused] * 8):
        t = 0.1 * (i + 1)
        elapsed = 0.0035 + hub.fixed(len(request), len(reply), 19200, 10) + (0.005 if i % 7 == 3 else 0.0)
        lines.append(json.dumps({"t": t, "dir": "rx", "hex": request.hex()}))
        lines.append(json.dumps({"t": t + elapsed, "dir": "tx", "hex": reply.hex()}))
    path = tmp_path / "hub.jsonl"
    path.write_text("\n".join(lines) + "\n")
    assert main(["fit", str(path), "--out", str(tmp_path / "told.toml")]) == 0
    out = capsys.readouterr().out
    assert "  link: hub, 19200 baud, 10-bit characters (replies of 2 lengths (5, 7 bytes): their times fit hub " in out
    assert "they grow by 1.00 of what hub's arithmetic adds over bare's (1.04 ms across them)" in out
    # the hub's arithmetic taken away, the turnaround is the drive's 3.5 ms (the base's is 2)
    assert re.search(r"\n  protocol\.turnaround_ms +3\.5 ms +\+-0\.5 +\(base 2\)\n", out), out
    assert main(["fit", str(path), "--out", str(tmp_path / "given.toml"), "--link", "hub"]) == 0
    assert "  link: hub, 19200 baud, 10-bit characters (as --link says)" in capsys.readouterr().out


def test_links_that_add_the_same_time_are_refused_saying_so() -> None:
    # no header: every link is a candidate; a line-timed pty's times are a serial line's exactly
    timings = capture("pty", 0.002, 3)
    with pytest.raises(C20SimError) as caught:
        choose_link(timings, tuple(LINKS), 19200, 10, "c.jsonl")
    message = str(caught.value)
    assert message.startswith(
        "c.jsonl: cannot tell how the capture was carried (bare or pty or serial or sniffer or device-server or "
        "gateway): "
    ), message
    # what a device server adds is a pty's and one more t3.5, and a sniffer's a pty's less the request's 8
    # characters (every request here is 8 bytes): the same for every length, so all five alike; bare is not
    alike = message.split("): ")[1].split(" add the same")[0].replace(" and ", ", ").split(", ")
    assert sorted(alike) == ["device-server", "gateway", "pty", "serial", "sniffer"], message
    assert message.endswith(
        " add the same time to each of its replies of 3 lengths (5, 7, 8 bytes) (less a constant, which the "
        f"turnaround takes): the times cannot tell them apart: give --link {alike[0]} or another (docs/fit.md, "
        "'What each link adds')"
    ), message
    # a sniffer's, told from a bare link's by the times even with no header: the others' arithmetic leaves its
    # replies sooner than their bytes take, and the slope tells sniffer from bare
    link, why = choose_link(capture("sniffer", 0.002, 3), tuple(LINKS), 19200, 10, "c.jsonl")
    assert link.name == "sniffer", why


def test_one_early_reply_of_a_small_group_is_not_its_floor() -> None:
    # what the gateway's arithmetic leaves of each transaction (ms) in a capture through serve's Modbus TCP on a
    # loaded machine: the ten 5-byte exceptions, one 0.9 ms before the others, and the 7-byte reads' 30 least
    # (228 more above them). The least of ten as the floor made the times grow by 1.85 of what a gateway adds
    exceptions = [3.46, 4.39, 4.4, 4.4, 4.42, 4.45, 5.89, 5.91, 6.93, 8.55]
    reads = [3.58, 4.06, 4.11, 4.23, 4.27, 4.28] + [4.31] * 6 + [4.32] * 4 + [4.33] * 6 + [4.34] * 5 + [4.35] * 3
    reads += [4.6] * 228
    gateway = LINKS["gateway"]
    timings = [
        Timing(0.0, net / 1000 + gateway.fixed(8, r, 19200, 10), 8, r)
        for r, values in ((5, exceptions), (7, reads))
        for net in values
    ]
    link, why = choose_link(timings, ("gateway", "bare"), 19200, 10, "capture.jsonl")
    assert link.name == "gateway", why
    # the second least of the exceptions (4.39) and the tenth percentile of the reads (4.34): 0.05 ms apart
    assert why.endswith("they grow by 0.95 of what gateway's arithmetic adds over bare's (1.04 ms across them)"), why

"""``GET /metrics``: the served simulator in the Prometheus text format, read at scrape time.

Everything is read when Prometheus asks, from what the simulator and the
line keep anyway (the drives' counters and telemetry, the line's latency
histogram and busy time), by a collector of the Prometheus client library
(``prometheus_client``), which also writes the format. Nothing is counted
for the metrics on the wire's path but the latency histogram's two additions
(:class:`c20sim.transport.line.Latency`), so a scrape every second costs the
replies nothing (bench/RESULTS.md).

Per drive (label ``drive``): the traffic counters of ``GET
/drives/N/counters``, exceptions by code (label ``code``), its state (one
series per state, the one it is in at 1), speed, set speed, bus voltage,
current, temperature, fault code. Per bus: the reply latency histogram, the
seconds the line was held by delayed replies, the requests waiting for it.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from dataclasses import dataclass

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.exposition import choose_encoder
from prometheus_client.registry import Collector, CollectorRegistry

from ..core.simulator import Simulator
from ..drive.statemachine import State
from ..drive.telemetry import Telemetry
from ..transport.line import LATENCY_BUCKETS, Line
from . import ops

__all__ = ["SimulatorCollector", "Snapshot", "exposition", "render", "snapshot", "snapshot_in_turns"]

#: Counters of GET /drives/N/counters that are plain totals -> (metric name, help).
_COUNTERS = {
    "requests": ("c20sim_requests", "Requests addressed to the drive (broadcasts included)"),
    "replies": ("c20sim_replies", "Normal replies the drive put on the line (exception replies are counted apart)"),
    "crc_errors": ("c20sim_crc_errors", "Frames with a bad CRC the drive saw"),
    "length_errors": ("c20sim_length_errors", "Frames of a wrong length the drive saw"),
    "silences": ("c20sim_silences", "Requests the drive did not answer (broadcasts, link faults)"),
    "injected": ("c20sim_injected", "Replies a link fault changed or dropped"),
}

#: Telemetry fields shown as gauges -> (metric name, help).
_GAUGES = {
    "speed_rpm": ("c20sim_speed_rpm", "Motor speed, signed (negative: reverse)"),
    "set_speed_rpm": ("c20sim_set_speed_rpm", "The speed the drive is set to"),
    "bus_v": ("c20sim_bus_voltage_volts", "DC bus voltage"),
    "current_a": ("c20sim_current_amperes", "Torque-producing current, signed"),
    "temperature_c": ("c20sim_temperature_celsius", "Power module temperature"),
    "fault_code": ("c20sim_fault_code", "The fault code of 2102H (0: no fault)"),
}


@dataclass(frozen=True)
class Snapshot:
    """What a scrape reports, read on the serving loop (cheap: plain values); formatted later, off the loop."""

    #: per drive: its address, its counters (``GET /drives/N/counters``), its telemetry
    drives: tuple[tuple[int, dict[str, object], Telemetry], ...]
    model_time: float
    #: the line's latency histogram (per bucket), its count and sum, busy seconds and requests waiting; or None
    line: tuple[tuple[int, ...], int, float, float, int] | None


#: Drives read per turn of the serving loop by :func:`snapshot_in_turns` (about 10 us each: a third of a ms a turn).
DRIVES_PER_TURN = 32


def _line_figures(line: Line | None) -> tuple[tuple[int, ...], int, float, float, int] | None:
    if line is None:
        return None
    latency = line.latency
    return (tuple(latency.counts), latency.count, latency.sum, line.busy_seconds, line.waiting)


def _drive_figures(sim: Simulator, address: int) -> tuple[int, dict[str, object], Telemetry]:
    """One drive's counters and telemetry as they are, the simulator synced by the caller: not
    :func:`ops.telemetry`, which syncs every drive for each one read (at 247 drives a scrape advanced the bus
    247 times over, about half a second of the serving loop)."""
    return address, ops.counters(sim, address), sim.drives[address].telemetry()


def snapshot(sim: Simulator, line: Line | None = None) -> Snapshot:
    """Read the figures now, all at once (the drives brought to the clock's time once, then a few us a drive)."""
    sim.sync()
    model_time = sim.now()
    drives = tuple(_drive_figures(sim, address) for address in sim.drives)
    return Snapshot(drives, model_time, _line_figures(line))


async def snapshot_in_turns(sim: Simulator, line: Line | None = None) -> Snapshot:
    """The same, :data:`DRIVES_PER_TURN` drives a turn of the loop, so a master's reply due meanwhile waits for
    one turn's reading at most. The drives are brought to the clock's time once, at the start: the snapshot is
    the bus at that time (a drive a master's request advanced meanwhile is read as that request left it)."""
    sim.sync()
    model_time = sim.now()
    drives: list[tuple[int, dict[str, object], Telemetry]] = []
    for i, address in enumerate(list(sim.drives)):
        if i and i % DRIVES_PER_TURN == 0:
            await asyncio.sleep(0)
        if address in sim.drives:  # a drive removed meanwhile is left out
            drives.append(_drive_figures(sim, address))
    return Snapshot(tuple(drives), model_time, _line_figures(line))


class SimulatorCollector(Collector):
    """Yields a snapshot's metric families (at each scrape: a fresh snapshot of ``sim``, or the one given)."""

    def __init__(self, sim: Simulator | None = None, line: Line | None = None, *, taken: Snapshot | None = None):
        self.sim = sim
        self.line = line
        self.taken = taken

    def collect(self) -> Iterator[Metric]:
        taken = self.taken
        if taken is None:
            assert self.sim is not None
            taken = snapshot(self.sim, self.line)
        counters = {key: CounterMetricFamily(name, text, labels=["drive"]) for key, (name, text) in _COUNTERS.items()}
        exceptions = CounterMetricFamily(
            "c20sim_exceptions", "Exception replies the drive sent, by exception code", labels=["drive", "code"]
        )
        gauges = {key: GaugeMetricFamily(name, text, labels=["drive"]) for key, (name, text) in _GAUGES.items()}
        state = GaugeMetricFamily(
            "c20sim_state", "The drive's state: 1 for the state it is in", labels=["drive", "state"]
        )
        for address, counted, telemetry in taken.drives:
            drive = str(address)
            for key, counter in counters.items():
                value = counted[key]
                assert isinstance(value, int)
                counter.add_metric([drive], value)
            by_code = counted["exceptions"]
            assert isinstance(by_code, dict)
            for code, value in sorted(by_code.items()):
                exceptions.add_metric([drive, code], value)
            for key, gauge in gauges.items():
                gauge.add_metric([drive], float(getattr(telemetry, key)))
            for s in State:
                state.add_metric([drive, s.value], 1.0 if telemetry.state == s.value else 0.0)
        yield from counters.values()
        yield exceptions
        yield from gauges.values()
        yield state
        yield GaugeMetricFamily("c20sim_model_time_seconds", "The model's time", value=taken.model_time)
        if taken.line is None:
            return
        counts, count, total, busy, waiting = taken.line
        buckets: list[tuple[str, float]] = []
        cumulative = 0
        for bound, in_bucket in zip(LATENCY_BUCKETS, counts, strict=False):
            cumulative += in_bucket
            buckets.append((repr(bound), cumulative))
        buckets.append(("+Inf", count))
        yield HistogramMetricFamily(
            "c20sim_reply_latency_seconds",
            "From a request's last byte to its reply handed to the port",
            buckets=buckets,
            sum_value=total,
        )
        yield CounterMetricFamily(
            "c20sim_line_busy_seconds",
            "Seconds the line was held (each transaction's RS485 time with bus timing; else delayed replies)",
            value=busy,
        )
        yield GaugeMetricFamily("c20sim_line_waiting", "Requests waiting for the line", value=waiting)


def render(taken: Snapshot, accept: str = "") -> tuple[bytes, str]:
    """A snapshot in the format the scraper's ``Accept`` header asks for (OpenMetrics, or the Prometheus text
    format 0.0.4 by default), as the client library negotiates it: pure work, for a worker thread."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(SimulatorCollector(taken=taken))
    encoder, content_type = choose_encoder(accept)
    return encoder(registry), content_type


def exposition(sim: Simulator, line: Line | None = None, accept: str = "") -> tuple[bytes, str]:
    """The metrics now, and their Content-Type (both steps at once, on the caller's thread)."""
    return render(snapshot(sim, line), accept)

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

from collections.abc import Iterator

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.exposition import choose_encoder
from prometheus_client.registry import Collector, CollectorRegistry

from ..core.simulator import Simulator
from ..drive.statemachine import State
from ..transport.line import LATENCY_BUCKETS, Line
from . import ops

__all__ = ["SimulatorCollector", "exposition"]

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


class SimulatorCollector(Collector):
    """Collects the simulator's drives and the line's figures at each scrape."""

    def __init__(self, sim: Simulator, line: Line | None = None) -> None:
        self.sim = sim
        self.line = line

    def collect(self) -> Iterator[Metric]:
        sim = self.sim
        sim.sync()
        counters = {key: CounterMetricFamily(name, text, labels=["drive"]) for key, (name, text) in _COUNTERS.items()}
        exceptions = CounterMetricFamily(
            "c20sim_exceptions", "Exception replies the drive sent, by exception code", labels=["drive", "code"]
        )
        gauges = {key: GaugeMetricFamily(name, text, labels=["drive"]) for key, (name, text) in _GAUGES.items()}
        state = GaugeMetricFamily(
            "c20sim_state", "The drive's state: 1 for the state it is in", labels=["drive", "state"]
        )
        for address in sim.drives:
            drive = str(address)
            counted = ops.counters(sim, address)
            for key, counter in counters.items():
                value = counted[key]
                assert isinstance(value, int)
                counter.add_metric([drive], value)
            by_code = counted["exceptions"]
            assert isinstance(by_code, dict)
            for code, value in sorted(by_code.items()):
                exceptions.add_metric([drive, code], value)
            telemetry = ops.telemetry(sim, address)
            for key, gauge in gauges.items():
                gauge.add_metric([drive], float(getattr(telemetry, key)))
            for s in State:
                state.add_metric([drive, s.value], 1.0 if telemetry.state == s.value else 0.0)
        yield from counters.values()
        yield exceptions
        yield from gauges.values()
        yield state
        yield GaugeMetricFamily("c20sim_model_time_seconds", "The model's time", value=sim.now())
        if self.line is None:
            return
        latency = self.line.latency
        buckets: list[tuple[str, float]] = []
        cumulative = 0
        for bound, count in zip(LATENCY_BUCKETS, latency.counts, strict=False):
            cumulative += count
            buckets.append((repr(bound), cumulative))
        buckets.append(("+Inf", latency.count))
        yield HistogramMetricFamily(
            "c20sim_reply_latency_seconds",
            "From a request's last byte to its reply handed to the port",
            buckets=buckets,
            sum_value=latency.sum,
        )
        yield CounterMetricFamily(
            "c20sim_line_busy_seconds",
            "Seconds the line was held (each transaction's RS485 time with bus timing; else delayed replies)",
            value=self.line.busy_seconds,
        )
        yield GaugeMetricFamily("c20sim_line_waiting", "Requests waiting for the line", value=self.line.waiting)


def exposition(sim: Simulator, line: Line | None = None, accept: str = "") -> tuple[bytes, str]:
    """The metrics now, and their Content-Type: the format the scraper's ``Accept`` header asks for
    (OpenMetrics, or the Prometheus text format 0.0.4 by default), as the client library negotiates it."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(SimulatorCollector(sim, line))
    encoder, content_type = choose_encoder(accept)
    return encoder(registry), content_type

"""GET /metrics' snapshot: the drives are brought to the clock's time once a scrape, not once a drive read."""

from __future__ import annotations

import asyncio

import pytest

from c20sim.control import metrics, ops
from c20sim.core.clock import VirtualClock
from c20sim.core.simulator import Simulator
from c20sim.drive.profile import load_profile


def _sim() -> Simulator:
    sim = Simulator(load_profile("c20-400hr"), range(1, 41), clock=VirtualClock())
    sim.clock.advance(2.5)
    return sim


def _count_syncs(sim: Simulator, monkeypatch: pytest.MonkeyPatch) -> list[float]:
    syncs: list[float] = []
    real = sim.sync

    def counted() -> None:
        syncs.append(sim.clock.now())
        real()

    monkeypatch.setattr(sim, "sync", counted)
    return syncs


@pytest.mark.parametrize("in_turns", [False, True])
def test_a_snapshot_syncs_the_bus_once_and_reads_every_drive_at_that_time(
    monkeypatch: pytest.MonkeyPatch, in_turns: bool
) -> None:
    sim = _sim()
    syncs = _count_syncs(sim, monkeypatch)
    taken = asyncio.run(metrics.snapshot_in_turns(sim)) if in_turns else metrics.snapshot(sim)
    assert syncs == [2.5]  # once, for 40 drives (it was once per drive read: 40 here, 247 on a full bus)
    assert taken.model_time == 2.5
    assert [address for address, _, _ in taken.drives] == list(range(1, 41))
    for address, counted, telemetry in taken.drives:
        assert telemetry == ops.telemetry(sim, address)  # what GET /drives/N/telemetry says at that time
        assert counted == ops.counters(sim, address)

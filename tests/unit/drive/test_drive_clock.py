"""Clocks: virtual time moves only by hand; real time follows an injected wall clock."""

from __future__ import annotations

import pytest

from c20sim.core.clock import Clock, RealtimeClock, VirtualClock


def test_virtual_clock_moves_only_when_told() -> None:
    clock = VirtualClock(5.0)
    assert clock.now() == 5.0
    assert clock.advance(3600.0) == 3605.0
    clock.set(4000.0)
    assert clock.now() == 4000.0
    assert isinstance(clock, Clock)


def test_virtual_clock_refuses_to_go_back() -> None:
    clock = VirtualClock(10.0)
    with pytest.raises(ValueError, match="backwards"):
        clock.advance(-1.0)
    with pytest.raises(ValueError, match="backwards"):
        clock.set(9.0)


class FakeWall:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_realtime_clock_scales_wall_time() -> None:
    wall = FakeWall()
    clock = RealtimeClock(10.0, t0=2.0, source=wall)
    assert clock.now() == 2.0
    wall.now = 101.5
    assert clock.now() == 17.0
    assert isinstance(clock, Clock)


def test_changing_speed_keeps_time_continuous() -> None:
    wall = FakeWall()
    clock = RealtimeClock(1.0, source=wall)
    wall.now = 104.0
    clock.speed = 100.0
    assert clock.now() == 4.0
    wall.now = 105.0
    assert clock.now() == 104.0
    with pytest.raises(ValueError):
        clock.speed = 0.0
    with pytest.raises(ValueError):
        RealtimeClock(-1.0, source=wall)

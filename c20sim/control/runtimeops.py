"""The frame log as the operations give it, and the realtime clock's runtime control (pause, resume, speed).

Part of :mod:`c20sim.control.ops` (which re-exports it). Pure: no I/O, no clock of its own.
"""

from __future__ import annotations

import itertools
from typing import Any

from ..core.bus import FrameRecord
from ..core.clock import RealtimeClock
from ..core.simulator import Simulator
from .opscore import ControlError, number

# --- The frame log.


def frames(
    sim: Simulator,
    *,
    last: int | None = None,
    slave: int | None = None,
    since: int = 0,
    first_seq: int = 0,
    wall_offset: float | None = None,
) -> list[dict[str, Any]]:
    """The frame log, oldest first, each record with its sequence number ``seq`` (from ``first_seq``).

    ``last`` keeps the newest N (N >= 1) of the records left after ``since`` and ``slave``;
    only the records kept are put in words, which is what costs. ``wall_offset`` (from the I/O layer)
    adds each frame's wall-clock time.
    """
    return frames_in_words(select_frames(sim, last=last, slave=slave, since=since, first_seq=first_seq), wall_offset)


def select_frames(
    sim: Simulator, *, last: int | None = None, slave: int | None = None, since: int = 0, first_seq: int = 0
) -> list[tuple[int, FrameRecord]]:
    """The records :func:`frames` keeps, with their sequence numbers (cheap: the records are not copied)."""
    if last is not None and (isinstance(last, bool) or last < 1):
        raise ControlError(f"last={last} must be at least 1")
    records = sim.bus.records
    skip = min(max(0, since - first_seq), len(records))
    kept = [
        (first_seq + i, record)
        for i, record in enumerate(itertools.islice(records, skip, None), start=skip)
        if slave is None or record.slave == slave
    ]
    if last is not None:
        kept = kept[-last:]
    return kept


def frames_in_words(kept: list[tuple[int, FrameRecord]], wall_offset: float | None = None) -> list[dict[str, Any]]:
    """Selected records in words: what costs, and touches no simulator state (records are frozen), so a worker
    thread may do it."""
    return [{"seq": seq, **record.as_dict(wall_offset)} for seq, record in kept]


# --- Runtime control: the clock.

#: The speed factors :func:`set_speed` takes: model seconds per wall second.
SPEED_RANGE = (0.001, 1000.0)


def clock_state(sim: Simulator) -> dict[str, Any]:
    """The clock: ``clock`` (virtual or realtime), ``t``, ``paused`` and ``speed`` (None for virtual)."""
    clock = sim.clock
    realtime = clock if isinstance(clock, RealtimeClock) else None
    return {
        "clock": "virtual" if sim.virtual else "realtime",
        "t": sim.now(),
        "paused": realtime.paused if realtime is not None else False,
        "speed": realtime.speed if realtime is not None else None,
    }


def _realtime(sim: Simulator, what: str) -> RealtimeClock:
    if not isinstance(sim.clock, RealtimeClock):
        raise ControlError(
            f"{what}: the clock is virtual and moves only when advanced; {what} is for serve --clock realtime", 409
        )
    return sim.clock


def pause(sim: Simulator) -> dict[str, Any]:
    """Stop the model's time (realtime clock; 409 for a virtual one): the drives stand still, and still
    answer the bus, until :func:`resume`."""
    clock = _realtime(sim, "pause")
    sim.sync()
    clock.pause()
    return clock_state(sim)


def resume(sim: Simulator) -> dict[str, Any]:
    """Let a paused realtime clock run on from where it stopped."""
    _realtime(sim, "resume").resume()
    return clock_state(sim)


def set_speed(sim: Simulator, factor: object) -> dict[str, Any]:
    """Set the realtime clock's speed factor (model seconds per wall second), with no jump in time."""
    clock = _realtime(sim, "speed")
    value = number("speed", factor, *SPEED_RANGE)
    sim.sync()
    clock.speed = value
    return clock_state(sim)

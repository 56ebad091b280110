"""The clock's routes: the model's time, advancing it, pausing and speeding the realtime clock, and a reset of
every drive."""

from __future__ import annotations

from typing import Any

from ..core.simulator import Simulator
from . import ops
from .routing import Field, Route


def _time(sim: Simulator) -> dict[str, Any]:
    return {"t": sim.now(), "clock": "virtual" if sim.virtual else "realtime"}


def _advance(sim: Simulator, seconds: object) -> dict[str, Any]:
    return {"t": ops.advance(sim, seconds)}


def _read_setup(sim: Simulator, fields: dict[str, Any]) -> dict[str, Any]:
    """The state file a reset names, read (bounded) before the reset: the blocking part, off the loop."""
    if "setup" in fields:
        fields["setup"] = ops.read_setup(sim, fields["setup"])
    return fields


#: The model's time and advancing it.
TIME: tuple[Route, ...] = (
    Route("GET", "/time", "time", "-", _time, help="the model's time"),
    Route(
        "POST",
        "/time/advance",
        "advance",
        '{"seconds": 1.5} (virtual clock only; 409 otherwise)',
        _advance,
        (Field("seconds", {"type": "number", "minimum": 0, "maximum": ops.MAX_ADVANCE}, True),),
        missing='give the time to advance by, such as {"seconds": 1.5}',
        changes=True,
        help="advance virtual time (serve --clock virtual)",
    ),
)

#: The clock, pausing, resuming and speeding it, and the reset.
CLOCK: tuple[Route, ...] = (
    Route(
        "GET",
        "/clock",
        "clock",
        "- (clock, t, paused, speed)",
        ops.clock_state,
        help="the clock: virtual or realtime, t, paused, speed",
    ),
    Route(
        "POST",
        "/clock/pause",
        "pause",
        "- (realtime clock: model time stops; 409 for a virtual clock)",
        ops.pause,
        changes=True,
        help="stop the model's time (realtime clock)",
    ),
    Route(
        "POST",
        "/clock/resume",
        "resume",
        "- (realtime clock: model time runs on)",
        ops.resume,
        changes=True,
        help="let the model's time run on (realtime clock)",
    ),
    Route(
        "PUT",
        "/clock/speed",
        "set_speed",
        '{"speed": 10} (realtime clock: model seconds per wall second, 0.001-1000)',
        lambda sim, speed: ops.set_speed(sim, speed),
        (Field("speed", {"type": "number", "minimum": ops.SPEED_RANGE[0], "maximum": ops.SPEED_RANGE[1]}, True),),
        missing='give the speed factor, such as {"speed": 10}',
        changes=True,
        cli="speed",
        help="set the realtime clock's speed factor, such as 10",
    ),
    Route(
        "POST",
        "/reset",
        "reset",
        '{"setup": "defaults"} or {"setup": "PATH of a state file"}: every drive anew, no restart',
        ops.reset,
        (Field("setup", {"type": "string", "description": '"defaults", or the path of a state file (--state)'}),),
        changes=True,
        help="every drive anew, no restart: defaults, or a state file's function codes",
        offload=_read_setup,
    ),
)

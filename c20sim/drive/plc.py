"""The simple PLC: speed source 6 (2007H = F00.02 = 6), a programme of timed speed stages.

The sheet lists 2007H = 6 "simple PLC setting" and no more. The INVT Goodrive family the sheet follows runs
its simple PLC from its P10 group (P10.00 the mode: stop after one cycle, hold the last stage's speed, or
cycle; then each stage's speed and running time) and can signal "stage completed" and "cycle completed" on
an output terminal. Here (all **assumed** for the C20, numbered after INVT):

- F10.00 the mode: 0 stop after one cycle (a ramp stop), 1 run on at the last stage's speed, 2 cycle;
- F10.02 + 2n, F10.03 + 2n: stage n's speed (rpm) and running time (0.1 s), n = 0-7; a stage of time 0 is
  skipped;
- the programme starts at its first stage whenever the drive starts running (forward or reverse, the
  direction the command's) with speed source 6, and goes back to it whenever the drive stops or trips;
- each stage's time runs from the stage's start, the ramp to its speed included;
- Y3 (300EH bit 2) pulses for :data:`PULSE_S` at each stage's end, Y4 (bit 3) at each cycle's end.

Stage ends are steps, so a steady segment stops at them (:meth:`Plc.due`) and the programme steps the same
whatever the polling; the flags are a function of the step, read between steps too.
"""

from __future__ import annotations

from collections.abc import Callable

from ..wire.registers import fcode_address
from .physics import STEP
from .terminals import Output

__all__ = [
    "CYCLE",
    "F_PLC_MODE",
    "F_STAGE_SPEED",
    "F_STAGE_TIME",
    "HOLD_LAST",
    "PULSE_S",
    "STAGES",
    "STOP_AFTER",
    "Plc",
]

F_PLC_MODE = fcode_address(10, 0)
STAGES = 8
F_STAGE_SPEED = tuple(fcode_address(10, 2 + 2 * n) for n in range(STAGES))
F_STAGE_TIME = tuple(fcode_address(10, 3 + 2 * n) for n in range(STAGES))
STOP_AFTER, HOLD_LAST, CYCLE = 0, 1, 2
#: How long the stage and cycle flags stay on (s; assumed).
PULSE_S = 0.5
_PULSE = round(PULSE_S / STEP)


class Plc:
    """One drive's simple PLC: which stage it is in, when that ends, and its flags."""

    __slots__ = ("active", "cycle_until", "cycles", "end", "stage", "stage_until")

    def __init__(self) -> None:
        self.stage_until = self.cycle_until = -1  #: the flags are on before these steps
        self.reset()

    def reset(self) -> None:
        """Back to the first stage, not running (the flags keep their pulse)."""
        self.active = False
        self.stage = 0
        self.end: int | None = None  #: the step the stage ends on; None: holding the last stage's speed
        self.cycles = 0

    @staticmethod
    def programme(get: Callable[[int], int], scale: float) -> list[tuple[int, int]]:
        """(stage number, its time in steps) of the stages that run, in order."""
        out = []
        for n in range(STAGES):
            steps = round(get(F_STAGE_TIME[n]) * scale / STEP)
            if steps > 0:
                out.append((n, steps))
        return out

    def speed(self, get: Callable[[int], int]) -> float:
        """The stage's speed (rpm)."""
        return float(get(F_STAGE_SPEED[self.stage]))

    def start(self, k: int, get: Callable[[int], int], scale: float) -> bool:
        """The drive started running at step ``k``: the first stage. False if the programme has none."""
        stages = self.programme(get, scale)
        self.active, self.cycles = True, 0
        if not stages:
            self.end = None
            return False
        self.stage, steps = stages[0]
        self.end = k + steps
        return True

    def due(self, k: int) -> bool:
        """Whether a stage ends by step ``k`` (monotone in ``k``)."""
        return self.active and self.end is not None and k >= self.end

    def next_stage(self, k: int, get: Callable[[int], int], scale: float) -> bool:
        """The stage ended at step ``k``: on to the next; at the programme's end, by the mode. True if the drive
        is to stop (mode 0 after its cycle)."""
        self.stage_until = k + _PULSE
        stages = self.programme(get, scale)
        later = [(n, steps) for n, steps in stages if n > self.stage]
        if later:
            self.stage, steps = later[0]
            self.end = k + steps
            return False
        self.cycle_until = k + _PULSE
        self.cycles += 1
        mode = get(F_PLC_MODE)
        if mode == CYCLE and stages:
            self.stage, steps = stages[0]
            self.end = k + steps
            return False
        self.end = None  # holding the last stage's speed, or stopping
        return mode == STOP_AFTER

    def flags(self, k: int) -> int:
        """Y3 and Y4 at step ``k``: a stage, a cycle just completed."""
        bits = 0
        if k < self.stage_until:
            bits |= Output.Y3
        if k < self.cycle_until:
            bits |= Output.Y4
        return bits

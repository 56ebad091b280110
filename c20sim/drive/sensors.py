"""The Hall sensors: the codes the rotor's angle gives, their edges, and the speed measured from them.

:class:`Hall` follows the rotor's electrical angle step by step (or across a
steady segment in one jump) and keeps the last edge and the speed measured
at it, as a drive with Hall sensors does: 3009H is the code at the rotor's
angle when read, 3006H the speed from the time between the last two edges,
which at low speed steps once per edge and lags, and reads 0 when no edge
came for :data:`HALL_TIMEOUT`. A broken sensor (:class:`HallFault`) gives
stuck or out-of-order codes, which the protection sees as
:attr:`Hall.glitch`.
"""

from __future__ import annotations

import enum
import math

from . import physics
from .physics import RPM, STEP, Segment

__all__ = ["HALL_TIMEOUT", "Hall", "HallFault", "noise"]

#: 3006H reads 0 when no Hall edge came for this long (s; assumed): 25 rpm at 4 pole pairs.
HALL_TIMEOUT = 0.1


class HallFault(enum.Enum):
    """A broken Hall sensor, as injected."""

    STUCK0 = "stuck0"  #: all three sensors read 0
    STUCK7 = "stuck7"  #: all three sensors read 1
    SEQUENCE = "sequence"  #: codes come out of order (a bad sensor or wiring)


class Hall:
    """The three Hall sensors on a rotor: its electrical angle, the last edge, and whether a code was bad."""

    __slots__ = ("before", "edge_rpm", "edge_t", "fault", "glitch", "seg_edge", "theta")

    def __init__(self) -> None:
        self.fault: HallFault | None = None
        self.reset()

    def reset(self) -> None:
        """At power-up: the rotor's angle at 0, no edge seen."""
        self.theta = 0.0  # the rotor's electrical angle at the last step
        self.edge_t: float | None = None  # time of the last Hall edge
        self.edge_rpm = 0.0  # the speed measured at it, from the time since the edge before
        self.seg_edge: tuple[float | None, float] = (None, 0.0)  # the two at a segment's start
        self.before = self.code()
        self.glitch = False  # the last step's code was stuck or out of sequence

    def code(self, theta: float | None = None) -> int:
        """The Hall code at the last step's angle, or at electrical angle ``theta``."""
        if theta is None:
            theta = self.theta
        fault = self.fault
        if fault is HallFault.STUCK0:
            return 0
        if fault is HallFault.STUCK7:
            return 7
        if fault is HallFault.SEQUENCE:  # every other code: each change flips two bits
            return physics.hall_code((2.0 * theta) % physics.TWO_PI)
        return physics.hall_code(theta)

    def step(self, speed: float, pole_pairs: int, t_start: float) -> None:
        """One step from ``t_start`` at ``speed`` (rpm): the edges crossed, the new angle and code."""
        self.edges(self.theta, speed * RPM * pole_pairs * STEP, t_start, 1, pole_pairs)
        self.theta = (self.theta + speed * RPM * pole_pairs * STEP) % physics.TWO_PI
        hall = self.code()
        # Healthy codes step through the sequence; an out-of-order sensor shows itself at its first edge.
        self.glitch = hall in (0, 7) or (self.fault is HallFault.SEQUENCE and hall != self.before)
        self.before = hall

    def mark_segment(self) -> None:
        """A steady segment starts: remember the last edge, from which its later edges are counted."""
        self.seg_edge = (self.edge_t, self.edge_rpm)

    def skip(self, seg: Segment, n: int, t_start: float, pole_pairs: int) -> None:
        """Step ``n`` of steady segment ``seg`` that started at ``t_start``: its edges, angle and code."""
        self.edge_t, self.edge_rpm = self.seg_edge
        self.edges(seg.theta0, seg.theta_rate * n, t_start, n, pole_pairs)
        self.theta = seg.theta(n)
        self.before = self.code()

    def now(self, since: float, speed: float, pole_pairs: int) -> int:
        """3009H: the code at the rotor's angle ``since`` s after the last step (no code skipped)."""
        theta = (self.theta + speed * RPM * pole_pairs * since) % physics.TWO_PI
        return self.code(theta)

    def edges(self, theta: float, move: float, t_start: float, steps: int, pole_pairs: int) -> None:
        """Record the Hall edges crossed moving ``move`` electrical radians from ``theta`` over ``steps`` steps."""
        self.edge_t, self.edge_rpm = self.edges_after(theta, move, t_start, steps * STEP, pole_pairs)

    def edges_after(
        self, theta: float, move: float, t_start: float, span: float, pole_pairs: int
    ) -> tuple[float | None, float]:
        """The last Hall edge and the speed measured at it, after moving ``move`` rad from ``theta`` in ``span`` s.

        The speed is measured from the time between the last two edges, as a drive with Hall sensors
        does: at low speed the reading steps once per edge and lags; two or more edges in the stretch
        (whose speed is constant) measure that speed exactly.
        """
        if move == 0.0:
            return self.edge_t, self.edge_rpm
        sector = physics.SECTOR
        end = theta + move
        if move > 0.0:
            crossed = math.floor(end / sector) - math.floor(theta / sector)
            last = math.floor(end / sector) * sector
        else:
            crossed = math.ceil(theta / sector) - math.ceil(end / sector)
            last = math.ceil(end / sector) * sector
        if crossed <= 0:
            return self.edge_t, self.edge_rpm
        t_edge = t_start + (last - theta) / move * span
        if crossed >= 2:  # the speed was constant over the stretch: its edges are evenly spaced
            return t_edge, abs(move) / span / (RPM * pole_pairs)
        if self.edge_t is not None and t_edge > self.edge_t:
            return t_edge, 60.0 / (6 * pole_pairs) / (t_edge - self.edge_t)
        return t_edge, 0.0

    def rpm(self, t: float, t_step: float, speed: float, pole_pairs: int) -> float:
        """The speed the Halls give at time ``t``, the last step being at ``t_step`` with the rotor at ``speed``.

        The last edge's measurement, bounded by the time since that edge (a slowing rotor reads lower
        before its next edge), and 0 once no edge came for :data:`HALL_TIMEOUT`.
        """
        since_step = t - t_step
        move = speed * RPM * pole_pairs * since_step
        edge_t, measured = self.edges_after(self.theta, move, t_step, since_step, pole_pairs)  # since the step
        since = t - edge_t if edge_t is not None else math.inf
        if since > HALL_TIMEOUT:
            return 0.0
        per_rpm = 60.0 / (6 * pole_pairs)  # rpm x seconds per sector
        return min(measured, per_rpm / since) if since > 0.0 else measured


def noise(seed: int, k: int) -> float:
    """A uniform value in [-1, 1) fixed by ``seed`` and step ``k``: the same at every look (splitmix64)."""
    z = (seed * 0x9E3779B97F4A7C15 + k * 0xBF58476D1CE4E5B9 + 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    z ^= z >> 31
    return z / 2.0**63 - 1.0

"""The physics of one internal step, as pure functions, and the steady segment.

Each function advances one quantity by one fixed step and is written so the
same inputs give the same floats: the model's determinism rests on it. Fast
quantities (the DC bus, whose RC constant is below a millisecond) use the
exact solution of their linear ODE over the step, so the fixed step stays
stable. :class:`Segment` is the closed form of a drive whose every input is
constant: only temperature, the I^2 t budgets and the rotor angle move, each
as an explicit function of the step count, so a segment is evaluated at any
step directly and skipping ahead costs nothing and changes nothing.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

__all__ = [
    "HALL_SEQUENCE",
    "RPM",
    "STEP",
    "TWO_PI",
    "Segment",
    "active_torque",
    "bus_step",
    "free_motion",
    "hall_code",
    "overload_rate",
    "ramp_toward",
    "s_ramp_toward",
]

#: The model's fixed internal step, seconds.
STEP = 0.001

#: rad/s per rpm.
RPM = 2.0 * math.pi / 60.0
TWO_PI = 2.0 * math.pi
SECTOR = math.pi / 3.0

#: 120-degree Hall codes through one electrical revolution, forward (each step flips one bit).
HALL_SEQUENCE = (1, 3, 2, 6, 4, 5)

ACCEL, DECEL, CONSTANT = "accel", "decel", "constant"


def ramp_toward(ref: float, target: float, up: float, down: float) -> tuple[float, str]:
    """Move the ramp output one step toward ``target`` (rpm, signed).

    Away from zero it moves by ``up``, toward zero by ``down``; a change of
    sign goes through zero at the deceleration rate first. Returns the new
    value and the phase (accel, decel or constant) for the fault codes.
    """
    if ref == target:
        return ref, CONSTANT
    if ref * target < 0.0 or abs(target) < abs(ref):
        floor = target if ref * target > 0.0 else 0.0
        return (max(ref - down, floor) if ref > 0.0 else min(ref + down, floor)), DECEL
    return (min(ref + up, target) if target > ref else max(ref - up, target)), ACCEL


def s_ramp_toward(
    ref: float, rate: float, target: float, up: float, down: float, start: float, end: float, full: float
) -> tuple[float, float, str]:
    """Move an S-curve ramp one step toward ``target`` (rpm, signed): (new value, new rate per step, phase).

    The rate (rpm per step) rises at a constant jerk over the ``start`` share of the ramp time, holds, and
    falls at a constant jerk over the ``end`` share so the ramp arrives at its target with no rate left (INVT
    P01.05-P01.07). Its peak is such that a change of ``full`` (the maximum speed) takes the time the linear
    rate ``up`` or ``down`` gives it, as a linear ramp would; a shorter change ends sooner. Away from zero it
    uses ``up``, toward zero (or through it) ``down``, as :func:`ramp_toward`.
    """
    if ref == target and rate == 0.0:
        return ref, 0.0, CONSTANT
    decel = ref * target < 0.0 or abs(target) < abs(ref)
    linear = down if decel else up
    peak = linear / (1.0 - 0.5 * (start + end))
    steps = full / linear  # the ramp time in steps
    rise = peak / (start * steps) if start > 0.0 else math.inf
    fall = peak / (end * steps) if end > 0.0 else math.inf
    way = 1.0 if target > ref else -1.0
    speed = rate * way  # the rate toward the target (negative: still moving away from it)
    left = abs(target - ref)
    stopping = speed * speed / (2.0 * fall) + 0.5 * speed if fall < math.inf else 0.0
    if speed > 0.0 and left <= stopping:
        # The rate whose fall at the end jerk covers exactly what is left: the ramp lands with no rate left.
        speed = math.sqrt(2.0 * fall * left + 0.25 * fall * fall) - 0.5 * fall
    else:
        speed = min(speed + rise, peak)
    if speed >= left:
        return target, 0.0, (DECEL if decel else ACCEL)
    return ref + way * speed, way * speed, (DECEL if decel else ACCEL)


def free_motion(speed: float, drive_torque: float, hold: float, viscous: float, inertia: float, dt: float) -> float:
    """Speed (rpm) after ``dt`` under a drive torque against friction and load.

    ``hold`` (Coulomb friction plus load torque, N m) opposes motion and can
    stop the rotor but never turn it backwards; ``viscous`` is N m per rpm.
    """
    if speed == 0.0:
        if abs(drive_torque) <= hold:
            return 0.0
        net = drive_torque - math.copysign(hold, drive_torque)
    else:
        net = drive_torque - math.copysign(hold, speed) - viscous * speed
    new = speed + net / inertia * dt / RPM
    if speed != 0.0 and new * speed <= 0.0 and not (drive_torque * new > 0.0 and abs(drive_torque) > hold):
        return 0.0
    return new


def active_torque(torque: float, speed: float, knee: float, free: float) -> float:
    """An active (overhauling) load's torque (N m, signed) at ``speed`` (rpm): its speed-torque characteristic.

    Full up to ``knee`` rpm, and whenever it opposes the motion; pushing the rotor faster than ``knee`` it falls
    linearly to zero at ``free`` rpm, where the load's own drag balances its pull. A free rotor driven by it
    settles below ``free``, where what is left of it meets the friction. Below the knee the value is the
    torque itself, bit for bit.
    """
    if torque * speed <= 0.0 or abs(speed) <= knee:
        return torque
    return torque * max(0.0, (free - abs(speed)) / (free - knee))


def bus_step(
    v: float,
    supply: float,
    load_a: float,
    *,
    inv_source: float,
    inv_bleed: float,
    inv_brake: float,
    chopper_v: float,
    capacitance: float,
    dt: float,
) -> float:
    """DC bus voltage after ``dt``: the capacitor between supply, load, bleed and brake resistor.

    The supply feeds through its source resistance and a rectifier (it can
    only charge the bus); the load draws ``load_a`` (negative when the motor
    regenerates); the brake chopper above ``chopper_v`` switches the brake
    resistor at kHz, so over a step it acts by its average: it holds the bus
    at ``chopper_v`` with the duty that takes what is fed in, up to the
    resistor fully on, and a bus fed more than that rises above the level. The
    ODE is linear over one step for each duty, solved exactly.
    """
    b = inv_bleed
    a = -load_a
    if v < supply:
        a += supply * inv_source
        b += inv_source
    new = _bus_solve(v, a, b, capacitance, dt)
    if chopper_v > 0.0 and new > chopper_v:
        new = max(_bus_solve(v, a, b + inv_brake, capacitance, dt), chopper_v)
    if new < 0.0 or (supply == 0.0 and new < 0.05):
        return 0.0  # a dead bus settles at exactly zero, so an unpowered drive idles
    return new


def _bus_solve(v: float, a: float, b: float, capacitance: float, dt: float) -> float:
    """The bus after ``dt`` from ``v`` under C dv/dt = a - b v."""
    v_inf = a / b
    return v_inf + (v - v_inf) * math.exp(-dt * b / capacitance)


def overload_rate(ratio: float, curve: tuple[tuple[float, float], ...], cooling_s: float) -> float:
    """Fraction of an overload budget used per second at ``ratio`` times the rated current.

    Above rated current the budget fills at 1 / (time to trip), the time
    interpolated on the inverse-time ``curve`` linearly in log time against
    log current; between rated current and the curve's first point the rate
    falls linearly to zero; past its last point it grows with the square of
    the current. At or below rated current the budget cools away: all of it
    in ``cooling_s`` at zero current (thermal memory).
    """
    if ratio <= 1.0:
        return -(1.0 - ratio * ratio) / cooling_s
    m0, t0 = curve[0]
    if ratio <= m0:
        return (ratio - 1.0) / (m0 - 1.0) / t0
    for (ma, ta), (mb, tb) in itertools.pairwise(curve):
        if ratio <= mb:
            x = math.log(ratio / ma) / math.log(mb / ma)
            return 1.0 / (ta * math.exp(x * math.log(tb / ta)))
    ml, tl = curve[-1]
    return (ratio / ml) ** 2 / tl


def hall_code(theta: float) -> int:
    """The Hall code of a healthy sensor at electrical angle ``theta`` (0 to 2 pi)."""
    return HALL_SEQUENCE[min(int(theta / SECTOR), 5)]


@dataclass(frozen=True, slots=True)
class Segment:
    """A steady stretch from step ``k0``: the closed forms of what still moves."""

    k0: int
    temp0: float
    temp_ss: float
    temp_rate: float  #: step / thermal time constant
    motor_i2t0: float
    motor_rate: float  #: I^2 t budget used per step (negative: recovering)
    drive_i2t0: float
    drive_rate: float
    theta0: float
    theta_rate: float  #: electrical radians per step

    def temp(self, n: int) -> float:
        if self.temp0 == self.temp_ss:
            return self.temp_ss
        return self.temp_ss + (self.temp0 - self.temp_ss) * math.exp(-n * self.temp_rate)

    def motor_i2t(self, n: int) -> float:
        return max(0.0, self.motor_i2t0 + n * self.motor_rate)

    def drive_i2t(self, n: int) -> float:
        return max(0.0, self.drive_i2t0 + n * self.drive_rate)

    def theta(self, n: int) -> float:
        return (self.theta0 + n * self.theta_rate) % TWO_PI


#: The motor's and the drive's overload budgets: each trips when its I^2 t reaches it.
BUDGET = 1.0

"""The integrator: the motor, the speed loop, the DC bus, heat and overload, one fixed step at a time.

:class:`Integrator` holds what moves with time (speed, ramp, current, bus,
temperature, the two I^2 t budgets, the stalled and braking step counters)
and advances it by one :data:`~c20sim.drive.physics.STEP` for a drive in a
given state. A speed loop of finite bandwidth (the ramp's torque fed forward,
a PI on the rest) drives a current clamped at the current limit; what it asks
is what overcurrent trips on. Current limiting (F11.05/F11.06, on by default as
INVT ships it) cuts the ramp's step so the loop asks no more than its level:
a heavy start or stop stretches instead of tripping; with it off, a ramp that
asks more than the trip level trips OC1/OC2. Overvoltage stall prevention (F11.03/F11.04)
is a regulator on the braking current that holds the bus at its level, moving at its own rate
(:meth:`Integrator.stall_regulate`); the motor
and the drive each have an inverse-time overload curve with thermal memory
(F02.27 scales the motor's); losses and so heating come from the current;
loads are passive (opposing motion) or active (signed, a hoist's weight, with
its own speed-torque characteristic: :func:`~c20sim.drive.physics.active_torque`).

A settled drive with constant inputs enters a :class:`~c20sim.drive.physics.Segment`:
its closed forms give the state at any later step directly, bit for bit as if
it had stepped, up to the first step a protection (which decides, not this)
would trip on.
"""

from __future__ import annotations

import math

from . import physics
from .config import Conditions, Config
from .physics import CONSTANT, DECEL, RPM, STEP, Segment
from .profile import Profile
from .segments import SteadySegments, target_rpm
from .sensors import Hall
from .statemachine import DRIVEN, RUNNING, State

__all__ = ["SETTLED_RPM", "ZERO_RPM", "Integrator", "target_rpm"]

#: Speed errors below this (rpm) while running at a constant set speed are settled: the loop is at rest.
SETTLED_RPM = 1e-6
#: Stopping on the ramp, the drive takes the rotor as stopped below this speed (rpm; assumed).
ZERO_RPM = 1.0

#: Overvoltage stall prevention closes the bus's distance from the stall level over this time (s; assumed:
#: well inside the bus's own time constants, slow enough for a 1 ms step not to ring).
STALL_CLOSE_S = 0.002
#: The stall regulator's braking current moves by at most this share of the current limit per 1 ms step
#: (assumed): from no braking to the limit in 10 ms.
STALL_SLEW_SHARE = 0.1
#: What is left of the bus's distance from the stall level after one step on the regulator's path.
STALL_DECAY = math.exp(-STEP / STALL_CLOSE_S)
#: Riding through a power loss (F11.01), the output frequency may fall from the maximum to zero in this share of
#: a second (a ramp faster than the regulator lets it go: the regulator sets the pace; assumed).
RIDE_DOWN = STEP / 0.05
#: The ride-through ends when the bus is back this far above its level (the supply back; assumed).
RIDE_EXIT = 1.05

Control = tuple[float, float, float, float, bool, float]  # ramp, current, new speed, integrator, limited, demand


class Integrator(SteadySegments):
    """What moves with time in one drive, and the step that moves it."""

    __slots__ = (  # k, temp, the two I^2 t budgets and the segment are SteadySegments' slots, which move them too
        *("bench", "capacitance", "cfg", "hall", "inv_bleed", "inv_brake", "inv_source", "profile", "t0"),
        *("brake_steps", "bus", "bus_settled", "current", "demand", "integ", "limited", "loss"),
        *("phase", "power", "ramp", "rate", "regen_a", "riding", "speed", "speed_before", "stall_steps"),
        *("temp_decay", "temp_rate", "active_now"),
    )
    cfg: Config
    segment: Segment | None

    def __init__(self, profile: Profile, bench: Conditions, hall: Hall, t0: float) -> None:
        self.profile, self.bench, self.hall, self.t0 = profile, bench, hall, t0
        s, th = profile.supply, profile.thermal
        self.k = 0
        self.capacitance = s.bus_capacitance_uf * 1e-6
        self.inv_source = 1.0 / max(s.source_resistance_ohm, 1e-3)
        self.inv_bleed = self.capacitance / s.bleed_time_constant_s
        self.inv_brake = 1.0 / s.brake_resistor_ohm
        self.temp_rate = STEP / th.time_constant_s
        self.temp_decay = math.exp(-self.temp_rate)
        self.temp = bench.ambient  # the temperature survives a power cycle

    def power_up(self) -> None:
        """At rest, the bus at the level the supply gives a stopped drive, the overload budgets full."""
        self.speed = self.speed_before = self.ramp = self.current = self.power = self.loss = 0.0
        self.integ = self.demand = self.active_now = 0.0
        self.regen_a = -1.0  # the stall regulator's braking current; < 0: disengaged
        self.riding = False  # riding through a power loss (F11.01)
        self.rate = 0.0  # the ramp's rate, rpm per step (an S curve goes on from it)
        self.bus: float = self.bus_rest(self.bench.supply)  # annotated: mypyc's own type pass cannot infer it
        self.bus_settled, self.limited, self.phase = True, False, CONSTANT
        self.motor_i2t = self.drive_i2t = 0.0
        self.stall_steps = self.brake_steps = 0
        self.segment = None

    def bus_rest(self, supply: float) -> float:
        """The bus of a stopped drive: the supply divided by the source and bleed resistances."""
        if supply <= 0.0:
            return 0.0
        return supply * self.inv_source / (self.inv_source + self.inv_bleed)

    def entered(self, was_driven: bool, driven: bool) -> None:
        """The state changed: a start catches a turning rotor where it is, an output off drops the current."""
        if driven and not was_driven:
            self.ramp = self.speed
        if not driven:
            self.ramp = self.current = self.power = self.loss = 0.0
            self.integ = self.demand = 0.0
        self.regen_a = -1.0
        if not driven:
            self.rate = 0.0
        self.brake_steps = self.stall_steps = 0
        self.segment = None

    # --- The step.

    def step(self, state: State) -> None:
        """One step of a drive in ``state``."""
        self.k += 1
        cfg, m, prot, th = self.cfg, self.profile.motor, self.profile.protection, self.profile.thermal
        kt, resistance = m.kt_nm_per_a, m.resistance_ohm
        speed = self.speed
        limited = False
        emf = kt * speed * RPM
        self.active_now = (
            physics.active_torque(cfg.active, speed, cfg.active_knee_rpm, cfg.active_free_rpm) if cfg.active else 0.0
        )
        if state in DRIVEN:
            target = target_rpm(state, cfg)
            riding = self.ride(state) if cfg.ride_v or self.riding else False
            aim = 0.0 if riding else target  # riding through a power loss: slowing, on the load's energy
            down = cfg.max_rpm * RIDE_DOWN if riding else cfg.down
            if cfg.s_start or cfg.s_end:
                ramp, _rate, phase = physics.s_ramp_toward(
                    self.ramp, self.rate, aim, cfg.up, down, cfg.s_start, cfg.s_end, cfg.max_rpm
                )
            else:
                ramp, phase = physics.ramp_toward(self.ramp, aim, cfg.up, down)
            full = self.control(state, ramp, aim, speed, emf)
            bound = cfg.limit_a if cfg.limit_a and phase != CONSTANT else math.inf
            if phase == DECEL and (riding or cfg.stall_v):
                bound = min(bound, self.stall_regulate(speed, emf, cfg.ride_v if riding else cfg.stall_v))
            else:
                self.regen_a = -1.0  # disengaged: the next deceleration starts it afresh
            if bound < math.inf and ramp != self.ramp:
                full = self.limited_to(state, full, ramp, aim, speed, emf, bound)
            ramp, current, new_speed, integ, limited, wanted = full
            self.integ, self.demand = integ, wanted
            # The S curve goes on from the rate the ramp actually moved at (a limit may have cut the step).
            self.rate = ramp - self.ramp if ramp != aim else 0.0
        else:
            target, ramp, phase = 0.0, 0.0, CONSTANT
            # Output off: only the freewheeling diodes conduct, once the back-EMF exceeds the bus.
            current = 0.0 if abs(emf) <= self.bus else -math.copysign(abs(emf) - self.bus, emf) / resistance
            new_speed = physics.free_motion(
                speed, kt * current + self.active_now, cfg.hold, cfg.viscous, cfg.inertia, STEP
            )
        bus, power, loss = self.bus_after(new_speed, current)
        self.bus_settled = abs(bus - self.bus) <= 1e-9  # the chopper's average holds a bus at its level: settled
        temp_ss = self.bench.ambient + loss * th.resistance_k_per_w
        self.temp = temp_ss + (self.temp - temp_ss) * self.temp_decay
        self.motor_i2t = max(0.0, self.motor_i2t + STEP * self.motor_rate(current))
        self.drive_i2t = max(0.0, self.drive_i2t + STEP * self.drive_rate(current))
        self.hall.step(new_speed, cfg.pole_pairs, self.t0 + (self.k - 1) * STEP)
        if state in RUNNING and abs(target) > prot.stall_speed_rpm and abs(new_speed) < prot.stall_speed_rpm:
            self.stall_steps += 1
        else:
            self.stall_steps = 0
        if state is State.BRAKING:
            self.brake_steps += 1
        self.speed_before, self.speed, self.ramp, self.current = speed, new_speed, ramp, current
        self.power, self.loss, self.bus, self.phase, self.limited = power, loss, bus, phase, limited

    def control(self, state: State, ramp: float, target: float, speed: float, emf: float) -> Control:
        """One step of the speed loop toward ``ramp``: (ramp, current, new speed, integrator, limited, demand).

        The ramp's acceleration torque is fed forward and a PI on the speed error does the rest (open loop,
        F00.00 = 1: a P alone, so the speed droops under load); the current limit clamps the current and holds
        the ramp back to the rotor. Nothing is changed.
        """
        cfg, m, prot = self.cfg, self.profile.motor, self.profile.protection
        kt, resistance = m.kt_nm_per_a, m.resistance_ohm
        error = (self.ramp - speed) * RPM  # where the rotor should be now; the feedforward takes it on
        integ = self.integ + cfg.ki * error * STEP
        wanted = (cfg.inertia * (ramp - self.ramp) * RPM / STEP + cfg.kp * error + integ) / kt
        high = min(prot.current_limit_a, (self.bus - emf) / resistance)
        low = max(-prot.current_limit_a, (-self.bus - emf) / resistance)
        limited = not low <= wanted <= high
        if limited:  # the integrator holds (no wind-up)
            integ = self.integ
            current = high if wanted > high else low
        else:
            current = wanted
        new_speed = physics.free_motion(speed, kt * current + self.active_now, cfg.hold, cfg.viscous, cfg.inertia, STEP)
        if limited:
            ramp = new_speed  # the current limit holds the ramp back
        elif (
            ramp == target and new_speed != (rest := self.rest_rpm(ramp)) and abs(new_speed - rest) < settled_rpm(state)
        ):
            # The loop has settled on a constant set speed: at rest exactly, so the drive can skip ahead.
            new_speed = rest
            if cfg.open_loop:  # no integrator: the rotor rests where the error's torque holds the load
                integ, current = 0.0, cfg.kp * (ramp - rest) * RPM / kt
            else:
                active = physics.active_torque(cfg.active, ramp, cfg.active_knee_rpm, cfg.active_free_rpm)
                integ = (math.copysign(cfg.hold, ramp) if ramp else 0.0) + cfg.viscous * ramp - active
                current = integ / kt
        return ramp, current, new_speed, integ, limited, wanted

    def rest_rpm(self, ramp: float) -> float:
        """Where the rotor settles at a constant ramp: on it in closed loop; in open loop (F00.00 = 1) below it
        by the slip the load needs, the loop's proportional torque kt^2 / R per rad/s (a voltage-mode drive's
        I R drop) meeting the load's (friction, viscous drag, load torque; an active load at its full pull)."""
        cfg = self.cfg
        if not cfg.open_loop or ramp == 0.0:
            return ramp
        gain = cfg.kp * RPM  # N m per rpm of slip
        pull = cfg.active if abs(ramp) <= cfg.active_knee_rpm else 0.0
        return (gain * ramp - math.copysign(cfg.hold, ramp) + pull) / (gain + cfg.viscous)

    def limited_to(
        self, state: State, full: Control, asked: float, target: float, speed: float, emf: float, bound: float
    ) -> Control:
        """The ramp's step cut so the loop asks no more than ``bound`` (A) on the side the step pushes.

        Current limiting (F11.05/F11.06) and overvoltage stall prevention (F11.03/F11.04) both act here. The
        demand is affine in the ramp's step (the step's acceleration torque is fed forward), so the step that
        asks exactly the bound is found in one division: the output frequency advances as fast as the bound
        allows and holds where the loop already asks it, accelerating and decelerating alike, and the ramp
        stretches instead of tripping (INVT GD20 P11.05, P11.06). At constant speed a load beyond the level
        meets the clamp as before (GD20 P11.07's frequency decrease there is not modelled: the clamp holds the
        ramp back to the rotor, which comes to the same).
        """
        held = self.control(state, self.ramp, target, speed, emf)
        push = full[5] - held[5]  # what the step adds to the demand
        if push == 0.0:
            return full
        signed = bound if push > 0.0 else -bound
        if (full[5] - signed) * push <= 0.0:
            return full  # the full step stays within the bound on the side it pushes
        share = (signed - held[5]) / push
        if share <= 0.0:
            return held
        return self.control(state, self.ramp + share * (asked - self.ramp), target, speed, emf)

    def ride(self, state: State) -> bool:
        """Whether the drive rides through a power loss this step (F11.01): from the bus falling below the
        ride-through level while running, until it is back :data:`RIDE_EXIT` above it (the supply back)."""
        ride_v = self.cfg.ride_v
        if not ride_v or state not in RUNNING:
            self.riding = False
        elif self.riding:
            self.riding = self.bus < ride_v * RIDE_EXIT
        else:
            self.riding = self.bus < ride_v
        return self.riding

    def stall_regulate(self, speed: float, emf: float, level: float) -> float:
        """Overvoltage stall prevention as a regulator: the braking current (A) a deceleration may ask now to hold
        the bus at ``level`` (the stall level; riding through a power loss, the ride-through level, where the
        same regulator feeds the bus from the load's energy).

        The bus is led to the stall level along a first-order path (time constant :data:`STALL_CLOSE_S`):
        the braking current is the one whose regenerated power brings the bus this step to the next point
        of that path, from the bus's own equation solved backwards (the supply, the bleed, and the brake
        resistor when the bus is above the chopper level); standing at the level, it is the current whose
        power the bus absorbs there. The result moves by at most :data:`STALL_SLEW_SHARE` of the current
        limit a step. So a heavy stop brakes at the current that holds the bus at the stall level, the output
        frequency falling at the rate that current allows (INVT GD20 P11.03/P11.04: the deceleration
        stretches while the bus is high), and 3004H and the bus move smoothly: a poll 1 ms after another
        differs by at most the slew (the regulator's own rate).
        """
        m, s, th = self.profile.motor, self.profile.supply, self.profile.thermal
        v, supply = self.bus, self.bench.supply
        goal = level + (v - level) * STALL_DECAY
        a, b = 0.0, self.inv_bleed
        if s.brake_chopper_v > 0.0 and goal > s.brake_chopper_v:
            b += self.inv_brake  # the chopper's duty is full above its level (physics.bus_step)
        if v < supply:
            a, b = supply * self.inv_source, b + self.inv_source
        decay = math.exp(-STEP * b / self.capacitance)
        v_inf = (goal - v * decay) / (1.0 - decay)
        regen = (v_inf * b - a) * max(v, 1.0)  # W into the bus that brings it to the goal this step
        # Regenerated power at a braking current i (A, > 0) against a back-EMF e (V): e i - (R + Rc) i^2 - sw i.
        e = abs(emf) - th.switching_loss_w_per_a
        r = m.resistance_ohm + th.conduction_resistance_ohm
        disc = e * e - 4.0 * r * regen
        if regen <= 0.0:
            wanted = 0.0
        elif e > 0.0 and disc >= 0.0:
            wanted = (e - math.sqrt(disc)) / (2.0 * r)
        else:
            wanted = self.profile.protection.current_limit_a  # the motor cannot regenerate that much
        slew = STALL_SLEW_SHARE * self.profile.protection.current_limit_a
        if self.regen_a < 0.0:  # engaged now: from the braking current flowing
            self.regen_a = max(0.0, -math.copysign(self.current, speed)) if speed else 0.0
        self.regen_a = min(max(wanted, self.regen_a - slew), self.regen_a + slew)
        return self.regen_a

    def bus_after(self, speed: float, current: float) -> tuple[float, float, float]:
        """The bus after this step with the motor at ``speed`` drawing ``current``: (bus, power, loss)."""
        m, th = self.profile.motor, self.profile.thermal
        power = (m.kt_nm_per_a * speed * RPM + current * m.resistance_ohm) * current
        loss = th.conduction_resistance_ohm * current * current + th.switching_loss_w_per_a * abs(current)
        bus = physics.bus_step(
            self.bus,
            self.bench.supply,
            (power + loss) / max(self.bus, 1.0),
            inv_source=self.inv_source,
            inv_bleed=self.inv_bleed,
            inv_brake=self.inv_brake,
            chopper_v=self.profile.supply.brake_chopper_v,
            capacitance=self.capacitance,
            dt=STEP,
        )
        return bus, power, loss

    def motor_rate(self, current: float) -> float:
        """The motor's overload budget used per second at ``current`` (negative: cooling)."""
        p = self.profile.protection
        return physics.overload_rate(
            abs(current) / self.cfg.motor_rated_a, p.motor_overload_curve, p.overload_cooling_s
        )

    def drive_rate(self, current: float) -> float:
        """The drive's overload budget used per second at ``current`` (negative: cooling)."""
        p = self.profile.protection
        return physics.overload_rate(
            abs(current) / p.drive_rated_current_a, p.drive_overload_curve, p.overload_cooling_s
        )


def settled_rpm(state: State) -> float:
    """How close to its set speed the rotor counts as there; stopping, zero speed is detected at 1 rpm."""
    return SETTLED_RPM if state in RUNNING else ZERO_RPM

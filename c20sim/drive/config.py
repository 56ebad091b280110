"""What the drive works from: the bench's conditions, and the settings derived from them and the parameters.

:class:`Conditions` holds what a bench does to a drive (its supply, its load,
the ambient, the analog inputs, the physical terminals, the dial switches),
as set through the drive's injection methods. :func:`configure` derives from
them, the function codes and the RAM registers the :class:`Config` the step
works from: speeds, ramps, channels, the speed loop's gains, the
communication timeout. A config only changes when an input does.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from ..wire.registers import Reg, RunChannel, SpeedSource, fcode_address
from ..wire.values import quick_init
from . import physics
from .params import ParameterStore
from .physics import STEP
from .profile import Profile
from .terminals import multi_speed_index
from .trips import COMM_CONTINUE, COMM_STOP, COMM_STOP_ANY, COMM_TRIP  # the communication cause's

__all__ = [
    "CHANNEL_COMM",
    "CHANNEL_DIAL",
    "CHANNEL_KEYPAD",
    "CHANNEL_TERMINAL",
    "COMM_CONTINUE",
    "COMM_STOP",
    "COMM_STOP_ANY",
    "COMM_TRIP",
    "CURRENT_LIMITING_DEFAULT",
    "CURRENT_LIMIT_LEVEL_DEFAULT_PCT",
    "DIAL_SPEED_SOURCE",
    "F_ANSWER_DELAY",
    "F_CURRENT_LIMITING",
    "F_CURRENT_LIMIT_LEVEL",
    "SOURCE_DIAL",
    "Conditions",
    "Config",
    "configure",
    "limit_speed",
]

# Function codes the model reads beyond the mirrored ones (absent in a profile: the [motor] value is used).
F_MAX_SPEED = fcode_address(0, 3)
F_KEYPAD_SPEED = fcode_address(0, 10)
F_JOG_SPEED = fcode_address(0, 13)
F_COMM_TIMEOUT = fcode_address(8, 2)
F_COMM_ACTION = fcode_address(8, 3)
F_MULTI_SPEED = fcode_address(5, 0)
F_MOTOR_OVERLOAD_COEFFICIENT = fcode_address(2, 27)
F_OV_STALL = fcode_address(11, 3)
F_OV_STALL_LEVEL = fcode_address(11, 4)
F_CURRENT_LIMITING = fcode_address(11, 5)
F_CURRENT_LIMIT_LEVEL = fcode_address(11, 6)
# Automatic behaviours (issue 42), numbered as the INVT family's (GD20 P08.28/P08.29, P01.21/P01.22): assumed.
F_AUTO_RESET_TRIALS = fcode_address(8, 28)
F_AUTO_RESET_INTERVAL = fcode_address(8, 29)
F_POWER_RESTART = fcode_address(1, 21)
F_POWER_RESTART_WAIT = fcode_address(1, 22)
#: The answer delay, ms (INVT P14.03 "communication response delay", 0-200 ms); read by the slave, not the step.
F_ANSWER_DELAY = fcode_address(8, 4)
#: Power-loss ride-through on/off and its level, % of the nominal bus (INVT GD20 P11.01; the level assumed).
F_RIDE_THROUGH = fcode_address(11, 1)
F_RIDE_THROUGH_LEVEL = fcode_address(11, 2)
#: The ride-through level where a profile has no F11.02, % of the nominal bus (assumed).
RIDE_THROUGH_LEVEL_DEFAULT_PCT = 80
#: S-curve ramps: 0 linear, 1 S curve; the start and end segments, 0.1 % of the ramp time (INVT GD20 P01.05-P01.07).
F_RAMP_SHAPE = fcode_address(1, 5)
F_S_START = fcode_address(1, 6)
F_S_END = fcode_address(1, 7)

#: Current limiting where a profile has no F11.05: on, as INVT ships it (GD20 P11.05 default "valid").
CURRENT_LIMITING_DEFAULT = 1
#: The current limiting level where a profile has no F11.06, % of the drive's rated current (GD20 P11.06,
#: G type default 160.0 %).
CURRENT_LIMIT_LEVEL_DEFAULT_PCT = 160.0

#: F00.00 / 2005H: the control modes the model tells apart.
CONTROL_OPEN_LOOP, CONTROL_DIAL = 1, 3


CHANNEL_KEYPAD, CHANNEL_TERMINAL, CHANNEL_COMM = RunChannel.KEYPAD, RunChannel.TERMINALS, RunChannel.COMMUNICATION
# The dial switches SW1-SW3 (sheet: 2005H "3: dial switch setting (SW1 valid), model related", 2006H "3: dial
# switch setting (SW3 valid)", 2007H "5: dial switch setting (SW2, SW3 valid)"). What each position selects is
# not in the sheet: assumed, each switch on or off.
#: 2006H = 3: SW3 on takes run commands from the terminals, off from the keypad (assumed).
CHANNEL_DIAL = RunChannel.DIAL_SWITCH
#: 2007H = 5: (SW2, SW3) select the speed source: keypad, AI1 knob, AI2 voltage, multi-segment (assumed).
SOURCE_DIAL = SpeedSource.DIAL_SWITCH
DIAL_SPEED_SOURCE = {(False, False): 0, (True, False): 1, (False, True): 2, (True, True): 4}


@dataclass(slots=True)
class Conditions:
    """What the bench does to the drive, as set (the Hall sensor's fault is the sensor's own)."""

    supply: float  #: the supply behind the DC bus, V
    ambient: float  #: degC
    load: float = 0.0  #: load torque opposing motion, N m
    active: float = 0.0  #: signed load torque, N m, positive pushing forward
    load_inertia: float = 0.0  #: kg m^2 added to the motor's
    ai: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  #: AI1-AI3, V
    physical_inputs: int = 0  #: the physical input terminals
    dial: tuple[bool, bool, bool] = (False, False, False)  #: SW1, SW2, SW3
    #: the conditions no part above reads, by their row's name (c20sim.drive.conditions: a row with no setter)
    extra: dict[str, object] = field(default_factory=dict)


@quick_init  # a write that changes a setting builds one: at half the price (wire/values.py)
@dataclass(frozen=True, slots=True)
class Config:
    """Everything the step needs that only changes when an input changes."""

    pole_pairs: int
    max_rpm: float
    up: float  #: rpm per step while accelerating
    down: float  #: rpm per step while decelerating
    reference_rpm: float
    jog_rpm: float
    channel: int
    source: int
    comm_timeout: float
    inertia: float
    hold: float  #: Coulomb friction plus load torque, N m
    viscous: float  #: N m per rpm
    active: float  #: signed load torque, N m, positive pushing forward
    active_knee_rpm: float  #: the active load pulls fully up to this speed (the motor's rated speed)
    active_free_rpm: float  #: and falls to nothing at this one (its own drag): [motor] active_load_free_rpm
    inputs: int  #: effective input terminals
    kp: float  #: speed loop, N m per rad/s
    ki: float  #: speed loop, N m per rad; 0 in open loop
    open_loop: bool  #: F00.00 = 1 (or 3 with SW1 on): no speed feedback, the speed droops under load
    stall_v: float  #: overvoltage stall level, V; 0 = off
    limit_a: float  #: current limiting level, A: the ramp holds while the loop would ask more; 0 = off
    motor_rated_a: float  #: rated current times the overload coefficient
    comm_action: int
    auto_reset_trials: int  #: F08.28: automatic fault resets before the fault stays; 0 = none
    auto_reset_steps: int  #: F08.29: steps from a trip (or a refused attempt) to the next automatic reset
    power_restart: bool  #: F01.21: run again once the power is back after an undervoltage trip while running
    power_restart_steps: int  #: F01.22: steps from the bus back to that restart
    s_start: float  #: F01.06: the S curve's start segment, a share of the ramp time; 0 with F01.05 = 0 (linear)
    s_end: float  #: F01.07: its end segment
    ride_v: float  #: F11.01/F11.02: the bus the drive holds from the load's energy on a power loss, V; 0 = off


def configure(profile: Profile, P: ParameterStore, ram: Mapping[int, int], bench: Conditions) -> Config:
    """The settings the step works from, for these parameters, RAM registers and conditions."""
    m, regs = profile.motor, profile.registers
    max_rpm = float(P.get(F_MAX_SPEED)) if F_MAX_SPEED in P else m.rated_speed_rpm
    accel = max(P.get(Reg.ACCEL_TIME), 1) * 0.1
    decel = max(P.get(Reg.DECEL_TIME), 1) * 0.1
    pole_pairs = max(P.get(Reg.POLE_PAIRS), 1)
    inputs = (bench.physical_inputs | ram[Reg.VIRTUAL_INPUTS]) & 0x1FF
    source = P.get(Reg.SPEED_SOURCE)
    if source == SOURCE_DIAL:
        source = DIAL_SPEED_SOURCE[bench.dial[1], bench.dial[2]]
    channel = P.get(Reg.RUN_CHANNEL)
    if channel == CHANNEL_DIAL:
        channel = CHANNEL_TERMINAL if bench.dial[2] else CHANNEL_KEYPAD
    reference = 0.0
    if source == 0 and F_KEYPAD_SPEED in P:
        reference = P.get(F_KEYPAD_SPEED) * regs[F_KEYPAD_SPEED].scale * 60.0 / pole_pairs
    elif source in (1, 2):
        reference = bench.ai[source - 1] / 10.0 * max_rpm
    elif source == 3:
        reference = float(ram[Reg.SPEED_SETPOINT])
    elif source == 4:
        segment = F_MULTI_SPEED + multi_speed_index(inputs)
        reference = float(P.get(segment)) if segment in P else 0.0
    jog = float(P.get(F_JOG_SPEED)) if F_JOG_SPEED in P else m.jog_speed_rpm
    timeout = P.get(F_COMM_TIMEOUT) * regs[F_COMM_TIMEOUT].scale if F_COMM_TIMEOUT in P else 0.0
    inertia = m.inertia_kg_m2 + bench.load_inertia
    bandwidth = physics.TWO_PI * profile.control.speed_loop_hz
    stall_on = P.get(F_OV_STALL) if F_OV_STALL in P else 1
    stall_pct = P.get(F_OV_STALL_LEVEL) if F_OV_STALL_LEVEL in P else 120
    mode = P.get(Reg.CONTROL_MODE)
    # Open loop (F00.00 = 1; 3 hands it to SW1: on open loop, off closed, assumed): a voltage-mode drive, whose
    # speed droops under load by the I R drop; assumed, the sheet names the mode only.
    open_loop = mode == CONTROL_OPEN_LOOP or (mode == CONTROL_DIAL and bench.dial[0])
    s_curve = F_RAMP_SHAPE in P and P.get(F_RAMP_SHAPE) == 1
    ride_pct = P.get(F_RIDE_THROUGH_LEVEL) if F_RIDE_THROUGH_LEVEL in P else RIDE_THROUGH_LEVEL_DEFAULT_PCT
    coefficient = (
        P.get(F_MOTOR_OVERLOAD_COEFFICIENT) * regs[F_MOTOR_OVERLOAD_COEFFICIENT].scale / 100.0
        if F_MOTOR_OVERLOAD_COEFFICIENT in P
        else 1.0
    )
    return Config(
        pole_pairs=pole_pairs,
        max_rpm=max_rpm,
        up=max_rpm / accel * STEP,
        down=max_rpm / decel * STEP,
        reference_rpm=limit_speed(profile, reference, max_rpm),
        jog_rpm=limit_speed(profile, jog, max_rpm),
        channel=channel,
        source=source,
        comm_timeout=timeout,
        inertia=inertia,
        hold=m.friction_nm + bench.load,
        viscous=m.viscous_nm_per_krpm / 1000.0,
        active=bench.active,
        active_knee_rpm=m.rated_speed_rpm,
        active_free_rpm=m.active_load_free_rpm,
        inputs=inputs,
        kp=m.kt_nm_per_a**2 / m.resistance_ohm if open_loop else inertia * bandwidth,
        ki=0.0 if open_loop else inertia * bandwidth * bandwidth / 4.0,
        open_loop=open_loop,
        stall_v=profile.supply.voltage_v * stall_pct / 100.0 if stall_on else 0.0,
        limit_a=_limit_a(profile, P),
        motor_rated_a=m.rated_current_a * max(coefficient, 0.01),
        comm_action=P.get(F_COMM_ACTION) if F_COMM_ACTION in P else COMM_TRIP,
        auto_reset_trials=P.get(F_AUTO_RESET_TRIALS) if F_AUTO_RESET_TRIALS in P else 0,
        auto_reset_steps=_steps(profile, P, F_AUTO_RESET_INTERVAL),
        power_restart=bool(P.get(F_POWER_RESTART)) if F_POWER_RESTART in P else False,
        power_restart_steps=_steps(profile, P, F_POWER_RESTART_WAIT),
        s_start=_share(profile, P, F_S_START) if s_curve else 0.0,
        s_end=_share(profile, P, F_S_END) if s_curve else 0.0,
        ride_v=profile.supply.voltage_v * ride_pct / 100.0 if F_RIDE_THROUGH in P and P.get(F_RIDE_THROUGH) else 0.0,
    )


def _limit_a(profile: Profile, P: ParameterStore) -> float:
    """The current limiting level, A (F11.05, F11.06); 0 with limiting off."""
    limiting = P.get(F_CURRENT_LIMITING) if F_CURRENT_LIMITING in P else CURRENT_LIMITING_DEFAULT
    limit_pct = (
        P.get(F_CURRENT_LIMIT_LEVEL) * profile.registers[F_CURRENT_LIMIT_LEVEL].scale
        if F_CURRENT_LIMIT_LEVEL in P
        else CURRENT_LIMIT_LEVEL_DEFAULT_PCT
    )
    # The level never exceeds the hardware clamp: above it the clamp acts first, as the limiting would.
    limit_a = min(profile.protection.drive_rated_current_a * limit_pct / 100.0, profile.protection.current_limit_a)
    return limit_a if limiting else 0.0


def _share(profile: Profile, P: ParameterStore, address: int) -> float:
    """A percentage function code as a share (0 where the profile lacks it)."""
    return P.get(address) * profile.registers[address].scale / 100.0 if address in P else 0.0


def _steps(profile: Profile, P: ParameterStore, address: int) -> int:
    """A time function code as a number of steps (at least one); one step where the profile lacks it."""
    if address not in P:
        return 1
    return max(1, round(P.get(address) * profile.registers[address].scale / STEP))


def limit_speed(profile: Profile, rpm: float, max_rpm: float) -> float:
    """A set speed within 0 to the maximum; a set speed above zero runs at least at the minimum speed."""
    rpm = min(max(rpm, 0.0), max_rpm)
    floor = min(profile.control.min_speed_rpm, max_rpm)
    return floor if 0.0 < rpm < floor else rpm

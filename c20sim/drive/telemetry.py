"""Telemetry: what the drive is doing, in engineering units, for a dashboard, a recorder or a test.

:func:`snapshot` reads a :class:`~c20sim.drive.model.Drive` at its current
time, through the same values as the register face (the status word, the
fault reported, the outputs), so a dashboard never disagrees with a master.
It changes nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from . import face
from .physics import BUDGET

if TYPE_CHECKING:
    from .face import Drive

__all__ = ["Telemetry", "snapshot"]


@dataclass(frozen=True, slots=True)
class Telemetry:
    """What the drive is doing, in engineering units, for a dashboard."""

    t: float
    state: str
    status: int  #: 2100H
    fault_code: int  #: 2102H
    fault_name: str
    speed_rpm: float  #: signed: negative is reverse
    set_speed_rpm: float
    ramp_rpm: float
    current_a: float  #: signed torque-producing current
    output_voltage_v: float
    output_power_w: float
    bus_v: float
    supply_v: float
    temperature_c: float
    ambient_c: float
    hall: int
    motor_overload: float  #: fraction of the motor's overload budget used (trips at 1)
    drive_overload: float  #: fraction of the drive's overload budget used (trips at 1)
    load_torque_nm: float
    load_inertia_kg_m2: float
    input_terminals: int  #: 300DH
    output_terminals: int  #: 300EH
    run_channel: int
    speed_source: int
    steady: bool  #: skipping ahead in closed form
    #: the last thing the drive did by itself (an automatic reset, a restart after power, a ride-through), with
    #: its time; "" if none since power-up
    auto_action: str = ""


def snapshot(d: Drive) -> Telemetry:
    """The drive's telemetry at its current time."""
    motion, bench = d.motion, d.bench
    fault = face.fault_reported(d)
    return Telemetry(
        t=d.t,
        state=d.machine.state.value,
        status=face.status1(d),
        fault_code=fault,
        fault_name=d.profile.fault_name(fault) if fault else "",
        speed_rpm=motion.speed,
        set_speed_rpm=face.set_rpm(d),
        ramp_rpm=motion.ramp,
        current_a=motion.current,
        output_voltage_v=face.output_volts(d),
        output_power_w=face.output_watts(d),
        bus_v=motion.bus,
        supply_v=bench.supply,
        temperature_c=motion.temp,
        ambient_c=bench.ambient,
        hall=face.hall_now(d),
        motor_overload=motion.motor_i2t / BUDGET,
        drive_overload=motion.drive_i2t / BUDGET,
        load_torque_nm=bench.load,
        load_inertia_kg_m2=bench.load_inertia,
        input_terminals=motion.cfg.inputs,
        output_terminals=face.outputs(d),
        run_channel=motion.cfg.channel,
        speed_source=motion.cfg.source,
        steady=motion.segment is not None,
        auto_action=d.machine.auto_note,
    )

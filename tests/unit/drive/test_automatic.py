"""What the drive does by itself (issue 42), on the model: the same at every polling rate."""

from __future__ import annotations

from c20sim.drive.config import F_AUTO_RESET_INTERVAL, F_AUTO_RESET_TRIALS
from c20sim.drive.model import STEP, Drive
from c20sim.drive.plc import F_PLC_MODE
from c20sim.drive.profile import FaultCause, load_profile
from c20sim.drive.terminals import Input
from c20sim.wire.registers import Reg


def timeline(poll: float, end: float) -> list[tuple[float, int, int]]:
    """An external fault held for 2.5 s with three automatic resets 1 s apart: (t, 2102H, resets) at each poll."""
    drive = Drive(load_profile("c20-400hr"))
    drive.write(F_AUTO_RESET_TRIALS, 3)
    drive.write(F_AUTO_RESET_INTERVAL, 10)
    drive.write(Reg.VIRTUAL_INPUTS, int(Input.EF))
    out = []
    k, released = 0, False
    while k * poll < end:
        k += 1
        t = k * poll
        if not released and t >= 2.5:
            drive.advance_to(2.5)
            drive.write(Reg.VIRTUAL_INPUTS, 0)
            released = True
        drive.advance_to(t)
        if abs(t / 0.5 - round(t / 0.5)) < 1e-9:  # compare every half second
            out.append((round(t, 3), drive.read(Reg.FAULT_CODE), drive.machine.auto_resets))
    return out


def test_automatic_resets_fall_on_the_same_step_whatever_the_polling() -> None:
    fine = timeline(STEP, 6.0)
    assert fine == timeline(0.5, 6.0) == timeline(0.1, 6.0)
    ef = load_profile("c20-400hr").fault_code(FaultCause.EXTERNAL)
    # Refused at 1.001 s and 2.001 s (EF held), taken at 3.001 s once it is gone.
    assert fine[:6] == [(0.5, ef, 0), (1.0, ef, 0), (1.5, ef, 1), (2.0, ef, 1), (2.5, ef, 2), (3.0, ef, 2)]
    assert fine[6] == (3.5, 0, 3)


def plc_timeline(poll: float, end: float) -> list[tuple[float, int, int, int]]:
    """The shipped PLC programme, cycling (F10.00 = 2): (t, 3006H, 300EH, stage) every half second."""
    drive = Drive(load_profile("c20-400hr"))
    drive.write(F_PLC_MODE, 2)
    drive.write(Reg.SPEED_SOURCE, 6)
    drive.write(Reg.COMMAND, 1)
    out = []
    k = 0
    while k * poll < end:
        k += 1
        drive.advance_to(k * poll)
        t = k * poll
        if abs(t / 0.5 - round(t / 0.5)) < 1e-9:
            out.append((round(t, 3), drive.read(Reg.MOTOR_SPEED), drive.read(Reg.OUTPUT_TERMINALS), drive.plc.stage))
    return out


def test_the_simple_plc_steps_on_the_same_step_whatever_the_polling() -> None:
    fine = plc_timeline(STEP, 65.0)
    assert fine == plc_timeline(0.5, 65.0) == plc_timeline(0.1, 65.0)
    # Shipped: 1000 rpm 10 s, 2000 rpm 10 s, 1500 rpm 5 s, 500 rpm 5 s; Y3 (0x4) for 0.5 s after each stage.
    by_t = {t: (speed, out, stage) for t, speed, out, stage in fine}
    assert by_t[9.5] == (1000, 0x1, 0) and by_t[10.0] == (1000, 0x1, 0)
    assert by_t[10.5][1:] == (0x5, 1) and by_t[11.0][1] == 0x1  # Y3 from 10.001 s to 10.501 s
    assert by_t[19.5] == (2000, 0x1, 1)
    assert by_t[29.5] == (500, 0x1, 3)
    assert by_t[39.5] == (1000, 0x1, 0)  # the second cycle

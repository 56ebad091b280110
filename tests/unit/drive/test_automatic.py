"""What the drive does by itself (issue 42), on the model: the same at every polling rate."""

from __future__ import annotations

from c20sim.drive.config import F_AUTO_RESET_INTERVAL, F_AUTO_RESET_TRIALS
from c20sim.drive.model import STEP, Drive
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

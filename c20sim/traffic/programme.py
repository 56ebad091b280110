"""The identification programme of ``c20sim exercise --out``: rest, run, speed steps, a load change, a stop,
polling the physical registers at a steady rate; and the same run on c20sim in virtual time."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import IO, TypeVar

from ..core.simulator import Simulator
from ..drive.profile import Profile
from ..wire.errors import C20SimError
from ..wire.protocol import ReadRequest
from ..wire.registers import Command, Reg
from .dialect import Prober, probe
from .master import DriveRefused, DriveSilent, Interrupted, Master
from .masterlinks import SimulatedLink, SimulatedTime

__all__ = [
    "POLL",
    "RAMP_POLL",
    "SETTINGS",
    "Step",
    "check_ready",
    "programme",
    "run_programme",
    "simulated_capture",
    "time_the_link",
]

T = TypeVar("T")

#: What the programme polls, in turn: the physical quantities, the status words and the fault code.
POLL: tuple[int, ...] = (
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.BUS_VOLTAGE,
    Reg.OUTPUT_VOLTAGE,
    Reg.STATUS1,
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.RAMP_FREQUENCY,
    Reg.OUTPUT_FREQUENCY,
    Reg.FAULT_CODE,
    Reg.OUTPUT_CURRENT,
    Reg.MOTOR_SPEED,
    Reg.BUS_VOLTAGE,
    Reg.TEMPERATURE,
    Reg.OUTPUT_POWER,
    Reg.STATUS2,
    Reg.HALL,
)

#: The settings read once before the programme starts: the fit takes the ramps and pole pairs from them.
SETTINGS: tuple[int, ...] = (
    Reg.DRIVE_ID,
    Reg.SOFTWARE_VERSION,
    Reg.POLE_PAIRS,
    Reg.ACCEL_TIME,
    Reg.DECEL_TIME,
    Reg.CONTROL_MODE,
    Reg.RUN_CHANNEL,
    Reg.SPEED_SOURCE,
)

#: What the programme polls while the speed ramps, every :data:`RAMP_PERIOD` (a ramp may last a tenth of a
#: second): the current, which carries the inertia, and the speed.
RAMP_POLL: tuple[int, ...] = (Reg.OUTPUT_CURRENT, Reg.MOTOR_SPEED)

#: Seconds between reads while a step ramps: 50 a second, within what a line at 19200 baud carries (74 one-register
#: reads a second with a 2 ms turnaround), so that none waits for the line behind the one before.
RAMP_PERIOD = 0.02

#: Rounds of the link's timing reads at the start: a one-register read, and one of 8 (answered, or refused with
#: an exception where the drive reads one at a time): replies of two lengths tell a link that keeps the line's
#: time (a longer reply takes longer) from one that does not.
TIMING_ROUNDS = 10

#: Silences in a row the programme tolerates (a lost frame on a real line) before it stops the drive.
SILENCES_IN_A_ROW = 3

STATUS_STOPPED = 3

#: The marks of a load change in the log: ``{"dir": "rx", "hex": "", "kind": "mark", "note": "load-on"}``.
LOAD_ON, LOAD_OFF = "load-on", "load-off"


# --- The identification programme.


@dataclass(frozen=True)
class Step:
    """One stretch of the programme: writes at its start, then polling for ``hold`` seconds."""

    say: str
    writes: tuple[tuple[int, int], ...] = ()
    hold: float = 0.0
    prompt: str = ""  #: a change the user makes by hand, confirmed before the step starts
    mark: str = ""  #: written to the log (an empty rx frame of kind "mark") once the user confirmed: load-on ...
    until_stopped: bool = False  #: poll on until status word 1 reads stopped (at most ``hold`` more)
    ramp: float = 0.0  #: seconds from the step's start that the speed ramps: :data:`RAMP_POLL` is read then


def programme(
    speeds: Sequence[float], hold: float, accel_s: float, decel_s: float, max_rpm: float, load: bool
) -> list[Step]:
    """The steps: rest, run and speed steps (each held ``hold`` s past its ramp), a load change, a stop.

    ``accel_s``/``decel_s`` are the drive's ramp times to ``max_rpm`` (2003H, 2004H), so each hold starts
    once the ramp is done.
    """
    steps = [Step("at rest: the supply without load", hold=min(hold, 3.0))]
    last = 0.0
    for index, rpm in enumerate(speeds):
        ramp = abs(rpm - last) / max_rpm * (accel_s if rpm > last else decel_s)
        writes: tuple[tuple[int, int], ...] = ((Reg.SPEED_SETPOINT, round(rpm)),)
        if index == 0:
            writes += ((Reg.COMMAND, int(Command.FORWARD)),)
        steps.append(Step(f"{'run at' if index == 0 else 'step to'} {rpm:g} rpm", writes, ramp + hold, ramp=ramp))
        last = rpm
    if load:
        steps.append(Step(f"with the load, at {last:g} rpm", (), hold, "apply the load now", LOAD_ON))
        steps.append(Step(f"load taken off, at {last:g} rpm", (), hold, "take the load off now", LOAD_OFF))
    stop_ramp = last / max_rpm * decel_s
    steps.append(Step("stop", ((Reg.COMMAND, int(Command.STOP)),), stop_ramp + 2.0, until_stopped=True, ramp=stop_ramp))
    steps.append(Step("at rest after the stop", hold=min(hold, 3.0)))
    return steps


Progress = Callable[[int, int, Step, float, float, dict[int, int]], None]
Confirm = Callable[[str], None]


def _stop(master: Master) -> str:
    """Tell the drive to stop; the words for the user on how it went."""
    try:
        master.write(Reg.COMMAND, int(Command.STOP))
    except C20SimError as exc:
        return f"telling it to stop failed too ({exc}): stop it by hand"
    return "the drive was told to stop (2000H = 5)"


def _again(master: Master, ask: Callable[[], T]) -> T:
    """``ask()`` asked again where its reply was lost, up to :data:`SILENCES_IN_A_ROW` times in all."""
    for attempt in range(SILENCES_IN_A_ROW):
        try:
            return ask()
        except DriveSilent:
            if attempt == SILENCES_IN_A_ROW - 1:
                raise
    raise AssertionError("unreachable")


def _read_again(master: Master, address: int) -> int:
    return _again(master, lambda: master.read(address))


def check_ready(master: Master) -> dict[int, int]:
    """The settings, read; C20SimError (one line) if the drive is not one the programme may start."""
    values: dict[int, int] = {}
    for address in SETTINGS:
        values[address] = _read_again(master, address)
    status = _read_again(master, Reg.STATUS1)
    fault = _read_again(master, Reg.FAULT_CODE)
    registers = master.registers
    if status != STATUS_STOPPED:
        state = registers[Reg.STATUS1].describe(status)
        raise C20SimError(
            f"the drive is not stopped ({state}, 2100H = {status}); the programme starts only a stopped drive"
        )
    if fault:
        raise C20SimError(f"the drive reports fault 0x{fault:02X}; reset it first (write command reset)")
    if values[Reg.RUN_CHANNEL] != 2:
        channel = registers[Reg.RUN_CHANNEL].describe(values[Reg.RUN_CHANNEL])
        raise C20SimError(
            f"run commands come from the {channel} (2006H = {values[Reg.RUN_CHANNEL]}); the programme needs "
            "communication: write run-channel 2 (a function code) first"
        )
    if values[Reg.SPEED_SOURCE] != 3:
        source = registers[Reg.SPEED_SOURCE].describe(values[Reg.SPEED_SOURCE])
        raise C20SimError(
            f"the speed reference comes from {source} (2007H = {values[Reg.SPEED_SOURCE]}); the programme needs "
            "Modbus: write speed-source 3 (a function code) first"
        )
    return values


def time_the_link(master: Master) -> None:
    """:data:`TIMING_ROUNDS` of a one-register read and a read of 8 (3000H-3007H; refused or not): at rest, 20 ms
    apart, so that neither waits for the line behind the one before."""
    for _ in range(TIMING_ROUNDS):
        master.clock.sleep(0.02)
        with contextlib.suppress(DriveSilent):  # a lost reply: that round has one timing fewer
            master.read(Reg.BUS_VOLTAGE)
        master.clock.sleep(0.02)
        with contextlib.suppress(DriveRefused, DriveSilent):  # refused: a drive that reads one at a time
            master.transact(ReadRequest(master.address, Reg.SET_FREQUENCY, 8))


@dataclass
class _Polling:
    """The programme's polling as it goes: the steady rate, the values last read, silences in a row, reads made."""

    period: float
    last: dict[int, int] = dataclasses.field(default_factory=dict)
    silent: int = 0
    reads: int = 0
    poll: Iterator[int] = dataclasses.field(default_factory=lambda: _cycle(POLL))
    ramp_poll: Iterator[int] = dataclasses.field(default_factory=lambda: _cycle(RAMP_POLL))


def run_programme(
    master: Master,
    steps: Sequence[Step],
    *,
    rate: float,
    progress: Progress | None = None,
    confirm: Confirm | None = None,
) -> int:
    """Run ``steps``, polling :data:`POLL` at ``rate`` reads a second; returns the reads made.

    A refusal, silence (:data:`SILENCES_IN_A_ROW` in a row) or a trip stops the drive and raises
    C20SimError in one line; KeyboardInterrupt stops it and raises :class:`Interrupted`.
    """
    polling = _Polling(1.0 / rate)
    started = False
    steps = list(steps)
    setpoint = 0  #: the speed set before the step being run
    repeated: set[int] = set()
    try:
        for index, step in enumerate(steps):
            if step.prompt and confirm is not None:
                confirm(step.prompt)
            if step.mark:
                master.mark(step.mark)
            before = setpoint
            for address, value in step.writes:
                _again(master, functools.partial(master.write, address, value))  # the same value again: harmless
                started = started or address == Reg.COMMAND
                setpoint = value if address == Reg.SPEED_SETPOINT else setpoint
            report = functools.partial(progress, index, len(steps)) if progress is not None else None
            in_ramp = _hold(master, step, polling, report)
            if step.ramp and in_ramp < 2 and before and setpoint and index not in repeated:
                # the ramp's reads were lost (a reply lost costs the timeout): back to the speed before, and again
                repeated |= {index + 1, index + 2}
                back = Step(f"{step.say}: again, its ramp's reads were lost", ((Reg.SPEED_SETPOINT, before),))
                steps[index + 1 : index + 1] = [
                    dataclasses.replace(back, hold=step.ramp + 1.0, ramp=step.ramp),
                    dataclasses.replace(step, say=f"{step.say} (again)", hold=step.ramp + 1.0),
                ]
    except KeyboardInterrupt:
        raise Interrupted(_stop(master) if started else "the drive was not started") from None
    except C20SimError as exc:
        if started:
            raise C20SimError(f"{exc}; {_stop(master)}") from None
        raise
    return polling.reads


def _hold(master: Master, step: Step, polling: _Polling, progress: Callable[..., None] | None) -> int:
    """Poll through ``step``'s hold (and, ``until_stopped``, until the drive reads stopped): the current and speed
    every :data:`RAMP_PERIOD` while the speed ramps, :data:`POLL` in turn at the steady rate after. Returns the
    current reads answered while the step ramped."""
    last, period = polling.last, polling.period
    in_ramp = 0
    begin = master.clock.now()
    end = begin + step.hold
    k = 0
    ramp_due = begin
    while True:
        now = master.clock.now()
        if now >= end and not (step.until_stopped and last.get(Reg.STATUS1) != STATUS_STOPPED):
            return in_ramp
        if step.until_stopped and now >= end + step.hold + 10.0:
            raise C20SimError("the drive did not stop within its ramp and 10 s more")
        ramping = now < begin + step.ramp
        due = begin + k * period
        if ramping:
            if ramp_due > now:
                master.clock.sleep(ramp_due - now)
            ramp_due = max(ramp_due, now) + RAMP_PERIOD
            k = math.floor((now - begin) / period)  # the steady rate picks up where the ramp ends
        elif due > now:
            master.clock.sleep(due - now)
        else:
            k = max(k, math.floor((now - begin) / period))  # late: go on at the rate, no burst
        k += 1
        address = next(polling.ramp_poll) if ramping else next(polling.poll)
        try:
            last[address] = master.read(address)
            polling.silent = 0
        except DriveSilent:
            polling.silent += 1
            if polling.silent >= SILENCES_IN_A_ROW:
                raise
            continue
        polling.reads += 1
        in_ramp += ramping and address == Reg.OUTPUT_CURRENT
        if address == Reg.FAULT_CODE and last[address]:
            name = master.registers[Reg.FAULT_CODE].describe(last[address])
            raise C20SimError(f"the drive tripped: fault {name} in step '{step.say}'")
        if progress is not None:
            progress(step, master.clock.now() - begin, step.hold, last)


def simulated_capture(
    sim: Simulator,
    out: IO[str],
    *,
    speeds: Sequence[float],
    hold: float,
    rate: float = 10.0,
    load_nm: float | None = None,
    address: int = 1,
    dialect: Profile | None = None,
) -> int:
    """The programme run on c20sim in this process, in virtual time, its capture written to ``out``; the load
    change (``load_nm``) made as a user would when told; with ``dialect`` (the base profile the user has), the
    dialect probe first, as ``exercise --dialect``. Returns the reads made. Tests and benchmarks use it."""
    registers = sim.profile.registers
    master = Master(SimulatedLink(sim), registers, address, clock=SimulatedTime(sim), log=out)
    master.header("simulated", sim.bus.line_baud, "8N1")
    if dialect is not None:
        probe(Prober(master.probe, address, dialect, rtu=True))
    settings = check_ready(master)
    time_the_link(master)
    accel = settings[Reg.ACCEL_TIME] * registers[Reg.ACCEL_TIME].scale
    decel = settings[Reg.DECEL_TIME] * registers[Reg.DECEL_TIME].scale
    steps = programme(speeds, hold, accel, decel, sim.profile.motor.rated_speed_rpm, load_nm is not None)
    drive = sim.drive(address)

    def confirm(prompt: str) -> None:
        drive.set_load_torque((load_nm or 0.0) if prompt.startswith("apply") else 0.0)

    return run_programme(master, steps, rate=rate, confirm=confirm)


def _cycle(items: Sequence[int]) -> Iterator[int]:
    while True:
        yield from items

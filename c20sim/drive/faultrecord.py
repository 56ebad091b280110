"""The fault record: the last faults and the drive's state at the current one, kept in EEPROM.

A SCADA alarm screen reads, after a trip, what the drive was doing when it tripped. The INVT Goodrive
family keeps it in its P07 group (GD20: P07.27 the current fault type, P07.28-P07.32 the five before it,
P07.33-P07.40 the running frequency, ramp reference frequency, output voltage, output current, bus
voltage, temperature and input and output terminal states at the current fault, P07.41-P07.48 the same
at the previous fault; the layout as the issue's survey of the INVT manuals gives it, the pages not
checked here). The C20's sheet names its function codes by INVT's groups but says nothing of a fault
record: the addresses (F07.27-F07.48 at 071BH-0730H), the scales (those of 3000H-3011H) and keeping it
across a power cycle are **assumed** from the family.

A profile has the record when it lists its cells (read-only function codes, ``access = "R"``); the drive
writes them at each trip, in one EEPROM save, before the output goes off (so the values are the ones the
trip met): the fault types shift down one (the oldest drops off), and the current fault's state becomes
the previous fault's. A restore of the defaults (200FH) keeps the record (INVT clears it only with its
own P00.18 = 2).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ..wire.registers import Reg, fcode_address

__all__ = [
    "CONTEXT",
    "CONTEXT_KEYS",
    "CONTEXT_NAMES",
    "CURRENT_CONTEXT",
    "FAULT_TYPES",
    "PREVIOUS_CONTEXT",
    "RECORD",
    "decode",
    "has_record",
    "shifted",
]

#: F07.27 (current fault) to F07.32 (the fifth before it): fault codes, newest first.
FAULT_TYPES = tuple(fcode_address(7, n) for n in range(27, 33))
#: What is kept at a fault, by the register that reads it live (its scale is the register's).
CONTEXT = (
    Reg.OUTPUT_FREQUENCY,  # running frequency, 0.01 Hz
    Reg.RAMP_FREQUENCY,  # ramp reference frequency, 0.01 Hz
    Reg.OUTPUT_VOLTAGE,  # 0.1 V
    Reg.OUTPUT_CURRENT,  # 0.01 A
    Reg.BUS_VOLTAGE,  # 0.1 V
    Reg.TEMPERATURE,  # 0.1 degC
    Reg.INPUT_TERMINALS,
    Reg.OUTPUT_TERMINALS,
)
CONTEXT_NAMES = (
    "running frequency",
    "ramp reference frequency",
    "output voltage",
    "output current",
    "bus voltage",
    "temperature",
    "input terminal states",
    "output terminal states",
)
#: F07.33-F07.40: the state at the current fault; F07.41-F07.48: at the previous one.
CURRENT_CONTEXT = tuple(fcode_address(7, 33 + i) for i in range(len(CONTEXT)))
PREVIOUS_CONTEXT = tuple(fcode_address(7, 41 + i) for i in range(len(CONTEXT)))
#: Every cell of the record.
RECORD = frozenset(FAULT_TYPES + CURRENT_CONTEXT + PREVIOUS_CONTEXT)


def has_record(addresses: Mapping[int, object]) -> bool:
    """Whether a profile's function codes include the whole record."""
    return all(a in addresses for a in RECORD)


#: The keys of a decoded context (:func:`decode`), with each register's scale to engineering units.
CONTEXT_KEYS = (
    ("running_hz", 0.01),
    ("ramp_hz", 0.01),
    ("output_v", 0.1),
    ("current_a", 0.01),
    ("bus_v", 0.1),
    ("temperature_c", 0.1),
    ("inputs", 1),
    ("outputs", 1),
)


def decode(read: Callable[[int], int]) -> dict[str, Any]:
    """The record in words: ``faults`` (newest first, 0 = none), ``at_fault`` and ``at_previous`` (the state at the
    current and the previous fault, in Hz, V, A, degC and terminal bit masks), from ``read`` of each cell."""

    def context(cells: tuple[int, ...]) -> dict[str, float | int]:
        out: dict[str, float | int] = {}
        for (key, scale), cell in zip(CONTEXT_KEYS, cells, strict=True):
            raw = read(cell)
            if key == "temperature_c" and raw >= 0x8000:
                raw -= 0x10000  # signed, as 300CH
            out[key] = raw if scale == 1 else round(raw * scale, 2)
        return out

    return {
        "faults": [read(cell) for cell in FAULT_TYPES],
        "at_fault": context(CURRENT_CONTEXT),
        "at_previous": context(PREVIOUS_CONTEXT),
    }


def shifted(stored: Mapping[int, int], code: int, read: Callable[[int], int]) -> dict[int, int]:
    """The record's cells after a trip with ``code``: ``read`` gives each context register's value now."""
    new: dict[int, int] = {FAULT_TYPES[0]: code & 0xFFFF}
    for older, newer in zip(FAULT_TYPES[1:], FAULT_TYPES[:-1], strict=True):
        new[older] = stored[newer]
    for previous, current, register in zip(PREVIOUS_CONTEXT, CURRENT_CONTEXT, CONTEXT, strict=True):
        new[previous] = stored[current]
        new[current] = read(register) & 0xFFFF
    return new

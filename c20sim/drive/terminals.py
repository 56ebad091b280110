"""The terminal bit map: the one place that says which bit is which terminal.

The sheet gives 200AH (virtual inputs, 9 bits) and 300DH (input terminal
status), 200BH (virtual outputs, 4 bits) and 300EH (output terminal status),
but not what each bit means. This map is **assumed**, after the terminals a
field project uses on a C20-400HR (FWD, REV, CLR) and the INVT family's
terminal functions; correct it here from a real drive. The effective inputs
(300DH) are the physical inputs ORed with the virtual ones (200AH); the
outputs (300EH) are the drive's own ORed with the virtual ones (200BH).
"""

from __future__ import annotations

import enum

__all__ = ["Input", "Output", "multi_speed_index"]


class Input(enum.IntFlag):
    """Input terminals, bits of 200AH, 300DH and the physical inputs (assumed)."""

    FWD = 0x001  #: run forward (level; terminal run channel)
    REV = 0x002  #: run reverse (level; terminal run channel)
    CLR = 0x004  #: fault reset (rising edge; any run channel)
    EF = 0x008  #: external fault (level; trips while set)
    S1 = 0x010  #: multi-segment speed select, bit 0
    S2 = 0x020  #: multi-segment speed select, bit 1
    S3 = 0x040  #: multi-segment speed select, bit 2
    JOGF = 0x080  #: jog forward (level; terminal run channel)
    JOGR = 0x100  #: jog reverse (level; terminal run channel)


class Output(enum.IntFlag):
    """Output terminals, bits of 300EH and 200BH (assumed)."""

    RUN = 0x1  #: the inverter drives the motor
    FAULT = 0x2  #: a fault is latched
    Y3 = 0x4  #: free: set only through 200BH
    Y4 = 0x8  #: free: set only through 200BH


def multi_speed_index(inputs: int) -> int:
    """Which multi-segment speed (0-7) the S1-S3 inputs select."""
    return (inputs >> 4) & 0b111

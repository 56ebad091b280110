"""The wall clock, for the records the line stamps on its own clock.

Every port stamps frames with the monotonic clock (the event loop's time,
``time.monotonic``, ``perf_counter``: CLOCK_MONOTONIC on Linux), which never
jumps but means nothing to a person. :data:`WALL_OFFSET` turns it into Unix
time for the frame log and the stream (``wall``); taken once, at import, so
a wall-clock jump later (NTP) does not reorder the log.
"""

from __future__ import annotations

import time

__all__ = ["WALL_OFFSET"]

#: Unix time minus the monotonic clock.
WALL_OFFSET = time.time() - time.monotonic()
